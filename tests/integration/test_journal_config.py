"""``journal.path`` is checked by ``canopen-gateway check`` and at start: a directory that cannot
be created or written is refused with exit code 2 and one line naming the file, ``journal.path``
and the operating system's reason; a good one is created. A gateway process started on a
damaged journal starts with a fresh one, keeps the damaged file aside and says so in one log
line. The example of docs/zenoh.md is the
tested one (docs/examples/backfill.py)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import yaml

from canopen_gateway.journal import Journal
from tests.helpers import free_port, gateway_process, unique_channel, wait_ready

ROOT = Path(__file__).resolve().parents[2]


def write_config(tmp_path: Path, journal: str) -> Path:
    raw = {
        "gateway": {"name": f"j{free_port()}"},
        "can": {"interface": "virtual", "channel": unique_channel()},
        "nodes": [{"name": "wire", "node_id": 1, "profile": "sgh10"}],
        "modbus": {"port": free_port()},
        "zenoh": {"listen": [f"tcp/127.0.0.1:{free_port()}"]},
        "journal": {"path": journal},
    }
    path = tmp_path / "gw.yaml"
    path.write_text(yaml.safe_dump(raw), encoding="utf-8")
    return path


def test_check_and_run_refuse_a_journal_path_that_cannot_be_created(tmp_path: Path) -> None:
    (tmp_path / "a-file").write_text("")
    cfg = write_config(tmp_path, "a-file/journal")
    for args in (["check", "-c", str(cfg)], None):
        if args is None:
            proc = gateway_process(cfg)
        else:
            proc = subprocess.Popen(
                [sys.executable, "-m", "canopen_gateway", *args],
                cwd=ROOT,
                stdout=subprocess.PIPE,
                stderr=subprocess.PIPE,
                text=True,
            )
        out, err = proc.communicate(timeout=60)
        assert proc.returncode == 2, (args, out, err)
        lines = [line for line in (err + out).splitlines() if "journal.path" in line]
        assert len(lines) == 1 and "Traceback" not in err
        assert str(cfg) in lines[0] and "Not a directory" in lines[0]


def test_check_creates_a_missing_journal_directory(tmp_path: Path) -> None:
    cfg = write_config(tmp_path, "state/journal")  # relative to the config file
    proc = subprocess.run(
        [sys.executable, "-m", "canopen_gateway", "check", "-c", str(cfg)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "state" / "journal").is_dir()


def test_the_docs_example_is_the_tested_one() -> None:
    doc = (ROOT / "docs/zenoh.md").read_text(encoding="utf-8")
    example = (ROOT / "docs/examples/backfill.py").read_text(encoding="utf-8")
    body = example[example.index("def rfc3339") : example.index("\n\nif __name__")]
    assert body in doc


def test_a_gateway_on_a_damaged_journal_starts_fresh_and_keeps_the_file_aside(
    tmp_path: Path,
) -> None:
    cfg = write_config(tmp_path, "journal")
    (tmp_path / "journal").mkdir()
    damaged = tmp_path / "journal" / "journal.sqlite3"
    damaged.write_bytes(b"not a database at all " * 500)
    proc = gateway_process(cfg)
    try:
        wait_ready(proc)
    finally:
        proc.terminate()
        _, err = proc.communicate(timeout=30)
    aside = [p for p in (tmp_path / "journal").iterdir() if ".damaged-" in p.name]
    assert len(aside) == 1 and aside[0].read_bytes() == b"not a database at all " * 500
    lines = [line for line in err.splitlines() if "damaged" in line]
    assert len(lines) == 1 and str(damaged) in lines[0] and aside[0].name in lines[0]
    fresh = Journal(tmp_path / "journal")
    fresh.open()  # the file the gateway made is a journal of this version
    assert fresh.set_aside is None
    fresh.stop()
