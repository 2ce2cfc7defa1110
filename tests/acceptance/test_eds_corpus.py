"""Real device files: every EDS/DCF of ``../shared/eds-corpus/`` (third-party files written by
device vendors and by other CANopen tools) that python canopen 2.4.1's ``import_od`` loads is
loaded by ``eds show``, accepted by ``check`` as a one-node config, and ``registers`` lists the
objects of its enabled PDO mappings; every object of those mappings is a register point of its
CiA 301 type and size (an input for a TPDO, a holding register for an RPDO, both for an object
in both), and a PDO built by python canopen's encoding of each object decodes to the registers
docs/modbus.md gives (an RPDO from those registers to the same bytes); and no file, as is or damaged (truncated, bytes flipped,
lines dropped), gives a traceback: every refusal is one line with file, line and section.

The corpus is read from next to the clone (never copied into the repository); the tests skip
when it is absent."""

from __future__ import annotations

import io
import logging
import random
import re
import struct
import warnings
from pathlib import Path
from typing import Any

import canopen
import pytest
from canopen.objectdictionary import datatypes as dt

from canopen_gateway.canopen.cia301 import TYPE_NAMES
from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.cli import main
from canopen_gateway.config import ConfigError
from canopen_gateway.eds import lint, load_eds
from canopen_gateway.eds.parse import read_text
from canopen_gateway.modbus.protocol import from_registers, to_registers
from canopen_gateway.northbound.regmap import build_register_map
from canopen_gateway.pdo.codec import compile_node
from canopen_gateway.profiles import ProfileError, load_node_profile
from tests.helpers import parse_checked_config, with_nodes

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


# --------------------------------------------------------------------------- every PDO signal

#: register type and count of each CiA 301 basic type (CiA 301 7.4.7.1 table 44; docs/modbus.md
#: "Types"); strings take a register per two bytes
REGISTERS: dict[int, tuple[str, int]] = {
    dt.BOOLEAN: ("uint16", 1), dt.INTEGER8: ("int16", 1), dt.UNSIGNED8: ("uint16", 1),
    dt.INTEGER16: ("int16", 1), dt.UNSIGNED16: ("uint16", 1), dt.INTEGER24: ("int32", 2),
    dt.UNSIGNED24: ("uint32", 2), dt.INTEGER32: ("int32", 2), dt.UNSIGNED32: ("uint32", 2),
    dt.REAL32: ("float32", 2), dt.INTEGER40: ("int64", 4), dt.INTEGER48: ("int64", 4),
    dt.INTEGER56: ("int64", 4), dt.INTEGER64: ("int64", 4), dt.UNSIGNED40: ("uint64", 4),
    dt.UNSIGNED48: ("uint64", 4), dt.UNSIGNED56: ("uint64", 4), dt.UNSIGNED64: ("uint64", 4),
    dt.REAL64: ("float64", 4), dt.TIME_OF_DAY: ("time_of_day", 4),
    dt.TIME_DIFFERENCE: ("time_difference", 4),
}  # fmt: skip
STRINGS = (dt.VISIBLE_STRING, dt.OCTET_STRING)


def reference_pdos(od: canopen.ObjectDictionary) -> list[tuple[str, int, list[tuple[int, int, int, Any]]]]:
    """Every enabled TPDO and RPDO as python canopen reads the file: (kind, number, entries of
    (index, sub, bits, the ODVariable or None for a dummy))."""
    out = []
    for kind, comm_base, map_base in (("tpdo", 0x1800, 0x1A00), ("rpdo", 0x1400, 0x1600)):
        for n in range(512):
            comm, mapping = od.get(comm_base + n), od.get(map_base + n)
            if comm is None or mapping is None or isinstance(comm, canopen.objectdictionary.ODVariable):
                continue
            cob = _held(comm.subindices.get(1))
            if not isinstance(cob, int) or cob & 0x80000000:
                continue
            if isinstance(mapping, canopen.objectdictionary.ODVariable) or 0 not in mapping.subindices:
                continue
            entries = []
            for sub in range(1, int(_held(mapping.subindices[0]) or 0) + 1):
                raw = _held(mapping.subindices.get(sub))
                if not isinstance(raw, int) or not raw:
                    continue
                index, subindex, bits = raw >> 16, (raw >> 8) & 0xFF, raw & 0xFF
                target = od.get(index)
                var = None
                if index >= 0x1000 and target is not None:
                    var = target if isinstance(target, canopen.objectdictionary.ODVariable) else target.subindices.get(subindex)
                entries.append((index, subindex, bits, var))
            if entries:
                out.append((kind, n + 1, entries))
    return out


def sample_value(data_type: int, bits: int) -> Any:
    """A value of the type that fits ``bits`` (the mapped length) and sets its high bits."""
    if data_type in STRINGS:
        return bytes(range(0x41, 0x41 + bits // 8))
    if data_type == dt.REAL32:
        return -1234.5
    if data_type == dt.REAL64:
        return 6.02214076e23
    if data_type == dt.BOOLEAN:
        return 1
    if data_type in (dt.TIME_OF_DAY, dt.TIME_DIFFERENCE):
        return 15671 << 32 | 30_600_250  # 2026-11-27 08:30:00.250, CiA 301 7.1.6.5
    width = min(bits, REGISTERS[data_type][1] * 16)
    if data_type in dt.SIGNED_TYPES:
        return -(1 << (width - 2)) - 3
    return (1 << (width - 1)) + 5


def pdo_bytes(od_entries: list[tuple[int, int, int, Any]], values: list[Any]) -> bytes:
    """A PDO's data: each value encoded by python canopen (``ODVariable.encode_raw``; the time
    types by their CiA 301 7.1.6.5 layout), packed at its mapped bit length from bit 0."""
    word, shift = 0, 0
    for (_i, _s, bits, var), value in zip(od_entries, values, strict=True):
        if var is not None and value is not None:
            if var.data_type in (dt.TIME_OF_DAY, dt.TIME_DIFFERENCE):
                data = value.to_bytes(6, "little")
            else:
                data = var.encode_raw(value)
            word |= (int.from_bytes(data, "little") & ((1 << bits) - 1)) << shift
        shift += bits
    return word.to_bytes((shift + 7) // 8, "little")


def expected_registers(data_type: int, value: Any, count: int) -> list[int]:
    """The registers of a value as docs/modbus.md says, high word first, by ``struct``."""
    if data_type in STRINGS:
        b = value.ljust(count * 2, b"\0")
    elif data_type == dt.REAL32:
        b = struct.pack(">f", value)
    elif data_type == dt.REAL64:
        b = struct.pack(">d", value)
    elif data_type == dt.TIME_OF_DAY:
        b = ((value >> 32) * 86_400_000 + (value & 0xFFFFFFF) + 441_763_200_000).to_bytes(8, "big")
    elif data_type == dt.TIME_DIFFERENCE:
        b = ((value >> 32) * 86_400_000 + (value & 0xFFFFFFF)).to_bytes(8, "big")
    else:
        b = value.to_bytes(count * 2, "big", signed=value < 0)
    return [int.from_bytes(b[i : i + 2], "big") for i in range(0, count * 2, 2)]


@pytest.mark.parametrize("eds", LOADED, ids=lambda p: p.name[:60])
def test_every_pdo_signal_agrees_with_the_register_map(eds: Path) -> None:
    """Each object of each enabled TPDO (RPDO) of the file is an input (holding) register point
    of its type and size, an object of both is both; a TPDO built by python canopen decodes to
    the registers docs/modbus.md gives, and an RPDO the gateway builds carries the value."""
    od = reference_od(eds)
    assert od is not None
    raw: dict[str, Any] = {"can": {"interface": "virtual", "channel": "x"},
                           "nodes": [{"name": "dev", "node_id": NODE_ID, "eds": str(eds)}]}  # fmt: skip
    cfg = parse_checked_config(raw, "cfg.yaml", environ={})
    lp = load_node_profile(cfg.nodes[0].setup)
    points = {(p.table, p.name): p for p in build_register_map(*with_nodes(cfg)).node_points("dev") if p.kind == "signal"}
    tpdos, rpdos = compile_node(lp, NODE_ID)
    codecs = {("tpdo", c.number): c for c in tpdos} | {("rpdo", c.number): c for c in rpdos}
    problems: list[str] = []
    for kind, number, entries in reference_pdos(od):
        table = "ir" if kind == "tpdo" else "hr"
        values = [sample_value(var.data_type, bits) if var is not None and (var.data_type in REGISTERS or var.data_type in STRINGS) else None
                  for _i, _s, bits, var in entries]  # fmt: skip
        frame = pdo_bytes(entries, values)
        codec = codecs.get((kind, number))  # compiled from the gateway's own reading of the file
        decoded: dict[str, Any] = {}
        if codec is None:
            problems.append(f"{kind.upper()}{number}: no codec")
        elif kind == "tpdo":
            decoded = dict(zip(codec.names, codec.decode(frame), strict=True))
        for (index, sub, bits, var), value in zip(entries, values, strict=True):
            if var is None:
                continue
            obj = f"{kind.upper()}{number} 0x{index:04X}:{sub:02X}"
            if value is None:
                problems.append(f"{obj}: data type 0x{var.data_type:04X} is no CiA 301 basic type of the table")
                continue
            sig = lp.profile.signal_for(ObjRef(index, sub))
            p = points.get((table, sig.name)) if sig is not None else None
            if p is None:
                problems.append(f"{obj}: no {table} point")
                continue
            want = ("string", (bits // 8 + 1) // 2) if var.data_type in STRINGS else REGISTERS[var.data_type]
            if (p.type, p.count) != want:
                problems.append(f"{obj}: {p.type} x{p.count}, expected {want}")
                continue
            regs = expected_registers(var.data_type, value, p.count)
            if kind == "tpdo" and codec is not None:
                got = to_registers(decoded.get(p.name), p)
                if got != regs:
                    problems.append(f"{obj}: frame {frame.hex()} gives registers {got}, expected {regs}")
            elif kind == "rpdo" and codec is not None:
                # the registers written, the other fields zero: the RPDO python canopen builds
                mine = [f.signal == p.name for f in codec.fields]
                out = [from_registers(regs, p) if m else v for m, v in zip(mine, codec.initial_values(), strict=True)]
                sent = codec.encode(out)
                built = pdo_bytes(entries, [v if m else None for m, v in zip(mine, values, strict=True)])
                if sent != built:
                    problems.append(f"{obj}: registers {regs} sent as {sent.hex()}, expected {built.hex()}")
    assert not problems, problems


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
            load_node_profile(parse_checked_config(raw, "cfg.yaml", environ={}).nodes[0].setup)
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
