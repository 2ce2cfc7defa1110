"""One COB-ID, one use: ``check`` (and every start) refuses a COB-ID two nodes, or a node and the
master, would use, naming both and where each got it; the master's dispatch table refuses a
second receiver; an absolute COB-ID of another node in an EDS/DCF and a DCF written for another
node id are warnings (``eds lint``, ``check``). SYNC-driven TPDOs without a SYNC producer:
a ``check`` warning, and the node's ``last_error`` while the values they alone carry are bad."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from canopen_gateway.bus.driver import BusDriver
from canopen_gateway.bus.master import Master
from canopen_gateway.bus.node.features.sync_wait import WAITING
from canopen_gateway.checks import config_warnings
from canopen_gateway.config import ConfigError
from canopen_gateway.config import parse_config as parse_unchecked
from canopen_gateway.eds import lint, load_eds
from canopen_gateway.image import ProcessImage
from tests.helpers import gateway_of, master_running, resolved, wait_until, with_nodes
from tests.helpers import parse_checked_config as parse_config
from tests.unit.test_node import sgh10

ROOT = Path(__file__).resolve().parents[2]
IO401 = ROOT / "tests" / "data" / "eds" / "io401.eds"
CIA402_SLAVE = ROOT / ".." / "shared" / "eds-corpus" / "ros-industrial__ros2_canopen__cia402_slave.eds"

WIRE = {"name": "wire", "node_id": 1, "profile": "sgh10"}
SYNC = {"sync_period_ms": 20}


def config(*nodes: dict[str, Any], **master: Any) -> dict[str, Any]:
    return {"can": {"interface": "virtual", "channel": "x"}, "master": master, "nodes": list(nodes)}


def problems(raw: dict[str, Any]) -> list[str]:
    with pytest.raises(ConfigError) as exc:
        parse_config(raw, "cfg.yaml", environ={})
    return exc.value.problems


def io_file(tmp_path: Path, name: str = "io.dcf", node_id: int | None = 1) -> Path:
    """io401.eds with TPDO1's COB-ID written absolute for node 1 (as a tool writes a DCF)."""
    text = IO401.read_text().replace("DefaultValue=$NODEID+0x180", "DefaultValue=0x181", 1)
    if node_id is not None:
        text += f"\n[DeviceComissioning]\nNodeID={node_id}\nBaudrate=250\n"
    path = tmp_path / name
    path.write_text(text)
    return path


def line_of(path: Path, text: str) -> int:
    return next(i for i, line in enumerate(path.read_text().splitlines(), 1) if line == text)


# --------------------------------------------------------------------------- clashes


def test_a_pdo_cob_id_of_another_node_is_refused_naming_both_and_where_each_got_it() -> None:
    io = {"name": "io", "node_id": 5, "eds": str(IO401), "tpdo": {1: {"cob_id": 0x181}}}
    assert problems(config(WIRE, io, **SYNC)) == [
        "cfg.yaml: nodes[1].tpdo.1.cob_id: COB-ID 0x181 of nodes[1] (io) TPDO1 "
        "(nodes[1].tpdo.1.cob_id) is also nodes[0] (wire) TPDO1 (default 0x180 + node id 1): "
        "one COB-ID cannot serve both (the frames of one would be taken for the other's)"
    ]


def test_a_dcf_written_for_node_1_used_at_node_5_is_refused_beside_node_1(tmp_path: Path) -> None:
    dcf = io_file(tmp_path)
    line = line_of(dcf, "DefaultValue=0x181")
    p = problems(config(WIRE, {"name": "io", "node_id": 5, "eds": str(dcf)}, **SYNC))
    assert p == [
        f"cfg.yaml: nodes[1]: COB-ID 0x181 of nodes[1] (io) TPDO1 (io.dcf [1800sub1] line {line}, "
        "absolute) is also nodes[0] (wire) TPDO1 (default 0x180 + node id 1): one COB-ID cannot "
        "serve both (the frames of one would be taken for the other's)"
    ]


def test_a_node_on_the_masters_heartbeat_id_is_refused() -> None:
    p = problems(config({**WIRE, "node_id": 127}, **SYNC))
    assert p == [
        "cfg.yaml: nodes[0].node_id: COB-ID 0x77F of nodes[0] (wire) heartbeat (default 0x700 + "
        "node id 127) is also the master heartbeat (master.node_id 127): one COB-ID cannot serve "
        "both (the frames of one would be taken for the other's)"
    ]
    parse_config(config({**WIRE, "node_id": 127}, node_id=126, **SYNC), "cfg.yaml", environ={})


async def test_a_master_without_a_heartbeat_leaves_its_node_id_to_a_node() -> None:
    """``master.heartbeat_ms: 0``: the master sends nothing on 700h + its node id, so a node may
    have that id (127 nodes on one bus): the config is accepted and the node's heartbeats are
    that node's (it comes up operational)."""
    async with master_running([{**WIRE, "node_id": 127}], master={"heartbeat_ms": 0}) as gw:
        await wait_until(lambda: gw.image.by_id[127].operational(), 10.0, "node 127 operational")
        assert gw.image.by_id[127].health.alive


def test_a_pdo_on_the_sync_cob_id_is_refused_only_when_sync_runs() -> None:
    io = {"name": "io", "node_id": 5, "eds": str(IO401), "rpdo": {1: {"cob_id": 0x080}}}
    [p] = problems(config(io, **SYNC))
    assert "nodes[0].rpdo.1.cob_id: COB-ID 0x080 of nodes[0] (io) RPDO1" in p
    assert "is also the master SYNC (master.sync_period_ms)" in p
    [p] = problems(config(io, sync_external=True))
    assert "is also the master SYNC of another master (master.sync_external)" in p
    cfg = parse_config(config(io), "cfg.yaml", environ={})
    assert cfg.nodes[0].rpdo[1].cob_id == 0x080


def test_two_pdos_of_one_node_on_one_cob_id_are_refused() -> None:
    io = {"name": "io", "node_id": 5, "eds": str(IO401), "tpdo": {2: {"cob_id": 0x185}}}
    [p] = problems(config(io, **SYNC))
    assert p.startswith("cfg.yaml: nodes[0].tpdo.2.cob_id: COB-ID 0x185 of nodes[0] (io) TPDO2")
    assert "is also nodes[0] (io) TPDO1 (default 0x180 + node id 5)" in p


def test_a_device_sending_and_receiving_on_one_cob_id_is_a_warning() -> None:
    """Its TPDO and its RPDO on one COB-ID (a real Sevcon DCF has RPDO6 and TPDO2 on 0x315):
    one receiver in the gateway, so it runs; writing that RPDO adds a second sender."""
    io = {"name": "io", "node_id": 5, "eds": str(IO401), "rpdo": {1: {"cob_id": 0x185}}}
    cfg = parse_config(config(io, **SYNC), "cfg.yaml", environ={})
    assert config_warnings(*with_nodes(cfg)) == [
        ("nodes[0].rpdo.1.cob_id", "node io: COB-ID 0x185 of nodes[0] (io) RPDO1 "
                                   "(nodes[0].rpdo.1.cob_id) is also nodes[0] (io) TPDO1 (default "
                                   "0x180 + node id 5): the device sends and receives on one COB-ID; "
                                   "a write of its RPDO would be a second sender on it"),
    ]  # fmt: skip


def test_every_start_runs_the_cob_id_check() -> None:

    io = {"name": "io", "node_id": 5, "eds": str(IO401), "tpdo": {1: {"cob_id": 0x181}}}
    cfg = parse_unchecked(config(WIRE, io, **SYNC), "cfg.yaml", environ={})
    with pytest.raises(ConfigError, match=r"COB-ID 0x181 of nodes\[1\] \(io\) TPDO1"):
        gateway_of(cfg)


def test_sync_produced_by_the_gateway_and_by_another_master_is_refused() -> None:
    p = problems(config(WIRE, sync_period_ms=10, sync_external=True))
    assert p == [
        "cfg.yaml: master.sync_external: true says another master produces SYNC, but "
        "master.sync_period_ms 10 makes this gateway produce it too; one SYNC producer per bus "
        "(CiA 301 7.2.5): set one of them"
    ]


def test_the_master_refuses_a_second_receiver_for_one_cob_id() -> None:
    """The dispatch table keeps one handler per COB-ID: a config that skipped the check
    cannot make node io's frames node wire's."""
    io = {"name": "io", "node_id": 5, "eds": str(IO401), "tpdo": {1: {"cob_id": 0x181}}}
    cfg = parse_unchecked(config(WIRE, io, **SYNC), "cfg.yaml", environ={})
    image = ProcessImage()
    with pytest.raises(AssertionError, match=r"COB-ID 0x181: io TPDO1 would replace wire TPDO1"):
        Master(cfg, image, BusDriver(cfg.can.bus_kwargs(), image), nodes=resolved(cfg))


# --------------------------------------------------------------------------- device files


def test_eds_lint_warns_of_an_absolute_cob_id_of_another_node(tmp_path: Path) -> None:
    eds = io_file(tmp_path, "io.eds", node_id=None)
    line = line_of(eds, "DefaultValue=0x181")
    result = lint(load_eds(eds))
    assert [(p.line, p.section, p.message) for p in result.warnings] == [
        (line, "1800sub1", "TPDO1 COB-ID 0x181 is absolute: the pre-defined TPDO1 COB-ID of "
                           "node 1; at any other node id it is still node 1's (relative: $NODEID+0x180)")
    ]  # fmt: skip
    r = subprocess.run([sys.executable, "-m", "canopen_gateway", "eds", "lint", str(eds)], capture_output=True, text=True)
    assert r.returncode == 1
    assert f"{eds}:{line}: [1800sub1]: warning: TPDO1 COB-ID 0x181 is absolute" in r.stdout
    # a DCF written for node 1 holds node 1's COB-IDs: right for its own node
    assert lint(load_eds(io_file(tmp_path))).warnings == ()


def test_check_warns_of_a_dcf_written_for_another_node_id(tmp_path: Path) -> None:
    dcf = io_file(tmp_path)
    cfg = parse_config(config({"name": "io", "node_id": 5, "eds": str(dcf)}, **SYNC), "cfg.yaml", environ={})
    nid = line_of(dcf, "NodeID=1")
    cob = line_of(dcf, "DefaultValue=0x181")
    assert config_warnings(*with_nodes(cfg)) == [
        ("nodes[0].node_id", f"node io: node id 5, but io.dcf [DeviceComissioning] line {nid} says "
                             "NodeID 1: the file was written for node 1; COB-IDs it writes absolute "
                             "are that node's"),
        ("nodes[0]", f"node io: io.dcf [1800sub1] line {cob}: TPDO1 COB-ID 0x181 is absolute: the "
                     "pre-defined TPDO1 COB-ID of node 1; at any other node id it is still node "
                     "1's (relative: $NODEID+0x180)"),
    ]  # fmt: skip
    at_1 = parse_config(config({"name": "io", "node_id": 1, "eds": str(dcf)}, **SYNC), "c.yaml", environ={})
    assert config_warnings(*with_nodes(at_1)) == []


# --------------------------------------------------------------------------- SYNC


@pytest.mark.skipif(not CIA402_SLAVE.is_file(), reason=f"no EDS corpus at {CIA402_SLAVE.parent}")
def test_check_warns_of_sync_driven_tpdos_without_a_sync_producer(tmp_path: Path) -> None:
    """ros2_canopen's cia402_slave.eds: TPDO1-3 transmission type 1 (every SYNC)."""
    node = {"name": "drive", "node_id": 2, "eds": str(CIA402_SLAVE), "tpdo": {1: {}, 2: {}, 4: {}}}
    cfg = parse_config(config(node), "cfg.yaml", environ={})
    assert config_warnings(*with_nodes(cfg)) == [
        ("nodes[0]", "node drive: TPDO1, TPDO2 are SYNC-driven (transmission type 0..240) but no "
                     "SYNC producer is configured: the device never sends them; set "
                     "master.sync_period_ms, or master.sync_external: true when another master "
                     "sends SYNC"),
    ]  # fmt: skip
    for master in ({"sync_period_ms": 10}, {"sync_external": True}):
        assert config_warnings(*with_nodes(parse_config(config(node, **master), "c.yaml", environ={}))) == []
    f = tmp_path / "drive.yaml"
    f.write_text(f"can: {{interface: virtual}}\nnodes:\n  - {{name: drive, node_id: 2, eds: {CIA402_SLAVE}, tpdo: {{1: {{}}}}}}\n")
    r = subprocess.run([sys.executable, "-m", "canopen_gateway", "check", "-c", str(f)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert "  warning: node drive: TPDO1 is SYNC-driven (transmission type 0..240) but no SYNC producer" in r.stdout


def test_a_node_whose_values_only_sync_tpdos_carry_says_it_waits_for_sync() -> None:
    """SGH10 with TPDO1 off: position and velocity come only in TPDO2 (every SYNC)."""
    h = sgh10(master={"sync_period_ms": 0}, tpdo={1: {"enabled": False}})
    h.start()
    h.bootup(1.0)
    h.heartbeats(1.01, 3.0)
    h.run_until(2.0)
    health = h.image.health
    assert health.last_error == (
        f"{WAITING} (TPDO2 carries position, velocity; master.sync_period_ms is 0 and "
        "master.sync_external is not set)"
    )
    # another master's SYNC after all: TPDO2 arrives, and the node says so no more
    [tpdo2] = h.node.tpdos
    assert health.fresh_since is not None
    h.image.put(tpdo2.names, (1, 2), 0.0, health.fresh_since + 0.01)
    h._take(h.node.tick(h.now))
    assert health.last_error == ""


@pytest.mark.parametrize(
    ("master", "tpdo"),
    [({"sync_period_ms": 50}, {1: {"enabled": False}}),
     ({"sync_period_ms": 0, "sync_external": True}, {1: {"enabled": False}}),
     ({"sync_period_ms": 0}, {})],  # TPDO1 (timer) carries what TPDO2 does
)  # fmt: skip
def test_no_sync_wait_with_a_sync_producer_or_another_source(master: dict[str, Any], tpdo: dict[int, Any]) -> None:
    h = sgh10(master=master, tpdo=tpdo)
    h.start()
    h.bootup(1.0)
    h.heartbeats(1.01, 3.0)
    h.run_until(2.0)
    assert h.image.health.lifecycle == "operational"
    assert h.image.health.last_error == ""
