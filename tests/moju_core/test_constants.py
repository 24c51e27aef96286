"""Every named numeric constant of the solver path is classified in docs/constants.md.

The reference page docs/constants.md lists each module-level UPPER_CASE number of ``moju_core``
outside its file formats, datasets, video front end, result types, camera estimators and
perspective solve, with its kind and reason; a constant added without a row fails here.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
#: Parts of moju_core outside the audited solver path (benchmarks/structure_metrics.py's,
#: plus the camera estimators and the perspective solve, which have their own design).
NOT_AUDITED = (
    "datasets/",
    "io/",
    "footage/",
    "cameras/",
    "perspective.py",
    "ply.py",
    "result.py",
    "errors.py",
    "file_types.py",
)


def _numeric(value: ast.expr | None) -> bool:
    return value is not None and any(
        isinstance(node, ast.Constant)
        and isinstance(node.value, (int, float))
        and not isinstance(node.value, bool)
        for node in ast.walk(value)
    )


def solver_constants() -> set[str]:
    """The module-level UPPER_CASE names bound to numbers on the audited solver path."""
    names = set()
    for path in sorted((ROOT / "moju_core").rglob("*.py")):
        if any(part in path.relative_to(ROOT).as_posix() for part in NOT_AUDITED):
            continue
        for node in ast.parse(path.read_text()).body:
            if isinstance(node, ast.Assign):
                targets, value = node.targets, node.value
            elif isinstance(node, ast.AnnAssign):
                targets, value = [node.target], node.value
            else:
                continue
            for target in targets:
                if isinstance(target, ast.Name) and re.fullmatch(r"_?[A-Z][A-Z0-9_]*", target.id):
                    if _numeric(value):
                        names.add(target.id)
    return names


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
