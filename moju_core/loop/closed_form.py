"""Method ``pta`` (Akhter et al.'s trajectory basis, :mod:`moju_core.pta`) in the loop's form.

It has no loop: one closed-form least-squares solve, ``O(F P K^2)``, returned as the
:class:`~moju_core.loop.admm.LoopOutput` of one converged iteration, so that the solver
packages every method's result the same way.
"""

from __future__ import annotations

import numpy as np

from moju_core import pta
from moju_core.cameras import projection
from moju_core.loop.admm import IterationHook, LoopOutput
from moju_core.result import StopReason, TrajectoryBasisFit


def solve_pta(
    tracks: np.ndarray,
    rotations: np.ndarray,
    n_bases: int,
    hook: IterationHook,
    observed: np.ndarray | None = None,
) -> LoopOutput:
    """One closed-form :func:`moju_core.pta.solve` (``n_bases`` as there), reported as a
    single converged iteration of the loop.

    The :class:`Result` contract holds as for the iterative methods: labels are all 0 (no
    local groups), ``history`` has one entry per key (gap 0: there is no split to close; rho 0:
    no penalty; the reprojection error and nuclear norm of the solution; 0 relabelled) and the
    stop reason is ``"converged"``.
    """
    n_frames, _, n_points = tracks.shape
    shapes, fit = pta.solve(tracks, rotations, n_bases, observed)
    residual = projection.project(rotations, shapes) - tracks
    if observed is not None:
        residual = residual[np.broadcast_to(observed[:, None, :], residual.shape)]
    nuclear = float(np.linalg.svd(shapes.reshape(n_frames, 3 * n_points), compute_uv=False).sum())
    hook(1, 0.0, 0.0)
    history = {
        "gap": 0.0,
        "gap_shape": 0.0,
        "gap_coefficients": 0.0,
        "rho": 0.0,
        "reprojection": float(np.sqrt(np.mean(residual**2))),
        "nuclear_norm": nuclear,
        "relabelled": 0.0,
    }
    return LoopOutput(
        shapes=shapes,
        rotations=rotations,
        labels=np.zeros(n_points, dtype=np.int64),
        history={key: np.array([value]) for key, value in history.items()},
        n_iter=1,
        stop_reason=StopReason.CONVERGED,
        n_groups=1,
        trajectory_basis=TrajectoryBasisFit(rank=int(fit["rank"]), condition=fit["condition"]),
    )
