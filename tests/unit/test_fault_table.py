"""docs/redundancy.md's fault table names the test of every row: each named test exists in
tests/integration/test_pair_faults.py, every row names one, and every test of that file is in
the table.

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


def fault_tests() -> set[str]:
    tree = ast.parse((ROOT / "tests" / "integration" / "test_pair_faults.py").read_text())
    return {f.name for f in tree.body if isinstance(f, ast.FunctionDef) and f.name.startswith("test_")}


def test_every_row_of_the_fault_table_names_an_existing_test_and_every_test_has_its_row() -> None:
    rows = table_rows()
    assert len(rows) >= 10
    named: set[str] = set()
    for row in rows:
        names = re.findall(r"`(test_\w+)`", row[-1])
        assert names, f"the row {row[0]!r} names no test"
        named.update(names)
    tests = fault_tests()
    assert named - tests == set(), "named in the table, not in test_pair_faults.py"
    assert tests - named == set(), "in test_pair_faults.py, no row of the table names it"
