"""Why a solve stopped, in words: the one table the ``moju`` commands print from."""

from __future__ import annotations

from moju_core.defaults import GAP_PRECISION
from moju_core.loop.stopping import loop_tolerance

#: What each stop reason of :attr:`moju_core.result.Result.stop_reason` means, for humans.
STOP_REASONS = {
    "converged": "converged: the shape gap fell below tol",
    "rho_max": "stopped: the penalty reached rho_max",
    "max_iter": "stopped: max_iter iterations reached",
}


def describe_stop(
    stop_reason: str,
    *,
    method: str | None = None,
    tol: float | None = None,
    shape_gap: float | None = None,
    exact_fit: bool = False,
) -> str:
    """One phrase for a solve's end, e.g. ``"converged: the shape gap 9.0e-11 fell below
    tol 1e-10"``.

    The loop tests the shape gap ``||S# - f(S)||_inf`` (``history["gap_shape"]``), not the
    larger gap of the coefficients that the progress bar shows while iterating; with the last
    shape gap and ``tol`` the phrase says which of the convergence tests ended the loop:
    below ``tol``; below the exact fit's precision when the loop fitted the tracks exactly
    (``exact_fit``, :attr:`moju_core.result.Diagnostics.exact_fit`;
    :func:`moju_core.loop.stopping.loop_tolerance`); or stalled below ``GAP_PRECISION`` (the
    precision of the S# step).
    """
    if method == "pta" and stop_reason == "converged":
        return "solved in closed form"
    reason = STOP_REASONS.get(stop_reason, stop_reason)
    if stop_reason != "converged" or shape_gap is None or tol is None:
        return reason
    if shape_gap < tol:
        return f"converged: the shape gap {shape_gap:.1e} fell below tol {tol:g}"
    limit = loop_tolerance(tol, exact_fit)
    if shape_gap < limit:
        return (
            f"converged: the shape gap {shape_gap:.1e} fell below {limit:g}, the precision of "
            f"an exact fit of the tracks (tol {tol:g} is finer)"
        )
    return (
        f"converged: the shape gap stalled at {shape_gap:.1e}, below {GAP_PRECISION:g} (the "
        "precision of the S# step)"
    )
