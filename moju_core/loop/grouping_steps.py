"""The local-group steps of Algorithm 1 (2 and 4-9) on the loop's state.

Each function is one step (or a fused pair), reads and updates a
:class:`~moju_core.loop.loop_state.LoopState` (and, for the adaptive grouping, a
:class:`~moju_core.loop.loop_state.GroupCoefficients`) and is called by
:func:`moju_core.loop.admm.iterate` when the step runs: steps 2 and 4-6 and 8 at regroupings
(every ``regroup_every`` iterations, the first included), step 7 every iteration of the
adaptive grouping, step 9 every iteration with local groups.
"""

from __future__ import annotations

import numpy as np

from moju_core.loop import clustering, grassmann, jump, lrr
from moju_core.loop.loop_state import GroupCoefficients, LoopSettings, LoopState

#: With hidden entries, step 9 fits each partly seen point in its group's subspace from its
#: values before the projection (after it the fit would return the projection unchanged),
#: with its hidden frames weighted :data:`GROUP_FILL_HIDDEN_WEIGHT` against 1 for the seen ones.
GROUP_FILL_FROM_UNPROJECTED = True
#: Small against a seen frame's 1: the hidden values (held by the data and temporal steps)
#: steer the fit of a point whose track ended, without outweighing what was seen.
GROUP_FILL_HIDDEN_WEIGHT = 0.1


def fit_group_subspaces(state: LoopState, p: int) -> None:
    """Step 2: the Grassmann point of every group, ``state.bases`` of shape (K, 3F, p).

    Exact at the first call, one refinement step from the previous bases afterwards
    (:func:`moju_core.loop.grassmann.group_subspaces`).
    """
    state.bases, _ = grassmann.group_subspaces(
        state.trajectories, state.bounds, p, previous=state.bases
    )


def update_kernel(state: LoopState, group_lrr: GroupCoefficients, settings: LoopSettings) -> None:
    """Steps 4-6: similarity graph of neighbouring groups, jump, kernel Gamma.

    The graph links each group to its ``params.n_neighbors`` spatially nearest ones (centroids of
    the track features). ``moju`` jumps the Grassmann points to the low-dimensional manifold
    (:func:`moju_core.loop.jump.jump`, which updates Delta) and takes the projection kernel
    there; ``sdg`` takes the kernel of the high-dimensional points themselves. A tiny ridge
    (1e-10 of the mean diagonal) keeps Gamma positive definite.
    """
    bounds, bases, n_groups = state.bounds, state.bases, state.n_groups
    params = settings.params
    centroids = np.add.reduceat(state.features, bounds[:-1], axis=0) / np.diff(bounds)[:, None]
    edges = clustering.neighbour_edges(centroids, params.n_neighbors)
    weights = clustering.similarity_graph(bases, edges)
    if params.method == "moju":
        group_lrr.delta, thetas = jump.jump(group_lrr.delta, bases, weights)
        gamma = grassmann.projection_kernel(thetas)
    else:
        gamma = grassmann.projection_kernel(bases)
    gamma = gamma + 1e-10 * np.trace(gamma) / n_groups * np.eye(n_groups)
    group_lrr.kernel = lrr.kernel_eigh(gamma)


def update_coefficients(group_lrr: GroupCoefficients, beta1: float, rho: float) -> None:
    """Step 7: the LRR coefficients C, with the kernel of the last regrouping."""
    group_lrr.coefficients = lrr.coefficient_step(
        group_lrr.kernel, group_lrr.aux, group_lrr.multiplier, beta1, rho
    )


def move_trajectories(
    state: LoopState, group_lrr: GroupCoefficients, settings: LoopSettings
) -> int:
    """Step 8: cluster the Grassmann points by C, move trajectories between groups.

    When any trajectory moves, the state is re-permuted into the new groups
    (:meth:`~moju_core.loop.loop_state.LoopState.permute`) and the bases refined from the old
    ones (the groups changed by a few members). Sets ``state.grouping_settled`` (at most
    ``settings.settled_moves`` trajectories moved) and adds to ``state.label_changes``.

    Returns
    -------
    int
        Number of trajectories that moved.
    """
    params = settings.params
    group_clusters = clustering.cluster_groups(
        group_lrr.coefficients, params.n_clusters, params.seed
    )
    new_labels = clustering.regroup(
        state.trajectories, state.labels, state.bases, group_clusters, settings.min_size
    )
    relabelled = int(np.count_nonzero(new_labels != state.labels))
    if relabelled:
        state.labels = new_labels
        state.permute(np.argsort(new_labels, kind="stable"))
        p = state.bases.shape[2]
        state.bases, _ = grassmann.group_subspaces(
            state.trajectories, state.bounds, p, previous=state.bases
        )
    state.label_changes += relabelled
    state.grouping_settled = relabelled <= settings.settled_moves
    return relabelled


def reconstruct_groups(state: LoopState, regrouped: bool) -> None:
    """Step 9: every trajectory replaced by its projection on its group's subspace.

    After a regrouping the projection uses the bases just fitted; between regroupings steps
    2 and 9 are fused (:func:`moju_core.loop.grassmann.track_and_project`: each basis tracked by
    one orthogonal-iteration step, then projected on). A point with hidden frames is then
    fitted on its observed frames only, and its group's subspace carries it through the
    hidden ones (:func:`moju_core.loop.grassmann.project_observed`). In place on ``state.shapes``.
    """
    trajectories = state.trajectories
    source = None
    if state.observed is not None and GROUP_FILL_FROM_UNPROJECTED:
        source = trajectories[:, ~state.observed.all(axis=0)].copy()
    if regrouped:
        grassmann.project_groups(trajectories, state.bounds, state.bases, out=trajectories)
    else:
        state.bases = grassmann.track_and_project(trajectories, state.bounds, state.bases)
    if state.observed is not None:
        grassmann.project_observed(
            trajectories,
            state.bounds,
            state.bases,
            state.observed,
            source=source,
            hidden_weight=GROUP_FILL_HIDDEN_WEIGHT if source is not None else 0.0,
        )
