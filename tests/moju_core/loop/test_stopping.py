"""The loop's stopping test: shape gap below tol with the grouping settled, a gap stalled at the
SVD's precision, rho_max, and tol = 0."""

from __future__ import annotations

import pytest

from moju_core.defaults import EXACT_GAP_PRECISION, GAP_PRECISION, STALL_ITERATIONS
from moju_core.loop.stopping import StoppingTest, loop_tolerance


def test_a_gap_below_tol_converges_only_once_the_grouping_settled() -> None:
    stopping = StoppingTest(tol=1e-6, rho_max=1e8)
    assert stopping(1e-3, True, 1.0) is None
    assert stopping(1e-7, False, 1.0) is None
    assert stopping(1e-7, True, 1.0) == "converged"


def test_rho_max_stops_a_loop_that_has_not_converged() -> None:
    stopping = StoppingTest(tol=1e-6, rho_max=100.0)
    assert stopping(1e-3, True, 99.0) is None
    assert stopping(1e-3, True, 100.0) == "rho_max"
    assert StoppingTest(tol=1e-6, rho_max=100.0)(1e-7, True, 100.0) == "converged"  # first


@pytest.mark.parametrize("tol", [1e-12, 0.0])
def test_a_gap_stalled_below_the_precision_converges_unless_tol_is_zero(tol: float) -> None:
    stopping = StoppingTest(tol=tol, rho_max=1e8)
    gaps = [1e-6, 0.5 * GAP_PRECISION] + [0.9 * GAP_PRECISION] * STALL_ITERATIONS
    reasons = [stopping(gap, True, 1.0) for gap in gaps]
    assert stopping.smallest_gap == 0.5 * GAP_PRECISION
    assert stopping.since_smallest == STALL_ITERATIONS
    expected = "converged" if tol > 0 else None
    assert reasons[:-1] == [None] * (len(gaps) - 1) and reasons[-1] == expected


def test_a_new_smallest_gap_restarts_the_stall_count() -> None:
    stopping = StoppingTest(tol=1e-12, rho_max=1e8)
    stopping(0.5 * GAP_PRECISION, True, 1.0)
    for _ in range(STALL_ITERATIONS - 1):
        assert stopping(0.9 * GAP_PRECISION, True, 1.0) is None
    assert stopping(0.4 * GAP_PRECISION, True, 1.0) is None  # falling again
    assert stopping.since_smallest == 0


@pytest.mark.parametrize(
    ("tol", "exact_fit", "expected"),
    [
        (1e-10, True, EXACT_GAP_PRECISION),  # a finer tol than the exact fit can resolve
        (1e-3, True, 1e-3),  # a coarser one is kept
        (0.0, True, 0.0),  # no convergence test stays none
        (1e-10, False, 1e-10),  # a soft fit keeps tol
    ],
)
def test_the_loop_tolerance_of_an_exact_fit_is_its_precision(
    tol: float, exact_fit: bool, expected: float
) -> None:
    assert loop_tolerance(tol, exact_fit) == expected
