"""Functions a reader can hold: no function or method of the gateway package runs over 80
lines (counted from its ``def`` line to its last line, nested functions counted inside their
outer one as well as on their own). A long builder becomes a table or its named steps."""

from __future__ import annotations

import ast
from pathlib import Path

GATEWAY = Path(__file__).resolve().parents[2] / "canopen_gateway"
MAX_LINES = 80


def _function_lengths(path: Path, root: Path = GATEWAY) -> dict[str, int]:
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    out = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            assert node.end_lineno is not None
            out[f"{path.relative_to(root)}:{node.lineno} {node.name}"] = (
                node.end_lineno - node.lineno + 1
            )
    return out


def test_no_function_of_the_gateway_is_over_80_lines() -> None:
    lengths: dict[str, int] = {}
    for p in sorted(GATEWAY.rglob("*.py")):
        lengths |= _function_lengths(p)
    assert len(lengths) > 500  # the walk found the package's functions
    too_long = {name: n for name, n in lengths.items() if n > MAX_LINES}
    assert too_long == {}


def test_the_count_sees_a_long_function_and_a_nested_one(tmp_path: Path) -> None:
    body = "".join(f"    x{i} = {i}\n" for i in range(MAX_LINES - 3))
    src = tmp_path / "probe.py"
    src.write_text(
        f"def long():\n{body}    def inner():\n        return 1\n    return inner\n\n\n"
        "def short():\n    return 1\n",
        encoding="utf-8",
    )
    assert _function_lengths(src, tmp_path) == {
        "probe.py:1 long": MAX_LINES + 1,
        f"probe.py:{MAX_LINES - 1} inner": 2,
        f"probe.py:{MAX_LINES + 4} short": 2,
    }
