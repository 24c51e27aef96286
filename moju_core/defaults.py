"""Data-derived defaults: every ``None`` in :class:`SolverParams` gets a value from a rule here.

The rules read only the sizes of the problem (F frames, P points), for the number of shape
bases the singular values of the scale-normalised measurements and, for the PTA basis, the
camera rotations, so the solver needs no hand tuning. Each rule is written next to its reason;
every value can be overridden.
"""

from __future__ import annotations

import math

import numpy as np

from moju_core.params import SolverParams
from moju_core.pta import dct_basis, trajectory_system

#: Target number of trajectories per local group. Large enough that a group's rank-p
#: approximation is well determined (many more columns than p) and small enough that a group
#: covers a patch of surface that deforms nearly linearly.
POINTS_PER_GROUP = 150

#: Below this many groups there is no local structure to exploit: the solver runs the plain
#: nuclear-norm loop (``n_groups`` resolves to 1).
MIN_GROUPS = 4

#: Default subspace dimension p: a smooth surface patch's trajectories are close to an affine
#: function of its two surface coordinates (rank 3); one more dimension absorbs curvature.
SUBSPACE_DIM = 4

#: Upper bound of the default number of groups (the LRR step costs O(K^3)).
MAX_DEFAULT_GROUPS = 600

#: Weight of the nuclear norm relative to the largest singular value of the initial shape
#: matrix ``f(pinv(R) W)`` (scale free). The loop is a continuation: the S# step thresholds at
#: ``beta2 / rho``, 0.2 x the top singular value at rho = 1e-2, relaxed by c = 1.1 per
#: iteration; the depth emerges during that relaxation, so the start must not be much lower
#: (measurements: benchmarks/notes/2026-12-06-rule-ablation.md, "Moved from the code").
BETA2_RELATIVE = 2e-3


#: A regrouping that moves at most this fraction of the trajectories counts as settled for the
#: stopping rule: once the shapes have converged, trajectories on group boundaries keep swapping
#: between nearly equal subspaces, and waiting for none to move runs the loop to its cap.
SETTLED_MOVE_FRACTION = 1e-2
#: Shape gap that counts as converged once it stops falling (see ``STALL_ITERATIONS``): about
#: sqrt(machine epsilon), the relative precision of the S# step's SVD through the F x F Gram
#: matrix; on noisy tracks the gap stops falling there, above a ``tol`` of 1e-10.
GAP_PRECISION = 1e-8
#: Shape gap at which a loop that fits the tracks exactly
#: (:func:`moju_core.priors.temporal_prior.depth_step`) stops, whatever smaller ``tol`` was asked:
#: nothing is shrunk from S# once rho is large, its Gram-matrix SVD resolves the small singular
#: values only to about 1e-7, and e3D has settled long before the gap reaches that.
EXACT_GAP_PRECISION = 1e-5
#: Iterations without a new smallest shape gap after which a gap below ``GAP_PRECISION`` counts
#: as converged.
STALL_ITERATIONS = 10
#: Approximate (windowed) rotations are refined with the shapes in every iteration while rho is
#: below this (moju_core.loop.admm.run, ``refine_rotations``): by then the threshold beta2 / rho
#: is below 1e-5 of the top singular value and the shapes have settled.
ROTATION_REFINE_RHO = 1e3
#: Largest condition number of the PTA system accepted by the default basis size: errors in the
#: tracks may grow at most tenfold in the trajectory coefficients. Held-out check:
#: benchmarks/notes/2026-12-06-rule-ablation.md.
PTA_MAX_CONDITION = 10.0
#: Deformation bases the S# step may leave unshrunk (:func:`unshrunk_values`), and the PTA basis
#: size the cameras must support before it leaves out more than the mean shape. The nuclear
#: norm shrinks every deformation it penalises towards the zero-depth start, which flattens
#: large deformations; leaving the leading ones out lets the temporal prior give them depth,
#: but only where the cameras constrain depth (k >= 3 cosines). The cap rises to the basis
#: shapes the tracks show where they show more (:func:`shown_basis_shapes`). Held-out check and
#: guard: benchmarks/notes/2026-12-06-rule-ablation.md, tests/moju_core/test_solve_rules.py.
MAX_UNSHRUNK_VALUES = 4
MIN_DEPTH_BASIS = 3
#: Iterations the S# step shrinks all but the mean shape before it leaves out
#: ``unshrunk_values``: the convex problem of the first iterations fixes the depth the
#: unshrunk values then keep, which matters most where the loop also refines the cameras
#: (held-out check and guard: as for :data:`MAX_UNSHRUNK_VALUES`).
UNSHRINK_AFTER = 20
#: Estimated noise variance of the scale-normalised tracks (relative to their mean square, by
#: :func:`moju_core.spectrum.noise_variance`) up to which the loop fits complete tracks exactly
#: and lets the temporal prior set the depths only
#: (:func:`moju_core.priors.temporal_prior.depth_step`):
#: a noise of 0.3 % of the tracks' RMS. Noise-free synthetic tracks give 1e-15 to 3e-6, the
#: paper's noise protocol at lambda_g = 0.002 already 2.5e-5 to 9e-5 (and 6e-4 at 0.01); above it
#: the data term stays soft, since exact fits of noisy tracks put the noise into the depths.
EXACT_DATA_NOISE = 1e-5
#: Smallest temporal-prior weight taken to set the depth: with it exact tracks are fitted
#: exactly (:func:`moju_core.loop.loop_state.fits_exactly`) and noisy ones may take the signal
#: fit, both giving the depth to the prior, whose cut-off (near gamma^(-1/4) radians per
#: frame) must lie well below one.
MIN_DEPTH_PRIOR = 10.0


def min_group_size(p: int) -> int:
    """Smallest local group: twice the subspace dimension (the docs' ``>= 2p``), at least 8."""
    return max(2 * p, 8)


def trajectory_basis_size(rotations: np.ndarray, limit: int | None = None) -> int:
    """Default size k of the PTA trajectory basis (method ``pta``): the largest k whose system
    is well conditioned.

    PTA solves ``W = M A`` with ``M = R (Theta kron I_3)``
    (:func:`moju_core.pta.trajectory_system`); the condition number of M is the factor by
    which errors in the tracks (noise, and the part of the trajectories outside the basis) can
    grow in the coefficients. It rises quickly with k once the low cosines can imitate the
    camera's own motion (slow, smooth rotation), and without a bound the solve is useless: on
    face4 (one slow yaw cycle; 1,500 points, known rotations) k = 12 gives condition 1.5e6 and
    e3D 75. The rule takes the largest k with ``3k <= 2F`` whose condition stays below
    :data:`PTA_MAX_CONDITION`: k = 2 on face4 (condition 4, e3D 0.11), k = 6 on the sequences
    whose camera sweeps three times (face3, paper, cloth: e3D 0.010, 0.006, 0.030, the best k
    of each), k = 1-2 on the 10-frame faces.

    Parameters
    ----------
    rotations : ndarray of shape (F, 2, 3)
        Camera rotations the solve will use.
    limit : int, optional
        Stop at this size (the answer is then ``min(k, limit)``, at a fraction of the cost).

    Returns
    -------
    int
        k >= 1 (k = 1 is the rigid solution: one constant coefficient shape per point).
    """
    n_frames = rotations.shape[0]
    largest = min(n_frames, 2 * n_frames // 3)
    if limit is not None:
        largest = min(largest, limit)
    best = 1
    for size in range(2, largest + 1):
        singular = np.linalg.svd(
            trajectory_system(rotations, dct_basis(n_frames, size)), compute_uv=False
        )
        if singular[-1] * PTA_MAX_CONDITION < singular[0]:
            break  # the condition only grows with k: stop at the first failure
        best = size
    return best


def unshrunk_values(rotations: np.ndarray, signal_rank: int = 0) -> int:
    """Default number of leading singular values of S# the nuclear norm leaves out (moju, sdg).

    ``min(k, cap)`` when the cameras support a well-conditioned trajectory basis of
    k >= :data:`MIN_DEPTH_BASIS` cosines (:func:`trajectory_basis_size`: the camera turns
    enough, and often enough, for the depth of a few smooth deformations to be seen from the
    side), else 1 (the mean shape only). The cap is :data:`MAX_UNSHRUNK_VALUES`, or the number
    of basis shapes the tracks show when that is larger (:func:`shown_basis_shapes`).

    Parameters
    ----------
    rotations : ndarray of shape (F, 2, 3)
        Camera rotations the solve starts from.
    signal_rank : int, default 0
        Number of singular values of W above the noise
        (:func:`moju_core.spectrum.significant_rank`); 0: unknown.

    Returns
    -------
    int
        1 to ``max(MAX_UNSHRUNK_VALUES, shown_basis_shapes(signal_rank))``.
    """
    cap = max(MAX_UNSHRUNK_VALUES, shown_basis_shapes(signal_rank))
    k = trajectory_basis_size(rotations, limit=cap)
    return k if k >= MIN_DEPTH_BASIS else 1


def shown_basis_shapes(signal_rank: int) -> int:
    """The fewest basis shapes (mean shape included) that explain a W of this rank.

    A basis shape ``B`` (3 x P) adds the rows of ``R_f B`` to W, at most 3 to its rank, so K
    shapes give rank at most 3K: ``ceil(rank / 3)``. It is a lower bound. A shape that moves
    the points along one direction only (a sheet's bending) adds 1, so the true count may be
    up to ``rank - 2``.
    """
    return math.ceil(signal_rank / 3)


def _groups(params: SolverParams, n_points: int, p: int) -> tuple[int, int]:
    """Default numbers of local groups and of clusters of groups.

    Parameters
    ----------
    params : SolverParams
        User parameters (``method``, ``n_groups``, ``n_clusters``).
    n_points : int
        P.
    p : int
        Subspace dimension of a group (resolved).

    Returns
    -------
    n_groups : int
        1 for ``bmm`` and ``pta``; else the user's, or one group per :data:`POINTS_PER_GROUP`
        points (at most :data:`MAX_DEFAULT_GROUPS`; 1 below :data:`MIN_GROUPS`).
    n_clusters : int
        At most ``n_groups - 1`` when there are several groups.
    """
    if params.method in ("bmm", "pta"):
        n_groups = 1
    elif params.n_groups is not None:
        n_groups = params.n_groups
    else:
        n_groups = min(MAX_DEFAULT_GROUPS, n_points // POINTS_PER_GROUP)
        # Fewer points: smaller groups, but never below the minimum size.
        if n_groups < MIN_GROUPS:
            n_groups = min(MIN_GROUPS, n_points // (2 * min_group_size(p)))
        if n_groups < MIN_GROUPS:
            n_groups = 1
    n_clusters = params.n_clusters or max(2, n_groups // 8)
    if n_groups > 1:
        n_clusters = min(n_clusters, n_groups - 1)
    return n_groups, n_clusters


def _betas(params: SolverParams, p: int, top_singular_value: float) -> tuple[float, float, float]:
    """Default weights ``beta1``, ``beta2`` and ``beta3`` of the loop's objective.

    Parameters
    ----------
    params : SolverParams
        User parameters; the weights set there are kept.
    p : int
        Subspace dimension of a group (resolved).
    top_singular_value : float
        Largest singular value of the initial shape matrix ``S#`` (units of the
        scale-normalised tracks).

    Returns
    -------
    beta1, beta2, beta3 : float
        By default ``beta1`` 1, ``beta2`` :data:`BETA2_RELATIVE` times ``top_singular_value``
        (in its units) and ``beta3`` ``beta1 * p``.
    """
    beta2 = params.beta2 or BETA2_RELATIVE * top_singular_value
    beta1 = params.beta1 or 1.0
    # Keep kernel eigen-directions whose eigenvalue exceeds p / 2 (half the self-similarity of
    # one subspace): LRR with a Frobenius error term shrinks the kernel's eigenvalues gamma by
    # max(0, 1 - beta3 / (2 beta1 gamma)).
    beta3 = params.beta3 or beta1 * p
    return beta1, beta2, beta3


def _unshrunk(
    params: SolverParams,
    free_mean_shape: bool,
    rotations: np.ndarray | None,
    noise: float,
    signal_rank: int,
) -> int:
    """Default ``unshrunk_values`` (the user's when set).

    Parameters
    ----------
    params : SolverParams
    free_mean_shape : bool
        Resolved ``free_mean_shape``.
    rotations : ndarray of shape (F, 2, 3) or None
        Camera rotations (needed for ``moju`` and ``sdg`` with a free mean shape).
    noise : float
        Estimated noise variance of the scale-normalised tracks.
    signal_rank : int
        Number of singular values of W above the noise; 0: unknown.

    Returns
    -------
    int
        :func:`unshrunk_values` for the local models on quiet tracks, else 1 with a free mean
        shape and 0 without.
    """
    unshrunk = params.unshrunk_values
    if unshrunk is None:
        local_model = params.method in ("moju", "sdg") and free_mean_shape
        if local_model and rotations is None:
            raise ValueError("'moju' and 'sdg' need the rotations to derive unshrunk_values")
        quiet = noise <= EXACT_DATA_NOISE
        unshrunk = (
            unshrunk_values(rotations, signal_rank)
            if local_model and quiet
            else int(bool(free_mean_shape))
        )
    return unshrunk


def _trajectory_bases(params: SolverParams, rotations: np.ndarray | None) -> int | None:
    """Default ``trajectory_bases``: :func:`trajectory_basis_size` for method ``pta`` when
    unset, else the user's value (``None`` for the other methods).

    ``rotations`` (ndarray of shape (F, 2, 3)) is needed only in the first case.
    """
    trajectory_bases = params.trajectory_bases
    if params.method == "pta" and trajectory_bases is None:
        if rotations is None:
            raise ValueError("method 'pta' needs the rotations to derive trajectory_bases")
        trajectory_bases = trajectory_basis_size(rotations)
    return trajectory_bases


def resolve(
    params: SolverParams,
    n_frames: int,
    n_points: int,
    top_singular_value: float,
    *,
    rotations: np.ndarray | None = None,
    noise: float = 0.0,
    signal_rank: int = 0,
) -> SolverParams:
    """Fill in every data-derived default of ``params``.

    Parameters
    ----------
    params : SolverParams
        User parameters; fields set by the user are kept.
    n_frames, n_points : int
        F and P.
    top_singular_value : float
        Largest singular value of the initial shape matrix ``S# = f(pinv(R) W)`` of the
        scale-normalised tracks.
    rotations : ndarray of shape (F, 2, 3), optional
        Camera rotations; needed to derive ``trajectory_bases`` (method ``pta``) and
        ``unshrunk_values`` (methods ``moju`` and ``sdg``).
    noise : float, default 0.0
        Estimated noise variance of the scale-normalised tracks
        (:func:`moju_core.spectrum.noise_variance`). Above :data:`EXACT_DATA_NOISE` only the
        mean shape is left unshrunk: unshrunk values keep the noise in their subspace (with
        the paper's noise, lambda_g 0.01-0.055, face3 at 2,000 points lost 1-6 % of e3D).
    signal_rank : int, default 0
        Number of singular values of W above the noise, which can raise the cap of
        ``unshrunk_values`` (:func:`unshrunk_values`); 0: unknown.

    Returns
    -------
    SolverParams
        A copy with no ``None`` left among the solver's numeric fields (``n_bases`` is resolved
        by the rotation step and may stay ``None`` when rotations are known;
        ``trajectory_bases`` is resolved for method ``pta`` only; ``smoothness`` of ``moju``
        and ``sdg`` is chosen from the data by :func:`moju_core.priors.smoothness.choose_smoothness`
        when unset).
    """
    trajectory_length = 3 * n_frames
    p = params.subspace_dim or min(SUBSPACE_DIM, trajectory_length - 1)
    n_groups, n_clusters = _groups(params, n_points, p)
    d_low = params.low_dim or min(trajectory_length - 1, 2 * p + 2)
    d_low = max(d_low, p)
    beta1, beta2, beta3 = _betas(params, p, top_singular_value)
    # The deformation-only nuclear norm and the temporal prior are the project's additions to
    # the loop (docs/solver.md); bmm stays Dai et al.'s method unless asked otherwise. The
    # smoothness of moju and sdg is chosen from the data by moju_core.priors.smoothness and stays
    # None here.
    baseline = params.method in ("bmm", "pta")
    free_mean_shape = params.free_mean_shape
    if free_mean_shape is None:
        free_mean_shape = not baseline
    unshrunk = _unshrunk(params, free_mean_shape, rotations, noise, signal_rank)
    smoothness = params.smoothness
    if smoothness is None and baseline:
        smoothness = 0.0
    return params.model_copy(
        update={
            "trajectory_bases": _trajectory_bases(params, rotations),
            "subspace_dim": p,
            "n_groups": n_groups,
            "n_clusters": n_clusters,
            "low_dim": d_low,
            "beta1": beta1,
            "beta2": beta2,
            "beta3": beta3,
            "free_mean_shape": free_mean_shape,
            "unshrunk_values": unshrunk,
            "smoothness": smoothness,
        }
    )


def expected_iterations(params: SolverParams) -> int:
    """Iterations until rho reaches rho_max (the loop may stop earlier on the gap); 1 for
    ``pta``, which solves in closed form."""
    if params.method == "pta":
        return 1
    growth = math.log(max(params.rho_max / params.rho, 1.0)) / math.log(params.rho_growth)
    return max(1, min(params.max_iter, math.ceil(growth) + 1))
