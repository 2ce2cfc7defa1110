"""What ``/healthz`` and the web console's overview say of the running gateway's CAN networks:
each network's bus (state and reason), its number, the other masters and SDO clients heard on
it, its nodes and its hot-standby pair's role; which buses keep the gateway not ready. The
application composes these documents with what only it knows (Modbus, Zenoh, the journal, the
nodes' health); this module reads the networks, on the event loop.

Imports: bus.network (the networks), bus.master (types), http.server (the pair's shape).
"""

from __future__ import annotations

from typing import Any

from canopen_gateway.bus.master import Master
from canopen_gateway.bus.network import Network, Networks
from canopen_gateway.http.server import pair_status


def pair_of(master: Master) -> dict[str, Any]:
    """``role`` and ``peer`` of a network's hot-standby pair (None outside one)."""
    pair = master.pair
    if pair is None:
        return pair_status(None, now_s=0.0, recent_s=0.0)
    redundancy = master.cfg.master.redundancy
    claim = pair.peer
    return pair_status(
        str(pair.role),
        now_s=master.clock(),
        recent_s=pair.timing.takeover_s,
        claim=None if claim is None else (claim.priority, claim.node_id, claim.at_s),
        peer_heartbeat_s=master.peer_heartbeat_s,
        peer_node_id=redundancy.peer_node_id if redundancy is not None else None,
        master_id=master.pair_master_id,
        conflict=master.pair_conflict,
        peer_role=pair.peer_role(master.clock()),  # its own heartbeat says it
    )


def network_status(net: Network) -> dict[str, Any]:
    """One network in /healthz: its number (CiA 309-3), bus (``state`` ``ok`` when up, with
    the reason otherwise), other masters and SDO clients heard, its nodes, its pair."""
    return {
        "number": net.number,
        "bus": net.bus_doc(),
        "bus_peers": net.master.peers.doc(),
        "nodes": list(net.master.nodes),
    } | pair_of(net.master)


def network_overview(net: Network) -> dict[str, Any]:
    """One network on the console's overview: its bus in words and state, reopens, frames
    (the console turns them into rates and a bus load), other masters, pair and nodes."""
    return net.cfg.can.words() | {
        "number": net.number,
        "state": net.state,
        "detail": net.detail,
        "reopens": net.driver.reopens,
        "frames_in": net.driver.rx_counters["frames_in"],
        "frames_out": net.driver.tx_counters["frames_out"],
        "peers": net.master.peers.doc(),
        "pair": pair_of(net.master),
        "nodes": list(net.master.nodes),
    }


def bus_reasons(networks: Networks) -> list[str]:
    """Each network whose bus is not ok, in words (``network line2: CAN bus down: ...``; the
    network named when there are several)."""
    named = len(networks) > 1
    return [
        (f"network {net.name}: " if named else "")
        + f"CAN bus {net.state}"
        + (f": {net.detail}" if net.detail else "")
        for net in networks
        if net.state != "ok"
    ]
