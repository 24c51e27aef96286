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

It is solved with cvxpy and Clarabel (an interior-point method).
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
        The solver's status (``"optimal"`` expected).
    seconds : float
        Wall time of building and solving.
    n_cones : int
        Number of (image, edge) cone constraints.
    """

    depths: np.ndarray
    lengths: np.ndarray
    status: str
    seconds: float
    n_cones: int


def solve_max_depth_cone(
    rays: np.ndarray, seen: np.ndarray, edges: np.ndarray, *, solver: str = "CLARABEL"
) -> ConeSolution:
    """Solve the maximum-depth cone program on a (small) set of points.

    Cost: ``C = (#seen edge-image pairs) ~ F P k / 2`` cones of size 3; an interior-point
    method takes ``O(C)`` per sparse factorisation times a few tens of iterations (about 1 s
    for F = 10, P = 90, k = 8; keep ``P`` to a few hundred).

    Parameters
    ----------
    rays : ndarray of shape (F, P, 2)
        Normalised image coordinates (dimensionless); only seen entries are read.
    seen : ndarray of shape (F, P), bool
        True where the point is seen.
    edges : ndarray of shape (E, 2), int
        Neighbour pairs.
    solver : str, default "CLARABEL"
        A cvxpy conic solver.

    Returns
    -------
    ConeSolution
        Entries with no cone (every neighbour unseen in that image) are left NaN: nothing
        bounds their depth.
    """
    import cvxpy as cp  # heavy import, needed only here

    start = time.perf_counter()
    n_frames, n_points = seen.shape
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
    depths_var = cp.Variable(n_var)
    lengths_var = cp.Variable(used_edges.size)
    coordinates = []
    for c in range(3):
        values = np.concatenate([q[frame_of, i_pts, c], -q[frame_of, j_pts, c]])
        diff = sp.csr_matrix(
            (values, (np.concatenate([rows, rows]), cols)), shape=(n_cones, n_var)
        )
        coordinates.append(diff @ depths_var)
    pick = sp.csr_matrix(
        (np.ones(n_cones), (rows, edge_var[edge_of])), shape=(n_cones, used_edges.size)
    )
    constraints = [
        depths_var >= 0,
        cp.SOC(pick @ lengths_var, cp.vstack(coordinates), axis=0),
        cp.sum(lengths_var) == used_edges.size,
    ]
    problem = cp.Problem(cp.Maximize(cp.sum(depths_var)), constraints)
    try:
        problem.solve(solver=solver)
        status = str(problem.status)
    except cp.error.SolverError as error:  # reported, not raised: the caller decides
        status = f"solver_error: {error}"
    depths = np.full(seen.shape, np.nan)
    lengths = np.full(len(edges), np.nan)
    if depths_var.value is not None:
        depths[constrained] = depths_var.value
        lengths[used_edges] = lengths_var.value
    return ConeSolution(depths, lengths, status, time.perf_counter() - start, n_cones)
