"""Every named numeric constant of the solver path is classified in docs/constants.md.

The reference page docs/constants.md lists each module-level UPPER_CASE number of ``moju_core``
outside its file formats, datasets, video front end, result types, camera estimators and
perspective solve, with its kind and reason; a constant added without a row fails here.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "benchmarks"))
from structure_metrics import NOT_SOLVER  # noqa: E402
from structure_metrics import solver_constants as _solver_constants  # noqa: E402

#: Beyond what benchmarks/structure_metrics.py leaves out of the solver path: the camera
#: estimators and the perspective solve, which have their own design.
NOT_AUDITED = (*NOT_SOLVER, "cameras/", "perspective.py")


def solver_constants() -> set[str]:
    """The module-level UPPER_CASE names bound to numbers on the audited solver path."""
    return set(_solver_constants(ROOT, NOT_AUDITED))


def documented_constants() -> set[str]:
    """The names in backticks on the reference page docs/constants.md."""
    text = (ROOT / "docs" / "constants.md").read_text()
    return set(re.findall(r"`(_?[A-Z][A-Z0-9_]*)`", text))


def test_every_solver_constant_is_classified_in_the_reference_page():
    missing = solver_constants() - documented_constants()
    assert not missing, f"constants without a row in docs/constants.md: {sorted(missing)}"


def test_the_doc_lists_no_constant_the_code_no_longer_has():
    stale = documented_constants() - solver_constants()
    assert not stale, f"rows of docs/solver.md for constants that are gone: {sorted(stale)}"
