"""What the solver returns and what it reports while it runs.

:class:`Result` is the one result type: :func:`moju_core.reconstruct` returns it,
:func:`moju_core.io.write_result` stores it and :func:`moju_core.io.read_result` reads it
back. Its by-products that are neither shapes nor cameras are the typed, frozen
:class:`Diagnostics`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from enum import StrEnum
from typing import Any, Literal, get_args

import numpy as np

from moju_core.params import SolverParams
from moju_core.solve_plan import SolvePlan

#: How the rotations of a solve were obtained: supplied (``"known"``) or estimated by one of
#: the methods of :func:`moju_core.cameras.estimate_cameras` (``"auto"`` resolves to one).
RotationSource = Literal["known", "intersection", "windowed", "rigid", "plane"]


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

    A ``str``: ``StopReason.CONVERGED == "converged"``, and result files store its value. A
    result holds ``"converged"``, ``"rho_max"`` or ``"max_iter"``; ``"stopped"`` (the loop's
    hook asked it to stop) is reported by the internal loop only, since
    :func:`moju_core.reconstruct` raises :class:`~moju_core.errors.Cancelled` instead.
    """

    CONVERGED = "converged"
    RHO_MAX = "rho_max"
    MAX_ITER = "max_iter"
    STOPPED = "stopped"


#: The stop reasons a :class:`Result` can hold (not :attr:`StopReason.STOPPED`).
RESULT_STOP_REASONS = (StopReason.CONVERGED, StopReason.RHO_MAX, StopReason.MAX_ITER)


@dataclass(frozen=True)
class Progress:
    """One progress report handed to the ``callback`` of :func:`moju_core.reconstruct`.

    ``stage`` is a :class:`Stage` (a str: ``"validating"``, ``"rotations"``,
    ``"initialising"``, ``"iterating"``, ``"finishing"``; a plain string is converted).
    ``gap`` is the ADMM primal gap of Algorithm 1 step 15 (``nan`` before the loop starts).
    ``fraction`` is an estimate in [0, 1] of the work done, ``elapsed`` and ``eta`` are
    seconds (``eta`` is ``None`` when unknown). ``iteration`` counts the iterations of every
    loop the solve has run: when a masked exact fit is solved again softly, the second loop's
    count continues from the first's (and may exceed ``max_iter``), and ``fraction`` never
    goes back.
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


@dataclass(frozen=True)
class RotationRigidity:
    """How rigid the tracks look over every three frames under each candidate's rotations.

    Each value is :func:`moju_core.cameras.windowed.short_time_rigidity` (unexplained energy
    over the energy of all three-frame windows, dimensionless in [0, 1]) minus the part the
    estimated noise explains, floored at 0. ``rotations="auto"`` keeps the windowed rotations
    when theirs is far below the intersection method's (docs/solver.md).
    """

    intersection: float
    windowed: float


@dataclass(frozen=True)
class TrajectoryBasisFit:
    """Conditioning of the single least-squares solve of method ``"pta"``.

    ``rank`` is the numerical rank of the system matrix of :func:`moju_core.pta.solve` (at
    most 3k, k = ``trajectory_bases``); ``condition`` the ratio of its largest to its smallest
    singular value (``inf`` when rank deficient).
    """

    rank: int
    condition: float


@dataclass(frozen=True)
class Diagnostics:
    """By-products of a solve that are neither shapes nor cameras, :attr:`Result.diagnostics`.

    Attributes
    ----------
    n_groups_used : int
        Local groups at the end of the loop (1 for ``"bmm"`` and ``"pta"``); below
        ``params.n_groups`` when a regrouping merged groups.
    rotation_source : {"known", "intersection", "windowed", "rigid", "plane"}
        Where the rotations came from: supplied, or the estimator that produced them (what
        ``rotations="auto"`` chose); ``"rigid"`` also when the intersection method fell back
        to the rigid rotations.
    rotation_window : int or None
        Frames per window of the windowed estimate, when it was computed; else None.
    rotations_refined : bool
        Whether the loop re-fitted the rotations to the shapes (windowed rotations, methods
        other than ``"pta"``).
    rotation_rigidity : RotationRigidity or None
        The comparison ``rotations="auto"`` made between its candidates; None when it made
        none.
    noise_variance : float
        Variance of white noise in the track coordinates estimated from the spectrum of W, in
        squared input units (e.g. pixels^2); 0 for noise-free low-rank tracks.
    observed_fraction : float
        Fraction of the F x P (frame, point) entries that were observed, in (0, 1].
    smoothness_trials : tuple of (float, float)
        The temporal-prior weights tried when ``smoothness`` was chosen from the data, in
        increasing order, each with its misfit (mean squared reprojection error over the mean
        square of the projected tracks, dimensionless); empty when it was not chosen.
    trajectory_basis : TrajectoryBasisFit or None
        Method ``"pta"`` only: the conditioning of its solve.
    signal_fit : bool
        Whether the loop fitted noisy tracks exactly after projecting them onto their signal
        subspace (:mod:`moju_core.priors.signal_fit`; with missing data, the completed tracks,
        every entry); ``smoothness_trials`` are then the trials on the projected tracks.
    completion_rank : int or None
        With missing data, the rank of the low-rank model of W the hidden entries were
        completed from (:func:`moju_core.completion.missing.complete`); None when nothing was
        missing.
    exact_completion : bool
        Whether W was found exactly of that rank
        (:func:`moju_core.completion.exact_model.exact_model`): the
        cameras and the fit then treat the trusted hidden entries as measured.
    completion_unexplained : float or None
        With missing data and a completion that is not exact, the held-out error its rank
        leaves beyond the noise, relative to rank one's
        (:attr:`moju_core.completion.missing.RankChoice.unexplained`). Above
        :data:`moju_core.completion.missing.MAX_UNEXPLAINED` (an articulated body's markers) no
        hidden
        entry is fitted as data. None otherwise.
    exact_fit : bool
        Whether the loop fitted the tracks exactly (noise-free tracks, or the signal fit's
        projection). It then stops once the shape gap is below
        :func:`moju_core.loop.stopping.loop_tolerance` (``EXACT_GAP_PRECISION``, 1e-5, when
        ``params.tol`` is smaller): below it the gap is rounding.
    plan : SolvePlan or None
        Every decision the solver took from the data (:mod:`moju_core.solve_plan`); None for
        results built without it and for files written before it was stored.
    """

    n_groups_used: int
    rotation_source: RotationSource
    rotation_window: int | None = None
    rotations_refined: bool = False
    rotation_rigidity: RotationRigidity | None = None
    noise_variance: float = 0.0
    observed_fraction: float = 1.0
    smoothness_trials: tuple[tuple[float, float], ...] = ()
    trajectory_basis: TrajectoryBasisFit | None = None
    signal_fit: bool = False
    completion_rank: int | None = None
    exact_completion: bool = False
    completion_unexplained: float | None = None
    exact_fit: bool = False
    plan: SolvePlan | None = None

    def __post_init__(self) -> None:
        if self.rotation_source not in get_args(RotationSource):
            raise ValueError(
                f"rotation_source is {self.rotation_source!r}; expected one of "
                f"{', '.join(get_args(RotationSource))}"
            )
        trials = tuple((float(w), float(m)) for w, m in self.smoothness_trials)
        object.__setattr__(self, "smoothness_trials", trials)

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready dict (nested dataclasses as dicts, tuples as lists once dumped)."""
        return asdict(self)

    @classmethod
    def from_dict(cls, values: Mapping[str, Any]) -> Diagnostics:
        """The inverse of :meth:`to_dict`; keys this version does not know are ignored.

        Raises
        ------
        TypeError, ValueError
            When a field without a default is missing or a value has the wrong form.
        """
        known = {name: values[name] for name in cls.__dataclass_fields__ if name in values}
        rigidity = known.get("rotation_rigidity")
        if rigidity is not None:
            known["rotation_rigidity"] = RotationRigidity(**rigidity)
        fit = known.get("trajectory_basis")
        if fit is not None:
            known["trajectory_basis"] = TrajectoryBasisFit(**fit)
        plan = known.get("plan")
        if plan is not None:
            known["plan"] = SolvePlan(**plan)
        return cls(**known)


def _running_version() -> str:
    from moju_core import __version__  # moju_core/__init__.py imports this module

    return __version__


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
    diagnostics : Diagnostics or None
        By-products of the solve (groups used, where the rotations came from, noise, ...).
        None for results built without them and for files written before they were stored.
    visibility : ndarray of shape (F, P), bool, or None
        The observations used: True where point ``j`` was observed in frame ``f``. ``shapes``
        holds every point in every frame; where this is False, the solver filled it in. All
        True for complete data; None only for results built without it (result files then
        store all True) and for files written before it was stored.
    version : str
        The moju version that computed the result (for a result read from a file: that wrote
        the file).
    metadata : dict of str to object
        What the caller stored with the result (:func:`moju_core.io.write_result`'s
        ``metadata``: job id, input name, ...); empty for a fresh solve.
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
    diagnostics: Diagnostics | None = None
    visibility: np.ndarray | None = None
    version: str = field(default_factory=_running_version)
    metadata: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.stop_reason = StopReason(self.stop_reason)
        if self.stop_reason not in RESULT_STOP_REASONS:
            raise ValueError(f"a Result cannot have stop_reason {self.stop_reason.value!r}")

    @property
    def n_frames(self) -> int:
        """Number of frames F."""
        return int(self.shapes.shape[0])

    @property
    def n_points(self) -> int:
        """Number of points P."""
        return int(self.shapes.shape[1])

    def __repr__(self) -> str:
        """Sizes and a few scalars, never the arrays (those are the attributes)."""
        n_frames, n_points = self.n_frames, self.n_points
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
    def final_shape_gap(self) -> float | None:
        """The shape gap ``||S# - f(S)||_inf`` of the last iteration (``history["gap_shape"]``),
        the quantity the stopping test compares with ``tol``; None without iterations."""
        gaps = self.history.get("gap_shape")
        return float(gaps[-1]) if gaps is not None and len(gaps) else None

    @property
    def exact_fit(self) -> bool:
        """Whether the loop fitted the tracks exactly (:attr:`Diagnostics.exact_fit`)."""
        return self.diagnostics is not None and self.diagnostics.exact_fit

    @property
    def converged(self) -> bool:
        """True when the loop stopped because the gap fell below ``tol``."""
        return self.stop_reason is StopReason.CONVERGED
