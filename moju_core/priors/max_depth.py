"""Surface prior that creates depth without rotation: the maximum-depth heuristic, made dense.

Chhatkuli, Pizarro, Collins and Bartoli, "Inextensible Non-Rigid Shape-from-Motion by
Second-Order Cone Programming", TPAMI 2017. With a perspective camera, an inextensible surface
seen in several images cannot be deeper in any image than its (shared, unknown) geodesic edge
lengths allow; maximising the depths under those bounds recovers the shapes up to one global
scale, without needing the camera to rotate. See ``docs/surface_prior.md``.

Pipeline of :func:`max_depth_shapes` (``F`` images, ``P`` points, ``k`` neighbours, ``A``
anchors):

1. anchors: ``A`` points spread over the image by farthest-point sampling, ``O(A P)``;
2. cone program on the anchors (:mod:`~moju_core.priors.cone_program`, Clarabel),
   ``O(F A k)`` cones, jointly on at most 30 key images, the others alone with their edge
   lengths (:mod:`~moju_core.priors.key_images`); groups of anchors cut off from the rest
   of an image are then held within their geodesic distance of it
   (:mod:`~moju_core.priors.cut_off_groups`);
3. all points: local-plane interpolation of the anchors' inverse depths, ``O(F P (m + log A))``
   (:mod:`~moju_core.priors.dense_depth`);
4. optional dense refinement (``refine_iter > 0``; off by default): the plain maximum-depth
   push under the same bounds on the ``k``-neighbour graph of all points, first-order,
   ``O(F P k)`` per iteration; graph ``O(F P k log P)``. It has no consistency term, so it
   brings back the plain heuristic's extra relief between the anchors: on rendered footage
   the interpolation alone is closer to the truth (``docs/surface_prior.md``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from moju_core.priors.cone_program import LengthScale
from moju_core.priors.cut_off_groups import hold_cut_off_groups
from moju_core.priors.dense_depth import homogeneous, interpolate_depths, refine_depths
from moju_core.priors.key_images import MAX_KEY_IMAGES, solve_by_key_images
from moju_core.priors.neighbour_graph import neighbour_edges, spread_anchors, visibility_of

__all__ = ["SurfaceFit", "max_depth_edges", "max_depth_shapes"]


@dataclass(frozen=True)
class SurfaceFit:
    """Shapes from the maximum-depth heuristic.

    Attributes
    ----------
    depths : ndarray of shape (F, P), float64
        Depth of each point along its viewing ray, > 0 where seen, NaN where not seen. One
        global scale for the sequence, fixed so that the mean of the seen depths is 1.
    shapes : ndarray of shape (F, P, 3), float64
        ``depth * [x', y', 1]`` in each image's camera frame (same unit as ``depths``).
    anchors : ndarray of shape (A,), int64
        Points solved by the cone program.
    status : str
        The cone solver's status (``"optimal"`` expected).
    seconds : dict of str to float
        Wall time per stage: ``graph``, ``cone``, ``interpolate``, ``refine``, ``total``.
    violation : float
        Mean relative excess of the dense edges over their bounds after refinement (0 = all
        bounds hold).
    n_edges : int
        Edges of the graph whose bounds the depths were fitted under: the dense neighbour
        graph when refined, else the anchors' graph.
    n_solves : int
        Cone programs solved (1 + edge-length consistency rounds).
    shrink : float
        Mean slack of the consistency term over the mean edge bound: how far the anchors'
        edges fall short of their bounds on average (0 = every edge at its bound everywhere).
    length_scale : {"edges", "pairs"}
        The anchors' length scale, as chosen by ``length_scale="auto"`` (see
        :class:`~moju_core.priors.cone_program.ConeSolution`).
    """

    depths: np.ndarray
    shapes: np.ndarray
    anchors: np.ndarray
    status: str
    seconds: dict = field(default_factory=dict)
    violation: float = 0.0
    n_edges: int = 0
    n_solves: int = 1
    shrink: float = 0.0
    length_scale: LengthScale = "edges"


def max_depth_edges(
    rays: np.ndarray, visibility: np.ndarray | None = None, *, k: int = 8
) -> np.ndarray:
    """The neighbour graph :func:`max_depth_shapes` uses on all points.

    Stable ``k``-nearest image neighbours (see
    :func:`~moju_core.priors.neighbour_graph.neighbour_edges`); ``O(F P k log P)``.

    Parameters
    ----------
    rays : ndarray of shape (F, P, 2)
        Normalised image coordinates, NaN where not seen.
    visibility : ndarray of shape (F, P), bool, optional
    k : int, default 8

    Returns
    -------
    edges : ndarray of shape (E, 2), int64
    """
    return neighbour_edges(rays, visibility, k=k)


def _dense_depths(
    rays: np.ndarray,
    seen: np.ndarray,
    anchors: np.ndarray,
    anchor_depths: np.ndarray,
    *,
    k: int,
    refine_iter: int,
    n_anchor_edges: int,
    seconds: dict[str, float],
) -> tuple[np.ndarray, float, int]:
    """Depths of all points from the anchors' (steps 3 and 4 of the pipeline).

    Parameters
    ----------
    rays : ndarray of shape (F, P, 2)
        Normalised image coordinates, NaN where not seen.
    seen : ndarray of shape (F, P), bool
    anchors : ndarray of shape (A,), int64
    anchor_depths : ndarray of shape (F, A)
        The cone program's depths of the anchors.
    k : int
        Image neighbours per point of the dense graph.
    refine_iter : int
        Iterations of the dense refinement (0: interpolation only, and no dense graph).
    n_anchor_edges : int
        Edges of the anchors' graph.
    seconds : dict of str to float
        Wall times (seconds): ``interpolate`` and ``refine`` are set, the dense graph's time
        is added to ``graph``.

    Returns
    -------
    depths : ndarray of shape (F, P)
        In the unit of ``anchor_depths``, not yet masked or normalised.
    violation : float
        Mean relative excess of the dense edges over their bounds (0 without refinement).
    n_edges : int
        Edges of the graph whose bounds the depths meet: the dense neighbour graph when
        refined, else ``n_anchor_edges``.
    """
    t0 = time.perf_counter()
    depths = interpolate_depths(rays, seen, anchors, anchor_depths)
    seconds["interpolate"] = time.perf_counter() - t0
    seconds["refine"] = 0.0
    if refine_iter <= 0:
        return depths, 0.0, n_anchor_edges
    t0 = time.perf_counter()
    edges = neighbour_edges(rays, seen, k=k)
    seconds["graph"] += time.perf_counter() - t0
    t0 = time.perf_counter()
    depths, violation = refine_depths(rays, seen, edges, depths, anchors, n_iter=refine_iter)
    seconds["refine"] = time.perf_counter() - t0
    return depths, violation, len(edges)


def _scaled_shapes(
    rays: np.ndarray, seen: np.ndarray, depths: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Depths masked and at the global scale, and the shapes they give.

    Parameters
    ----------
    rays : ndarray of shape (F, P, 2)
    seen : ndarray of shape (F, P), bool
    depths : ndarray of shape (F, P)
        Depths along the rays, any scale.

    Returns
    -------
    depths : ndarray of shape (F, P)
        NaN where not seen or not positive; the mean of the others is 1.
    shapes : ndarray of shape (F, P, 3)
        ``depth * [x', y', 1]`` (same unit as ``depths``).
    """
    depths = np.where(seen & (depths > 0), depths, np.nan)
    if np.any(np.isfinite(depths)):
        depths = depths / np.nanmean(depths)  # the global scale: mean seen depth 1
    return depths, depths[..., None] * homogeneous(rays)


def max_depth_shapes(
    rays: np.ndarray,
    visibility: np.ndarray | None = None,
    *,
    n_anchor: int = 200,
    k: int = 8,
    seed: int = 0,
    rigidity: float = 30.0,
    outlier_price: float = np.inf,
    refine_iter: int = 0,
    n_key_images: int = MAX_KEY_IMAGES,
    smoothed_starts: bool = False,
    length_scale: LengthScale = "auto",
) -> SurfaceFit:
    """Per-image 3D shapes from perspective tracks by the maximum-depth heuristic.

    Parameters
    ----------
    rays : ndarray of shape (F, P, 2)
        Normalised image coordinates ``(x', y') = ((u - cx)/fx, (v - cy)/fy)``, NaN where not
        seen.
    visibility : ndarray of shape (F, P), bool, optional
        True where seen (combined with the finiteness of ``rays``).
    n_anchor : int, default 200
        Points solved exactly by the cone program; all points when ``P <= n_anchor`` (then no
        interpolation or refinement is needed).
    k : int, default 8
        Image neighbours per point (for the anchors' graph and the dense graph).
    seed : int, default 0
        Seed of the anchor sampling (the only randomness).
    rigidity : float, default 30
        Price of an edge shrinking below its bound in the cone program (edge-length
        consistency; 0 gives the plain maximum-depth heuristic). See
        :func:`~moju_core.priors.cone_program.solve_max_depth_cone`.
    outlier_price : float, default inf
        Price of an edge exceeding its bound (a soft upper bound against wrong tracks);
        ``inf`` keeps the bounds hard, which measured better (docs/surface_prior.md).
    refine_iter : int, default 0
        Iterations of the dense refinement; 0 (the default) stops at the interpolation of
        the anchors' depths, which measured closer to the truth on rendered footage.
    n_key_images : int, default :data:`~moju_core.priors.key_images.MAX_KEY_IMAGES`
        Most images whose cone program is solved jointly; the others are solved alone with
        their edge lengths (:func:`~moju_core.priors.key_images.solve_by_key_images`).
    smoothed_starts : bool, default False
        Also start the consistency rounds from the plain program's depths smoothed per image
        and keep the cheapest result (:mod:`~moju_core.priors.smoothed_starts`).
    length_scale : {"edges", "pairs", "auto"}, default "auto"
        How the cone program scales its unknown lengths: mean 1 over the edges, over the
        (image, edge) pairs, or both solved and the one closer to an isometry kept (see
        :func:`~moju_core.priors.cone_program.solve_max_depth_cone`).

    Returns
    -------
    SurfaceFit

    Raises
    ------
    ValueError
        If ``rays`` is not (F, P, 2) or fewer than 2 images see points.
    """
    t_start = time.perf_counter()
    rays = np.asarray(rays, dtype=np.float64)
    seen = visibility_of(rays, visibility)
    if seen.shape[0] < 2 or seen.sum() == 0:
        raise ValueError("the maximum-depth heuristic needs at least 2 images with seen points")
    n_points = seen.shape[1]
    seconds: dict[str, float] = {}

    t0 = time.perf_counter()
    anchors = spread_anchors(rays, seen, n_anchor=n_anchor, seed=seed)
    anchor_edges = neighbour_edges(rays[:, anchors], seen[:, anchors], k=k)
    seconds["graph"] = time.perf_counter() - t0

    cone = solve_by_key_images(
        rays[:, anchors],
        seen[:, anchors],
        anchor_edges,
        rigidity=rigidity,
        outlier_price=outlier_price,
        n_key=n_key_images,
        smoothed_starts=smoothed_starts,
        length_scale=length_scale,
    )
    cone_depths = hold_cut_off_groups(
        rays[:, anchors], seen[:, anchors], anchor_edges, cone.depths, cone.lengths, cone.shrink
    )
    seconds["cone"] = cone.seconds

    violation, n_edges = 0.0, len(anchor_edges)
    if anchors.size == n_points:
        depths = cone_depths
        seconds["interpolate"] = seconds["refine"] = 0.0
    else:
        depths, violation, n_edges = _dense_depths(
            rays,
            seen,
            anchors,
            cone_depths,
            k=k,
            refine_iter=refine_iter,
            n_anchor_edges=n_edges,
            seconds=seconds,
        )

    depths, shapes = _scaled_shapes(rays, seen, depths)
    seconds["total"] = time.perf_counter() - t_start
    return SurfaceFit(
        depths,
        shapes,
        anchors,
        cone.status,
        seconds,
        violation,
        n_edges,
        cone.n_solves,
        cone.shrink,
        cone.length_scale,
    )
