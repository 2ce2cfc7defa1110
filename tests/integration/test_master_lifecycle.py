"""Node lifecycle against simulated devices on a virtual bus: found running, configured in the
order of the boot steps, reconfigured after a power cycle, reported when it never appears or
when a step is refused; PDO layouts chosen at boot (BEI 2005h, MSK5000 remapping) decoded."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import can

from canopen_gateway.bus.node.lifecycle import LifecycleState
from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.config import load_config
from canopen_gateway.device.boot_steps import build_boot_steps
from canopen_gateway.profiles import load_profile
from tests.helpers import gateway_of, make_config, simulated_bus, wait_until
from tests.helpers import master_running as running
from tests.helpers import node_operational as operational

REPO = Path(__file__).resolve().parents[2]


async def test_node_running_before_the_gateway_is_found_by_probe_and_configured_in_order() -> None:
    cfg = make_config(
        [{"name": "wire", "node_id": 1, "profile": "sgh10"}],
        modbus={"enabled": False},
        zenoh={"enabled": False},
    )
    sim = simulated_bus(cfg)
    sim.start()  # the device boots now: its boot-up is gone before the gateway listens
    observer = can.Bus(interface="virtual", channel=cfg.can.channel)
    gw = gateway_of(cfg, simulate=False)
    try:
        await wait_until(lambda: sim.nodes["wire"].powered, 2, "device powered")
        await gw.start()
        await wait_until(lambda: operational(gw, "wire"), 5, "wire operational")
        rt = gw.master.nodes["wire"]
        assert rt.image.health.boot_count == 0  # found by the 1000h probe, not by a boot-up
        frames = []
        while (msg := observer.recv(timeout=0)) is not None:
            frames.append(msg)
    finally:
        await gw.stop()
        observer.shutdown()
        sim.stop()
    nmt = [bytes(m.data) for m in frames if m.arbitration_id == 0x000]
    assert nmt == [b"\x80\x01", b"\x01\x01"]  # pre-operational first, start at the end
    # SDO download requests (initiate, command 001x xxxx) on 601h, in the order of the steps
    downloads = [
        ObjRef(int.from_bytes(m.data[1:3], "little"), m.data[3])
        for m in frames
        if m.arbitration_id == 0x601 and m.data[0] >> 5 == 1
    ]
    assert downloads == [st.object for st in rt.boot_steps]
    i_preop = next(i for i, m in enumerate(frames) if m.arbitration_id == 0x000)
    i_first_sdo = next(
        i for i, m in enumerate(frames) if m.arbitration_id == 0x601 and m.data[0] >> 5 == 1
    )
    i_start = max(i for i, m in enumerate(frames) if m.arbitration_id == 0x000)
    i_last_answer = max(i for i, m in enumerate(frames) if m.arbitration_id == 0x581)
    assert i_preop < i_first_sdo and i_last_answer < i_start
    assert sim.nodes["wire"].get(0x1017, 0) == 100  # heartbeat 100 ms (profile)
    assert sim.nodes["wire"].get(0x1800, 5) == 10  # TPDO1 every 10 ms (profile)


async def test_power_cycled_node_is_reconfigured_and_started_again() -> None:
    async with running([{"name": "wire", "node_id": 1, "profile": "sgh10"}]) as gw:
        await wait_until(lambda: operational(gw, "wire"), 5, "wire operational")
        rt = gw.master.nodes["wire"]
        sim = gw.sim.nodes["wire"]
        boots = rt.image.health.boot_count
        # the runner sends the power-on frames (boot-up) that power_cycle returns
        gw.sim.runner.call(lambda now: sim.power_cycle(now))
        # power-on reloads the EDS defaults (1017h = 0): only a new configuration brings 100 back
        await wait_until(lambda: rt.image.health.boot_count == boots + 1, 3, "boot-up seen")
        await wait_until(lambda: rt.lifecycle.configurations == 2, 5, "second configuration")
        await wait_until(lambda: operational(gw, "wire"), 5, "operational again")
        assert sim.get(0x1017, 0) == 100
        assert int(sim.nmt_state) == 0x05
        seq = rt.image.signals["position"].seq
        await wait_until(lambda: rt.image.signals["position"].seq > seq + 3, 3, "TPDOs again")


async def test_configured_node_that_never_appears_is_reported_after_the_boot_timeout() -> None:
    async with running(
        [{"name": "ghost", "node_id": 9, "profile": "sgh10"}],
        simulate={"nodes": []},
        master={"boot_timeout_s": 0.5, "sdo_timeout_s": 0.1},
    ) as gw:
        h = gw.image.nodes["ghost"].health
        await wait_until(lambda: "did not appear" in h.last_error, 3, "boot timeout reported")
        assert "0.5 s" in h.last_error
        assert not h.alive
        assert h.lifecycle == "waiting"


async def test_refused_boot_step_is_reported_with_object_and_abort_code_and_retried() -> None:
    # POSI+ 2005h accepts 00h, 02h, 20h, 22h only (manual 002 5): 11h is refused 06090030h
    node = {
        "name": "rotary",
        "node_id": 3,
        "profile": "posi_plus",
        "sdo": [{"object": "0x2005:00", "value": 0x11}],
    }
    async with running([node]) as gw:
        rt = gw.master.nodes["rotary"]
        h = rt.image.health
        await wait_until(lambda: rt.lifecycle.attempt >= 2, 5, "the refused step retried")
        assert "0x2005:00" in h.last_error
        assert "06090030" in h.last_error
        assert h.last_sdo_abort == 0x06090030
        assert rt.lifecycle.state == LifecycleState.CONFIGURING
        # the backoff doubles (0.5 s, 1 s, ...): the retry is scheduled, not hammered
        assert rt.lifecycle.retry_at_s is not None
        assert rt.lifecycle.step_failures == rt.lifecycle.attempt
        assert gw.sim.nodes["rotary"].nmt_state != 0x05  # never started with a bad config


async def test_bei_pdo_type_2_is_written_at_boot_and_its_speed_decoded() -> None:
    node = {"name": "rotary", "node_id": 3, "profile": "posi_plus", "pdo_variant": 0x22}
    motion = {"rotary": {"kind": "ramp", "min": 0, "max": 8_000_000, "speed": 50_000}}
    async with running([node], simulate={"nodes": "all", "motion": motion}) as gw:
        await wait_until(lambda: operational(gw, "rotary"), 5, "rotary operational")
        sim = gw.sim.nodes["rotary"]
        assert sim.get(0x2005, 0) == 0x22  # the device and the decoder agree on type 2
        steps = [str(s.object) for s in gw.master.nodes["rotary"].boot_steps]
        assert steps.index("0x2005:00") < steps.index("0x1800:02")  # layout before the TPDOs
        await wait_until(lambda: gw.image.nodes["rotary"].signals["speed"].seq > 2 and gw.image.nodes["rotary"].signals["speed"].value, 3, "speed decoded")
        # 2002h: counts per 5 ms; the ramp runs 50000 counts/s = 250 per 5 ms (sim hint)
        assert 200 <= gw.image.nodes["rotary"].signals["speed"].value <= 300


async def test_msk5000_tpdo_remapped_by_node_sdo_writes_is_decoded_by_the_new_mapping() -> None:
    # MSK5000 manual 4.3.1.2 example: position, sys register 5122h:01, flag 0 register 5122h:02
    remap = [
        ("0x1800:01", 0x80000182),
        ("0x1A00:00", 0),
        ("0x1A00:01", 0x60040020),
        ("0x1A00:02", 0x51220108),
        ("0x1A00:03", 0x51220208),
        ("0x1A00:00", 3),
        ("0x1800:01", 0x182),
    ]
    node = {
        "name": "magnet",
        "node_id": 2,
        "profile": "msk5000",
        "sdo": [{"object": o, "value": v} for o, v in remap],
    }
    async with running([node], master={"sync_period_ms": 0}) as gw:
        await wait_until(lambda: operational(gw, "magnet"), 5, "magnet operational")
        rt = gw.master.nodes["magnet"]
        tpdo1 = next(c for c in rt.tpdos if c.number == 1)
        assert tpdo1.names == ("position", "sys_register", "flag0_register")
        sim = gw.sim.nodes["magnet"]
        assert sim.get(0x1A00, 0) == 3
        sigs = gw.image.nodes["magnet"].signals
        await wait_until(lambda: sigs["sys_register"].seq > 2, 3, "sys register by TPDO1")
        # not referenced after power-on: sys register bit 1 (manual 5122h:01)
        assert sigs["sys_register"].value == sim.get(0x5122, 1)
        assert sigs["sys_register"].value & 0x02
        assert sigs["flag0_register"].value == sim.get(0x5122, 2)
        assert rt.image.rx.pdo_too_short == 0


def boot_table(lp: Any, node: Any) -> str:
    """The Markdown table docs/canopen.md shows for one node's boot configuration."""
    steps = build_boot_steps(lp, node.setup)
    lines = ["| object | value | type | why |", "| --- | --- | --- | --- |"]
    for st in steps:
        v = st.value
        shown = f"{v} (0x{v:X})" if isinstance(v, int) and v > 9 else str(v)
        lines.append(f"| {st.object} | {shown} | {st.type} | {st.description.replace('|', '/')} |")
    return "\n".join(lines)


def test_docs_list_the_boot_steps_build_boot_steps_gives_for_the_demo_nodes() -> None:
    """docs/canopen.md shows, per demo node, the SDO writes of its boot configuration; on a
    mismatch the message carries the current table to paste."""
    cfg = load_config(REPO / "config" / "demo.yaml", environ={})
    doc = (REPO / "docs" / "canopen.md").read_text(encoding="utf-8")
    for n in cfg.nodes:
        lp = load_profile(n.profile, cfg.base_dir)
        table = boot_table(lp, n)
        heading = f"### {n.name} ({lp.profile.title}, node id {n.node_id}, "
        assert heading in doc, f"docs/canopen.md lacks the section {heading!r}"
        section = doc.split(heading, 1)[1].split("\n### ", 1)[0]
        assert table in section, f"docs/canopen.md, {n.name}: the boot steps are now\n{table}"


async def test_node_with_configure_false_is_only_started() -> None:
    cfg = make_config(
        [{"name": "wire", "node_id": 1, "profile": "sgh10", "configure": False}],
        modbus={"enabled": False},
        zenoh={"enabled": False},
    )
    sim = simulated_bus(cfg)
    sim.start()
    observer = can.Bus(interface="virtual", channel=cfg.can.channel)
    gw = gateway_of(cfg, simulate=False)
    try:
        await wait_until(lambda: sim.nodes["wire"].powered, 2, "device powered")
        await gw.start()
        rt = gw.master.nodes["wire"]
        await wait_until(
            lambda: rt.lifecycle.state == LifecycleState.OPERATIONAL, 5, "lifecycle operational"
        )
        await wait_until(lambda: int(sim.nodes["wire"].nmt_state) == 0x05, 2, "device started")
        assert rt.image.health.alive  # it answered the probe
        frames = []
        while (msg := observer.recv(timeout=0)) is not None:
            frames.append(msg)
    finally:
        await gw.stop()
        observer.shutdown()
        sim.stop()
    assert not [m for m in frames if m.arbitration_id == 0x601 and m.data[0] >> 5 == 1]
    assert [bytes(m.data) for m in frames if m.arbitration_id == 0x000][-1] == b"\x01\x01"
    assert sim.nodes["wire"].get(0x1017, 0) == 0  # factory value: nothing written
