"""The ADMM loop of Algorithm 1 (paper Eq. 16), for the methods ``moju``, ``sdg`` and ``bmm``.

:func:`run` sets up a :class:`~moju_core.loop.loop_state.LoopState` and repeats :func:`iterate`,
one pass of the algorithm's steps, until the :class:`~moju_core.loop.stopping.StoppingTest` (or
the caller's hook) ends it. Each step is a function of the state, named after what it updates:

1. :func:`shape_update` (S, by the data term of :mod:`moju_core.loop.data_terms`, with
   :func:`refit_rotations` when the loop refines the cameras);
2, 4-9. the local-group steps of :mod:`moju_core.loop.grouping_steps`;
10. :func:`low_rank_update` (S#); 11. :func:`aux_update` (Z);
12. :func:`multiplier_update` (L1, L2), then the data term's residual;
13-15. :func:`increase_penalty` and the stopping test.

A further step is one more such function, called at its place in :func:`iterate`: it reads
and updates the state's arrays (in group order; a step that reorders the points goes through
:meth:`~moju_core.loop.loop_state.LoopState.permute`, and a new point-indexed array of the state
is added there), and what the parameters fix for the whole loop goes into
:class:`~moju_core.loop.loop_state.LoopSettings` (filled once by
:func:`~moju_core.loop.loop_state.loop_settings`). A step on the trajectories after the local
reconstruction goes right after step 9 (:func:`moju_core.loop.grouping_steps.reconstruct_groups`).

The state is kept in per-frame form ``(F, 3, P)``; its two rearrangements are free reshapes:
trajectory form ``S`` (3F x P, row ``3f + c`` is coordinate c of frame f) and shape form
``S#`` (F x 3P, row f is ``[X_f, Y_f, Z_f]``). Point-indexed arrays are kept permuted into
group order, so every local group is a contiguous column block; ``order`` maps the columns
back to the input's points (the paper's ordering vector ``P``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from moju_core.cameras import projection as camera
from moju_core.cameras.refinement import fit_rotations_to_shapes
from moju_core.defaults import ROTATION_REFINE_RHO
from moju_core.loop import clustering, grouping_steps, lrr
from moju_core.loop.data_terms import DataTerm
from moju_core.loop.loop_state import (
    GroupCoefficients,
    LoopSettings,
    LoopState,
    initial_state,
    loop_settings,
    permute_points,
)
from moju_core.loop.stopping import StoppingTest, loop_tolerance
from moju_core.params import SolverParams
from moju_core.priors import temporal_prior
from moju_core.result import StopReason, TrajectoryBasisFit

#: Called once per iteration with (iteration, gap, rho); returning True stops the loop.
IterationHook = Callable[[int, float, float], bool]


@dataclass(frozen=True)
class LoopCameras:
    """The cameras a loop starts from.

    Attributes
    ----------
    rotations : ndarray of shape (F, 2, 3)
        Rows orthonormal.
    refine : bool
        Whether the loop re-fits them to the shapes (approximate rotations).
    """

    rotations: np.ndarray
    refine: bool = False


#: The per-iteration diagnostics of :attr:`LoopOutput.history`, in the order of iterate().
HISTORY_KEYS = (
    "gap",
    "gap_shape",
    "gap_coefficients",
    "rho",
    "reprojection",
    "nuclear_norm",
    "relabelled",
)


@dataclass
class LoopOutput:
    """What :func:`run` returns: the loop's internal output, which
    :func:`moju_core.reconstruct` turns into the public :class:`moju_core.result.Result`.

    Attributes
    ----------
    shapes : ndarray of shape (F, 3, P)
        Per-frame shapes in the input's point order, in the units of the tracks.
    rotations : ndarray of shape (F, 2, 3)
        The rotations at the end (refined or as given).
    labels : ndarray of shape (P,), int64
        Group of every point (input order).
    history : dict of str to ndarray of shape (n_iter,)
        Per-iteration diagnostics, keys :data:`HISTORY_KEYS` (see
        :class:`moju_core.result.Result`).
    n_iter : int
        Iterations run.
    stop_reason : StopReason
        Why the loop ended; :attr:`StopReason.STOPPED <moju_core.result.StopReason.STOPPED>`
        when the hook asked it to.
    n_groups : int
        Local groups at the end.
    label_changes : int
        Trajectories moved between groups, summed over the regroupings.
    trajectory_basis : TrajectoryBasisFit or None
        Method ``"pta"`` only (built by the solver, not by :func:`run`).
    exact_fit : bool
        Whether the loop fitted the tracks exactly (its tolerance then
        :func:`moju_core.loop.stopping.loop_tolerance`).
    """

    shapes: np.ndarray
    rotations: np.ndarray
    labels: np.ndarray
    history: dict[str, np.ndarray]
    n_iter: int
    stop_reason: StopReason
    n_groups: int = 1
    label_changes: int = 0
    trajectory_basis: TrajectoryBasisFit | None = None
    exact_fit: bool = False


def run(
    tracks: np.ndarray,
    cameras: LoopCameras,
    params: SolverParams,
    term: DataTerm,
    *,
    features: np.ndarray | None = None,
    hook: IterationHook | None = None,
) -> LoopOutput:
    """Run Algorithm 1 on scale-normalised, centred tracks.

    Parameters
    ----------
    tracks : ndarray of shape (F, 2, P)
        Centred, scale-normalised measurements (``W`` per frame); for a masked input, the
        hidden entries at their completion (the start uses them, the data term does not).
    cameras : LoopCameras
        The rotations (F, 2, 3) to start from, and whether the loop refines them: while
        ``rho < ROTATION_REFINE_RHO`` every iteration fits them to the current low-rank shapes
        (:func:`moju_core.cameras.refinement.fit_rotations_to_shapes`), for approximate
        rotations (the windowed estimate).
    params : SolverParams
        Fully resolved parameters (:func:`moju_core.defaults.resolve`), ``smoothness`` and
        ``free_mean_shape`` included.
    term : DataTerm
        The data term of the S-update and the entries it fits
        (:func:`moju_core.loop.data_terms.choose_term`).
    features : ndarray of shape (P, c), optional
        Track coordinates used for the initial k-means++ groups and the spatial neighbour
        graph (:func:`moju_core.loop.clustering.track_features`); computed when omitted.
    hook : callable, optional
        ``hook(iteration, gap, rho) -> bool``; True stops the loop
        (``stop_reason=StopReason.STOPPED``).

    Returns
    -------
    LoopOutput
        ``stop_reason`` is ``STOPPED`` also when the data term said the fit went astray
        (:meth:`~moju_core.loop.data_terms.DataTerm.gone_astray`), for a caller that then
        solves another way.
    """
    n_frames, _, n_points = tracks.shape
    settings = loop_settings(params, n_frames, n_points)
    # S = S# = pinv(R) W, the zero-depth start: from the tracks as given, i.e. with the
    # hidden entries of a masked input at their completion (moju_core.completion.missing).
    state = initial_state(tracks, cameras.rotations, params.rho, term.observed, term.measured)
    term.start(state)
    if settings.local:
        initial_groups(state, settings, features)
    group_lrr = GroupCoefficients.initial(state.n_groups, n_frames, params.low_dim, params.seed)
    stopping = StoppingTest(loop_tolerance(params.tol, term.exact), params.rho_max)
    history: dict[str, list[float]] = {key: [] for key in HISTORY_KEYS}
    stop_reason, iteration = StopReason.MAX_ITER, 0
    for iteration in range(1, params.max_iter + 1):
        diagnostics = iterate(state, group_lrr, settings, term, cameras.refine, iteration)
        for key in HISTORY_KEYS:
            history[key].append(diagnostics[key])
        if hook is not None and hook(iteration, diagnostics["gap"], state.rho):
            stop_reason = StopReason.STOPPED
            break
        if term.gone_astray(state, iteration):
            stop_reason = StopReason.STOPPED
            break
        reason = stopping(diagnostics["gap_shape"], state.grouping_settled, state.rho)
        if reason is not None:
            stop_reason = reason
            break
        increase_penalty(state, params)

    inverse = state.inverse_order()
    return LoopOutput(
        shapes=permute_points(state.shapes, inverse),
        rotations=state.rotations,
        labels=state.labels[inverse],
        history={key: np.asarray(values) for key, values in history.items()},
        n_iter=iteration,
        stop_reason=stop_reason,
        n_groups=state.n_groups,
        label_changes=state.label_changes,
        exact_fit=term.exact,
    )


def initial_groups(state: LoopState, settings: LoopSettings, features: np.ndarray | None) -> None:
    """The initial local groups (k-means++ on the track features), the state put in their order.

    ``features`` of shape (P, c) are computed from the (masked) tracks when None.
    """
    n_frames, n_points, params = state.n_frames, state.n_points, settings.params
    if features is None:
        features = clustering.track_features(state.tracks.reshape(2 * n_frames, n_points))
    labels = clustering.initial_labels(features, params.n_groups, settings.min_size, params.seed)
    state.labels, state.features = labels, features
    state.n_groups = int(labels.max()) + 1
    state.permute(np.argsort(labels, kind="stable"))


def iterate(
    state: LoopState,
    group_lrr: GroupCoefficients,
    settings: LoopSettings,
    term: DataTerm,
    refine_rotations: bool,
    iteration: int,
) -> dict[str, float]:
    """One iteration of Algorithm 1 (steps 1-12) on the state, in place.

    Parameters
    ----------
    state : LoopState
    group_lrr : GroupCoefficients
        The LRR variables (used with the adaptive grouping only).
    settings : LoopSettings
    term : DataTerm
        The S-update's data term.
    refine_rotations : bool
        Whether the rotations are re-fitted to the shapes while ``rho`` is small.
    iteration : int
        1 for the first iteration.

    Returns
    -------
    dict of str to float
        This iteration's diagnostics, one value per :data:`HISTORY_KEYS` entry.
    """
    params = settings.params
    term.prepare(state, iteration)
    shape_update(state, settings, term)  # 1
    if refine_rotations and iteration > 1 and state.rho < ROTATION_REFINE_RHO:
        refit_rotations(state)
    relabelled = 0
    if settings.local:
        # The first iteration always regroups, so the bases exist before they are tracked.
        regroup_now = (iteration - 1) % params.regroup_every == 0
        if regroup_now:
            grouping_steps.fit_group_subspaces(state, params.subspace_dim)  # 2
            if settings.adaptive:
                grouping_steps.update_kernel(state, group_lrr, settings)  # 4-6
        if settings.adaptive:
            grouping_steps.update_coefficients(group_lrr, params.beta1, state.rho)  # 7
        if regroup_now and settings.adaptive and params.n_clusters < state.n_groups:
            relabelled = grouping_steps.move_trajectories(state, group_lrr, settings)  # 8
        grouping_steps.reconstruct_groups(state, regroup_now)  # 9
    nuclear = low_rank_update(state, settings, term, settings.kept_at(iteration))  # 10
    if settings.adaptive:
        aux_update(group_lrr, params.beta3, state.rho)  # 11
    gap_shape, gap_coefficients = multiplier_update(
        state, group_lrr if settings.adaptive else None
    )  # 12
    reprojection = term.residual(state)
    return {
        "gap": max(gap_shape, gap_coefficients),
        "gap_shape": gap_shape,
        "gap_coefficients": gap_coefficients,
        "rho": state.rho,
        "reprojection": reprojection,
        "nuclear_norm": nuclear,
        "relabelled": float(relabelled),
    }


def shape_update(state: LoopState, settings: LoopSettings, term: DataTerm) -> None:
    """Step 1, the S-update: data term plus the coupling ``rho/2 ||S - (S# + L1/rho)||^2``.

    The data term's own step (:mod:`moju_core.loop.data_terms`), in place on ``state.shapes``.
    """
    np.add(state.sharp, state.scaled, out=state.work)
    target = state.work.reshape(state.n_frames, 3, state.n_points)
    term.shape_step(state, settings.prior, target)


def refit_rotations(state: LoopState) -> None:
    """Alternate: the rotations that best project the current low-rank shapes S#.

    :func:`moju_core.cameras.refinement.fit_rotations_to_shapes` (hidden entries of the tracks
    at the shapes' projection); the data term's right-hand side and viewing directions follow.
    """
    low_rank = state.sharp.reshape(state.n_frames, 3, state.n_points)
    seen = (
        state.tracks
        if state.observed is None
        else camera.fill_unobserved(state.rotations, state.tracks, low_rank, state.observed)
    )
    state.rotations = fit_rotations_to_shapes(state.rotations, seen, low_rank)
    state.back_projected = camera.back_project(state.rotations, state.tracks)
    state.depth_pull = None
    state.normals = camera.viewing_directions(state.rotations)


def low_rank_update(state: LoopState, settings: LoopSettings, term: DataTerm, keep: int) -> float:
    """Step 10, the S#-update: singular value thresholding of ``f(S) - L1/rho`` by beta2/rho,
    with the ``keep`` leading values left unshrunk.

    Followed by the temporal prior's filter on the frames, unless the S-update solved it
    (:mod:`moju_core.priors.temporal_prior`). In place on ``state.sharp``.

    Returns
    -------
    float
        The nuclear norm of the new S#.
    """
    params, rho = settings.params, state.rho
    np.subtract(state.shape_form, state.scaled, out=state.work)
    smoothing = (
        None
        if settings.prior is None or term.solves_prior
        else temporal_prior.smoothing_filter(settings.prior, rho)
    )
    _, nuclear = lrr.singular_value_threshold(
        state.work,
        params.beta2 / rho,
        out=state.sharp,
        keep=keep,
        left=smoothing,
        warm=state.svt_warm,
    )
    return nuclear


def aux_update(group_lrr: GroupCoefficients, beta3: float, rho: float) -> None:
    """Step 11, the Z-update: singular value thresholding of ``C + L2/rho`` by beta3/rho."""
    group_lrr.aux, _ = lrr.singular_value_threshold(
        group_lrr.coefficients + group_lrr.multiplier / rho, beta3 / rho
    )


def multiplier_update(state: LoopState, group_lrr: GroupCoefficients | None) -> tuple[float, float]:
    """Step 12: ``L1 += rho (S# - f(S))`` (scaled: ``scaled += S# - f(S)``), ``L2 += rho (C - Z)``.

    Parameters
    ----------
    state : LoopState
    group_lrr : GroupCoefficients or None
        None without the adaptive grouping (no C, Z).

    Returns
    -------
    gap_shape : float
        ``max|S# - f(S)|``.
    gap_coefficients : float
        ``max|C - Z|``, 0 without the adaptive grouping.
    """
    residual_shape = np.subtract(state.sharp, state.shape_form, out=state.work)
    state.scaled += residual_shape  # in units of the current rho
    gap_shape = float(max(residual_shape.max(), -residual_shape.min()))
    if group_lrr is None:
        return gap_shape, 0.0
    residual_coefficients = group_lrr.coefficients - group_lrr.aux
    group_lrr.multiplier += state.rho * residual_coefficients
    return gap_shape, float(np.abs(residual_coefficients).max())


def increase_penalty(state: LoopState, params: SolverParams) -> None:
    """Steps 13-14: ``rho <- min(rho_max, c rho)``, the scaled multiplier rescaled to match."""
    next_rho = min(params.rho_max, params.rho_growth * state.rho)
    state.scaled *= state.rho / next_rho
    state.rho = next_rho
