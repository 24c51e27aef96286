"""Choosing the weight of the temporal smoothness prior from the data.

The prior (:mod:`moju_core.priors.temporal_prior`) helps where the camera turns fast compared with
the deformation (a frame's depth is seen by its neighbours) and harms where the shape changes
a lot from one frame to the next (ten frames of a changing facial expression): the right weight
depends on the sequence, and no sequence-independent value served both (measured on the
synthetic sequences, known rotations: face2 e3D 0.040 without the prior and 0.063 at weight 1;
the rolling sheet 0.071 without and 0.013 at weight 10).

The rule is a discrepancy principle on the signal part of the tracks. The tracks of a random
subset of the points are first projected onto the directions of W that stand above the noise
(the rank of :func:`moju_core.spectrum.significant_rank`), so that the trial solves see
neither noise nor the denoising that the local subspaces of the full solve provide. The loop is
run on them, and the largest weight of :data:`SMOOTHNESS_GRID` is kept whose reprojection
misfit exceeds the misfit without the prior by at most ``DEFORMATION_ALLOWANCE`` of their
non-rigid energy (the energy beyond their best rank-3, i.e. rigid, approximation): a prior that
explains away more of the deformation suppresses real motion. Being a fraction of the tracks'
own non-rigid energy, the bound depends neither on units nor on the number of points. The misfit
grows with the weight, so the largest allowed weight is found by bisection over the grid: four
trial solves instead of six.

Measured on the synthetic sequences (known rotations, no noise; excess misfit over the
non-rigid energy): the weights that lowered e3D cost 0.6-1.5 % of the non-rigid energy (face3
and face4 at 100, the sheet at 100, the cloth at 10), the ones that raised it 5-7 % or more (the
10-frame faces at 0.1, face3 and face4 at 1000, the cloth at 100); 2.5 % sits between. With
noise (3 %, the full solve) the weights chosen this way were as good as the best of the grid
to within 10 % of e3D, where a rule on the noisy tracks themselves let through weights that
smoothed the faces' expressions away.

Where the solve fits the tracks exactly (noise-free, complete tracks and fixed cameras:
:func:`moju_core.loop.loop_state.fits_exactly`), the weight
:data:`~moju_core.defaults.MIN_DEPTH_PRIOR`
that sets the depths there is allowed the larger excess :data:`EXACT_FIT_ALLOWANCE` when the
bisection settles below it. The trials fit softly, and their misfit counts the motion a prior
explains away; the exact fit keeps that motion, so the same weight then costs only a choice
of depths. Both allowances were checked on held-out seeds against a fixed weight and without
the exact-fit allowance (benchmarks/notes/2026-12-06-rule-ablation.md).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from moju_core.defaults import MIN_DEPTH_PRIOR
from moju_core.loop import admm
from moju_core.loop.data_terms import choose_term
from moju_core.params import SolverParams
from moju_core.spectrum import project_tracks

#: Weights tried, in increasing order (gamma relative to the data term of scale-normalised
#: tracks; the prior's cut-off is near gamma^(-1/4) radians per frame).
SMOOTHNESS_GRID = (0.0, 0.1, 1.0, 10.0, 100.0, 1000.0)
#: The prior may add this fraction of the tracks' non-rigid energy to the misfit.
DEFORMATION_ALLOWANCE = 0.025
#: The excess misfit allowed to :data:`~moju_core.defaults.MIN_DEPTH_PRIOR` when the solve will
#: fit the tracks exactly at that weight: the trials fit softly, where a prior explains away
#: part of the observed motion; the exact fit keeps all of it and the prior sets only the
#: depths, so the trials' misfit overstates the harm (held-out check and guard:
#: benchmarks/notes/2026-12-06-rule-ablation.md, tests/moju_core/priors/test_smoothness_rules.py).
EXACT_FIT_ALLOWANCE = 0.25
#: Points the trial solves use (a seeded random subset when there are more). The misfits are
#: means over F x 2 x 400 entries; on the synthetic sequences 400 and 1,000 points chose the
#: same weights.
SELECTION_POINTS = 400
#: Loop controls the trial solves take from the schema's defaults, not from the caller: the rule
#: was set with them, and a solve asked to run long (e.g. ``max_iter=10_000, rho_growth=1.0005``)
#: must not run its four trial solves that long too.
#: Frames the trial solves use: a contiguous run of this many from the middle of a longer
#: sequence. The weight is a property of how fast the shapes change from frame to frame
#: relative to the camera, which a stretch of the sequence shows as well as the whole; this
#: keeps the choice's cost independent of F.
SELECTION_FRAMES = 150
TRIAL_LOOP_CONTROL = {
    name: SolverParams.model_fields[name].default
    for name in ("max_iter", "tol", "rho", "rho_max", "rho_growth")
}


@dataclass(frozen=True)
class SmoothnessChoice:
    """The weights the trials allow, and the trials themselves.

    Attributes
    ----------
    weight : float
        The largest weight of :data:`SMOOTHNESS_GRID` within :data:`DEFORMATION_ALLOWANCE`:
        the weight of a loop that fits the tracks softly.
    exact_weight : float
        The weight of a loop that fits the tracks exactly
        (:func:`moju_core.loop.loop_state.fits_exactly`): ``weight``, or
        :data:`~moju_core.defaults.MIN_DEPTH_PRIOR` where ``weight`` is below it and that
        weight's excess misfit is within :data:`EXACT_FIT_ALLOWANCE`.
    trials : list of (float, float)
        The weights tried, in increasing order, and their mean squared reprojection error
        relative to the mean square of the (projected) tracks.
    """

    weight: float
    exact_weight: float
    trials: list[tuple[float, float]] = field(default_factory=list)


def choose_smoothness(
    tracks: np.ndarray,
    rotations: np.ndarray,
    params: SolverParams,
    signal_basis: np.ndarray,
    *,
    refine_rotations: bool = False,
    hook: admm.IterationHook | None = None,
    observed: np.ndarray | None = None,
) -> SmoothnessChoice:
    """The largest weights of :data:`SMOOTHNESS_GRID` whose misfit the tracks allow, for a
    soft and for an exact fit (one set of trial solves serves both).

    Parameters
    ----------
    tracks : ndarray of shape (F, 2, P)
        Centred, scale-normalised tracks.
    rotations : ndarray of shape (F, 2, 3)
        The rotations the solve will start from.
    params : SolverParams
        Resolved parameters (``smoothness`` is ignored); the trial solves use one local group
        (groups of the subset's size would not represent the full solve's) and the default
        loop controls (:data:`TRIAL_LOOP_CONTROL`).
    signal_basis : ndarray of shape (2F, r)
        Orthonormal left singular vectors of W for its r singular values above the noise.
    refine_rotations : bool, default False
        Whether the solve refines the rotations (the trial solves then do too).
    hook : callable, optional
        Passed to every trial solve (:func:`moju_core.loop.admm.run`): the solver reports
        progress and honours cancellation through it.
    observed : ndarray of shape (F, P), bool, optional
        Where the points are observed (None: all). The trial solves then fit the observed
        entries only, so that the completion of the hidden ones (``tracks`` holds it there)
        does not count as misfit.

    Returns
    -------
    SmoothnessChoice
        All weights 0 and no trials when there are fewer than 3 frames or no signal.
    """
    n_frames, _, n_points = tracks.shape
    if n_frames < 3 or signal_basis.shape[1] == 0:
        return SmoothnessChoice(0.0, 0.0)  # no second differences, or nothing above the noise
    if n_points > SELECTION_POINTS:
        rng = np.random.default_rng(params.seed)
        chosen = np.sort(rng.choice(n_points, SELECTION_POINTS, replace=False))
        tracks = tracks[:, :, chosen]
        if observed is not None:
            observed = observed[:, chosen]
    signal = project_tracks(tracks, signal_basis).reshape(2 * n_frames, -1)
    if n_frames > SELECTION_FRAMES:
        first = (n_frames - SELECTION_FRAMES) // 2
        signal = signal[2 * first : 2 * (first + SELECTION_FRAMES)]
        rotations = rotations[first : first + SELECTION_FRAMES]
        if observed is not None:
            observed = observed[first : first + SELECTION_FRAMES]
        n_frames = SELECTION_FRAMES
    energy = float(np.mean(signal**2))
    deformation = non_rigid_energy(np.linalg.svd(signal, compute_uv=False))
    allowed_excess = DEFORMATION_ALLOWANCE * deformation
    signal_tracks = np.ascontiguousarray(signal.reshape(n_frames, 2, -1))
    trials: list[tuple[float, float]] = []

    def misfit(weight: float) -> float:
        trial = params.model_copy(
            update={"smoothness": weight, "n_groups": 1, **TRIAL_LOOP_CONTROL}
        )
        term = choose_term(
            n_frames, signal_tracks.shape[2], observed, banded_prior=refine_rotations and weight > 0
        )
        out = admm.run(
            signal_tracks, admm.LoopCameras(rotations, refine_rotations), trial, term, hook=hook
        )
        value = float(out.history["reprojection"][-1] ** 2) / energy
        trials.append((weight, value))
        return value

    unsmoothed = misfit(SMOOTHNESS_GRID[0])
    allowed = unsmoothed + allowed_excess
    # Bisection for the last allowed weight: accepted[low] holds, rejected[high] (or the end).
    low, high = 0, len(SMOOTHNESS_GRID)
    while high - low > 1:
        middle = (low + high) // 2
        if misfit(SMOOTHNESS_GRID[middle]) <= allowed:
            low = middle
        else:
            high = middle
    chosen = exact = SMOOTHNESS_GRID[low]
    if chosen < MIN_DEPTH_PRIOR:
        # The bisection's first trial is the grid's middle, MIN_DEPTH_PRIOR: no new solve.
        tried = dict(trials)
        depth_misfit = (
            tried[MIN_DEPTH_PRIOR] if MIN_DEPTH_PRIOR in tried else misfit(MIN_DEPTH_PRIOR)
        )
        if depth_misfit - unsmoothed <= EXACT_FIT_ALLOWANCE * deformation:
            exact = MIN_DEPTH_PRIOR
    return SmoothnessChoice(chosen, exact, sorted(trials))


def non_rigid_energy(singular_values: np.ndarray) -> float:
    """Fraction of a measurement matrix's energy beyond its best rank-3 approximation.

    Parameters
    ----------
    singular_values : ndarray
        Singular values of the centred tracks W (2F x P), decreasing.

    Returns
    -------
    float
        ``sum_{i > 3} s_i^2 / sum_i s_i^2``: 0 for a rigid object seen without noise.
    """
    squared = np.asarray(singular_values, dtype=np.float64) ** 2
    total = float(squared.sum())
    return float(squared[3:].sum()) / total if total > 0 else 0.0
