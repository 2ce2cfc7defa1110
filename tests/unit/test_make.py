"""The Makefile and the repository's own settings as a new user meets them: a ``.venv`` made by
another Python is made again (not reused and failing), ``make clean`` and git know ``dist/``,
``make tools`` installs the ``nc -N`` the docs use, and every skipped test says why."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

pytestmark = pytest.mark.skipif(shutil.which("make") is None, reason="no make on this machine")


def project(tmp_path: Path, recorded: str) -> Path:
    """A copy of the Makefile and pyproject.toml with a .venv installed by ``recorded``."""
    for name in ("Makefile", "pyproject.toml"):
        shutil.copy(ROOT / name, tmp_path / name)
    venv = tmp_path / ".venv"
    (venv / "bin").mkdir(parents=True)
    (venv / "bin" / "python").touch()
    (venv / ".python").write_text(recorded + "\n", encoding="utf-8")
    for stamp in (".installed-run", ".installed-test"):
        (venv / stamp).touch()  # newer than pyproject.toml: installed
    return tmp_path


def dry_run(where: Path, *targets: str) -> str:
    r = subprocess.run(
        ["make", "-n", f"PYTHON={sys.executable}", *targets],
        cwd=where,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 0, r.stderr
    return r.stdout


def this_python() -> str:
    return f"{sys.executable} {sys.version.split()[0]}"


def test_a_venv_made_by_another_python_is_made_again(tmp_path: Path) -> None:
    where = project(tmp_path, "/usr/bin/python3.10 3.10.12")
    out = dry_run(where, ".venv/.installed-run")
    assert "another Python (/usr/bin/python3.10 3.10.12)" in out
    assert "rm -rf .venv" in out and f"{sys.executable} -m venv .venv" in out
    assert f"echo '{this_python()}' > .venv/.python" in out
    assert "pip install -q -e ." in out


def test_a_venv_made_by_this_python_is_reused(tmp_path: Path) -> None:
    where = project(tmp_path, this_python())
    out = dry_run(where, ".venv/.installed-run")
    assert "'.venv/.installed-run' is up to date" in out, out


def test_make_clean_removes_dist_and_git_ignores_it() -> None:
    assert "rm -rf .venv build dist" in dry_run(ROOT, "clean")
    r = subprocess.run(
        ["git", "check-ignore", "-q", "dist/canopen_gateway-0.1.0-py3-none-any.whl"], cwd=ROOT
    )
    assert r.returncode == 0, "dist/ (pip wheel -w dist .) is not ignored"


def test_make_tools_installs_the_netcat_the_docs_use() -> None:
    out = dry_run(ROOT, "tools")
    assert "netcat-openbsd" in out and "nc -h" in out


def test_skipped_tests_say_why(tmp_path: Path) -> None:
    test = tmp_path / "test_skip.py"
    test.write_text(
        "import pytest\n\n@pytest.mark.skip(reason='no EDS corpus here')\ndef test_x():\n    pass\n"
    )
    r = subprocess.run(
        [sys.executable, "-m", "pytest", "-c", str(ROOT / "pyproject.toml"), "-q", str(test)],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert "SKIPPED [1]" in r.stdout and "no EDS corpus here" in r.stdout, r.stdout


def test_test_quick_is_the_lint_and_the_unit_tests_and_test_the_whole_suite(tmp_path: Path) -> None:
    where = project(tmp_path, this_python())
    quick = [line for line in dry_run(where, "test-quick").splitlines() if not line.startswith("make")]  # fmt: skip
    assert [line.split()[0].rsplit("/", 1)[-1] for line in quick] == ["ruff", "lint-imports", "mypy", "python"]
    assert quick[-1].endswith("-m pytest -q tests/unit")
    whole = [line for line in dry_run(where, "test").splitlines() if not line.startswith("make")]
    assert whole[-1].endswith("-m pytest -q")  # every test directory
