"""Whether a solve can work on F frames and P points, and roughly how much memory it needs.

These checks compare parameters with the sizes of the input only; the data itself (rank,
noise, observations) is judged by the solver. The solver, the CLI, the HTTP API (before a job
is queued) and the worker (before a job runs) all call these functions, so a refusal reads
the same everywhere. Each ``check_*`` function raises
:class:`moju_core.errors.MeasurementError` (or :class:`~moju_core.errors.MeasurementTooLarge`
for memory) with a message that says what to change.
"""

from __future__ import annotations

import math

import numpy as np

from moju_core import defaults
from moju_core.errors import MeasurementError, MeasurementTooLarge
from moju_core.params import SolverParams, rotation_method

__all__ = [
    "MIN_ESTIMATION_FRAMES",
    "check_fit",
    "check_group_sizes",
    "check_memory",
    "check_n_bases",
    "check_rotation_frames",
    "check_subspace_dim",
    "check_trajectory_bases",
    "describe_bytes",
    "estimate_memory_bytes",
    "memory_problem",
    "min_frames_for_bases",
]

#: Fewest frames from which orthographic camera rotations can be estimated: three views fix a
#: rigid Euclidean reconstruction (and ``min_frames_for_bases(1) == 3``).
MIN_ESTIMATION_FRAMES = 3

#: Byte units of the memory estimate and its message.
_MIB = 2**20
_GIB = 2**30
#: Bytes of float64 the solver keeps per (frame, point) pair; see :func:`estimate_memory_bytes`.
_SOLVER_BYTES_PER_FRAME_POINT = (8 * 3 + 4 * 2) * 8
#: Interpreter, numpy/scipy/scikit-learn and the small per-group matrices.
_SOLVER_BASE_BYTES = 128 * _MIB


def min_frames_for_bases(n_bases: int) -> int:
    """Fewest frames for which the intersection constraints can determine ``Q``.

    ``Q`` (3K x 3K, symmetric) has ``3K (3K + 1) / 2`` unknowns and, noise-free, a solution
    space of dimension ``2K^2 - K`` (Akhter et al., "In defense of orthonormality
    constraints", CVPR 2009; Dai et al. 2012). Every frame gives two equations, so at least
    ``(5K^2 + 5K) / 4`` frames are needed. For K = 1 this is 3: the classic requirement of
    three orthographic views for a rigid Euclidean reconstruction.

    Parameters
    ----------
    n_bases : int
        Number of shape bases K >= 1.

    Returns
    -------
    int
        ``ceil(5 K (K + 1) / 4)``.
    """
    return math.ceil(5 * n_bases * (n_bases + 1) / 4)


def check_rotation_frames(n_frames: int) -> None:
    """Refuse to estimate camera rotations from fewer than three frames."""
    if n_frames < MIN_ESTIMATION_FRAMES:
        raise MeasurementError(
            f"estimating the camera rotations needs at least {MIN_ESTIMATION_FRAMES} frames "
            f"(orthographic views), got {n_frames}; send more frames, or give the rotations "
            "R (F x 2 x 3) and use rotations 'known'"
        )


def check_n_bases(n_bases: int, n_frames: int, n_points: int) -> None:
    """Refuse a number of shape bases K that W (2F x P) is too small to factorise at rank 3K.

    Raises
    ------
    ValueError
        If ``n_bases`` is not a positive integer.
    MeasurementError
        If F is below :func:`min_frames_for_bases` or P below ``3K + 1``.
    """
    if isinstance(n_bases, bool) or not isinstance(n_bases, (int, np.integer)) or n_bases < 1:
        raise ValueError(f"n_bases must be a positive integer, got {n_bases!r}")
    needed_frames = min_frames_for_bases(n_bases)
    if n_frames < needed_frames:
        raise MeasurementError(
            f"n_bases={n_bases} needs at least {needed_frames} frames to determine the "
            f"rotations, got {n_frames}; use fewer shape bases (or leave n_bases unset) or "
            "more frames"
        )
    # Centred columns sum to zero, so W has rank at most P - 1.
    if n_points < 3 * n_bases + 1:
        raise MeasurementError(
            f"n_bases={n_bases} needs a rank-{3 * n_bases} factorisation of W and so at least "
            f"{3 * n_bases + 1} tracked points, got {n_points}; use fewer shape bases (or "
            "leave n_bases unset) or more points"
        )


def check_subspace_dim(subspace_dim: int, n_frames: int) -> None:
    """Refuse a local subspace dimension p that is not below the trajectory length 3F."""
    trajectory_length = 3 * n_frames
    if subspace_dim >= trajectory_length:
        raise MeasurementError(
            f"subspace_dim={subspace_dim} must be smaller than the length of a 3D "
            f"trajectory, 3F = {trajectory_length} for {n_frames} frames. Lower subspace_dim "
            "or leave it unset"
        )


def check_group_sizes(n_groups: int, subspace_dim: int, n_points: int) -> None:
    """Refuse a group count whose groups (each at least ``min_group_size(p)``) the points
    cannot fill."""
    if n_groups <= 1:
        return
    group = defaults.min_group_size(subspace_dim)
    if n_groups * group > n_points:
        raise MeasurementError(
            f"n_groups={n_groups} needs at least {n_groups * group} points (groups of at "
            f"least {group} for subspace_dim={subspace_dim}); the input has {n_points}. "
            "Lower n_groups or leave it unset to derive it from the data"
        )


def check_trajectory_bases(trajectory_bases: int, n_frames: int) -> None:
    """Refuse a PTA basis with more unknowns per point (3k) than equations (2F)."""
    if 3 * trajectory_bases > 2 * n_frames:
        raise MeasurementError(
            f"trajectory_bases={trajectory_bases} needs 3k <= 2F, i.e. at least "
            f"{-(-3 * trajectory_bases // 2)} frames; the input has {n_frames}. Lower "
            f"trajectory_bases (at most {2 * n_frames // 3}) or leave it unset"
        )


def check_fit(params: SolverParams, n_frames: int, n_points: int, *, has_rotations: bool) -> None:
    """Refuse parameters that cannot work on F frames and P points.

    Parameters left unset (``None``) are judged by the default they will get when the default
    depends on the sizes only (``subspace_dim``); those derived from the data itself
    (``n_bases``, ``n_groups``, ``trajectory_bases``) are left to the solver, which checks
    them again once resolved.

    Parameters
    ----------
    params : SolverParams
        The parameters as given (unset fields allowed) or as resolved.
    n_frames, n_points : int
        F and P of the input.
    has_rotations : bool
        Whether camera rotations come with the input (see
        :func:`moju_core.params.rotation_method`).

    Raises
    ------
    MeasurementError
        With the first parameter that does not fit, and what to change.
    """
    method = rotation_method(params.rotations, has_rotations)
    if method != "known":
        check_rotation_frames(n_frames)
        if method in ("auto", "intersection") and params.n_bases is not None:
            check_n_bases(params.n_bases, n_frames, n_points)
    if params.method in ("moju", "sdg"):
        p = params.subspace_dim
        if p is None:
            p = min(defaults.SUBSPACE_DIM, 3 * n_frames - 1)
        else:
            check_subspace_dim(p, n_frames)
        if params.n_groups is not None:
            check_group_sizes(params.n_groups, p, n_points)
    if params.method == "pta" and params.trajectory_bases is not None:
        check_trajectory_bases(params.trajectory_bases, n_frames)


def estimate_memory_bytes(n_frames: int, n_points: int) -> int:
    """Rough peak memory of one reconstruction of F frames and P points, in bytes.

    The ADMM loop keeps about eight arrays of shape (3F, P) in float64 alive at once (the
    trajectories S, the shape matrix S#, the multiplier L1, the local reconstruction, the
    S-update's right-hand side and the temporaries of the SVT and of the regrouping), plus
    about four of shape (2F, P) (the input W, its centred and scaled copy, the reprojection and
    its residual). That is ``(8 * 3 + 4 * 2) * 8 = 256`` bytes per (frame, point) pair. The
    per-group matrices (3F x p) and the K_g x K_g graph are small next to these; a fixed
    128 MiB covers them and the interpreter with its numerical libraries.

    The estimate is meant for admission control (refusing a job that cannot fit), not for
    accounting; it errs on the high side.

    Parameters
    ----------
    n_frames : int
        Number of frames F (>= 0).
    n_points : int
        Number of points P (>= 0).

    Returns
    -------
    int
        ``256 * F * P + 128 MiB``.
    """
    if n_frames < 0 or n_points < 0:
        raise ValueError(
            f"n_frames and n_points must be >= 0, got n_frames={n_frames}, n_points={n_points}"
        )
    return _SOLVER_BYTES_PER_FRAME_POINT * int(n_frames) * int(n_points) + _SOLVER_BASE_BYTES


def describe_bytes(n_bytes: int) -> str:
    """A size for a message: MiB below one GiB, else GiB with one decimal."""
    if n_bytes < _GIB:
        return f"{n_bytes / _MIB:.0f} MiB"
    return f"{n_bytes / _GIB:.1f} GiB"


def memory_problem(
    n_frames: int, n_points: int, limit: int, *, limit_name: str = "the memory limit"
) -> str | None:
    """Why a solve of F frames and P points does not fit in ``limit`` bytes, or None if it does.

    ``limit_name`` names the setting that holds the limit, for the message (e.g. an
    environment variable).
    """
    needed = estimate_memory_bytes(n_frames, n_points)
    if needed <= limit:
        return None
    return (
        f"{n_frames} frames x {n_points} points would need about {describe_bytes(needed)} "
        f"to solve; the limit is {describe_bytes(limit)} per job ({limit_name}): subsample "
        "the points or frames"
    )


def check_memory(
    n_frames: int, n_points: int, limit: int, *, limit_name: str = "the memory limit"
) -> None:
    """Raise :class:`MeasurementTooLarge` with :func:`memory_problem`'s message, if any."""
    problem = memory_problem(n_frames, n_points, limit, limit_name=limit_name)
    if problem is not None:
        raise MeasurementTooLarge(problem)
