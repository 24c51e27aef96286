"""The ADMM loop of Algorithm 1 (paper Eq. 16), for the methods ``moju``, ``sdg`` and ``bmm``.

:func:`run` sets up a :class:`~moju_core.loop.loop_state.LoopState` and repeats :func:`iterate`,
one pass of the algorithm's steps, until the :class:`~moju_core.loop.stopping.StoppingTest` (or
the caller's hook) ends it. Each step is a function of the state, named after what it updates:

1. :func:`shape_update` (S, with :func:`refit_rotations` when the loop refines the cameras);
2, 4-9. the local-group steps of :mod:`moju_core.loop.grouping_steps`;
10. :func:`low_rank_update` (S#); 11. :func:`aux_update` (Z);
12. :func:`multiplier_update` (L1, L2), then :func:`reprojection_error`;
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
from moju_core.loop.loop_state import (
    GroupCoefficients,
    LoopSettings,
    LoopState,
    flat,
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
#: ``abandon(shapes) -> bool``: whether the loop has gone astray, given the shapes (F, 3, P) in
#: the loop's point order; :func:`run` asks every :data:`ABANDON_CHECK_EVERY` iterations.
AbandonTest = Callable[[np.ndarray], bool]
#: Iterations between two :data:`AbandonTest` calls: a diverging masked exact fit grows about
#: twofold per iteration (face3, 2,000 points, the closing occlusion, seed 92), so a check every
#: ten iterations finds it within a few tens of iterations at a small cost.
ABANDON_CHECK_EVERY = 10

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
    rotations: np.ndarray,
    params: SolverParams,
    *,
    features: np.ndarray | None = None,
    hook: IterationHook | None = None,
    refine_rotations: bool = False,
    observed: np.ndarray | None = None,
    exact_data: bool = False,
    measured: np.ndarray | None = None,
    abandon: AbandonTest | None = None,
) -> LoopOutput:
    """Run Algorithm 1 on scale-normalised, centred tracks with given rotations.

    Parameters
    ----------
    tracks : ndarray of shape (F, 2, P)
        Centred, scale-normalised measurements (``W`` per frame).
    rotations : ndarray of shape (F, 2, 3)
        Camera rotations (rows orthonormal).
    params : SolverParams
        Fully resolved parameters (:func:`moju_core.defaults.resolve`), ``smoothness`` and
        ``free_mean_shape`` included.
    features : ndarray of shape (P, c), optional
        Track coordinates used for the initial k-means++ groups and the spatial neighbour
        graph (:func:`moju_core.loop.clustering.track_features`); computed when omitted.
    hook : callable, optional
        ``hook(iteration, gap, rho) -> bool``; True stops the loop
        (``stop_reason=StopReason.STOPPED``).
    refine_rotations : bool, default False
        Refine the rotations with the shapes: while ``rho < ROTATION_REFINE_RHO``, every
        iteration fits them to the current low-rank shapes ``S#``
        (:func:`moju_core.cameras.refinement.fit_rotations_to_shapes`), an alternating minimisation
        of the data term over R. For approximate rotations (the windowed estimate).
    observed : ndarray of shape (F, P), bool, optional
        Where the points are observed; the data term runs over these entries only (the
        tracks' values elsewhere are not used). None: all observed.
    exact_data : bool, default False
        With the temporal prior on and fixed cameras (``refine_rotations`` false), fit the
        tracks exactly and let the prior set the depths only
        (:func:`moju_core.priors.temporal_prior.depth_step`): for tracks without measurable noise.
    measured : ndarray of shape (F, P), bool, optional
        With ``exact_data`` and hidden entries: the entries fitted exactly (the observed
        ones); the other entries of ``observed`` are fitted softly
        (:func:`moju_core.priors.temporal_prior.masked_depth_step`).
    abandon : callable, optional
        :data:`AbandonTest`, asked every :data:`ABANDON_CHECK_EVERY` iterations: True stops
        the loop (``StopReason.STOPPED``) with the shapes as they are, for a caller that then
        solves another way.

    Returns
    -------
    LoopOutput
    """
    n_frames, _, n_points = tracks.shape
    settings = loop_settings(
        params, n_frames, n_points, observed, refine_rotations, exact_data=exact_data
    )
    # S = S# = pinv(R) W, the zero-depth start: from the tracks as given, i.e. with the
    # hidden entries of a masked input at their completion (moju_core.completion.missing).
    state = initial_state(tracks, rotations, params.rho, observed, measured)
    if settings.local:
        initial_groups(state, settings, features)
    group_lrr = GroupCoefficients.initial(state.n_groups, n_frames, params.low_dim, params.seed)
    stopping = StoppingTest(loop_tolerance(params.tol, settings.exact_data), params.rho_max)
    history: dict[str, list[float]] = {key: [] for key in HISTORY_KEYS}
    stop_reason, iteration = StopReason.MAX_ITER, 0
    for iteration in range(1, params.max_iter + 1):
        diagnostics = iterate(state, group_lrr, settings, iteration)
        for key in HISTORY_KEYS:
            history[key].append(diagnostics[key])
        if hook is not None and hook(iteration, diagnostics["gap"], state.rho):
            stop_reason = StopReason.STOPPED
            break
        if abandon is not None and iteration % ABANDON_CHECK_EVERY == 0 and abandon(state.shapes):
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
        exact_fit=settings.exact_data,
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
    state: LoopState, group_lrr: GroupCoefficients, settings: LoopSettings, iteration: int
) -> dict[str, float]:
    """One iteration of Algorithm 1 (steps 1-12) on the state, in place.

    Parameters
    ----------
    state : LoopState
    group_lrr : GroupCoefficients
        The LRR variables (used with the adaptive grouping only).
    settings : LoopSettings
    iteration : int
        1 for the first iteration.

    Returns
    -------
    dict of str to float
        This iteration's diagnostics, one value per :data:`HISTORY_KEYS` entry.
    """
    params = settings.params
    shape_update(state, settings)  # 1
    if settings.refine_rotations and iteration > 1 and state.rho < ROTATION_REFINE_RHO:
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
    nuclear = low_rank_update(state, settings, settings.kept_at(iteration))  # 10
    if settings.adaptive:
        aux_update(group_lrr, params.beta3, state.rho)  # 11
    gap_shape, gap_coefficients = multiplier_update(
        state, group_lrr if settings.adaptive else None
    )  # 12
    reprojection = reprojection_error(state, settings)
    return {
        "gap": max(gap_shape, gap_coefficients),
        "gap_shape": gap_shape,
        "gap_coefficients": gap_coefficients,
        "rho": state.rho,
        "reprojection": reprojection,
        "nuclear_norm": nuclear,
        "relabelled": float(relabelled),
    }


def shape_update(state: LoopState, settings: LoopSettings) -> None:
    """Step 1, the S-update: data term plus the coupling ``rho/2 ||S - (S# + L1/rho)||^2``.

    Per frame and point a 3 x 3 solve (:func:`moju_core.cameras.projection.data_step`),
    over the observed entries only; or, with the exact temporal prior, a banded solve over
    the frames (:func:`moju_core.priors.temporal_prior.smooth_data_step`), which needs every entry:
    the
    unobserved ones then take the current shapes' projection (a majoriser of the masked data
    term, :func:`moju_core.cameras.projection.fill_unobserved`). Tracks without noise are
    fitted exactly: the depth step (:func:`moju_core.priors.temporal_prior.depth_step`), with hidden
    entries placed in the image first (:func:`~moju_core.priors.temporal_prior.masked_depth_step`).
    In place on ``state.shapes``.
    """
    n_frames, n_points = state.n_frames, state.n_points
    np.add(state.sharp, state.scaled, out=state.work)
    target = state.work.reshape(n_frames, 3, n_points)
    if settings.exact_data:
        if state.depth_pull is None:
            state.depth_pull = temporal_prior.depth_pull(
                state.back_projected, state.normals, settings.prior
            )
        if state.measured is None:
            temporal_prior.depth_step(
                state.back_projected,
                state.normals,
                target,
                state.rho,
                settings.prior,
                state.shapes,
                pull=state.depth_pull,
            )
        else:
            hidden = ~state.measured
            temporal_prior.masked_depth_step(
                state.back_projected,
                state.measured,
                hidden if state.observed is None else hidden & state.observed,
                state.normals,
                target,
                state.rho,
                settings.prior,
                state.shapes,
                pull=state.depth_pull,
            )
    elif settings.exact_prior:
        if state.observed is not None:
            filled = camera.fill_unobserved(
                state.rotations, state.tracks, state.shapes, state.observed
            )
            state.back_projected = camera.back_project(state.rotations, filled)
        temporal_prior.smooth_data_step(
            state.back_projected, state.normals, target, state.rho, settings.prior, state.shapes
        )
    else:
        camera.data_step(
            state.back_projected,
            state.normals,
            target,
            state.rho,
            out=state.shapes,
            observed=state.observed,
        )


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


def low_rank_update(state: LoopState, settings: LoopSettings, keep: int) -> float:
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
        if settings.prior is None or settings.exact_prior
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


def reprojection_error(state: LoopState, settings: LoopSettings) -> float:
    """RMS of ``R S - W`` over the observed entries (in the tracks' units).

    With a visibility mask and the soft data term the per-frame translation is an unknown of
    the masked data term too: the mean residual of each frame's observed points is moved into
    the tracks (and the data term's right-hand side is recomputed). Into every entry: no step
    reads the tracks at an unobserved entry (the soft and exact-prior steps mask or fill
    them), so moving them too changes nothing and saves indexing them.

    An exact fit has no such unknown: moving a frame's translation by ``t`` and its shape by
    ``-R_f^T t`` leaves every residual as it is, and the depth step refits the measured
    entries to any translation, so a refit would only shift the frame by the soft entries'
    mean residual again at every iteration (under the closing occlusion still about 1e-4 of
    the tracks' scale per iteration when the loop ends, on face3 and face4). The translation
    of the completion stays.
    """
    reprojection = camera.project(state.rotations, state.shapes, out=state.reprojection)
    reprojection -= state.tracks
    if state.observed is None:
        return float(np.sqrt(np.vdot(reprojection, reprojection) / (2 * settings.n_observed)))
    # Zeroed at the few unobserved entries (cheaper than masking).
    flat(reprojection)[state.unobserved_entries()] = 0.0
    squared = float(np.vdot(reprojection, reprojection))
    if settings.exact_data:
        return float(np.sqrt(squared / (2 * settings.n_observed)))
    sums = reprojection.sum(axis=2)
    shift = sums / settings.frame_counts  # (F, 2), R S - W on average
    # Over the n_f observed entries of a frame, sum (r - shift)^2 = sum r^2 - shift * sum r:
    # no second pass over the residuals (they are not read after this).
    squared = max(squared - float(np.vdot(shift, sums)), 0.0)
    state.tracks += shift[:, :, None]
    # back_project is linear in the tracks: update it by the shift's back-projection.
    state.back_projected += np.einsum("fji,fj->fi", state.rotations, shift)[:, :, None]
    return float(np.sqrt(squared / (2 * settings.n_observed)))


def increase_penalty(state: LoopState, params: SolverParams) -> None:
    """Steps 13-14: ``rho <- min(rho_max, c rho)``, the scaled multiplier rescaled to match."""
    next_rho = min(params.rho_max, params.rho_growth * state.rho)
    state.scaled *= state.rho / next_rho
    state.rho = next_rho
