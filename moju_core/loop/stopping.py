"""When the ADMM loop stops (Algorithm 1, steps 13-15, with the project's convergence rule).

The paper stops on ``max(gap_shape, gap_coefficients) < tol``. The C-Z split of the LRR step
closes only like ``beta3 / rho`` (C follows the kernel, which moves with S), so that test
would always run to ``rho_max``; C and Z steer the grouping only, so the loop stops when the
shape gap is below tol and the last regrouping moved (almost) no trajectory: at most
``SETTLED_MOVE_FRACTION`` of them (:attr:`moju_core.loop.loop_state.LoopState.grouping_settled`).
A gap below ``GAP_PRECISION`` that has stopped falling for ``STALL_ITERATIONS`` iterations is
at the precision of the S# step (its Gram-matrix SVD); it would not reach a smaller tol, and
counts as converged too. ``tol = 0`` turns the convergence test off. A loop that fits the
tracks exactly stops at a shape gap of ``EXACT_GAP_PRECISION`` whatever smaller tol was asked
(:func:`loop_tolerance`).
"""

from __future__ import annotations

import numpy as np

from moju_core.defaults import EXACT_GAP_PRECISION, GAP_PRECISION, STALL_ITERATIONS
from moju_core.result import StopReason


def loop_tolerance(tol: float, exact_fit: bool) -> float:
    """The shape-gap tolerance the loop stops at: ``tol``, or at least
    :data:`moju_core.defaults.EXACT_GAP_PRECISION` when it fits the tracks exactly (below it
    the gap is rounding). 0 stays 0 (no convergence test)."""
    return max(tol, EXACT_GAP_PRECISION) if exact_fit and tol > 0 else tol


class StoppingTest:
    """The loop's stopping test, called once per iteration after the multiplier update.

    Parameters
    ----------
    tol : float
        Tolerance on the shape gap ``max|S# - f(S)|``; 0: never converged.
    rho_max : float
        Largest penalty: the loop stops once rho has reached it.

    Attributes
    ----------
    smallest_gap : float
        Smallest shape gap seen so far (inf before the first call).
    since_smallest : int
        Iterations since it was seen.
    """

    def __init__(self, tol: float, rho_max: float) -> None:
        self.tol = tol
        self.rho_max = rho_max
        self.smallest_gap = np.inf
        self.since_smallest = 0

    def at_precision(self) -> bool:
        """The gap is below ``GAP_PRECISION`` and has not fallen for ``STALL_ITERATIONS``."""
        return (
            self.tol > 0  # tol = 0: no convergence test at all
            and self.smallest_gap < GAP_PRECISION
            and self.since_smallest >= STALL_ITERATIONS
        )

    def __call__(self, gap_shape: float, grouping_settled: bool, rho: float) -> StopReason | None:
        """Why to stop after this iteration, or None to go on.

        Parameters
        ----------
        gap_shape : float
            This iteration's shape gap ``max|S# - f(S)|``.
        grouping_settled : bool
            The last regrouping moved at most ``SETTLED_MOVE_FRACTION`` of the trajectories.
        rho : float
            This iteration's penalty.

        Returns
        -------
        StopReason or None
        """
        if gap_shape < self.smallest_gap:
            self.smallest_gap, self.since_smallest = gap_shape, 0
        else:
            self.since_smallest += 1
        if (gap_shape < self.tol or self.at_precision()) and grouping_settled:
            return StopReason.CONVERGED
        if rho >= self.rho_max:
            return StopReason.RHO_MAX
        return None
