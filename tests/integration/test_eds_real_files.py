"""What real device files bring, end to end: a mapped object of a type the gateway does not
serve is skipped and the other signals of its PDO decode at their bit offsets (a frame from the
test, python canopen's LocalNode answering SDO from the same file); a device with neither
heartbeat nor node guarding in its EDS runs unsupervised and its values go stale by data age;
guarding is chosen for a device whose EDS has only 100Ch/100Dh."""

from __future__ import annotations

import asyncio
import math
import struct
from pathlib import Path

import can
import pytest
from pymodbus.client import AsyncModbusTcpClient

from canopen_gateway.cli import main
from canopen_gateway.config import ConfigError, NodeConfig
from canopen_gateway.device.settings import resolve_node_settings
from canopen_gateway.image import Quality
from canopen_gateway.profiles import load_node_profile
from tests.helpers import gateway_of, make_config, modbus_gateway, operational, wait_until
from tests.integration.test_eds_devices import boot, gateway_with, local_node

DATA = Path(__file__).resolve().parents[1] / "data" / "eds"
IO = DATA / "io401.eds"
CORPUS = Path(__file__).resolve().parents[2] / ".." / "shared" / "eds-corpus"

DOMAIN_2002 = (
    "\n[2002]\nParameterName=Raw status\nObjectType=0x2\nDataType=0x000F\nAccessType=ro\nPDOMapping=1\n"
)


def io_variant(tmp_path: Path, name: str, *, domain_in_tpdo2: bool = False, drop: tuple[str, ...] = ()) -> Path:
    """io401.eds with TPDO2 = [6100h:02/16, 2002h DOMAIN/32, 6401h:01/16], or without the
    sections ``drop`` (e.g. 1017h)."""
    text = IO.read_text(encoding="utf-8")
    if domain_in_tpdo2:
        text = text.replace("DefaultValue=2\nPDOMapping=0\n\n[1A01sub1]", "DefaultValue=3\nPDOMapping=0\n\n[1A01sub1]")
        text = text.replace("DefaultValue=0x64010110\nPDOMapping=0\n\n[1A01sub3]", "DefaultValue=0x20020020\nPDOMapping=0\n\n[1A01sub3]")  # fmt: skip
        sub3 = "[1A01sub3]\nParameterName=Mapped object 3\nObjectType=0x7\nDataType=0x0007\nAccessType=rw\nDefaultValue="  # fmt: skip
        text = text.replace(sub3 + "0x00000000", sub3 + "0x64010110")
        text += DOMAIN_2002
        text = text.replace("[ManufacturerObjects]\nSupportedObjects=0", "[ManufacturerObjects]\nSupportedObjects=1\n1=0x2002")  # fmt: skip
    for index in drop:
        head, rest = text.split(f"[{index}]\n", 1)
        _, tail = rest.split("\n\n", 1)
        text = head + tail
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    return p


async def test_an_unserved_object_is_skipped_and_the_other_signals_decode_at_their_offsets(tmp_path: Path) -> None:
    eds = io_variant(tmp_path, "io_domain.eds", domain_in_tpdo2=True)
    lp = load_node_profile(NodeConfig.model_validate({"name": "io", "node_id": 5, "eds": str(eds)}).setup)
    assert [(str(e.object), e.bits) for e in lp.profile.tpdos[1].mapping] == [("0x6100:02", 16), ("0x2002:00", 32), ("0x6401:01", 16)]  # fmt: skip
    assert "0x2002:00" not in {str(s.object) for s in lp.profile.signals}
    assert any("[1A01sub2]: TPDO2 entry 0x2002:00/32 (DOMAIN) is not a type the gateway serves: skipped" in w for w in lp.warnings), lp.warnings  # fmt: skip
    async with gateway_with(eds, 5, "io") as (gw, _node, bus, _):
        io = gw.image.nodes["io"]
        await wait_until(lambda: io.is_valid("analogue_input_1"), 5, "mapping verified")
        bus.send(can.Message(arbitration_id=0x285, data=struct.pack("<HIh", 0xBEEF, 0xDEADBEEF, -300), is_extended_id=False))  # fmt: skip
        await wait_until(lambda: io.signals["analogue_input_1"].seq > 0, 5, "TPDO2 decoded")
        assert io.signals["read_input_11h_to_20h"].value == 0xBEEF
        assert io.signals["analogue_input_1"].value == -300
        client = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus.port, timeout=3)
        await client.connect()
        try:
            regs = (await client.read_input_registers(103, count=2, device_id=5)).registers
        finally:
            client.close()
        assert regs[0] == 0xBEEF and struct.unpack(">h", struct.pack(">H", regs[1]))[0] == -300


@pytest.mark.skipif(not CORPUS.is_dir(), reason="no EDS corpus")
def test_a_mapped_real64_is_served_as_a_signal_of_its_pdo(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    eds = CORPUS / "jinr-greenlab__canopen__Test.eds"
    cfg = tmp_path / "c.yaml"
    cfg.write_text(f"can: {{interface: virtual, channel: x}}\nnodes:\n  - {{name: dev, node_id: 5, eds: '{eds}'}}\n")  # fmt: skip
    assert main(["check", "-c", str(cfg)]) == 0
    out = capsys.readouterr().out
    assert "12 process signals" in out and "double_2001_06" in out and "double_2000_06" in out
    assert main(["eds", "lint", str(eds)]) == 0
    assert "REAL64" not in capsys.readouterr().out


def test_supervision_follows_the_device(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    def settings(eds: Path, **kw: object) -> tuple[str, int | None, list[str]]:
        n = NodeConfig.model_validate({"name": "io", "node_id": 5, "eds": str(eds), **kw})
        lp = load_node_profile(n.setup)
        cfg = make_config([{"name": "io", "node_id": 5, "eds": str(eds), **kw}])
        s = resolve_node_settings(cfg.master, n, lp.profile)
        return s.supervision, lp.stale_after_ms, list(lp.notes)

    assert settings(IO) == ("heartbeat", None, [])
    guarded = io_variant(tmp_path, "guarded.eds", drop=("1017",))
    text = guarded.read_text(encoding="utf-8") + (
        "\n[100C]\nParameterName=Guard time\nDataType=0x0006\nAccessType=rw\nDefaultValue=200\n"
        "\n[100D]\nParameterName=Life time factor\nDataType=0x0005\nAccessType=rw\nDefaultValue=2\n"
    )
    guarded.write_text(text, encoding="utf-8")
    n = NodeConfig.model_validate({"name": "io", "node_id": 5, "eds": str(guarded)})
    boot_cfg = load_node_profile(n.setup).profile.boot
    assert (boot_cfg.supervision, boot_cfg.guard_time_ms, boot_cfg.life_time_factor) == ("guarding", 200, 2)
    bare = io_variant(tmp_path, "bare.eds", drop=("1017",))
    sup, stale_ms, notes = settings(bare)
    assert (sup, stale_ms) == ("none", 300)  # 3 x the longest TPDO event timer (100 ms)
    assert notes == ["bare.eds has neither 1017h (heartbeat) nor 100Ch/100Dh (node guarding): a lost device cannot be detected otherwise; its values go stale 300 ms after their last TPDO (3 x the longest TPDO event timer)"]  # fmt: skip
    with pytest.raises(ConfigError) as err:  # an explicit supervision wins, and is checked
        settings(bare, supervision="heartbeat")
    assert err.value.problems == ["<memory>: nodes[0]: heartbeat: 0x1017:00 is not in bare.eds"]
    cfg = tmp_path / "c.yaml"
    cfg.write_text(f"can: {{interface: virtual, channel: x}}\nnodes:\n  - {{name: io, node_id: 5, eds: '{bare}'}}\n")
    assert main(["check", "-c", str(cfg)]) == 0
    assert f"  warning: node io: {notes[0]}" in capsys.readouterr().out.splitlines()


@pytest.mark.skipif(not CORPUS.is_dir(), reason="no EDS corpus")
def test_faulhaber_with_node_guarding_only_is_accepted_with_the_one_line_node_entry(tmp_path: Path) -> None:
    eds = CORPUS / "KITmedical__kacanopen__605.3150.51-V-EK-2-60.eds"
    lp = load_node_profile(NodeConfig.model_validate({"name": "motor", "node_id": 5, "eds": str(eds)}).setup)
    assert lp.profile.boot.supervision == "guarding"
    cfg = tmp_path / "c.yaml"
    cfg.write_text(f"can: {{interface: virtual, channel: x}}\nnodes:\n  - {{name: motor, node_id: 5, eds: '{eds}'}}\n")  # fmt: skip
    assert main(["check", "-c", str(cfg)]) == 0


async def test_an_unsupervised_device_runs_and_its_values_go_stale_by_data_age(tmp_path: Path) -> None:
    eds = io_variant(tmp_path, "bare.eds", drop=("1017",))
    cfg = make_config([{"name": "io", "node_id": 5, "eds": str(eds)}], simulate={"nodes": []},
                      master={"probe_at_start": False})  # fmt: skip
    net, node = local_node(IO, 5, cfg.can.channel)  # its 1017h is 0: no heartbeat on the bus
    sender = can.Bus(interface="virtual", channel=cfg.can.channel)
    gw = gateway_of(cfg)
    await gw.start()
    try:
        assert gw.master.nodes["io"].settings.supervision == "none"
        boot(node)
        io = gw.image.nodes["io"]
        await wait_until(lambda: io.operational() and io.is_valid("analogue_input_1"), 8, "io configured and started")
        sender.send(can.Message(arbitration_id=0x285, data=struct.pack("<Hh", 7, -5), is_extended_id=False))
        await wait_until(lambda: io.signals["analogue_input_1"].seq > 0, 5, "TPDO2 decoded")
        sig = io.signals["analogue_input_1"]
        assert sig.value == -5
        assert io.stale_after_s == 0.3
        # the last instant at which the value is 0.3 s old or less (float sums round either way)
        limit = sig.monotonic + 0.3
        while limit - sig.monotonic > 0.3:
            limit = math.nextafter(limit, -math.inf)
        while math.nextafter(limit, math.inf) - sig.monotonic <= 0.3:
            limit = math.nextafter(limit, math.inf)
        assert io.quality(sig, now_monotonic=limit) == Quality.GOOD
        assert io.quality(sig, now_monotonic=math.nextafter(limit, math.inf)) == Quality.STALE
    finally:
        await gw.stop()
        sender.shutdown()
        net.disconnect()


# --------------------------------------------------------------------------- identity (1018h)


async def test_a_device_whose_1018h_differs_from_its_eds_is_refused_at_boot_and_never_served() -> None:
    import json
    import urllib.request

    from tests.helpers import free_port
    from tests.zenoh_client import ZClient

    cfg = make_config([{"name": "io", "node_id": 5, "eds": str(IO)}], simulate={"nodes": []},
                      master={"probe_at_start": False}, health={"port": free_port()})  # fmt: skip
    net, node = local_node(IO, 5, cfg.can.channel)
    node.set_data(0x1018, 2, struct.pack("<I", 0x999))  # another product of the same vendor
    sender = can.Bus(interface="virtual", channel=cfg.can.channel)
    gw = gateway_of(cfg)
    await gw.start()
    try:
        boot(node)
        io = gw.image.nodes["io"]
        await wait_until(lambda: io.health.last_error.startswith("wrong device"), 8, "identity refused")
        assert io.health.last_error == (
            "wrong device: vendor 0xABC product 0x999, expected vendor 0xABC product 0x401 "
            "(1018h against the EDS): not configured"
        )
        rt = gw.master.nodes["io"]
        assert rt.lifecycle.state == "waiting" and rt.lifecycle.configurations == 0
        # the device sends its TPDO anyway: never served
        sender.send(can.Message(arbitration_id=0x285, data=struct.pack("<Hh", 7, -5), is_extended_id=False))
        await wait_until(lambda: io.signals["analogue_input_1"].seq > 0, 5, "frame seen")
        client = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus.port, timeout=3)
        await client.connect()
        try:
            rr = await client.read_input_registers(100, count=1, device_id=5)
            diag = (await client.read_input_registers(0, count=4, device_id=5)).registers
        finally:
            client.close()
        assert rr.isError() and rr.exception_code == 0x0B
        assert diag[0] == int(Quality.BAD) and diag[3] == 0  # quality bad, lifecycle waiting
        z = ZClient(gw.cfg.zenoh.listen)
        try:
            r = await z.get_one("canopen/test/io/value/analogue_input_1")
            assert not r.ok or r.body.get("quality") != "good"
        finally:
            z.close()
        url = f"http://127.0.0.1:{cfg.health.port}/healthz"
        body = await asyncio.to_thread(lambda: urllib.request.urlopen(url, timeout=3).read())  # noqa: S310
        assert json.loads(body)["nodes"]["io"]["last_error"].startswith("wrong device: vendor 0xABC product 0x999")
        url = f"http://127.0.0.1:{cfg.health.port}/api/node/io"  # the web console's node page
        body = await asyncio.to_thread(lambda: urllib.request.urlopen(url, timeout=3).read())  # noqa: S310
        assert "wrong device: vendor 0xABC product 0x999" in body.decode()
        z = ZClient(gw.cfg.zenoh.listen)
        try:
            r = await z.get_one("canopen/test/io/snapshot")
            assert "wrong device: vendor 0xABC product 0x999" in json.dumps(r.body)
        finally:
            z.close()
    finally:
        await gw.stop()
        sender.shutdown()
        net.disconnect()


async def test_identity_check_false_configures_any_device() -> None:
    cfg = make_config([{"name": "io", "node_id": 5, "eds": str(IO), "identity_check": False}],
                      simulate={"nodes": []}, master={"probe_at_start": False})  # fmt: skip
    net, node = local_node(IO, 5, cfg.can.channel)
    node.set_data(0x1018, 2, struct.pack("<I", 0x999))
    gw = gateway_of(cfg)
    await gw.start()
    try:
        boot(node)
        await wait_until(lambda: gw.master.nodes["io"].lifecycle.state == "operational", 8, "configured")
    finally:
        await gw.stop()
        net.disconnect()


async def test_a_file_with_the_vendor_alone_refuses_a_device_of_another_vendor_and_says_what_it_cannot_check(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], caplog: pytest.LogCaptureFixture
) -> None:
    import logging

    from tests.helpers import edited_copy

    eds = edited_copy(tmp_path, IO, "ProductNumber=0x00000401", "ProductNumber=", "vendor.eds")
    path = tmp_path / "c.yaml"
    path.write_text(f"can: {{interface: virtual, channel: x}}\nnodes:\n  - {{name: io, node_id: 5, eds: '{eds}'}}\n")  # fmt: skip
    assert main(["check", "-c", str(path)]) == 0
    note = "node io: 0x1018:02 (product) not checked: vendor.eds gives no ProductNumber in [DeviceInfo]; only 0x1018:01 (vendor) is compared"  # fmt: skip
    assert f"  note: {note}" in capsys.readouterr().out.splitlines()
    caplog.set_level(logging.INFO, logger="gateway")
    cfg = make_config([{"name": "io", "node_id": 5, "eds": str(eds)}], simulate={"nodes": []},
                      master={"probe_at_start": False})  # fmt: skip
    net, node = local_node(IO, 5, cfg.can.channel)
    node.set_data(0x1018, 1, struct.pack("<I", 0xDEF))  # a device of another vendor
    gw = gateway_of(cfg)
    await gw.start()
    try:
        boot(node)
        io = gw.image.nodes["io"]
        await wait_until(lambda: io.health.last_error.startswith("wrong device"), 8, "identity refused")
        assert io.health.last_error == "wrong device: vendor 0xDEF, expected vendor 0xABC (1018h against the EDS): not configured"  # fmt: skip
        rt = gw.master.nodes["io"]
        assert rt.lifecycle.state == "waiting" and rt.lifecycle.configurations == 0
        assert not io.operational()  # never started
    finally:
        await gw.stop()
        net.disconnect()
    said = [r.getMessage() for r in caplog.records if "not checked" in r.getMessage()]
    assert said == [f"node io (id 5): {note.removeprefix('node io: ')}"]


def test_a_node_whose_pdos_map_nothing_is_warned_of_with_the_objects_it_may_map(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cfg = tmp_path / "c.yaml"
    off = "{1: {enabled: false}, 2: {enabled: false}}"
    cfg.write_text(f"can: {{interface: virtual, channel: x}}\nnodes:\n  - {{name: io, node_id: 5, eds: '{IO}', tpdo: {off}, rpdo: {off}}}\n")  # fmt: skip
    assert main(["check", "-c", str(cfg)]) == 0
    out = capsys.readouterr().out.splitlines()
    assert any(line.startswith("  node io: id 5,") and "0 process signals ()" in line for line in out), out
    warning = next(line for line in out if "serves no process data" in line)
    assert warning.startswith("  warning: node io: serves no process data: map one with `tpdo:`")
    assert 'e.g. `tpdo: {1: {mapping: ["0x6000:01"], transmission: 255}}`' in warning
    assert "PDO-mappable in io401.eds: 0x6000:01 (" in warning and "0x6401:01" in warning


@pytest.mark.skipif(not CORPUS.is_dir(), reason="no EDS corpus")
async def test_an_encoder_file_that_maps_nothing_is_warned_of_and_never_served_as_good(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A CiA 406 sample file of another project: TPDO mappings of 0 entries, PDOMapping=0
    everywhere. ``check`` warns; run with the node simulated, the node answers and is
    operational, but Modbus quality says bad, the console says why and counts it out of the
    usable nodes, and the simulated device sends no TPDO (none the gateway would call
    unexpected)."""
    eds = CORPUS / "KITmedical__kacanopen__406.eds"
    path = tmp_path / "c.yaml"
    path.write_text(f"can: {{interface: virtual, channel: x}}\nnodes:\n  - {{name: enc, node_id: 11, eds: '{eds}'}}\n")  # fmt: skip
    assert main(["check", "-c", str(path)]) == 0
    warning = next(line for line in capsys.readouterr().out.splitlines() if "serves no process data" in line)
    assert "serves no process data: map one with `tpdo:`" in warning
    assert "KITmedical__kacanopen__406.eds marks no object PDO-mappable (PDOMapping=1)" in warning
    cfg = make_config([{"name": "enc", "node_id": 11, "eds": str(eds)}], health={"port": 0})
    sniffer = can.Bus(interface="virtual", channel=cfg.can.channel)
    frames: list[can.Message] = []
    notifier = can.Notifier(sniffer, [frames.append])

    def operational_heartbeats() -> int:  # the simulator sends in its own time order
        return sum(1 for m in list(frames) if m.arbitration_id == 0x70B and bytes(m.data) == b"\x05")

    async with modbus_gateway(cfg, [(operational("enc"), "enc operational")]) as (gw, client):
        # two heartbeats after entering OPERATIONAL: its input sample (10 ms) came before
        await wait_until(lambda: operational_heartbeats() >= 2, 5, "two operational heartbeats")
        assert not [m for m in frames if m.arbitration_id in (0x18B, 0x28B)]
        rr = await client.read_input_registers(0, count=1, device_id=11)
        assert rr.registers == [2]  # bad: no value to serve
        from canopen_gateway.web.views import ConsoleModel

        model = ConsoleModel(gw.cfg, gw.image, gw.commands, gw.overview, regmap=gw.modbus.regmap)
        row = model.node_row("enc")
        assert (row["quality"], row["quality_note"], row["presence"]) == (
            "bad", "no process data: its PDOs map nothing", "alive"
        )
        assert model.overview()["nodes_usable"] == 0
        assert gw.image.counters["unknown_cob_id"] == 0
    notifier.stop()
    sniffer.shutdown()


@pytest.mark.skipif(not CORPUS.is_dir(), reason="no EDS corpus")
def test_the_example_of_a_node_without_process_data_maps_an_input_and_pasted_warns_no_more(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A CiA 402 drive file whose PDOs map nothing: the example is its statusword (6041h, ro),
    not its controlword (6040h, rww: an output); pasted as given, check warns of nothing."""
    eds = CORPUS / "ros-industrial__ros2_canopen__cia402_slave.eds"
    cfg = tmp_path / "c.yaml"
    cfg.write_text(f"can: {{interface: virtual, channel: x}}\nnodes:\n  - {{name: drive, node_id: 13, eds: '{eds}'}}\n")
    assert main(["check", "-c", str(cfg)]) == 0
    warning = next(line for line in capsys.readouterr().out.splitlines() if "serves no process data" in line)
    example = warning.split("e.g. `")[1].split("`")[0]
    assert example == 'tpdo: {1: {mapping: ["0x6041:00"], transmission: 255}}'
    cfg.write_text(f"can: {{interface: virtual, channel: x}}\nnodes:\n  - {{name: drive, node_id: 13, eds: '{eds}', {example}}}\n")
    assert main(["check", "-c", str(cfg)]) == 0
    assert not [line for line in capsys.readouterr().out.splitlines() if line.startswith("  warning")]
