"""docs/redundancy.md's fault table names the test of every row: each named test exists (in
tests/integration/test_pair_faults.py, or another test file of the project: the role machine
and nodes on a fake clock, the generated sequences, the seeded random faults, what the devices
see across a take-over, check's refusals and warnings, the driver, the health document and the
console), every row names one, and every test of test_pair_faults.py is in the table.

Imports: the standard library only.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def table_rows() -> list[list[str]]:
    doc = (ROOT / "docs" / "redundancy.md").read_text(encoding="utf-8")
    section = doc.split("## Faults: what the pair does, what a user sees", 1)[1].split("\n## ", 1)[0]
    lines = [ln for ln in section.splitlines() if ln.startswith("| ") and not ln.startswith("| fault ")]
    return [[c.strip() for c in ln.strip("|").split(" | ")] for ln in lines]


def names_of_tests_in(path: Path) -> set[str]:
    """The tests of a module: module-level ``def test_...`` (async too), and a hypothesis
    state machine's test case bound to a name (``test_x = Machine.TestCase``)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    names = {f.name for f in tree.body if isinstance(f, ast.FunctionDef | ast.AsyncFunctionDef)}
    names |= {t.id for a in tree.body if isinstance(a, ast.Assign) for t in a.targets if isinstance(t, ast.Name)}
    return {n for n in names if n.startswith("test_")}


def fault_tests() -> set[str]:
    return names_of_tests_in(ROOT / "tests" / "integration" / "test_pair_faults.py")


def test_every_row_of_the_fault_table_names_an_existing_test_and_every_test_has_its_row() -> None:
    rows = table_rows()
    assert len(rows) >= 10
    named: set[str] = set()
    for row in rows:
        names = re.findall(r"`(test_\w+)`", row[-1])
        assert names, f"the row {row[0]!r} names no test"
        named.update(names)
    every = set().union(*(names_of_tests_in(p) for p in (ROOT / "tests").rglob("test_*.py")))
    assert named - every == set(), "named in the table, no such test"
    assert fault_tests() - named == set(), "in test_pair_faults.py, no row of the table names it"
