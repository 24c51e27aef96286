"""Every named numeric constant of the solver path is classified in docs/constants.md.

The reference page docs/constants.md lists each module-level UPPER_CASE number of ``moju_core``
outside its file formats, datasets, video front end and result types, with
its kind and reason; a constant added without a row fails here. A name bound in more than one
module is listed once per module, as ``NAME`` (``path``), so that one row cannot stand for
another module's constant.
"""

from __future__ import annotations

import re
import sys
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "benchmarks"))
from structure_metrics import NOT_SOLVER  # noqa: E402
from structure_metrics import solver_constants as _solver_constants  # noqa: E402

#: What benchmarks/structure_metrics.py leaves out of the solver path.
NOT_AUDITED = NOT_SOLVER


def solver_constants() -> set[str]:
    """The module-level UPPER_CASE names bound to numbers on the audited solver path."""
    return set(_solver_constants(ROOT, NOT_AUDITED))


def documented_constants() -> set[str]:
    """The names in backticks on the reference page docs/constants.md."""
    text = (ROOT / "docs" / "constants.md").read_text()
    return set(re.findall(r"`(_?[A-Z][A-Z0-9_]*)`", text))


def binding_modules(name: str) -> list[str]:
    """The audited modules (paths under ``moju_core/``) that bind ``name`` at module level."""
    binding = re.compile(rf"^{re.escape(name)}\s*(:[^=]*)?=", re.MULTILINE)
    return [
        path.relative_to(ROOT / "moju_core").as_posix()
        for path in sorted((ROOT / "moju_core").rglob("*.py"))
        if not any(part in path.relative_to(ROOT).as_posix() for part in NOT_AUDITED)
        and binding.search(path.read_text())
    ]


def test_every_solver_constant_is_classified_in_the_reference_page():
    missing = solver_constants() - documented_constants()
    assert not missing, f"constants without a row in docs/constants.md: {sorted(missing)}"


def test_the_doc_lists_no_constant_the_code_no_longer_has():
    stale = documented_constants() - solver_constants()
    assert not stale, f"rows of docs/constants.md for constants that are gone: {sorted(stale)}"


def test_a_name_bound_in_several_modules_has_a_row_for_each():
    text = (ROOT / "docs" / "constants.md").read_text()
    bindings = Counter(_solver_constants(ROOT, NOT_AUDITED))
    missing = [
        f"{name} ({module})"
        for name, count in bindings.items()
        if count > 1
        for module in binding_modules(name)
        if f"`{name}` (`{module}`)" not in text
    ]
    assert not missing, f"constants of one name without a row per module: {missing}"
