"""docs/redundancy.md's fault table names the test of every row: each named test exists in
one of the pair's test files (``TEST_FILES``), every row names one, and every test of
tests/integration/test_pair_faults.py is in the table.

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


#: where a row's test may be: the processes, the role machine and nodes on a fake clock, the
#: generated sequences, the check, the driver, the health document and the console
TEST_FILES = (
    "integration/test_pair_faults.py", "integration/test_pair_random_faults.py",
    "unit/test_pair_machine.py", "unit/test_node_listening.py", "unit/test_pair_sequences.py",
    "unit/test_pair_check.py", "unit/test_driver_send.py", "unit/test_bus_clock.py",
    "unit/test_health.py", "browser/test_web_console.py",
)  # fmt: skip


def fault_tests(path: str = "integration/test_pair_faults.py") -> set[str]:
    tree = ast.parse((ROOT / "tests" / path).read_text())
    names = {f.name for f in tree.body if isinstance(f, ast.FunctionDef | ast.AsyncFunctionDef)}
    # a hypothesis state machine's test case is bound to a name: test_x = Machine.TestCase
    names |= {t.id for a in tree.body if isinstance(a, ast.Assign) for t in a.targets if isinstance(t, ast.Name)}
    return {n for n in names if n.startswith("test_")}


def test_every_row_of_the_fault_table_names_an_existing_test_and_every_test_has_its_row() -> None:
    rows = table_rows()
    assert len(rows) >= 10
    named: set[str] = set()
    for row in rows:
        names = re.findall(r"`(test_\w+)`", row[-1])
        assert names, f"the row {row[0]!r} names no test"
        named.update(names)
    anywhere = set().union(*(fault_tests(p) for p in TEST_FILES))
    assert named - anywhere == set(), "named in the table, in none of the pair's test files"
    tests = fault_tests()
    assert tests - named == set(), "in test_pair_faults.py, no row of the table names it"
