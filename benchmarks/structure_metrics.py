"""Size measures of the solver's code: the longest functions and the named numeric constants.

    python benchmarks/structure_metrics.py [ROOT]

ROOT is a checkout (default: this one). Prints the three longest functions of ``moju_core``
(lines, docstrings included) and the number of module-level UPPER_CASE names bound to
numbers on the solver path (``moju_core`` without its file formats, datasets, video front end
and result types). Run it on an export of an older commit
(``git archive REV moju_core | tar -x -C DIR``) to compare.
"""

from __future__ import annotations

import ast
import re
import sys
from pathlib import Path

#: Parts of moju_core that are not the solver path.
NOT_SOLVER = (
    "datasets/",
    "io/",
    "footage/",
    "render.py",
    "tracking.py",
    "video.py",
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


def solver_constants(root: Path, excluded: tuple[str, ...] = NOT_SOLVER) -> list[str]:
    """Module-level UPPER_CASE names bound to numbers in ``root/moju_core``, outside the
    paths that contain one of ``excluded`` (one entry per binding)."""
    names = []
    for path in sorted((root / "moju_core").rglob("*.py")):
        if any(part in path.relative_to(root).as_posix() for part in excluded):
            continue
        for node in ast.parse(path.read_text()).body:
            if isinstance(node, ast.Assign):
                targets, value = node.targets, node.value
            elif isinstance(node, ast.AnnAssign):
                targets, value = [node.target], node.value
            else:
                continue
            names += [
                target.id
                for target in targets
                if isinstance(target, ast.Name)
                and re.fullmatch(r"_?[A-Z][A-Z0-9_]*", target.id)
                and _numeric(value)
            ]
    return names


def main() -> None:
    root = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).resolve().parents[1]
    functions = []
    for path in sorted((root / "moju_core").rglob("*.py")):
        name = path.relative_to(root).as_posix()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                functions.append((node.end_lineno - node.lineno + 1, f"{name}:{node.name}"))
    for lines, name in sorted(functions, reverse=True)[:3]:
        print(f"{lines:4d} lines  {name}")
    print(f"named numeric constants on the solver path: {len(solver_constants(root))}")


if __name__ == "__main__":
    main()
