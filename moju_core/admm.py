"""The ADMM loop of Algorithm 1 (paper Eq. 16), for the methods ``moju``, ``sdg`` and ``bmm``.

State is kept in per-frame form ``(F, 3, P)``; its two rearrangements are free reshapes:
trajectory form ``S`` (3F x P, row ``3f + c`` is coordinate c of frame f) and shape form
``S#`` (F x 3P, row f is ``[X_f, Y_f, Z_f]``). Point-indexed arrays are kept permuted into
group order, so every local group is a contiguous column block; ``order`` maps the columns
back to the input's points (the paper's ordering vector ``P``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from moju_core import clustering, grassmann, jump, lrr, temporal_prior
from moju_core.cameras import projection as camera
from moju_core.cameras.refinement import fit_rotations_to_shapes
from moju_core.defaults import (
    GAP_PRECISION,
    ROTATION_REFINE_RHO,
    SETTLED_MOVE_FRACTION,
    STALL_ITERATIONS,
    min_group_size,
)
from moju_core.params import SolverParams

#: Called once per iteration with (iteration, gap, rho); returning True stops the loop.
IterationHook = Callable[[int, float, float], bool]


@dataclass
class LoopOutput:
    """What :func:`run` returns.

    shapes : ndarray of shape (F, 3, P) in the input's point order.
    labels : ndarray of shape (P,) group of every point (input order).
    history : per-iteration diagnostics (see :class:`moju_core.result.Result`).
    rotations : ndarray of shape (F, 2, 3), the rotations at the end (refined or as given).
    """

    shapes: np.ndarray
    rotations: np.ndarray
    labels: np.ndarray
    history: dict[str, np.ndarray]
    n_iter: int
    stop_reason: str
    label_changes: int = 0
    extras: dict[str, object] = field(default_factory=dict)


def _permute(points_last: np.ndarray, perm: np.ndarray) -> np.ndarray:
    """Reorder the last (point) axis into a new C-contiguous array.

    ``a[:, :, perm]`` would return a non-contiguous layout, and every later reshape of it to
    the trajectory or shape form would silently copy.
    """
    return np.take(points_last, perm, axis=-1)


def _bounds(sorted_labels: np.ndarray, n_groups: int) -> np.ndarray:
    return np.concatenate([[0], np.cumsum(np.bincount(sorted_labels, minlength=n_groups))])


def run(
    tracks: np.ndarray,
    rotations: np.ndarray,
    params: SolverParams,
    *,
    features: np.ndarray | None = None,
    hook: IterationHook | None = None,
    refine_rotations: bool = False,
    observed: np.ndarray | None = None,
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
        graph (:func:`moju_core.clustering.track_features`); computed when omitted.
    hook : callable, optional
        ``hook(iteration, gap, rho) -> bool``; True stops the loop (``stop_reason="stopped"``).
    refine_rotations : bool, default False
        Refine the rotations with the shapes: while ``rho < ROTATION_REFINE_RHO``, every
        iteration fits them to the current low-rank shapes ``S#``
        (:func:`moju_core.cameras.refinement.fit_rotations_to_shapes`), an alternating minimisation
        of the data term over R. For approximate rotations (the windowed estimate).
    observed : ndarray of shape (F, P), bool, optional
        Where the points are observed; the data term runs over these entries only (the
        tracks' values elsewhere are not used). None: all observed.

    Returns
    -------
    LoopOutput
    """
    n_frames, _, n_points = tracks.shape
    p = params.subspace_dim
    rng = np.random.default_rng(params.seed)
    local = params.method != "bmm" and params.n_groups > 1
    # grouping="fixed" (an ablation): the initial groups stay, steps 4-8 and the Z-update never
    # run; each group is still reconstructed on its own subspace (steps 2 and 9).
    adaptive = local and params.grouping == "adaptive"

    # S = pinv(R) W, the zero-depth start: from the tracks as given, i.e. with the hidden
    # entries of a masked input at their completion (moju_core.missing).
    start = camera.back_project(rotations, tracks)
    if observed is not None:
        # The unobserved entries carry no data: zero there, so that the S-update's right-hand
        # side uses the observed entries only.
        tracks = np.where(observed[:, None, :], tracks, 0.0)
    back_projected = camera.back_project(rotations, tracks)
    normals = camera.viewing_directions(rotations)
    prior = (
        temporal_prior.temporal_prior(n_frames, params.smoothness) if params.smoothness else None
    )
    # With fixed cameras the prior filters S# (cheap); when the loop re-fits the cameras to S#
    # it is solved exactly in the S-update (see moju_core.temporal_prior for the measurements).
    exact_prior = prior is not None and refine_rotations
    # The truncated nuclear norm: with free_mean_shape the top singular value is not shrunk.
    kept_values = 1 if params.free_mean_shape else 0
    shapes = start  # S = pinv(R) W
    sharp = shapes.reshape(n_frames, 3 * n_points).copy()  # S# = f(S)
    # The multiplier L1 is stored scaled, ``scaled = L1 / rho``: both places it enters (the
    # S-update target ``S# + L1/rho`` and the S#-step input ``f(S) - L1/rho``) need it so, and
    # its update becomes ``scaled <- (rho / rho_next) (scaled + S# - f(S))``.
    scaled = np.zeros_like(sharp)
    work = np.empty_like(sharp)
    rho = params.rho

    order = np.arange(n_points)
    labels = np.zeros(n_points, dtype=np.int64)
    if local:
        if features is None:
            features = clustering.track_features(tracks.reshape(2 * n_frames, n_points))
        labels = clustering.initial_labels(
            features, params.n_groups, min_group_size(p), params.seed
        )
        order = np.argsort(labels, kind="stable")
        labels = labels[order]
        back_projected = _permute(back_projected, order)
        tracks = _permute(tracks, order)
        if observed is not None:
            observed = _permute(observed, order)
        shapes = _permute(shapes, order)
        sharp = shapes.reshape(n_frames, 3 * n_points).copy()
        features = features[order]
    reprojection = np.empty_like(tracks)
    n_observed = n_frames * n_points if observed is None else int(observed.sum())
    frame_counts = None if observed is None else observed.sum(axis=1)[:, None].astype(float)
    n_groups = int(labels.max()) + 1
    bounds = _bounds(labels, n_groups)
    group_clusters = np.zeros(n_groups, dtype=np.int64)
    coefficients = np.zeros((n_groups, n_groups))  # C
    aux = np.zeros_like(coefficients)  # Z
    mult_coef = np.zeros_like(coefficients)  # L2
    kernel = lrr.kernel_eigh(np.zeros_like(coefficients))  # Gamma, set by the first regrouping
    bases = None
    d_low = min(params.low_dim, 3 * n_frames)
    delta = jump.initial_map(3 * n_frames, d_low, rng)
    clusters_enabled = adaptive and params.n_clusters < n_groups

    history: dict[str, list[float]] = {
        key: []
        for key in (
            "gap",
            "gap_shape",
            "gap_coefficients",
            "rho",
            "reprojection",
            "nuclear_norm",
            "relabelled",
        )
    }
    stop_reason = "max_iter"
    labels_stable = True
    settled_moves = int(SETTLED_MOVE_FRACTION * n_points)
    smallest_gap, since_smallest = np.inf, 0
    total_relabelled = 0
    iteration = 0
    for iteration in range(1, params.max_iter + 1):
        # Large arrays are updated in place (out=): allocating fresh (F, 3P) arrays every
        # iteration costs more in page faults than the arithmetic on them.
        # 1. S-update: data term + coupling to S#.
        np.add(sharp, scaled, out=work)
        target = work.reshape(n_frames, 3, n_points)
        if exact_prior:
            if observed is not None:
                # The banded solve needs every entry: the unobserved ones take the current
                # shapes' projection (a majoriser of the masked data term, camera.fill_unobserved).
                filled = camera.fill_unobserved(rotations, tracks, shapes, observed)
                back_projected = camera.back_project(rotations, filled)
            temporal_prior.smooth_data_step(back_projected, normals, target, rho, prior, shapes)
        else:
            camera.data_step(back_projected, normals, target, rho, out=shapes, observed=observed)
        if refine_rotations and iteration > 1 and rho < ROTATION_REFINE_RHO:
            # Alternate: the rotations that best project the current low-rank shapes.
            low_rank = sharp.reshape(n_frames, 3, n_points)
            seen = (
                tracks
                if observed is None
                else camera.fill_unobserved(rotations, tracks, low_rank, observed)
            )
            rotations = fit_rotations_to_shapes(rotations, seen, low_rank)
            back_projected = camera.back_project(rotations, tracks)
            normals = camera.viewing_directions(rotations)
        trajectories = shapes.reshape(3 * n_frames, n_points)
        relabelled = 0
        # The first iteration always regroups, so the bases exist before they are tracked.
        regroup_now = local and (iteration - 1) % params.regroup_every == 0
        if regroup_now:
            # 2. Grassmann points of the groups (exact at the start, warm-started afterwards).
            bases, _ = grassmann.group_subspaces(trajectories, bounds, p, previous=bases)
        if regroup_now and adaptive:
            # 4. Similarity graph over spatially neighbouring groups.
            centroids = np.add.reduceat(features, bounds[:-1], axis=0) / np.diff(bounds)[:, None]
            edges = clustering.neighbour_edges(centroids, params.n_neighbors)
            weights = clustering.similarity_graph(bases, edges)
            if params.method == "moju":
                # 5. Jump to the low-dimensional manifold; 6. kernel there.
                delta, thetas = jump.jump(delta, bases, weights)
                gamma = grassmann.projection_kernel(thetas)
            else:
                # sdg: the kernel of the high-dimensional points themselves.
                gamma = grassmann.projection_kernel(bases)
            gamma = gamma + 1e-10 * np.trace(gamma) / n_groups * np.eye(n_groups)
            kernel = lrr.kernel_eigh(gamma)
        if adaptive:
            # 7. LRR coefficients (every iteration, with the kernel of the last regrouping).
            coefficients = lrr.coefficient_step(kernel, aux, mult_coef, params.beta1, rho)
        if regroup_now:
            if clusters_enabled:
                # 8. Cluster the Grassmann points, move trajectories between groups.
                group_clusters = clustering.cluster_groups(
                    coefficients, params.n_clusters, params.seed
                )
                new_labels = clustering.regroup(
                    trajectories, labels, bases, group_clusters, min_group_size(p)
                )
                relabelled = int(np.count_nonzero(new_labels != labels))
                if relabelled:
                    perm = np.argsort(new_labels, kind="stable")
                    labels = new_labels[perm]
                    order = order[perm]
                    back_projected = _permute(back_projected, perm)
                    tracks = _permute(tracks, perm)
                    if observed is not None:
                        observed = _permute(observed, perm)
                    features = features[perm]
                    shapes = _permute(shapes, perm)
                    sharp = _permute(sharp.reshape(n_frames, 3, n_points), perm).reshape(
                        n_frames, -1
                    )
                    scaled = _permute(scaled.reshape(n_frames, 3, n_points), perm).reshape(
                        n_frames, -1
                    )
                    work = np.empty_like(sharp)
                    reprojection = np.empty_like(tracks)
                    bounds = _bounds(labels, n_groups)
                    trajectories = shapes.reshape(3 * n_frames, n_points)
                    # The groups changed by a few members: refine from the old bases.
                    bases, _ = grassmann.group_subspaces(trajectories, bounds, p, previous=bases)
                total_relabelled += relabelled
                labels_stable = relabelled <= settled_moves
            # 9. Local reconstruction on each group's subspace.
            grassmann.project_groups(trajectories, bounds, bases, out=trajectories)
        elif local:
            # 2 and 9 fused between regroupings: track each group's subspace, project on it.
            bases = grassmann.track_and_project(trajectories, bounds, bases)
        if local and observed is not None:
            # Hidden frames of a point follow its group's subspace (fitted on the seen ones).
            grassmann.project_observed(trajectories, bounds, bases, observed)
        shape_form = shapes.reshape(n_frames, 3 * n_points)
        # 10. S#-update: singular value thresholding.
        np.subtract(shape_form, scaled, out=work)
        # ... followed by the temporal prior's filter on the frames, unless the S-update
        # solved it (moju_core.temporal_prior).
        smoothing = (
            None if prior is None or exact_prior else temporal_prior.smoothing_filter(prior, rho)
        )
        _, nuclear = lrr.singular_value_threshold(
            work, params.beta2 / rho, out=sharp, keep=kept_values, left=smoothing
        )
        # 11. Z-update.
        if adaptive:
            aux, _ = lrr.singular_value_threshold(
                coefficients + mult_coef / rho, params.beta3 / rho
            )
        # 12. Multipliers.
        residual_shape = np.subtract(sharp, shape_form, out=work)
        scaled += residual_shape  # L1 += rho (S# - f(S)), in units of the current rho
        gap_shape = float(max(residual_shape.max(), -residual_shape.min()))
        gap_coef = 0.0
        if adaptive:
            residual_coef = coefficients - aux
            mult_coef += rho * residual_coef
            gap_coef = float(np.abs(residual_coef).max())
        gap = max(gap_shape, gap_coef)
        camera.project(rotations, shapes, out=reprojection)
        reprojection -= tracks
        if observed is not None:
            reprojection *= observed[:, None, :]  # RMS over the observed entries below
            # The per-frame translation is an unknown of the masked data term too: the mean
            # residual of each frame's observed points is moved into it.
            shift = reprojection.sum(axis=2) / frame_counts  # (F, 2), R S - W on average
            tracks += shift[:, :, None] * observed[:, None, :]
            reprojection -= shift[:, :, None] * observed[:, None, :]
            back_projected = camera.back_project(rotations, tracks)
        history["gap"].append(gap)
        history["gap_shape"].append(gap_shape)
        history["gap_coefficients"].append(gap_coef)
        history["rho"].append(rho)
        history["reprojection"].append(
            float(np.sqrt(np.vdot(reprojection, reprojection) / (2 * n_observed)))
        )
        history["nuclear_norm"].append(nuclear)
        history["relabelled"].append(float(relabelled))
        # 13-15. Penalty schedule and convergence test.
        if hook is not None and hook(iteration, gap, rho):
            stop_reason = "stopped"
            break
        # The paper stops on max(gap_shape, gap_coefficients) < tol. The C-Z split of the
        # LRR step closes only like beta3 / rho (C follows the kernel, which moves with S), so
        # that test would always run to rho_max; C and Z steer the grouping only, so the loop
        # stops when the shape gap is below tol and the last regrouping moved (almost) no
        # trajectory: at most SETTLED_MOVE_FRACTION of them.
        # A gap below GAP_PRECISION that has stopped falling is at the precision of the S#
        # step (its Gram-matrix SVD); it would not reach a smaller tol.
        if gap_shape < smallest_gap:
            smallest_gap, since_smallest = gap_shape, 0
        else:
            since_smallest += 1
        at_precision = (
            params.tol > 0  # tol = 0: no convergence test at all
            and smallest_gap < GAP_PRECISION
            and since_smallest >= STALL_ITERATIONS
        )
        if (gap_shape < params.tol or at_precision) and labels_stable:
            stop_reason = "converged"
            break
        if rho >= params.rho_max:
            stop_reason = "rho_max"
            break
        next_rho = min(params.rho_max, params.rho_growth * rho)
        scaled *= rho / next_rho
        rho = next_rho

    inverse = np.empty_like(order)
    inverse[order] = np.arange(n_points)
    return LoopOutput(
        shapes=_permute(shapes, inverse),
        rotations=rotations,
        labels=labels[inverse],
        history={key: np.asarray(values) for key, values in history.items()},
        n_iter=iteration,
        stop_reason=stop_reason,
        label_changes=total_relabelled,
        extras={"n_groups": n_groups},
    )
