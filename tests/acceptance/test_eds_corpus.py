"""Real device files: every EDS/DCF of ``../shared/eds-corpus/`` (third-party files written by
device vendors and by other CANopen tools) that python canopen 2.4.1's ``import_od`` loads is
loaded by ``eds show``, accepted by ``check`` as a one-node config, and ``registers`` lists the
objects of its enabled PDO mappings; and no file, as is or damaged (truncated, bytes flipped,
lines dropped), gives a traceback: every refusal is one line with file, line and section.

The corpus is read from next to the clone (never copied into the repository); the tests skip
when it is absent."""

from __future__ import annotations

import io
import logging
import random
import re
import warnings
from pathlib import Path
from typing import Any

import canopen
import pytest

from gateway.checks import parse_checked_config
from gateway.cia301 import TYPE_NAMES
from gateway.cli import main
from gateway.config import ConfigError
from gateway.eds import lint, load_eds
from gateway.eds.parse import read_text
from gateway.profiles import ProfileError, load_node_profile

CORPUS = Path(__file__).resolve().parents[2] / ".." / "shared" / "eds-corpus"
FILES = sorted(p for p in CORPUS.glob("*") if p.suffix.lower() in (".eds", ".dcf")) if CORPUS.is_dir() else []
pytestmark = pytest.mark.skipif(not FILES, reason=f"no EDS corpus at {CORPUS}")

NODE_ID = 5
#: ``file:line: [section]: message`` on one line (``(no section)`` for a line before any)
REFUSAL = re.compile(r"^[^\n]+\.(eds|dcf):\d+: (\[[^\]\n]*\]|\(no section\)): [^\n]+$", re.I)


def reference_od(path: Path) -> canopen.ObjectDictionary | None:
    """python canopen's reading of the file (its text decoded as the gateway does: UTF-8, else
    Latin-1), None when it refuses the file."""
    fp = io.StringIO(read_text(path))
    fp.name = str(path)  # type: ignore[misc]  # import_od picks EDS or DCF by the name
    logging.disable(logging.CRITICAL)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return canopen.import_od(fp, NODE_ID)
    except Exception:
        return None
    finally:
        logging.disable(logging.NOTSET)


def _held(var: Any) -> Any:
    """A DCF's ParameterValue (what the device holds), else the EDS DefaultValue."""
    if var is None:
        return None
    return var.value if getattr(var, "value", None) is not None else var.default


def reference_pdo_objects(od: canopen.ObjectDictionary) -> set[str]:
    """Objects of the enabled PDO mappings, as python canopen reads them, that the file defines
    with a type the gateway serves."""
    out: set[str] = set()
    for comm_base, map_base in ((0x1800, 0x1A00), (0x1400, 0x1600)):
        for n in range(512):
            comm, mapping = od.get(comm_base + n), od.get(map_base + n)
            if comm is None or mapping is None or isinstance(comm, canopen.objectdictionary.ODVariable):
                continue
            cob = comm.subindices.get(1)
            if not isinstance(_held(cob), int) or _held(cob) & 0x80000000:
                continue
            if isinstance(mapping, canopen.objectdictionary.ODVariable) or 0 not in mapping.subindices:
                continue
            count = _held(mapping.subindices[0]) or 0
            for sub in range(1, int(count) + 1):
                entry = mapping.subindices.get(sub)
                raw = _held(entry)
                if not isinstance(raw, int) or not raw:
                    continue
                index, subindex = raw >> 16, (raw >> 8) & 0xFF
                target = od.get(index)
                if index < 0x1000 or target is None:
                    continue
                var = target if isinstance(target, canopen.objectdictionary.ODVariable) else target.subindices.get(subindex)
                if var is not None and var.data_type in TYPE_NAMES:
                    out.add(f"0x{index:04X}:{subindex:02X}")
    return out


LOADED = [p for p in FILES if reference_od(p) is not None]


def config_file(tmp_path: Path, eds: Path) -> Path:
    cfg = tmp_path / "one.yaml"
    cfg.write_text(f"can: {{interface: virtual, channel: corpus}}\nnodes:\n  - {{name: dev, node_id: {NODE_ID}, eds: '{eds}'}}\n")  # fmt: skip
    return cfg


def test_the_corpus_is_there_and_python_canopen_loads_most_of_it() -> None:
    assert len(FILES) >= 40 and len(LOADED) >= 40


@pytest.mark.parametrize("eds", LOADED, ids=lambda p: p.name[:60])
def test_every_file_python_canopen_loads_is_shown_checked_and_served(
    eds: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["eds", "show", str(eds), "--node-id", str(NODE_ID)]) == 0
    assert "| PDO | COB-ID |" in capsys.readouterr().out
    cfg = config_file(tmp_path, eds)
    assert main(["check", "-c", str(cfg)]) == 0
    out = capsys.readouterr().out
    assert out.startswith(f"{cfg}: OK\n")
    assert re.search(rf"^  {re.escape(str(eds.resolve()))}: \d+ warnings", out, re.M), out
    assert main(["registers", "-c", str(cfg)]) == 0
    registers = capsys.readouterr().out
    expected = reference_pdo_objects(reference_od(eds))  # type: ignore[arg-type]
    missing = sorted(o for o in expected if f"({o})" not in registers)
    assert not missing, f"objects of enabled PDOs not in the register map: {missing}"


# --------------------------------------------------------------------------- damaged files


def _damaged(rng: random.Random, data: bytes) -> bytes:
    how = rng.choice(["truncate", "flip", "drop"])
    if how == "truncate":
        return data[: rng.randrange(len(data))]
    if how == "flip":
        b = bytearray(data)
        for _ in range(rng.randint(1, 40)):
            b[rng.randrange(len(b))] = rng.randrange(256)
        return bytes(b)
    lines = data.split(b"\n")
    for _ in range(rng.randint(1, max(1, len(lines) // 10))):
        del lines[rng.randrange(len(lines))]
    return b"\n".join(lines)


CASES = 120  # bounded: seeded, so every run damages the same files the same way


def test_damaged_corpus_files_never_give_a_traceback(tmp_path: Path) -> None:
    rng = random.Random(20261126)
    small = [p for p in FILES if p.stat().st_size < 120_000]  # the big ones: same code, slower
    refused = 0
    for case in range(CASES):
        src = rng.choice(small)
        path = tmp_path / f"case{case}{src.suffix}"
        path.write_bytes(_damaged(rng, src.read_bytes()))
        eds = load_eds(path)  # only an unreadable file is refused here
        for w in eds.warnings:
            assert REFUSAL.match(str(w)), w
        result = lint(eds)
        for e in result.errors:
            assert REFUSAL.match(str(e)), e
        raw: dict[str, Any] = {"can": {"interface": "virtual", "channel": "x"},
                               "nodes": [{"name": "dev", "node_id": NODE_ID, "eds": str(path)}]}  # fmt: skip
        try:
            load_node_profile(parse_checked_config(raw, "cfg.yaml", environ={}).nodes[0])
        except ProfileError as exc:
            refused += 1
            assert REFUSAL.match(str(exc)), str(exc)
        except ConfigError as exc:
            refused += 1
            for line in exc.problems:
                assert line.startswith("cfg.yaml: nodes[0].eds: "), line
                assert REFUSAL.match(line.removeprefix("cfg.yaml: nodes[0].eds: ")), line
        else:
            assert not result.errors
    assert refused < CASES
