"""``canopen-gateway registers --format modicon|kepware``: the register map as PLC and SCADA
tools import it. Modicon rows: the exact header, 6-digit 1-based addresses per table, IEC types,
the word order of values over several registers; the KEPServerEX tag import: its columns, unique
tag names that carry the signal name (a unit's ``alive`` register and ``alive`` discrete input
told apart), one device per file (``--unit``). ``--csv`` stays the CSV of ``--format csv``."""

from __future__ import annotations

import csv
import io
import re
from pathlib import Path

import pytest

from canopen_gateway.cli import main
from canopen_gateway.northbound.plc_tags import (
    IEC_TYPE,
    KEPWARE_TYPE,
    modicon_address,
    to_kepware,
    to_modicon,
)
from canopen_gateway.northbound.regmap import RegisterMap, build_register_map
from tests.helpers import load_checked_config, with_nodes

ROOT = Path(__file__).resolve().parents[2]
DEMO = str(ROOT / "config" / "demo.yaml")
MODICON_HEADER = "unit_id,modicon,words,iec_type,word_order,node,signal,unit,description"
FIRST_DIGIT = {"coil": "0", "discrete input": "1", "input register": "3", "holding register": "4"}


@pytest.fixture(scope="module")
def demo_map() -> RegisterMap:
    cfg = load_checked_config(DEMO)
    return build_register_map(*with_nodes(cfg))


def rows(text: str) -> list[dict[str, str]]:
    return list(csv.DictReader(io.StringIO(text)))


def test_modicon_header_is_exact_and_addresses_are_6_digit_1_based(demo_map: RegisterMap) -> None:
    text = to_modicon(demo_map)
    assert text.splitlines()[0] == MODICON_HEADER
    plain = rows(demo_map.to_csv())  # protocol addresses, 0-based, ranges written a-b
    modicon = rows(text)
    assert len(modicon) == len(plain)
    for m, p in zip(modicon, plain, strict=True):
        assert re.fullmatch(r"[0134]\d{5}", m["modicon"]), m
        first = int(p["address"].split("-")[0])
        assert m["modicon"] == FIRST_DIGIT[p["table"]] + f"{first + 1:05d}"
        assert m["iec_type"] in {"BOOL", "INT", "UINT", "DINT", "UDINT", "REAL", "LREAL", "STRING"}
        if p["table"] in ("coil", "discrete input"):
            assert (m["words"], m["iec_type"]) == ("1", "BOOL")
        if int(m["words"]) > 1:
            assert m["word_order"] in ("big", "little"), m
        else:
            assert m["word_order"] == ""


def test_modicon_rows_name_the_values_a_plc_engineer_looks_for(demo_map: RegisterMap) -> None:
    by_name = {(r["unit_id"], r["signal"], r["modicon"][0]): r for r in rows(to_modicon(demo_map))}
    position = by_name[("1", "position", "3")]  # the README's mbpoll -r 101: input register 100
    assert (position["modicon"], position["words"], position["iec_type"], position["word_order"]) == (
        "300101", "2", "DINT", "big")  # fmt: skip
    assert position["unit"] == "mm"
    assert by_name[("1", "nmt_command", "4")]["modicon"] == "400001"
    assert by_name[("1", "alive", "1")]["modicon"] == "100001"  # discrete input 0
    assert by_name[("1", "alive", "3")]["modicon"] == "300003"  # input register 2
    assert by_name[("247", "frames_in", "3")]["iec_type"] == "UDINT"


def test_kepware_file_is_one_device_with_the_driver_columns_and_unique_tag_names(demo_map: RegisterMap) -> None:
    text = to_kepware(demo_map, 125)
    header = text.splitlines()[0].split(",")
    for column in ("Tag Name", "Address", "Data Type", "Respect Data Type", "Client Access",
                   "Scan Rate", "Description"):  # fmt: skip
        assert column in header
    tags = rows(text)
    names = [t["Tag Name"] for t in tags]
    assert len(names) == len(set(names))
    units_points = [p for p in demo_map.sorted_points() if p.unit == 125]
    assert len(tags) == len(units_points)
    for t, p in zip(tags, units_points, strict=True):
        assert p.name in t["Tag Name"]
        assert re.fullmatch(r"[A-Za-z0-9_]+", t["Tag Name"])
        assert t["Address"][:6] == modicon_address(p) and re.fullmatch(r"[0134]\d{5}(\.\d+H)?", t["Address"])
        assert t["Data Type"] in {"Boolean", "Word", "Short", "DWord", "Long", "Float", "Double", "String"}
        assert t["Client Access"] in ("RO", "R/W") and t["Respect Data Type"] == "1"
        assert int(t["Scan Rate"]) > 0
    alive = [t for t in tags if "alive" in t["Tag Name"]]
    assert {(t["Tag Name"], t["Address"], t["Data Type"]) for t in alive} == {
        ("display_alive_IR", "300003", "Word"), ("display_alive_DI", "100001", "Boolean")}  # fmt: skip
    assert {t["Client Access"] for t in tags if t["Tag Name"] == "display_set_point1"} == {"R/W"}


def test_every_register_type_has_an_iec_and_a_kepware_type() -> None:
    from canopen_gateway.northbound.regmap import _REG_TYPE

    assert set(_REG_TYPE.values()) | {"bool"} <= set(IEC_TYPE) & set(KEPWARE_TYPE)


def test_registers_command_formats_and_unit(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["registers", "-c", DEMO, "--csv"]) == 0
    csv_text = capsys.readouterr().out
    assert main(["registers", "-c", DEMO, "--format", "csv"]) == 0
    assert capsys.readouterr().out == csv_text
    assert main(["registers", "-c", DEMO, "--format", "modicon", "--unit", "2"]) == 0
    assert {r["unit_id"] for r in rows(capsys.readouterr().out)} == {"2"}
    assert main(["registers", "-c", DEMO, "--format", "kepware", "--unit", "1"]) == 0
    assert "wire_position" in capsys.readouterr().out
    assert main(["registers", "-c", DEMO, "--format", "kepware"]) == 2
    err = capsys.readouterr().err
    assert "give --unit N" in err and "1 (wire)" in err and "247 (gateway)" in err
    assert main(["registers", "-c", DEMO, "--format", "modicon", "--unit", "99"]) == 2
    assert "no such unit id" in capsys.readouterr().err
