"""moju_cli.stop_reasons: the end of a solve in words, consistent with the test that ended it."""

from __future__ import annotations

import pytest

from moju_cli.stop_reasons import STOP_REASONS, describe_stop
from moju_core.defaults import EXACT_GAP_PRECISION, GAP_PRECISION


def test_converged_names_the_shape_gap_and_tol() -> None:
    assert describe_stop("converged", tol=1e-10, shape_gap=9.0e-11) == (
        "converged: the shape gap 9.0e-11 fell below tol 1e-10"
    )


def test_a_stalled_shape_gap_is_told_apart_from_one_below_tol() -> None:
    text = describe_stop("converged", tol=1e-12, shape_gap=5e-9)
    assert text.startswith("converged: the shape gap stalled at 5.0e-09")
    assert f"below {GAP_PRECISION:g}" in text


def test_an_exact_fit_that_stopped_at_its_precision_says_so() -> None:
    text = describe_stop("converged", tol=1e-10, shape_gap=9.5e-6, exact_fit=True)
    assert text == (
        f"converged: the shape gap 9.5e-06 fell below {EXACT_GAP_PRECISION:g}, the precision "
        "of an exact fit of the tracks (tol 1e-10 is finer)"
    )
    assert "stalled" not in text


@pytest.mark.parametrize("reason", ["rho_max", "max_iter"])
def test_other_reasons_read_from_the_table(reason: str) -> None:
    assert describe_stop(reason, tol=1e-4, shape_gap=1.0) == STOP_REASONS[reason]


def test_without_the_gap_the_table_is_used_and_pta_is_a_closed_form() -> None:
    assert describe_stop("converged") == STOP_REASONS["converged"]
    assert describe_stop("converged", method="pta", tol=0.0, shape_gap=0.0) == (
        "solved in closed form"
    )
