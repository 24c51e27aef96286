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

__all__ = ["edge_bounds", "homogeneous", "interpolate_depths", "refine_depths"]


def homogeneous(rays: np.ndarray) -> np.ndarray:
    """``[x', y', 1]`` (..., 3) of rays (..., 2): ``depth * homogeneous(rays)`` is a point."""
    return np.concatenate([rays, np.ones(rays.shape[:-1] + (1,))], axis=-1)


def interpolate_depths(
    rays: np.ndarray,
    seen: np.ndarray,
    anchors: np.ndarray,
    anchor_depths: np.ndarray,
    *,
    m: int = 8,
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


def edge_bounds(
    rays: np.ndarray, depths: np.ndarray, known: np.ndarray, edges: np.ndarray
) -> np.ndarray:
    """Largest 3D length of each edge over the images where both ends are known.

    Cost: ``O(F E)`` time, ``O(E)`` memory (one image at a time).

    Parameters
    ----------
    rays : ndarray of shape (F, P, 2)
    depths : ndarray of shape (F, P)
    known : ndarray of shape (F, P), bool
    edges : ndarray of shape (E, 2), int

    Returns
    -------
    bounds : ndarray of shape (E,)
        NaN for an edge never known whole.
    """
    bounds = np.full(len(edges), -np.inf)
    i, j = edges[:, 0], edges[:, 1]
    for f in range(rays.shape[0]):
        x = depths[f, :, None] * homogeneous(rays[f])
        both = known[f, i] & known[f, j]
        lengths = np.linalg.norm(x[i] - x[j], axis=1)
        bounds = np.where(both, np.maximum(bounds, lengths), bounds)
    return np.where(np.isfinite(bounds), bounds, np.nan)


def _refine_image(
    q: np.ndarray,
    d: np.ndarray,
    free: np.ndarray,
    i: np.ndarray,
    j: np.ndarray,
    bounds: np.ndarray,
    n_iter: int,
    push: float,
    n_project: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Push-and-project iterations on one image; returns its depths and final edge excess."""
    n_points = d.size
    scale = float(np.mean(d[d > 0])) if np.any(d > 0) else 1.0
    qi, qj = q[i], q[j]

    def project(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        diff = d[i, None] * qi - d[j, None] * qj
        length = np.linalg.norm(diff, axis=1)
        excess = length - bounds
        active = excess > 0
        u = diff / np.maximum(length, 1e-300)[:, None]
        gi = np.einsum("ek,ek->e", u, qi)
        gj = -np.einsum("ek,ek->e", u, qj)
        # Floor on the squared gradient: a fronto-parallel edge barely changes length with
        # depth; an unbounded step there would be a jump, not a projection.
        step = np.where(active, excess / np.maximum(gi**2 + gj**2, 1e-2), 0.0)
        delta = -np.bincount(i, step * gi, n_points) - np.bincount(j, step * gj, n_points)
        count = np.bincount(i, active, n_points) + np.bincount(j, active, n_points)
        return delta / np.maximum(count, 1.0), excess

    for it in range(n_iter):
        d = d + np.where(free, push * scale * (1.0 - it / max(n_iter - 1, 1)), 0.0)
        for _ in range(n_project):
            delta, _ = project(d)
            # Steps clipped to 5 % of the depth per sweep keep the Jacobi iteration stable.
            d = np.where(free, d + np.clip(delta, -0.05 * d, 0.05 * d), d)
    _, excess = project(d)
    return d, excess


def refine_depths(
    rays: np.ndarray,
    seen: np.ndarray,
    edges: np.ndarray,
    depths: np.ndarray,
    anchors: np.ndarray,
    *,
    n_iter: int = 60,
    push: float = 2e-3,
    n_project: int = 3,
) -> tuple[np.ndarray, float]:
    """Maximum-depth refinement of all points with the inextensibility bounds as a penalty.

    Each iteration moves every non-anchor depth away from the camera by ``push`` times the
    image's mean depth (decaying linearly to 0 over the iterations, so the last ones only
    restore the bounds), then runs ``n_project`` Jacobi sweeps in which each edge longer than
    its bound shortens itself along the two viewing rays (the first-order correction of the
    length constraint), the corrections of a point averaged over its violated edges. With the
    bounds fixed the images are independent, so they are refined one at a time.

    Cost: ``O(n_iter n_project F E)`` time with ``E ~ P k / 2`` edges; ``O(E)`` memory.

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
    known = seen & np.isfinite(depths)
    d_all = np.where(known, depths, 0.0)
    bounds = edge_bounds(rays, d_all, known, edges)
    ok = np.isfinite(bounds)
    edges, bounds = edges[ok], bounds[ok]
    is_anchor = np.zeros(seen.shape[1], dtype=bool)
    is_anchor[anchors] = True
    out = np.full(seen.shape, np.nan)
    excess_sum, n_seen = 0.0, 0
    for f in range(seen.shape[0]):
        both = known[f, edges[:, 0]] & known[f, edges[:, 1]]
        i, j = edges[both, 0], edges[both, 1]
        q = homogeneous(np.where(known[f, :, None], rays[f], 0.0))
        d, excess = _refine_image(
            q, d_all[f], known[f] & ~is_anchor, i, j, bounds[both], n_iter, push, n_project
        )
        out[f] = np.where(known[f], d, np.nan)
        excess_sum += float(np.sum(np.maximum(excess, 0.0) / bounds[both]))
        n_seen += int(both.sum())
    return out, excess_sum / max(n_seen, 1)
