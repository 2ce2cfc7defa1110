"""A simulated device built from a DCF holds what the DCF says it holds (ParameterValue, and the
``[xxxxValue]`` sections of CiA 306 CompactSubObj objects as Lely's dcfgen writes them): the
mapping the gateway decodes from the same file. Device: tests/data/eds/compact.dcf, fake clock."""

from __future__ import annotations

import struct
from pathlib import Path

from canopen_gateway.profiles import load_node_profile
from canopen_gateway.sim.node import SimNode
from tests.helpers import frame, make_config, resolved

DCF = Path(__file__).resolve().parents[1] / "data" / "eds" / "compact.dcf"
NODE = 10


def sim_of_dcf() -> SimNode:
    cfg = make_config([{"name": "io", "node_id": NODE, "eds": str(DCF)}])
    node = SimNode(load_node_profile(cfg.nodes[0].setup, cfg.base_dir), NODE)
    node.power_on(0.0)
    return node


def test_compact_mapping_values_are_what_the_simulated_device_holds() -> None:
    node = sim_of_dcf()
    assert [node.sdo_read_local(f"0x1A00:{s:02X}") for s in range(3)] == [2, 0x20000110, 0x20000210]
    assert [node.sdo_read_local(f"0x1A01:{s:02X}") for s in range(2)] == [1, 0x21000020]
    # ParameterValue, not DefaultValue: event timer 100 ms, inhibit 200 x 100 us, serial number
    assert node.sdo_read_local("0x1800:05") == 100
    assert node.sdo_read_local("0x1801:03") == 200
    assert node.sdo_read_local("0x1018:04") == 0x1234


def test_each_tpdo_goes_out_with_the_mapping_the_gateway_decodes() -> None:
    cfg = make_config([{"name": "io", "node_id": NODE, "eds": str(DCF)}])
    rn = resolved(cfg)[cfg.nodes[0].name]
    node = SimNode(rn.lp, NODE)
    node.power_on(0.0)
    node.handle(frame(0x000, f"01 {NODE:02X}"), 0.0)
    sent = {m.arbitration_id: bytes(m.data) for m in node.tick(0.05)}
    codecs = {c.cob_id: c for c in rn.tpdos}
    assert sorted(codecs) == sorted(sent) == [0x180 + NODE, 0x280 + NODE]
    a1, a2 = node.get(0x2000, 1), node.get(0x2000, 2)
    assert sent[0x180 + NODE] == struct.pack("<hh", a1, a2)
    assert codecs[0x180 + NODE].decode(sent[0x180 + NODE]) == (a1, a2)
    assert codecs[0x280 + NODE].decode(sent[0x280 + NODE]) == (node.get(0x2100, 0),)


def variant(tmp_path: Path, *edits: tuple[str, str]) -> Path:
    """compact.dcf with each (old, new) of ``edits`` replaced once."""
    text = DCF.read_text(encoding="utf-8")
    for old, new in edits:
        assert old in text, old
        text = text.replace(old, new, 1)
    p = tmp_path / "variant.dcf"
    p.write_text(text, encoding="utf-8")
    return p


def sim_of(path: Path) -> SimNode:
    cfg = make_config([{"name": "io", "node_id": NODE, "eds": str(path)}])
    node = SimNode(load_node_profile(cfg.nodes[0].setup, cfg.base_dir), NODE)
    node.power_on(0.0)
    return node


def test_the_identity_the_gateway_checks_is_held_where_the_file_gives_it_in_device_info_only(
    tmp_path: Path,
) -> None:
    node = sim_of(
        variant(
            tmp_path,
            ("DefaultValue=0x00000ABC\nParameterValue=0x00000ABC\n", ""),
            ("DefaultValue=0x00000C0D\nParameterValue=0x00000C0D\n", ""),
        )
    )
    assert (node.sdo_read_local("0x1018:01"), node.sdo_read_local("0x1018:02")) == (0xABC, 0xC0D)


def test_the_sdo_server_answers_on_600h_plus_its_node_id_whatever_1200h_holds(tmp_path: Path) -> None:
    # 1200h as a DCF written for node 2 holds it (Lely's dcfgen writes literal COB-IDs)
    sdo_server = (
        "[1200]\nParameterName=SDO server parameter\nObjectType=0x09\nSubNumber=3\n\n"
        "[1200sub0]\nParameterName=Highest sub-index supported\nDataType=0x0005\nAccessType=const\nDefaultValue=2\n\n"
        "[1200sub1]\nParameterName=COB-ID client to server\nDataType=0x0007\nAccessType=ro\nParameterValue=0x602\n\n"
        "[1200sub2]\nParameterName=COB-ID server to client\nDataType=0x0007\nAccessType=ro\nParameterValue=0x582\n\n"
        "[1800]\n"
    )
    node = sim_of(variant(tmp_path, ("[1800]\n", sdo_server)))
    answer = node.handle(frame(0x600 + NODE, "40 00 10 00 00 00 00 00"), 0.1)
    assert [(m.arbitration_id, bytes(m.data[:4]).hex()) for m in answer] == [(0x580 + NODE, "43001000")]
    assert node.handle(frame(0x602, "40 00 10 00 00 00 00 00"), 0.2) == []
