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
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

__all__ = ["ConeSolution", "solve_max_depth_cone"]


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
    """

    depths: np.ndarray
    lengths: np.ndarray
    status: str
    seconds: float
    n_cones: int
    n_solves: int = 1
    shrink: float = 0.0


def solve_max_depth_cone(
    rays: np.ndarray,
    seen: np.ndarray,
    edges: np.ndarray,
    *,
    rigidity: float = 30.0,
    n_rounds: int = 6,
    tol: float = 1e-3,
    outlier_price: float = np.inf,
) -> ConeSolution:
    """Solve the maximum-depth cone program on a (small) set of points.

    Cost: ``C = (#seen edge-image pairs) ~ F P k / 2`` cones of size 4; an interior-point
    method takes ``O(C)`` per sparse factorisation times a few tens of iterations (about 0.5 s
    for F = 10, P = 90, k = 8; keep ``P`` to a few hundred), times ``1 + n_rounds`` with
    the consistency term.

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

    Returns
    -------
    ConeSolution
        Entries with no cone (every neighbour unseen in that image) are left NaN: nothing
        bounds their depth. If a round fails, the last successful round is returned with the
        failing status.
    """
    import clarabel  # the interior-point solver, imported only when a program is solved

    start = time.perf_counter()
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

    q = np.concatenate([rays, np.ones(rays.shape[:2] + (1,))], axis=2)
    i_pts, j_pts = edges[edge_of, 0], edges[edge_of, 1]
    rows = np.arange(n_cones)
    cols = np.concatenate([var_index[frame_of, i_pts], var_index[frame_of, j_pts]])
    # diffs[c] @ d is coordinate c of X_fi - X_fj for every (image, edge) pair.
    diffs = [
        sp.csr_matrix(
            (np.concatenate([q[frame_of, i_pts, c], -q[frame_of, j_pts, c]]),
             (np.concatenate([rows, rows]), cols)),
            shape=(n_cones, n_var),
        )
        for c in range(3)
    ]
    pick = sp.csr_matrix(
        (np.ones(n_cones), (rows, edge_var[edge_of])), shape=(n_cones, used_edges.size)
    )
    n_len = used_edges.size

    # Clarabel's standard form: minimise c.x s.t. A x + s = b, s in a product of cones.
    # Unknowns x = [depths (n_var), lengths (n_len), slacks (n_cones)]; slacks stay 0 in
    # the plain program. Each cone row block is (l_e, X_fi - X_fj), interleaved per cone.
    # With a finite outlier price, a second slack t_fe >= 0 loosens each upper bound,
    # ||X_fi - X_fj|| <= l_e + t_fe, so that a wrong track in a few images cannot inflate l_e.
    n_t = n_cones if np.isfinite(outlier_price) else 0
    n_x = n_var + n_len + n_cones + n_t
    zero_d = sp.csr_matrix((n_cones, n_var))
    zero_s = sp.csr_matrix((n_cones, n_cones))
    loosen = sp.eye(n_cones, format="csr") if n_t else sp.csr_matrix((n_cones, 0))
    stacked = sp.vstack([
        sp.hstack([zero_d, pick, zero_s, loosen]),
        *[sp.hstack([m, sp.csr_matrix((n_cones, n_len)), zero_s,
                     sp.csr_matrix((n_cones, n_t))]) for m in diffs],
    ]).tocsr()
    order = (np.arange(4)[None, :] * n_cones + np.arange(n_cones)[:, None]).ravel()
    soc_block = -stacked[order]
    scale_row = sp.csr_matrix(
        (np.ones(n_len), (np.zeros(n_len, dtype=np.int64), n_var + np.arange(n_len))),
        shape=(1, n_x),
    )
    nonneg_block = -sp.eye(n_x, format="csr")  # depths, lengths and slacks >= 0

    def solve(cost: np.ndarray, lower: sp.csr_matrix | None) -> tuple[str, np.ndarray | None]:
        blocks = [scale_row, nonneg_block]
        cones = [clarabel.ZeroConeT(1)]
        n_nonneg = n_x
        if lower is not None:
            blocks.append(-lower)
            n_nonneg += n_cones
        cones.append(clarabel.NonnegativeConeT(n_nonneg))
        blocks.append(soc_block)
        cones.extend([clarabel.SecondOrderConeT(4)] * n_cones)
        a_matrix = sp.vstack(blocks).tocsc()
        b_vector = np.zeros(a_matrix.shape[0])
        b_vector[0] = n_len  # sum of lengths = E: mean edge length 1
        settings = clarabel.DefaultSettings()
        settings.verbose = False
        solution = clarabel.DefaultSolver(
            sp.csc_matrix((n_x, n_x)), cost, a_matrix, b_vector, cones, settings
        ).solve()
        status = str(solution.status).split(".")[-1]
        ok = status in ("Solved", "AlmostSolved")
        return status, (np.asarray(solution.x) if ok else None)

    cost = np.zeros(n_x)
    cost[:n_var] = -1.0
    cost[n_var + n_len:] = 1e3  # first round: slacks are unused, make them expensive
    status, x = solve(cost, None)
    best = x
    n_solves, shrink = 1, 0.0
    if best is not None and rigidity > 0 and n_rounds > 0:
        mean_depth = float(np.mean(best[:n_var]))
        # Objective in dimensionless units: mean depth over the first round's mean depth,
        # minus the price of the mean slack (lengths have mean 1).
        cost[:n_var] = -1.0 / (n_var * mean_depth)
        cost[n_var + n_len:n_var + n_len + n_cones] = rigidity / n_cones
        if n_t:
            cost[n_var + n_len + n_cones:] = outlier_price / n_cones
        for _ in range(n_rounds):
            previous = best[:n_var]
            vectors = np.stack([m @ previous for m in diffs], axis=1)
            vectors /= np.maximum(np.linalg.norm(vectors, axis=1, keepdims=True), 1e-300)
            along = sum(sp.diags(vectors[:, c]) @ diffs[c] for c in range(3))
            # u . (X_i - X_j) - l_e + s >= 0, a linear (nonnegative-cone) row per cone.
            lower = sp.hstack(
                [along, -pick, sp.eye(n_cones), sp.csr_matrix((n_cones, n_t))]
            ).tocsr()
            status, x = solve(cost, lower)
            n_solves += 1
            if x is None:
                break
            best = x
            shrink = float(np.mean(best[n_var + n_len:n_var + n_len + n_cones]))
            change = np.max(np.abs(best[:n_var] - previous)) / max(np.max(previous), 1e-300)
            if change < tol:
                break
    depths = np.full(seen.shape, np.nan)
    lengths = np.full(len(edges), np.nan)
    if best is not None:
        depths[constrained] = best[:n_var]
        lengths[used_edges] = best[n_var:n_var + n_len]
    return ConeSolution(
        depths, lengths, status, time.perf_counter() - start, n_cones, n_solves, shrink
    )
