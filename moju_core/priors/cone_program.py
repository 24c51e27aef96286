"""The maximum-depth heuristic as one second-order cone program (Chhatkuli et al., TPAMI 2017).

Unknowns: the depth ``d_fp > 0`` of each seen point ``p`` in each image ``f`` (its 3D point is
``X_fp = d_fp q_fp`` with ``q_fp = [x', y', 1]``), and one length ``l_e`` per neighbour edge,
shared by all images. An inextensible surface cannot bring two neighbours farther apart than
their geodesic distance, so in every image where both ends are seen

    ||d_fi q_fi - d_fj q_fj|| <= l_e.

Depth is unobservable in perspective without motion cues, but every image must fit inside the
same edge lengths; maximising the depths pushes each image to its most extended shape allowed by
those lengths, which for a bent inextensible surface is close to the true one (the surface
cannot be deeper without stretching in some image). The scale is fixed by ``sum_e l_e = E``
(mean edge length 1); the program is

    maximise sum_{f,p seen} d_fp  s.t. the cones above, sum_e l_e = E, d >= 0.

It is solved by Clarabel (an interior-point conic solver), called directly: cvxpy's
compilation took longer than the solve at a few hundred anchors.

Edge-length consistency (``rigidity > 0``). The program above only bounds lengths from above:
in an image where part of the surface is squeezed (shorter than its bound), nothing stops the
maximisation from spending the spare length on a fold away from the camera; a cushion pressed
by hand becomes a bowl. An isometric surface keeps each length in *every* image, so we also ask
``||X_fi - X_fj|| >= l_e - s_fe`` with a slack ``s_fe >= 0`` paid at rate ``rigidity`` (in units
of the mean depth gained per unit of mean edge length): an edge may shrink, but only when the
depths gain more than its price. The lower bound is not convex; it is replaced by its
linearisation ``u_fe . (X_fi - X_fj) >= l_e - s_fe`` around the previous solution (``u_fe`` the
unit edge direction), which implies the true bound since ``||v|| >= u . v`` for a unit ``u``, and
the program is re-solved with updated directions (a convex-concave procedure, which never
decreases the objective). This is maximum rigidity's edge-length consistency (Ji et al., ICCV
2017) added to the maximum-depth program.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import Literal

import numpy as np
import scipy.sparse as sp

from moju_core.priors.dense_depth import homogeneous
from moju_core.priors.smoothed_starts import smoothed_start_depths

__all__ = [
    "CLARABEL_SETTINGS",
    "ConeSolution",
    "LengthScale",
    "isometry_residual",
    "solve_max_depth_cone",
]

#: How the unknown edge lengths are scaled (see :func:`solve_max_depth_cone`).
LengthScale = Literal["edges", "pairs", "auto"]

#: Clarabel settings changed from its defaults, for every solve. Iterative refinement (up to
#: 10 extra back-substitutions per Newton step) and Ruiz equilibration (a rescaling of the rows
#: and columns) are off: the rows are already in units of the mean edge length, and convergence
#: is still judged on the true residuals at the default 1e-8 tolerances. The prior takes
#: 0.6-0.7 of the time, e3D the same or lower (``docs/surface_prior.md``). The tolerances stay
#: at the defaults: at 1e-5 the consistency rounds' depths moved by up to 2.5 times (the optimum
#: is flat along some depths) and e3D rose from 0.27 to 1.4 on a rendered scene.
CLARABEL_SETTINGS: dict[str, object] = {
    "iterative_refinement_enable": False,
    "equilibrate_enable": False,
}


@dataclass(frozen=True)
class ConeSolution:
    """Result of :func:`solve_max_depth_cone`.

    Attributes
    ----------
    depths : ndarray of shape (F, P), float64
        Depths in units of the mean edge length; NaN where not seen or not constrained.
    lengths : ndarray of shape (E,), float64
        Edge length bounds ``l_e`` (mean 1 over the edges used), NaN for unused edges.
    status : str
        Clarabel's status of the last solve (``"Solved"`` expected).
    seconds : float
        Wall time of building and solving.
    n_cones : int
        Number of (image, edge) cone constraints.
    n_solves : int
        Cone programs solved (1 + consistency rounds).
    shrink : float
        Mean slack ``s_fe`` of the last round over the mean ``l_e`` (how much the edges shrink
        below their bound; 0 without consistency).
    length_scale : {"edges", "pairs"}
        The length scale of the solution kept: ``"auto"``'s choice (``"edges"`` where the two
        programs are the same; meaningless where the lengths were given).
    """

    depths: np.ndarray
    lengths: np.ndarray
    status: str
    seconds: float
    n_cones: int
    n_solves: int = 1
    shrink: float = 0.0
    length_scale: LengthScale = "edges"


def solve_max_depth_cone(
    rays: np.ndarray,
    seen: np.ndarray,
    edges: np.ndarray,
    *,
    rigidity: float = 30.0,
    n_rounds: int = 6,
    tol: float = 1e-3,
    outlier_price: float = np.inf,
    lengths: np.ndarray | None = None,
    smoothed_starts: bool = False,
    length_scale: LengthScale = "auto",
) -> ConeSolution:
    """Solve the maximum-depth cone program on a (small) set of points.

    Cost: ``C = (#seen edge-image pairs) ~ F P k / 2`` cones of size 4; an interior-point
    method takes ``O(C)`` per sparse factorisation times a few tens of iterations (about 0.5 s
    for F = 10, P = 90, k = 8; keep ``P`` to a few hundred), times ``1 + n_rounds`` with
    the consistency term, and twice that with ``length_scale="auto"`` where the two length
    scales differ (missing data).

    Parameters
    ----------
    rays : ndarray of shape (F, P, 2)
        Normalised image coordinates (dimensionless); only seen entries are read.
    seen : ndarray of shape (F, P), bool
        True where the point is seen.
    edges : ndarray of shape (E, 2), int
        Neighbour pairs.
    rigidity : float, default 30
        Price of shrinking an edge below its bound (0: plain maximum-depth heuristic).
    n_rounds : int, default 6
        Most linearise-and-solve rounds of the consistency term.
    tol : float, default 1e-3
        Stop the rounds when the depths change by less than this (relative, max norm).
    outlier_price : float, default inf
        Price of an edge exceeding its bound in the consistency rounds (same units as
        ``rigidity``; must exceed 1, the gain of stretching everything, to stay bounded);
        ``inf`` keeps the bounds hard.
    lengths : ndarray of shape (E,), optional
        Edge lengths fixed in advance (from a solve of other images of the same surface, in
        its units), instead of unknowns scaled to mean 1. Given the lengths the images are
        independent: :mod:`~moju_core.priors.key_images` solves them one at a time (pinned by
        equality rows, the lengths would still couple several images in the factorisation).
    smoothed_starts : bool, default False
        Also run the consistency rounds from the plain solution smoothed in each image
        (:mod:`~moju_core.priors.smoothed_starts`), and keep the rounds' result of lowest
        cost; the rounds then cost three times as much.
    length_scale : {"edges", "pairs", "auto"}, default "auto"
        How the unknown lengths are scaled: ``"edges"``, mean 1 over the edges
        (``sum_e l_e = L``); ``"pairs"``, mean 1 over the (image, edge) pairs, each length
        counted once per image that sees its edge whole (``sum_e n_e l_e = sum_e n_e``). With
        every edge seen in every image the two are the same program. With missing data the
        edge scale lets the maximisation lengthen the edges seen in many images, where a
        longer bound raises many depths, at the expense of those seen in few. ``"auto"``
        solves both and keeps the solution closer to an isometry
        (:func:`isometry_residual`); it solves once where the two programs are the same.

    Returns
    -------
    ConeSolution
        Entries with no cone (every neighbour unseen in that image) are left NaN: nothing
        bounds their depth. If a round fails, the last successful round is returned with the
        failing status.
    """
    start = time.perf_counter()
    pairs = _edge_image_pairs(rays, seen, edges)
    settings = dict(
        rigidity=rigidity, n_rounds=n_rounds, tol=tol, outlier_price=outlier_price,
        lengths=lengths, smoothed_starts=smoothed_starts,
    )  # fmt: skip
    scales = _candidate_scales(length_scale, pairs, fixed=lengths is not None)
    solutions = [_solve_scaled(rays, pairs, scale, **settings) for scale in scales]
    if len(solutions) == 1:
        return solutions[0]
    residuals = [isometry_residual(rays, edges, s.depths, s.lengths) for s in solutions]
    kept = solutions[int(np.argmin(residuals))]
    return replace(
        kept, seconds=time.perf_counter() - start, n_solves=sum(s.n_solves for s in solutions)
    )


def _solve_scaled(
    rays: np.ndarray,
    pairs: _EdgeImagePairs,
    length_scale: LengthScale,
    *,
    rigidity: float,
    n_rounds: int,
    tol: float,
    outlier_price: float,
    lengths: np.ndarray | None,
    smoothed_starts: bool,
) -> ConeSolution:
    """:func:`solve_max_depth_cone` with one length scale (``"edges"`` or ``"pairs"``)."""
    start = time.perf_counter()
    program = _assemble_program(
        pairs,
        soft_bounds=bool(np.isfinite(outlier_price)),
        lengths=lengths,
        length_scale=length_scale,
    )
    status, best = _solve_program(program, _first_round_cost(program))
    n_solves, shrink = 1, 0.0
    if best is not None and rigidity > 0 and n_rounds > 0:
        cost = _consistency_cost(program, best, rigidity, outlier_price)
        starts = [best[program.depths]]
        if smoothed_starts:
            starts += _smoothed(rays, pairs, best)
        status, best, n_rounds_run, shrink = _cheapest_rounds(
            program, cost, best, starts, status, n_rounds=n_rounds, tol=tol
        )
        n_solves += n_rounds_run
    depths, lengths = _unpack(pairs, best)
    return ConeSolution(
        depths, lengths, status, time.perf_counter() - start, pairs.n_cones, n_solves, shrink,
        length_scale,
    )  # fmt: skip


def isometry_residual(
    rays: np.ndarray, edges: np.ndarray, depths: np.ndarray, lengths: np.ndarray
) -> float:
    """How far shapes are from keeping their edges' lengths: the mean of
    ``|1 - ||X_fi - X_fj|| / l_e|`` over the (image, edge) pairs with both depths known
    (dimensionless; inf if there is none).

    ``rays`` (F, P, 2), ``edges`` (E, 2) int, ``depths`` (F, P) NaN where unknown and
    ``lengths`` (E,) NaN where unused, as :class:`ConeSolution` has them. O(F E).
    """
    points = depths[..., None] * homogeneous(rays)
    spans = np.linalg.norm(points[:, edges[:, 0]] - points[:, edges[:, 1]], axis=2)
    ratios = (spans / lengths[None])[np.isfinite(spans) & np.isfinite(lengths)[None]]
    return float(np.mean(np.abs(1.0 - ratios))) if ratios.size else float("inf")


@dataclass(frozen=True)
class _EdgeImagePairs:
    """The (image, edge) pairs where both ends of an edge are seen, and their cone matrices.

    Attributes
    ----------
    constrained : ndarray of shape (F, P), bool
        Entries in at least one pair: the ``V`` depth unknowns, in row-major order.
    used_edges : ndarray of shape (L,), int
        Edges seen whole in at least one image: the ``L`` length unknowns, in order.
    n_edges : int
        Number ``E`` of edges given (used or not).
    diffs : list of 3 sparse matrices of shape (C, V)
        ``diffs[c] @ d`` is coordinate ``c`` of ``X_fi - X_fj`` for each of the ``C`` pairs.
    pick : sparse matrix of shape (C, L)
        ``pick @ l`` is the length bound ``l_e`` of each pair's edge.
    n_var, n_len, n_cones : int
        ``V``, ``L`` and ``C``.
    """

    constrained: np.ndarray
    used_edges: np.ndarray
    n_edges: int
    diffs: list[sp.csr_matrix]
    pick: sp.csr_matrix
    n_var: int
    n_len: int
    n_cones: int


def _edge_image_pairs(rays: np.ndarray, seen: np.ndarray, edges: np.ndarray) -> _EdgeImagePairs:
    """Find the (image, edge) pairs seen whole and build their cone matrices.

    ``rays`` (F, P, 2), ``seen`` (F, P) bool and ``edges`` (E, 2) int as in
    :func:`solve_max_depth_cone`.
    """
    edges = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    both = seen[:, edges[:, 0]] & seen[:, edges[:, 1]]  # (F, E)
    frame_of, edge_of = np.nonzero(both)
    used_edges = np.unique(edge_of)
    constrained = np.zeros_like(seen)
    constrained[frame_of, edges[edge_of, 0]] = True
    constrained[frame_of, edges[edge_of, 1]] = True
    # Only constrained entries become unknowns: an unconstrained depth would be unbounded.
    var_index = np.full(seen.shape, -1, dtype=np.int64)
    var_index[constrained] = np.arange(int(constrained.sum()))
    n_var = int(constrained.sum())
    edge_var = np.full(len(edges), -1, dtype=np.int64)
    edge_var[used_edges] = np.arange(used_edges.size)
    n_cones = frame_of.size

    q = homogeneous(rays)
    i_pts, j_pts = edges[edge_of, 0], edges[edge_of, 1]
    rows = np.arange(n_cones)
    cols = np.concatenate([var_index[frame_of, i_pts], var_index[frame_of, j_pts]])
    diffs = [
        sp.csr_matrix(
            (
                np.concatenate([q[frame_of, i_pts, c], -q[frame_of, j_pts, c]]),
                (np.concatenate([rows, rows]), cols),
            ),
            shape=(n_cones, n_var),
        )
        for c in range(3)
    ]
    pick = sp.csr_matrix(
        (np.ones(n_cones), (rows, edge_var[edge_of])), shape=(n_cones, used_edges.size)
    )
    return _EdgeImagePairs(
        constrained, used_edges, len(edges), diffs, pick, n_var, used_edges.size, n_cones
    )


@dataclass(frozen=True)
class _ConeProgram:
    """The rows of the program that every solve shares, in Clarabel's standard form.

    Clarabel solves: minimise ``c . x`` s.t. ``A x + s = b``, ``s`` in a product of cones.
    The unknowns are ``x = [depths (V), lengths (L), slacks s_fe (C), loosenings t_fe (T)]``;
    the slacks stay 0 in the plain program. With a finite outlier price (``T = C``; else
    ``T = 0``) each upper bound is loosened, ``||X_fi - X_fj|| <= l_e + t_fe``, so that a wrong
    track in a few images cannot inflate ``l_e``.

    Attributes
    ----------
    pairs : _EdgeImagePairs
        The pairs the cones come from.
    n_t, n_x : int
        ``T`` and the number of unknowns ``V + L + C + T``.
    scale_row : sparse matrix of shape (1 or L, n_x)
        Sums the lengths (set equal to ``L``: mean edge length 1), or picks each length when
        they are fixed.
    scale_rhs : ndarray of shape (1 or L,)
        What ``scale_row @ x`` equals: ``L``, or the fixed lengths.
    nonneg_block : sparse matrix of shape (n_x, n_x)
        ``-I``: every unknown is nonnegative.
    soc_block : sparse matrix of shape (4 C, n_x)
        Minus the rows ``(l_e + t_fe, X_fi - X_fj)`` of each pair, one size-4 cone per pair.
    """

    pairs: _EdgeImagePairs
    n_t: int
    n_x: int
    scale_row: sp.csr_matrix
    scale_rhs: np.ndarray
    nonneg_block: sp.csr_matrix
    soc_block: sp.csr_matrix

    @property
    def depths(self) -> slice:
        """Where the depths are in ``x``."""
        return slice(0, self.pairs.n_var)

    @property
    def lengths(self) -> slice:
        """Where the lengths are in ``x``."""
        return slice(self.pairs.n_var, self.pairs.n_var + self.pairs.n_len)

    @property
    def slacks(self) -> slice:
        """Where the shrink slacks ``s_fe`` are in ``x``."""
        start = self.pairs.n_var + self.pairs.n_len
        return slice(start, start + self.pairs.n_cones)


def _assemble_program(
    pairs: _EdgeImagePairs,
    *,
    soft_bounds: bool,
    lengths: np.ndarray | None = None,
    length_scale: LengthScale = "edges",
) -> _ConeProgram:
    """Build the shared rows: the length scale (``length_scale``, see
    :func:`solve_max_depth_cone`; or the fixed ``lengths`` (E,)), nonnegativity and the cones
    of the pairs."""
    n_var, n_len, n_cones = pairs.n_var, pairs.n_len, pairs.n_cones
    n_t = n_cones if soft_bounds else 0
    n_x = n_var + n_len + n_cones + n_t
    zero_d = sp.csr_matrix((n_cones, n_var))
    zero_s = sp.csr_matrix((n_cones, n_cones))
    loosen = sp.eye(n_cones, format="csr") if n_t else sp.csr_matrix((n_cones, 0))
    stacked = sp.vstack(
        [
            sp.hstack([zero_d, pairs.pick, zero_s, loosen]),
            *[
                sp.hstack(
                    [m, sp.csr_matrix((n_cones, n_len)), zero_s, sp.csr_matrix((n_cones, n_t))]
                )
                for m in pairs.diffs
            ],
        ]
    ).tocsr()
    # Clarabel wants each cone's 4 rows together: interleave the 4 blocks of C rows.
    order = (np.arange(4)[None, :] * n_cones + np.arange(n_cones)[:, None]).ravel()
    rows = np.zeros(n_len, dtype=np.int64) if lengths is None else np.arange(n_len)
    weights = _length_weights(pairs, length_scale) if lengths is None else np.ones(n_len)
    scale_row = sp.csr_matrix(
        (weights, (rows, n_var + np.arange(n_len))),
        shape=(1 if lengths is None else n_len, n_x),
    )
    rhs = np.array([weights.sum()]) if lengths is None else np.asarray(lengths)[pairs.used_edges]
    return _ConeProgram(
        pairs, n_t, n_x, scale_row, rhs, -sp.eye(n_x, format="csr"), -stacked[order]
    )


def _candidate_scales(
    length_scale: LengthScale, pairs: _EdgeImagePairs, *, fixed: bool
) -> list[LengthScale]:
    """The length scales to solve: the one asked for, or for ``"auto"`` both where they give
    different programs (lengths not ``fixed`` and the edges not all seen whole in the same
    number of images), else the edge scale alone."""
    if length_scale not in ("edges", "pairs", "auto"):
        raise ValueError(f"length_scale must be 'edges', 'pairs' or 'auto', got {length_scale!r}")
    if length_scale != "auto":
        return [length_scale]
    counts = _length_weights(pairs, "pairs")
    differ = not fixed and counts.size > 0 and np.ptp(counts) > 0
    return ["edges", "pairs"] if differ else ["edges"]


def _length_weights(pairs: _EdgeImagePairs, length_scale: LengthScale) -> np.ndarray:
    """Weight (L,) of each length in the scale row: 1 (``"edges"``), or the number of images
    that see the edge whole (``"pairs"``)."""
    if length_scale == "edges":
        return np.ones(pairs.n_len)
    return np.asarray(pairs.pick.sum(axis=0), dtype=np.float64).ravel()


def _solve_program(
    program: _ConeProgram, cost: np.ndarray, lower: sp.csr_matrix | None = None
) -> tuple[str, np.ndarray | None]:
    """Solve the program once with Clarabel.

    ``cost`` (n_x,) is the linear objective; ``lower`` (C, n_x), if given, adds the rows
    ``lower @ x >= 0`` (a consistency round's linearised lower bounds). Returns Clarabel's
    status and the solution ``x`` (n_x,), or None unless solved (or almost).
    """
    import clarabel  # the interior-point solver, imported only when a program is solved

    blocks = [program.scale_row, program.nonneg_block]
    cones = [clarabel.ZeroConeT(program.scale_rhs.size)]
    n_nonneg = program.n_x
    if lower is not None:
        blocks.append(-lower)
        n_nonneg += program.pairs.n_cones
    cones.append(clarabel.NonnegativeConeT(n_nonneg))
    blocks.append(program.soc_block)
    cones.extend([clarabel.SecondOrderConeT(4)] * program.pairs.n_cones)
    a_matrix = sp.vstack(blocks).tocsc()
    b_vector = np.zeros(a_matrix.shape[0])
    b_vector[: program.scale_rhs.size] = program.scale_rhs
    problem = (sp.csc_matrix((program.n_x, program.n_x)), cost, a_matrix, b_vector, cones)
    status, x = _clarabel(problem, CLARABEL_SETTINGS)
    if x is None and CLARABEL_SETTINGS:
        # The faster settings trade robustness for speed: an input they do not solve is
        # solved again with Clarabel's defaults before the program counts as failed.
        status, x = _clarabel(problem, {})
    return status, x


def _clarabel(problem: tuple, changed: dict[str, object]) -> tuple[str, np.ndarray | None]:
    """One Clarabel solve of ``problem`` (P, q, A, b, cones) with the ``changed`` settings;
    the status, and the solution unless it is not solved (or almost)."""
    import clarabel

    settings = clarabel.DefaultSettings()
    settings.verbose = False
    for name, value in changed.items():
        setattr(settings, name, value)
    solution = clarabel.DefaultSolver(*problem, settings).solve()
    status = str(solution.status).split(".")[-1]
    ok = status in ("Solved", "AlmostSolved")
    return status, (np.asarray(solution.x) if ok else None)


def _first_round_cost(program: _ConeProgram) -> np.ndarray:
    """Objective (n_x,) of the plain program: maximise the sum of depths."""
    cost = np.zeros(program.n_x)
    cost[program.depths] = -1.0
    cost[program.slacks.start :] = 1e3  # slacks are unused, make them expensive
    return cost


def _consistency_cost(
    program: _ConeProgram, first: np.ndarray, rigidity: float, outlier_price: float
) -> np.ndarray:
    """Objective (n_x,) of the consistency rounds, given the first round's solution ``first``.

    In dimensionless units: mean depth over the first round's mean depth, minus the price of
    the mean slack (lengths have mean 1).
    """
    n_var, n_cones = program.pairs.n_var, program.pairs.n_cones
    mean_depth = float(np.mean(first[program.depths]))
    cost = np.zeros(program.n_x)
    cost[program.depths] = -1.0 / (n_var * mean_depth)
    cost[program.slacks] = rigidity / n_cones
    if program.n_t:
        cost[program.slacks.stop :] = outlier_price / n_cones
    return cost


def _linearised_lower(program: _ConeProgram, previous: np.ndarray) -> sp.csr_matrix:
    """Rows (C, n_x) of ``u_fe . (X_fi - X_fj) - l_e + s_fe >= 0`` around depths ``previous``.

    ``u_fe`` is the unit direction of each pair's edge in the previous solution (V,).
    """
    pairs = program.pairs
    vectors = np.stack([m @ previous for m in pairs.diffs], axis=1)
    vectors /= np.maximum(np.linalg.norm(vectors, axis=1, keepdims=True), 1e-300)
    along = sum(sp.diags(vectors[:, c]) @ pairs.diffs[c] for c in range(3))
    return sp.hstack(
        [along, -pairs.pick, sp.eye(pairs.n_cones), sp.csr_matrix((pairs.n_cones, program.n_t))]
    ).tocsr()


def _consistency_rounds(
    program: _ConeProgram,
    cost: np.ndarray,
    best: np.ndarray,
    start: np.ndarray,
    status: str,
    *,
    n_rounds: int,
    tol: float,
) -> tuple[str, np.ndarray, int, float]:
    """Linearise the lower bounds around the depths ``start`` (V,), then around each round's
    solution, and re-solve, up to ``n_rounds`` times.

    ``best`` (n_x,) is the solution kept if the first round fails. Stops early when a round
    fails (keeping the last solution) or when the depths change by less than ``tol``. Returns
    the last status, the last solution, the rounds solved and the mean slack of the last
    solution.
    """
    n_solved, shrink, previous = 0, 0.0, start
    for _ in range(n_rounds):
        status, x = _solve_program(program, cost, _linearised_lower(program, previous))
        n_solved += 1
        if x is None:
            break
        best = x
        shrink = float(np.mean(best[program.slacks]))
        change = np.max(np.abs(best[program.depths] - previous)) / max(np.max(previous), 1e-300)
        previous = best[program.depths]
        if change < tol:
            break
    return status, best, n_solved, shrink


def _smoothed(rays: np.ndarray, pairs: _EdgeImagePairs, first: np.ndarray) -> list[np.ndarray]:
    """Starts (each (V,)) from the plain solution ``first`` (n_x,) smoothed per image; an
    entry the smoothing leaves unknown keeps its plain depth."""
    plain = first[: pairs.n_var]
    depths = _unpack(pairs, first)[0]
    starts = []
    for smoothed in smoothed_start_depths(rays, depths):
        start = smoothed[pairs.constrained]
        starts.append(np.where(np.isfinite(start) & (start > 0), start, plain))
    return starts


def _cheapest_rounds(
    program: _ConeProgram,
    cost: np.ndarray,
    best: np.ndarray,
    starts: list[np.ndarray],
    status: str,
    *,
    n_rounds: int,
    tol: float,
) -> tuple[str, np.ndarray, int, float]:
    """:func:`_consistency_rounds` from each of ``starts`` (each (V,)); the result of lowest
    ``cost`` among those whose rounds solved, else the first start's, with the rounds solved
    summed over the starts. Every round's solution is feasible for the lower bounds it
    linearises, so the costs compare like for like; ``best`` (the plain solution, kept when a
    first round fails) is not, and never competes."""
    results = [
        _consistency_rounds(program, cost, best, start, status, n_rounds=n_rounds, tol=tol)
        for start in starts
    ]
    solved = [r for r in results if r[1] is not best] or results[:1]
    chosen = min(solved, key=lambda r: float(cost @ r[1]))
    return chosen[0], chosen[1], sum(r[2] for r in results), chosen[3]


def _unpack(pairs: _EdgeImagePairs, x: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Depths (F, P) and lengths (E,) from a solution ``x``, NaN where not unknowns (or no x)."""
    depths = np.full(pairs.constrained.shape, np.nan)
    lengths = np.full(pairs.n_edges, np.nan)
    if x is not None:
        depths[pairs.constrained] = x[: pairs.n_var]
        lengths[pairs.used_edges] = x[pairs.n_var : pairs.n_var + pairs.n_len]
    return depths, lengths
