"""What the solver returns and what it reports while it runs."""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np

from moju_core.params import SolverParams


class Stage(StrEnum):
    """Stage of a solve in :attr:`Progress.stage`, in the order they happen.

    A ``str``: ``Stage.ITERATING == "iterating"``, and it is written as its value.
    ``TRACKING`` is reported for video inputs only, by the tracker before the solve; the
    others by :func:`moju_core.reconstruct`.
    """

    TRACKING = "tracking"
    VALIDATING = "validating"
    ROTATIONS = "rotations"
    INITIALISING = "initialising"
    ITERATING = "iterating"
    FINISHING = "finishing"


class StopReason(StrEnum):
    """Why the loop stopped, :attr:`Result.stop_reason`.

    A ``str``: ``StopReason.CONVERGED == "converged"``, and result files store its value.
    """

    CONVERGED = "converged"
    RHO_MAX = "rho_max"
    MAX_ITER = "max_iter"


@dataclass(frozen=True)
class Progress:
    """One progress report handed to the ``callback`` of :func:`moju_core.reconstruct`.

    ``stage`` is a :class:`Stage` (a str: ``"validating"``, ``"rotations"``,
    ``"initialising"``, ``"iterating"``, ``"finishing"``; a plain string is converted).
    ``gap`` is the ADMM primal gap of Algorithm 1 step 15 (``nan`` before the loop starts).
    ``fraction`` is an estimate in [0, 1] of the work done, ``elapsed`` and ``eta`` are
    seconds (``eta`` is ``None`` when unknown).
    """

    stage: Stage
    iteration: int
    max_iter: int
    gap: float
    rho: float
    fraction: float
    elapsed: float
    eta: float | None

    def __post_init__(self) -> None:
        object.__setattr__(self, "stage", Stage(self.stage))


@dataclass(repr=False)
class Result:
    """Reconstruction of one sequence.

    Attributes
    ----------
    shapes : ndarray of shape (F, P, 3), float64
        Per-frame 3D points in the units of the input tracks, each frame centred.
    rotations : ndarray of shape (F, 2, 3), float64
        Per-frame camera rotations (rows orthonormal) used by the solver.
    labels : ndarray of shape (P,), int64
        Local group of every point after the last regrouping.
    history : dict of str to ndarray of shape (n_iter,)
        Per-iteration ``gap``, ``rho``, ``gap_shape``, ``gap_coefficients``,
        ``reprojection`` (RMS reprojection error, input units), ``nuclear_norm`` and
        ``relabelled`` (number of points that changed group).
    timings : dict of str to float
        Seconds spent per stage (``rotations``, ``initialise``, ``iterate``, ``total``).
    params : SolverParams
        The parameters actually used, with every data-derived default filled in.
    n_iter : int
        Number of ADMM iterations run.
    stop_reason : StopReason
        A str (a plain string is converted): ``"converged"`` (shape gap below ``tol``, or
        stalled below 1e-8, with the grouping settled; see docs/solver.md), ``"rho_max"`` or
        ``"max_iter"``.
    scale : float
        The factor the tracks were divided by before solving (RMS of the centred tracks).
    extras : dict of str to object
        Method-specific by-products (not stored in result files).
    visibility : ndarray of shape (F, P), bool, or None
        The observations used: True where point ``j`` was observed in frame ``f``. ``shapes``
        holds every point in every frame; where this is False, the solver filled it in. All
        True for complete data; None only for results built without it (result files then
        store all True).
    """

    shapes: np.ndarray
    rotations: np.ndarray
    labels: np.ndarray
    history: dict[str, np.ndarray]
    timings: dict[str, float]
    params: SolverParams
    n_iter: int
    stop_reason: StopReason
    scale: float
    extras: dict[str, object] = field(default_factory=dict)
    visibility: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.stop_reason = StopReason(self.stop_reason)

    def __repr__(self) -> str:
        """Sizes and a few scalars, never the arrays (those are the attributes)."""
        n_frames, n_points = self.shapes.shape[:2]
        observed = 1.0 if self.visibility is None else float(np.mean(self.visibility))
        total = self.timings.get("total")
        seconds = "" if total is None else f", seconds={total:.3g}"
        return (
            f"Result(frames={n_frames}, points={n_points}, method={self.params.method!r}, "
            f"rotations={self.params.rotations!r}, n_iter={self.n_iter}, "
            f"stop_reason={self.stop_reason.value!r}, n_groups={self.params.n_groups}, "
            f"observed={observed:.3g}, scale={self.scale:.4g}{seconds})"
        )

    @property
    def converged(self) -> bool:
        """True when the loop stopped because the gap fell below ``tol``."""
        return self.stop_reason is StopReason.CONVERGED
