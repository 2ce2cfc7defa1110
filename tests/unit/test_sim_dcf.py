"""A simulated device built from a DCF holds what the DCF says it holds (ParameterValue, and the
``[xxxxValue]`` sections of CiA 306 CompactSubObj objects as Lely's dcfgen writes them): the
mapping the gateway decodes from the same file. Device: tests/data/eds/compact.dcf, fake clock."""

from __future__ import annotations

import struct
from pathlib import Path

from gateway.bus.resolved import resolve_node
from gateway.profiles import load_node_profile
from gateway.sim.node import SimNode
from tests.helpers import frame, make_config

DCF = Path(__file__).resolve().parents[1] / "data" / "eds" / "compact.dcf"
NODE = 10


def sim_of_dcf() -> SimNode:
    cfg = make_config([{"name": "io", "node_id": NODE, "eds": str(DCF)}])
    node = SimNode(load_node_profile(cfg.nodes[0], cfg.base_dir), NODE)
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
    resolved = resolve_node(cfg, cfg.nodes[0])
    node = SimNode(resolved.lp, NODE)
    node.power_on(0.0)
    node.handle(frame(0x000, f"01 {NODE:02X}"), 0.0)
    sent = {m.arbitration_id: bytes(m.data) for m in node.tick(0.05)}
    codecs = {c.cob_id: c for c in resolved.tpdos}
    assert sorted(codecs) == sorted(sent) == [0x180 + NODE, 0x280 + NODE]
    a1, a2 = node.get(0x2000, 1), node.get(0x2000, 2)
    assert sent[0x180 + NODE] == struct.pack("<hh", a1, a2)
    assert codecs[0x180 + NODE].decode(sent[0x180 + NODE]) == (a1, a2)
    assert codecs[0x280 + NODE].decode(sent[0x280 + NODE]) == (node.get(0x2100, 0),)
