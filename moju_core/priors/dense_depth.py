"""From anchor depths to every point: interpolation and a first-order maximum-depth refinement.

Both steps are vectorised over images and edges; neither forms anything of size ``P^2``.

* :func:`interpolate_depths` fits, around each point, a plane to the nearest anchors: for a
  plane ``n . X = c`` seen along ``q = [x', y', 1]`` the inverse depth ``1/d = n . q / c`` is
  *linear* in the image coordinates, so a weighted linear fit of ``1/d`` over the ``m`` nearest
  anchors reproduces planes exactly and curved surfaces to second order in the anchor spacing.
* :func:`refine_depths` then applies the maximum-depth heuristic to all points with the
  inextensibility bounds as a penalty: it alternates a small push of every depth away from the
  camera with Jacobi projections that shorten the edges longer than their bound ``l_e``
  (position-based dynamics restricted to the viewing rays), anchors held at the cone program's
  values. The bounds are the largest length of each edge over the images of the interpolated
  surface, i.e. the fixed point of the cone program's ``l_e = max_f ||X_fi - X_fj||``.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["edge_bounds", "interpolate_depths", "refine_depths"]


def _homogeneous(rays: np.ndarray) -> np.ndarray:
    return np.concatenate([rays, np.ones(rays.shape[:-1] + (1,))], axis=-1)


def interpolate_depths(
    rays: np.ndarray, seen: np.ndarray, anchors: np.ndarray, anchor_depths: np.ndarray,
    *, m: int = 8,
) -> np.ndarray:
    """Depths of all seen points from the anchors' depths, by local planes.

    Cost: ``O(F P (m + log A))`` time, ``O(P m)`` memory per image.

    Parameters
    ----------
    rays : ndarray of shape (F, P, 2)
        Normalised image coordinates.
    seen : ndarray of shape (F, P), bool
        True where seen.
    anchors : ndarray of shape (A,), int
        Point indices of the anchors.
    anchor_depths : ndarray of shape (F, A)
        Their depths (NaN where unknown).
    m : int, default 8
        Anchors per local fit.

    Returns
    -------
    depths : ndarray of shape (F, P), float64
        Positive where seen and at least one anchor is known in that image; NaN elsewhere.
        Anchors keep their own depth.
    """
    n_frames, n_points = seen.shape
    depths = np.full((n_frames, n_points), np.nan)
    for f in range(n_frames):
        known = np.isfinite(anchor_depths[f]) & (anchor_depths[f] > 0)
        ids = anchors[known]
        targets = np.flatnonzero(seen[f])
        if ids.size == 0 or targets.size == 0:
            continue
        inverse = 1.0 / anchor_depths[f, known]
        mm = min(m, ids.size)
        dist, nn = cKDTree(rays[f, ids]).query(rays[f, targets], mm)
        dist, nn = dist.reshape(targets.size, mm), nn.reshape(targets.size, mm)
        if mm < 3:  # too few for a plane: inverse-distance average
            w = 1.0 / (dist + 1e-12) ** 2
            depths[f, targets] = 1.0 / (np.sum(w * inverse[nn], 1) / np.sum(w, 1))
            continue
        # Weighted linear fit of 1/d in (x', y') centred at the target; Gaussian weights with
        # the local anchor spacing as width, plus a tiny ridge so collinear anchors stay solvable.
        offsets = rays[f, ids][nn] - rays[f, targets][:, None, :]
        h = np.maximum(np.median(dist, axis=1, keepdims=True), 1e-12)
        w = np.exp(-((dist / h) ** 2))
        basis = np.concatenate([np.ones(offsets.shape[:2] + (1,)), offsets], axis=2)
        gram = np.einsum("pm,pmi,pmj->pij", w, basis, basis)
        gram += np.eye(3) * 1e-9 * np.trace(gram, axis1=1, axis2=2)[:, None, None]
        gram[:, 1:, 1:] += np.eye(2) * (1e-6 * h[:, :, None] ** 2) * w.sum(1)[:, None, None]
        rhs = np.einsum("pm,pmi,pm->pi", w, basis, inverse[nn])
        intercept = np.linalg.solve(gram, rhs[..., None])[:, 0, 0]
        # A fit may overshoot at the border; fall back to the nearest anchor there.
        bad = ~(intercept > 0.5 * inverse[nn].min(1)) | ~(intercept < 2.0 * inverse[nn].max(1))
        intercept[bad] = inverse[nn[bad, 0]]
        depths[f, targets] = 1.0 / intercept
    position = np.full(n_points, -1)
    position[anchors] = np.arange(anchors.size)
    keep = np.isfinite(anchor_depths) & seen[:, anchors]
    rows, cols = np.nonzero(keep)
    depths[rows, anchors[cols]] = anchor_depths[rows, cols]
    return depths


def edge_bounds(shapes: np.ndarray, both: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Largest length of each edge over the images where both ends are seen.

    Cost: ``O(F E)``.

    Parameters
    ----------
    shapes : ndarray of shape (F, P, 3)
    both : ndarray of shape (F, E), bool
    edges : ndarray of shape (E, 2), int

    Returns
    -------
    bounds : ndarray of shape (E,)
        NaN for an edge never seen whole.
    """
    lengths = np.linalg.norm(shapes[:, edges[:, 0]] - shapes[:, edges[:, 1]], axis=2)
    lengths = np.where(both, lengths, -np.inf)
    bounds = lengths.max(axis=0)
    return np.where(np.isfinite(bounds), bounds, np.nan)


def refine_depths(
    rays: np.ndarray, seen: np.ndarray, edges: np.ndarray, depths: np.ndarray,
    anchors: np.ndarray, *, n_iter: int = 60, push: float = 2e-3, n_project: int = 3,
) -> tuple[np.ndarray, float]:
    """Maximum-depth refinement of all points with the inextensibility bounds as a penalty.

    Each iteration moves every non-anchor depth away from the camera by ``push`` times the
    mean depth (decaying linearly to 0 over the iterations, so the last ones only restore the
    bounds), then runs ``n_project`` Jacobi sweeps in which each edge longer than its bound
    shortens itself along the two viewing rays (the first-order correction of the length
    constraint), the corrections of a point averaged over its violated edges.

    Cost: ``O(n_iter n_project F E)`` with ``E ~ P k / 2`` edges; memory ``O(F E)``.

    Parameters
    ----------
    rays : ndarray of shape (F, P, 2)
    seen : ndarray of shape (F, P), bool
    edges : ndarray of shape (E, 2), int
    depths : ndarray of shape (F, P)
        Starting depths (NaN where unknown); anchors keep theirs.
    anchors : ndarray of shape (A,), int
    n_iter, push, n_project
        Iterations, push per iteration (fraction of the mean depth), projections per iteration.

    Returns
    -------
    depths : ndarray of shape (F, P)
        Refined depths.
    violation : float
        Final mean relative excess ``mean(max(0, len/l - 1))`` over the seen edges.
    """
    q = _homogeneous(np.where(np.isfinite(rays), rays, 0.0))
    known = seen & np.isfinite(depths)
    d = np.where(known, depths, 0.0)
    both = known[:, edges[:, 0]] & known[:, edges[:, 1]]
    bounds = edge_bounds(d[..., None] * q, both, edges)
    ok = np.isfinite(bounds)
    edges, both, bounds = edges[ok], both[:, ok], bounds[ok]
    i, j = edges[:, 0], edges[:, 1]
    free = known.copy()
    free[:, anchors] = False
    scale = float(np.mean(d[known])) if known.any() else 1.0
    qi, qj = q[:, i], q[:, j]
    n_points = d.shape[1]

    def project(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        diff = d[:, i, None] * qi - d[:, j, None] * qj
        length = np.linalg.norm(diff, axis=2)
        excess = np.where(both, length - bounds, 0.0)
        active = excess > 0
        u = diff / np.maximum(length, 1e-300)[..., None]
        gi = np.einsum("fek,fek->fe", u, qi)
        gj = -np.einsum("fek,fek->fe", u, qj)
        # Floor on the squared gradient: a fronto-parallel edge barely changes length with
        # depth; an unbounded step there would be a jump, not a projection.
        denom = np.maximum(gi**2 + gj**2, 1e-2)
        step = np.where(active, excess / denom, 0.0)
        delta = np.zeros_like(d)
        count = np.zeros_like(d)
        for f in range(d.shape[0]):
            delta[f] -= np.bincount(i, step[f] * gi[f], n_points)
            delta[f] -= np.bincount(j, step[f] * gj[f], n_points)
            count[f] += np.bincount(i, active[f], n_points) + np.bincount(j, active[f], n_points)
        return delta / np.maximum(count, 1.0), excess

    excess = np.zeros_like(both, dtype=float)
    for it in range(n_iter):
        d = d + np.where(free, push * scale * (1.0 - it / max(n_iter - 1, 1)), 0.0)
        for _ in range(n_project):
            delta, excess = project(d)
            # Steps clipped to 5 % of the depth per sweep keep the Jacobi iteration stable.
            delta = np.clip(delta, -0.05 * d, 0.05 * d)
            d = np.where(free, d + delta, d)
    _, excess = project(d)
    violation = float(np.mean(np.maximum(excess[both], 0) / bounds[np.nonzero(both)[1]]))
    return np.where(known, d, np.nan), violation
