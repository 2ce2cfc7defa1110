"""EDS files checked when loaded (file, line, section for every problem), signals and PDOs
derived from an EDS, profiles as overlays, and `check` comparing a config with its EDS."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.cli import main
from canopen_gateway.config import ConfigError
from canopen_gateway.device.boot_steps import build_boot_steps
from canopen_gateway.eds import lint, load_eds
from canopen_gateway.northbound.regmap import build_register_map
from canopen_gateway.pdo.verify import MappingRead, compare_mapping, mapping_reads
from canopen_gateway.profiles import ProfileError, load_node_profile
from tests.helpers import edited_copy, line_of, parse_checked_config, with_nodes

DATA = Path(__file__).resolve().parents[1] / "data" / "eds"
IO = DATA / "io401.eds"
FLOW = DATA / "measure.eds"





def lint_of(path: Path) -> tuple[list[str], list[str]]:
    result = lint(load_eds(path))
    return [str(p) for p in result.errors], [str(p) for p in result.warnings]


# --------------------------------------------------------------------------- load is not lint


@pytest.mark.parametrize(
    ("old", "new", "section", "message"),
    [
        ("[6401sub2]", "[6401sbu2]", "6401sbu2", "unknown section"),
        ("[6401]\nParameterName=Read analogue input 16-bit\nObjectType=0x8\nSubNumber=3", "[6401]\nParameterName=Read analogue input 16-bit\nObjectType=0x8\nSubNumber=0x1l", "6401", "SubNumber=0x1l: '0x1l' is not a number"),  # fmt: skip
        ("[6401]\nParameterName=Read analogue input 16-bit\nObjectType=0x8\nSubNumber=3", "[6401]\nParameterName=Read analogue input 16-bit\nObjectType=0x8\nSubNumber=4", "6401", "SubNumber=4 but 3 sub-sections follow"),  # fmt: skip
        ("[1017]\nParameterName=Producer heartbeat time\nObjectType=0x7\n", "[1017]\nParameterName=Producer heartbeat time\nObjectType=0x3\n", "1017", "ObjectType=0x3 is not a CiA 306 object type: read as VAR"),  # fmt: skip
        ("[1017]\nParameterName=Producer heartbeat time\nObjectType=0x7\nDataType=0x0006", "[1017]\nParameterName=Producer heartbeat time\nObjectType=0x7\nDataType=0x000E", "1017", "DataType=0x000E is not a CiA 301 basic data type: read as DOMAIN"),  # fmt: skip
        ("[1017]\nParameterName=Producer heartbeat time\nObjectType=0x7\nDataType=0x0006\nAccessType=rw", "[1017]\nParameterName=Producer heartbeat time\nObjectType=0x7\nDataType=0x0006\nAccessType=rx", "1017", "AccessType=rx: not one of"),  # fmt: skip
        ("[1017]\nParameterName=Producer heartbeat time\n", "[1017]\n", "1017", "ParameterName is missing or empty"),  # fmt: skip
        ("[1017]\nParameterName=Producer heartbeat time\nObjectType=0x7\nDataType=0x0006\n", "[1017]\nParameterName=Producer heartbeat time\nObjectType=0x7\n", "1017", "DataType is missing"),  # fmt: skip
    ],
)
def test_a_deviation_is_a_warning_with_file_line_and_section_and_the_file_loads(
    tmp_path: Path, old: str, new: str, section: str, message: str
) -> None:
    p = edited_copy(tmp_path, IO, old, new)
    errors, warnings = lint_of(p)
    assert errors == []
    match = [x for x in warnings if f"[{section}]" in x and message in x]
    assert match, warnings
    path, line, _ = match[0].split(":", 2)
    assert path == str(p)
    sec_line = line_of(p, f"[{section}]")
    assert sec_line <= int(line) <= sec_line + 10
    assert load_node_profile(Node(eds=str(p)).cfg.setup).profile.signal("analogue_input_1") is not None


def test_cia306_defaults_missing_object_type_any_number_notation_hex_reals(tmp_path: Path) -> None:
    text = IO.read_text(encoding="utf-8")
    text = text.replace("ObjectType=0x7\n", "")  # CiA 306 4.6.3.2: missing means VAR
    text = text.replace("PDOMapping=1", "PDOMapping=0x1").replace("PDOMapping=0\n", "PDOMapping=0x0\n")
    text += (
        "\n[2000]\nParameterName=Gain\nDataType=0x0008\nAccessType=rw\nDefaultValue=0x40490FDB\n"
        "HighLimit=0x457a0000\n\n[2001]\nParameterName=Mode\nDataType=0x0005\nAccessType=RW\n"
        "DefaultValue=010\n\n[2002]\nParameterName=Blob\nObjectType=0x2\nDataType=0x000F\n"
        "AccessType=rw\n\n[2003]\nParameterName=Vendor type\nDataType=0x0040\nAccessType=ro\n"
        "\n[VirtualDeviceDefinitions]\nVD0=abc\n"
    )
    text = text.replace("[DeviceInfo]\n", "[DeviceInfo]\nVendorNumber=\n")
    p = tmp_path / "defaults.eds"
    p.write_text(text, encoding="utf-8")
    eds = load_eds(p)
    od = eds.od
    assert od[0x1017].data_type == 0x0006 and od[0x6000][1].pdo_mappable
    assert abs(od[0x2000].default - 3.1415927) < 1e-6 and od[0x2000].max == 4000.0
    assert od[0x2001].default == 8 and od[0x2001].access_type == "rw"  # octal, CiA 306 4.6.3
    assert od[0x2002].data_type == 0x000F and od[0x2003].data_type == 0x000F
    assert od.device_information.vendor_number is None
    warnings = [str(w) for w in eds.warnings]
    assert [w for w in warnings if "[VirtualDeviceDefinitions]" in w and "unknown section" in w]
    assert [w for w in warnings if "[2003]" in w and "DataType=0x0040" in w]
    assert not [w for w in warnings if "ObjectType" in w or "PDOMapping" in w]


def test_an_enabled_pdo_the_gateway_would_decode_wrongly_is_refused_in_one_line(tmp_path: Path) -> None:
    p = edited_copy(tmp_path, IO, "DefaultValue=0x64010110", "DefaultValue=0x6401011O")
    errors, _ = lint_of(p)
    line = line_of(p, "[1A01sub2]")
    assert errors == [f"{p}:{line}: [1A01sub2]: TPDO2: 1A01h:00 counts entry 02h, which has no value"]
    with pytest.raises(ProfileError) as err:
        load_node_profile(Node(eds=str(p)).cfg.setup)
    assert str(err.value) == errors[0]
    # the node's own settings may disable that PDO: then the file serves the rest
    lp = load_node_profile(Node(eds=str(p), tpdo={2: {"enabled": False}}).cfg.setup)
    assert [x.number for x in lp.profile.tpdos] == [1]
    long = edited_copy(tmp_path, IO, "DefaultValue=0x64010110", "DefaultValue=0x64010140", "long.eds")
    errors, _ = lint_of(long)
    assert errors == [f"{long}:{line_of(long, '[1A01sub0]')}: [1A01sub0]: TPDO2 maps 80 bits; a PDO carries at most 64"]


def test_a_line_that_is_not_key_value_is_a_warning_with_its_line(tmp_path: Path) -> None:
    p = edited_copy(tmp_path, IO, "PDOMapping=0\n\n[1018]", "PDOMapping=0\nthis is no key\n\n[1018]")
    errors, warnings = lint_of(p)
    assert errors == []
    assert warnings == [f"{p}:{line_of(p, 'this is no key')}: [1017]: line 'this is no key' is not 'key=value': ignored"]  # fmt: skip


def test_listed_object_without_section_and_unlisted_object_are_warnings(tmp_path: Path) -> None:
    p = edited_copy(tmp_path, IO, "18=0x6411", "18=0x6412")
    _, warnings = lint_of(p)
    assert any("object 0x6412 is listed but has no section [6412]" in x for x in warnings)
    assert any("[6411]: object is not listed" in x for x in warnings)


def test_eds_lint_exit_codes(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["eds", "lint", str(IO)]) == 0
    assert capsys.readouterr().out.strip() == f"{IO}: 0 errors, 0 warnings"
    warn = edited_copy(tmp_path, IO, "[6401sub2]", "[6401sbu2]")
    assert main(["eds", "lint", str(warn)]) == 1
    out = capsys.readouterr().out.splitlines()
    assert any(x.startswith(f"{warn}:{line_of(warn, '[6401sbu2]')}: [6401sbu2]: warning: unknown section") for x in out)
    assert main(["eds", "show", "--strict", str(warn)]) == 1
    capsys.readouterr()
    bad = edited_copy(tmp_path, IO, "DefaultValue=0x64010110", "DefaultValue=0x6401011O", "bad.eds")
    assert main(["eds", "lint", str(bad)]) == 2
    assert ": [1A01sub2]: error: TPDO2: 1A01h:00 counts entry 02h" in capsys.readouterr().out


def test_the_builtin_and_test_eds_files_pass_the_checker() -> None:
    for f in [*Path("canopen_gateway/profiles").glob("*.eds"), IO, FLOW]:
        assert load_eds(f).od is not None


def test_non_ascii_names_load_and_slug_to_ascii() -> None:
    eds = load_eds(FLOW)
    assert eds.product_name == "Durchflussmesser Größe 3"
    assert eds.od[0x1008].default == "Durchflussmesser Größe 3 – µ"


# --------------------------------------------------------------------------- derivation


class Node:
    def __init__(self, **kw: Any) -> None:
        from canopen_gateway.config import NodeConfig

        self.cfg = NodeConfig.model_validate({"name": "n", "node_id": 5, **kw})


def test_signals_of_an_eds_only_node_come_from_its_enabled_pdos() -> None:
    lp = load_node_profile(Node(eds=str(IO)).cfg.setup)
    sigs = {s.name: (str(s.object), s.type, s.access) for s in lp.profile.signals}
    assert sigs == {
        "read_input_1h_to_8h": ("0x6000:01", "uint8", "ro"),
        "read_input_9h_to_10h": ("0x6000:02", "uint8", "ro"),
        "read_input_1h_to_10h": ("0x6100:01", "uint16", "ro"),
        "read_input_11h_to_20h": ("0x6100:02", "uint16", "ro"),
        "analogue_input_1": ("0x6401:01", "int16", "ro"),
        "write_output_1h_to_8h": ("0x6200:01", "uint8", "rw"),
        "write_output_9h_to_10h": ("0x6200:02", "uint8", "rw"),
        "write_output_1h_to_10h": ("0x6300:01", "uint16", "rw"),
        "analogue_output_1": ("0x6411:01", "int16", "rw"),
    }  # TPDO3 (6401h:02) has COB-ID bit 31 set: skipped
    assert [(p.number, p.cob_id, p.event_timer_ms) for p in lp.profile.tpdos] == [(1, 0x185, 100), (2, 0x285, 100)]  # fmt: skip


def test_a_dcf_is_read_like_its_eds_with_the_parameter_values_of_the_commissioning(
    tmp_path: Path,
) -> None:
    text = IO.read_text(encoding="utf-8")
    head, rest = text.split("[1800sub5]", 1)
    section, tail = rest.split("\n\n", 1)
    dcf = tmp_path / "io401.dcf"
    dcf.write_text(
        head + "[1800sub5]" + section + "\nParameterValue=250\n\n" + tail
        + "\n[DeviceComissioning]\nNodeID=5\nNodeName=io\nBaudrate=250\n",
        encoding="utf-8",
    )  # fmt: skip
    assert load_eds(dcf).is_dcf
    lp = load_node_profile(Node(eds=str(dcf)).cfg.setup)
    assert [(p.number, p.event_timer_ms) for p in lp.profile.tpdos] == [(1, 250), (2, 100)]


def test_a_disabled_pdo_enabled_by_the_config_is_served() -> None:
    lp = load_node_profile(Node(eds=str(IO), tpdo={3: {"enabled": True}}).cfg.setup)
    assert [p.number for p in lp.profile.tpdos] == [1, 2, 3]
    assert lp.profile.tpdos[2].cob_id == 0x385
    assert lp.profile.signal("analogue_input_2").object == ObjRef(0x6401, 2)


def test_shared_slugs_fall_back_to_index_and_sub() -> None:
    from canopen_gateway.eds.pdos import unique_names

    od = load_eds(IO).od
    names = unique_names(od, [ObjRef(0x6401, 1), ObjRef(0x6401, 2)], {"analogue_input_1"})
    assert names == {ObjRef(0x6401, 1): "analogue_input_1_6401_01", ObjRef(0x6401, 2): "analogue_input_2"}


def test_config_remap_is_one_cia301_sequence_and_the_codec_follows_it() -> None:
    from canopen_gateway.pdo.codec import compile_node

    n = Node(eds=str(IO), tpdo={1: {"mapping": ["0x6401:01", "0x0005:00", "0x6000:01"], "inhibit_ms": 1.5}}).cfg  # fmt: skip
    lp = load_node_profile(n.setup)
    steps = [(str(s.object), s.value) for s in build_boot_steps(lp, n.setup) if s.object.index >= 0x1400]
    assert steps == [
        ("0x1800:01", 0x80000185), ("0x1800:03", 15), ("0x1A00:00", 0), ("0x1A00:01", 0x64010110),
        ("0x1A00:02", 0x00050008), ("0x1A00:03", 0x60000108), ("0x1A00:00", 3), ("0x1800:01", 0x185),
    ]  # fmt: skip
    tpdos, _ = compile_node(lp, 5)
    t1 = next(c for c in tpdos if c.number == 1)
    assert t1.names == ("analogue_input_1", "read_input_1h_to_8h")
    assert t1.decode(bytes.fromhex("FEFF00A5")) == (-2, 0xA5)


def test_msk5000_manual_remap_in_the_config_serves_every_mapped_object() -> None:
    cfg = parse_checked_config(
        {
            "can": {"interface": "virtual", "channel": "x"},
            "nodes": [{"name": "magnet", "node_id": 1, "profile": "msk5000",
                       "tpdo": {1: {"mapping": ["0x6004:00", "0x5122:01", "0x5122:02"]}}}],
        },
        environ={},
    )  # fmt: skip
    rm = build_register_map(*with_nodes(cfg))
    ir = {p.name: p.address for p in rm.points if p.table == "ir" and p.kind == "signal"}
    assert {"position", "sys_register", "flag0_register", "speed"} <= set(ir)


def test_verify_compare_names_the_pdo_expected_and_held() -> None:
    lp = load_node_profile(Node(eds=str(FLOW)).cfg.setup)
    reads = mapping_reads(lp, 5)
    held: dict[ObjRef, int | None] = {r.object: r.expected for r in reads}
    assert compare_mapping(reads, held) == []
    held[ObjRef(0x1A01, 2)] = 0x20010020
    held[ObjRef(0x1401 - 1, 1)] = None
    out = [str(m) for m in compare_mapping(reads, held)]
    assert out == [
        "TPDO2: expected COB-ID 0x285, [0x2002:00/8, 0x2003:00/32], device holds COB-ID 0x285, [0x2002:00/8, 0x2001:00/32]",  # fmt: skip
        "RPDO1: expected COB-ID 0x205, [0x2100:00/32], device holds COB-ID (no answer), [0x2100:00/32]",  # fmt: skip
    ]
    assert all(isinstance(r, MappingRead) for r in reads)


# --------------------------------------------------------------------------- check


def problems(nodes: list[dict[str, Any]], **sections: Any) -> list[str]:
    raw = {"can": {"interface": "virtual", "channel": "x"}, "nodes": nodes, **sections}
    with pytest.raises(ConfigError) as err:
        parse_checked_config(raw, "cfg.yaml", environ={})
    return err.value.problems


def test_check_refuses_a_32_bit_entry_on_a_16_bit_object() -> None:
    p = problems([{"name": "io", "node_id": 5, "eds": str(IO), "tpdo": {1: {"mapping": ["0x6100:01/32"]}}}])
    assert p == ["cfg.yaml: nodes[0].tpdo.1.mapping[0]: TPDO1 entry 0x6100:01/32: the object is UNSIGNED16 (16 bit) in io401.eds; must be /16"]  # fmt: skip


def test_check_refuses_a_missing_sub_index_and_unwritable_rpdo_entries() -> None:
    p = problems([{"name": "io", "node_id": 5, "eds": str(IO), "rpdo": {1: {"mapping": ["0x6000:01", "0x6200:03/8"]}}}])  # fmt: skip
    assert p == ["cfg.yaml: nodes[0].rpdo.1.mapping[1]: 0x6200:03: 6200h has no sub-index 03h"]
    p = problems([{"name": "io", "node_id": 5, "eds": str(IO), "rpdo": {1: {"mapping": ["0x6000:01", "0x6200:02"]}}}])  # fmt: skip
    assert p == ["cfg.yaml: nodes[0].rpdo.1.mapping[0]: RPDO1 entry 0x6000:01: not writable (ro) in io401.eds"]


def test_check_refuses_a_mapping_longer_than_64_bits_and_unmappable_objects() -> None:
    p = problems([{"name": "io", "node_id": 5, "eds": str(IO), "tpdo": {1: {"mapping": ["0x1017:00", "0x1018:01/32", "0x1018:02/32"]}}}])  # fmt: skip
    assert any("nodes[0].tpdo.1" in x and "more than 8 bytes" in x for x in p), p


def test_check_refuses_a_remap_of_a_device_with_read_only_mapping_objects() -> None:
    p = problems([{"name": "flow", "node_id": 6, "eds": str(FLOW), "tpdo": {1: {"mapping": ["0x2001:00", "0x2000:00"]}}}])  # fmt: skip
    assert p == ["cfg.yaml: nodes[0].tpdo.1: 0x1A00:00 is read-only (const) in measure.eds, cannot set it to 0"]


def test_check_refuses_boot_values_outside_the_eds_limits() -> None:
    p = problems([{"name": "flow", "node_id": 6, "eds": str(FLOW), "heartbeat_ms": 20000}])
    assert p == ["cfg.yaml: nodes[0].heartbeat_ms: 20000 for 0x1017:00 (producer heartbeat time (ms)) is outside 0..10000 (LowLimit/HighLimit in measure.eds)"]  # fmt: skip


def test_check_refuses_an_sgh10_or_msk5000_heartbeat_of_5_ms_as_their_manuals_do() -> None:
    """SGH10 manual 000 4.7.2.14 and MSK5000 manual 001 4.6.1.15: 1017h "0d, 10d ... 65535d"."""
    for profile in ("sgh10", "msk5000"):
        p = problems([{"name": "enc", "node_id": 1, "profile": profile, "heartbeat_ms": 5}])
        assert p == [f"cfg.yaml: nodes[0].heartbeat_ms: 5 for 0x1017:00 (producer heartbeat time (ms)) is not allowed: 0 or 10..65535 (profile {profile}); producer heartbeat time in ms; 0 = off"]  # fmt: skip
        ok = {"name": "enc", "node_id": 1, "profile": profile, "heartbeat_ms": 10}
        parse_checked_config({"can": {"interface": "virtual", "channel": "x"}, "nodes": [ok]}, "cfg.yaml", environ={})  # fmt: skip


def test_check_refuses_ap05_heartbeat_and_external_heartbeat_of_5_ms() -> None:
    p = problems(
        [{"name": "display", "node_id": 125, "profile": "ap05", "heartbeat_ms": 5,
          "external_heartbeat": {"interval_ms": 5, "keepalive_ms": 2}}]
    )  # fmt: skip
    assert "cfg.yaml: nodes[0].heartbeat_ms: 5 for 0x1017:00 (producer heartbeat time (ms)) is not allowed: 0 or 10..65535 (profile ap05); producer heartbeat time in ms; 0 = off" in p  # fmt: skip
    assert any(x.startswith("cfg.yaml: nodes[0].external_heartbeat.interval_ms: 5 for 0x5F09:01") and "0 or 10..65535" in x for x in p), p  # fmt: skip


def test_cli_check_exits_2_for_an_ap05_heartbeat_of_5_ms(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cfg = tmp_path / "c.yaml"
    cfg.write_text("nodes:\n  - {name: display, node_id: 125, profile: ap05, heartbeat_ms: 5}\n")
    assert main(["check", "-c", str(cfg)]) == 2
    err = capsys.readouterr().err
    assert f"{cfg}: nodes[0].heartbeat_ms: 5 for 0x1017:00" in err and "0 or 10..65535" in err


def overlay(tmp_path: Path, body: str) -> str:
    p = tmp_path / "io.yaml"
    p.write_text(f"family: io\neds: {IO}\n{body}", encoding="utf-8")
    return str(p)


def test_check_refuses_an_overlay_type_that_is_not_the_eds_type(tmp_path: Path) -> None:
    prof = overlay(tmp_path, "signals:\n  - {name: ain, object: '0x6401:01', type: uint32}\n")
    p = problems([{"name": "io", "node_id": 5, "profile": prof}])
    assert p == ["cfg.yaml: nodes[0] (io signal ain): type uint32 but 0x6401:01 is INTEGER16 in io401.eds: must be int16 (or another 16-bit type)"]  # fmt: skip


def test_check_refuses_a_pdo_signal_in_no_pdo_and_a_layout_not_the_eds_mapping(tmp_path: Path) -> None:
    prof = overlay(
        tmp_path,
        "signals:\n  - {name: ain2, object: '0x6401:02', transport: pdo}\n"
        "tpdos:\n  - {number: 2, mapping: ['0x6401:01/16', '0x6100:02/16']}\n",
    )
    p = problems([{"name": "io", "node_id": 5, "profile": prof}])
    assert "cfg.yaml: nodes[0] (io signal ain2): declared as a PDO signal, but 0x6401:02 is in no PDO of the layout" in p  # fmt: skip
    assert "cfg.yaml: nodes[0] (TPDO2): TPDO2 layout [0x6401:01/16, 0x6100:02/16] is not the EDS mapping [0x6100:02/16, 0x6401:01/16] and is not written at boot: it would be decoded with the wrong layout" in p  # fmt: skip


def test_overlay_profile_names_units_and_scaling_on_derived_signals(tmp_path: Path) -> None:
    prof = overlay(tmp_path, "signals:\n  - {name: pressure, object: '0x6401:01', unit: bar, scale: 0.01}\n")
    cfg = parse_checked_config({"can": {"interface": "virtual", "channel": "x"}, "nodes": [{"name": "io", "node_id": 5, "profile": prof}]}, environ={})  # fmt: skip
    lp = load_node_profile(cfg.nodes[0].setup, cfg.base_dir)
    s = lp.profile.signal("pressure")
    assert (s.type, s.access, s.transport, s.unit) == ("int16", "ro", "pdo", "bar")
    assert "analogue_input_1" not in {x.name for x in lp.profile.signals}


def test_eds_show_and_profile_init(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["eds", "show", str(IO), "--node-id", "5"]) == 0
    out = capsys.readouterr().out
    assert "| TPDO3 | 0x385 | disabled (COB-ID bit 31) |" in out
    assert "| 0x6401:01 | Analogue input 1 | INTEGER16 | ro | yes |" in out
    target = tmp_path / "flow.yaml"
    assert main(["profile", "init", "--eds", str(FLOW), "-o", str(target)]) == 0
    cfg = parse_checked_config({"can": {"interface": "virtual", "channel": "x"}, "nodes": [{"name": "flow", "node_id": 6, "profile": str(target)}]}, environ={})  # fmt: skip
    lp = load_node_profile(cfg.nodes[0].setup, cfg.base_dir)
    assert [s.name for s in lp.profile.signals] == ["temperatur", "durchfluss", "status", "zahler", "sollwert"]
    bad = edited_copy(tmp_path, IO, "[6401sub2]", "[6401sbu2]")
    assert main(["eds", "show", str(bad)]) == 0
    assert capsys.readouterr().err == f"{bad}: 2 warnings (canopen-gateway eds lint {bad})\n"


# --------------------------------------------------------------------------- simulator


def _nmt(cs: int, node_id: int) -> Any:
    import can

    return can.Message(arbitration_id=0, data=bytes([cs, node_id]), is_extended_id=False)


def test_simulator_serves_an_eds_it_has_never_seen() -> None:
    import can

    from canopen_gateway.sim.node import SimNode

    lp = load_node_profile(Node(eds=str(IO)).cfg.setup)
    sim = SimNode(lp, 5)
    boot = sim.power_on(0.0)
    assert [(m.arbitration_id, bytes(m.data)) for m in boot] == [(0x705, b"\x00")]
    sent = sim.handle(_nmt(0x01, 5), 0.0) + sim.tick(0.0)
    cobs = sorted({m.arbitration_id for m in sent})
    assert cobs == [0x185, 0x285], "each enabled TPDO once on entering OPERATIONAL"
    first = {m.arbitration_id: bytes(m.data) for m in sent}
    later = {m.arbitration_id: bytes(m.data) for m in sim.tick(0.5)}
    assert later and later != {k: first[k] for k in later}, "mapped inputs move"
    # RPDO1 (6200h:01/02) is written into the dictionary; 6200h is an output, not 1800h:05
    sim.handle(can.Message(arbitration_id=0x205, data=b"\x5a\x03", is_extended_id=False), 0.6)
    assert (sim.get(0x6200, 1), sim.get(0x6200, 2)) == (0x5A, 3)
    assert sim.get(0x1800, 5) == 100


def test_simulator_answers_a_utf8_device_name_by_sdo() -> None:
    from canopen_gateway.sim.node import SimNode

    sim = SimNode(load_node_profile(Node(eds=str(FLOW)).cfg.setup), 6)
    sim.power_on(0.0)
    assert sim.sdo_read_local("0x1008:00") == "Durchflussmesser Größe 3 – µ"


def test_expected_identity_is_what_the_file_gives_and_a_dcf_serial(tmp_path: Path) -> None:
    from canopen_gateway.profiles import expected_identity, identity_check

    lp = load_node_profile(Node(eds=str(IO)).cfg.setup)
    assert expected_identity(lp) == ((ObjRef(0x1018, 1), 0xABC), (ObjRef(0x1018, 2), 0x401))
    text = IO.read_text(encoding="utf-8")
    head, rest = text.split("[1018sub4]", 1)
    section, tail = rest.split("\n\n", 1)
    dcf = tmp_path / "io.dcf"
    dcf.write_text(head + "[1018sub4]" + section + "\nParameterValue=0x00C0FFEE\n\n" + tail, encoding="utf-8")
    lp = load_node_profile(Node(eds=str(dcf)).cfg.setup)
    assert expected_identity(lp)[-1] == (ObjRef(0x1018, 4), 0xC0FFEE)
    assert identity_check(lp).not_checked == ()
    # a file with the product alone: the product is compared, and the vendor said not to be
    anonymous = edited_copy(tmp_path, IO, "VendorNumber=0x00000ABC", "VendorNumber=", "anon.eds")
    check = identity_check(load_node_profile(Node(eds=str(anonymous)).cfg.setup))
    assert check.expected == ((ObjRef(0x1018, 2), 0x401),)
    assert check.not_checked == ("0x1018:01 (vendor) not checked: anon.eds gives no VendorNumber in [DeviceInfo]; only 0x1018:02 (product) is compared",)  # fmt: skip
    # the vendor alone (VendorNumber, but ProductNumber 0: none): a device of another vendor is refused
    vendor_only = edited_copy(tmp_path, IO, "ProductNumber=0x00000401", "ProductNumber=0", "vendor.eds")
    check = identity_check(load_node_profile(Node(eds=str(vendor_only)).cfg.setup))
    assert check.expected == ((ObjRef(0x1018, 1), 0xABC),)
    assert check.not_checked == ("0x1018:02 (product) not checked: vendor.eds gives no ProductNumber (ProductNumber=0x0 in [DeviceInfo] stands for none); only 0x1018:01 (vendor) is compared",)  # fmt: skip
    neither = edited_copy(tmp_path, anonymous, "ProductNumber=0x00000401", "ProductNumber=", "neither.eds")
    check = identity_check(load_node_profile(Node(eds=str(neither)).cfg.setup))
    assert check.expected == ()
    assert check.not_checked == ("identity (1018h) not checked: neither.eds gives no VendorNumber or ProductNumber in [DeviceInfo]: any device at this node id is configured",)  # fmt: skip


def test_device_info_other_than_1018h_is_a_warning_and_that_number_is_not_compared(tmp_path: Path) -> None:
    from canopen_gateway.profiles import expected_identity

    p = edited_copy(tmp_path, IO, "VendorNumber=0x00000ABC", "VendorNumber=0x00000ABD")
    # the file contradicts itself on the vendor: only the product is checked at boot
    assert expected_identity(load_node_profile(Node(eds=str(p)).cfg.setup)) == ((ObjRef(0x1018, 2), 0x401),)
    _, warnings = lint_of(p)
    assert warnings == [f"{p}:{line_of(p, 'VendorNumber=0x00000ABD')}: [DeviceInfo]: VendorNumber=0xABD but 1018h:01 DefaultValue=0xABC: the identity check at boot does not compare it"]  # fmt: skip


def test_profile_init_keeps_the_objects_name_and_index_as_each_signals_description(
    tmp_path: Path,
) -> None:
    """A profile written by ``profile init`` describes each signal as the EDS-only node does
    (``Temperatur (0x6401:01)``-like: the object's name and index), so the register map of a
    node that got a profile does not lose the words its EDS gave it."""
    target = tmp_path / "flow.yaml"
    assert main(["profile", "init", "--eds", str(FLOW), "-o", str(target)]) == 0
    cfg = parse_checked_config({"can": {"interface": "virtual", "channel": "x"}, "nodes": [{"name": "flow", "node_id": 6, "profile": str(target)}]}, environ={})  # fmt: skip
    with_profile = load_node_profile(cfg.nodes[0].setup, cfg.base_dir).profile
    eds_only = load_node_profile(Node(eds=str(FLOW)).cfg.setup).profile
    by_object = {s.object: s.description for s in eds_only.signals}
    for s in with_profile.signals:
        assert s.description == by_object[s.object], s.name
        assert s.description.endswith(f"({s.object})") and len(s.description) > len(f"({s.object})")
