"""docs/redundancy.md's fault table names the test of every row: each named test exists (in
tests/integration/test_pair_faults.py, or another test file of the project: the rows of what
the devices see across a take-over, of check's warnings), every row names one, and every test
of test_pair_faults.py is in the table.

Imports: the standard library only.
"""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def table_rows() -> list[list[str]]:
    doc = (ROOT / "docs" / "redundancy.md").read_text(encoding="utf-8")
    section = doc.split("## Faults: what the pair does, what a user sees", 1)[1].split("\n## ", 1)[0]
    lines = [ln for ln in section.splitlines() if ln.startswith("| ") and not ln.startswith("| fault ")]
    return [[c.strip() for c in ln.strip("|").split(" | ")] for ln in lines]


def names_of_tests_in(path: Path) -> set[str]:
    """The test functions of a module (module-level ``def test_...``, async too)."""
    return set(re.findall(r"^(?:async )?def (test_\w+)\(", path.read_text(encoding="utf-8"), re.M))


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
    tests = fault_tests()
    every = set().union(*(names_of_tests_in(p) for p in (ROOT / "tests").rglob("test_*.py")))
    assert named - every == set(), "named in the table, no such test"
    assert tests - named == set(), "in test_pair_faults.py, no row of the table names it"
