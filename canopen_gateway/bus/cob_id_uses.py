"""Which COB-IDs the gateway uses on the bus, and where each one comes from.

Per configured node, as resolved (``device/resolved.py``: what the reader dispatches on and what
the node's RPDOs are sent on): the COB-ID of every enabled TPDO and RPDO, and the node's EMCY,
SDO response, SDO request and heartbeat (CiA 301 7.3.3 pre-defined connection set: function
code + node id). The master's own: NMT 000h, SYNC 080h when this gateway produces it
(``master.sync_period_ms``) or another master does (``master.sync_external``), its heartbeat
700h + ``master.node_id`` (sent, and watched for another master on that id) unless
``master.heartbeat_ms`` is 0 outside a pair (then the master's node id is not on the bus and a
node may have it), LSS 7E4h/7E5h (CiA 305).

Where a PDO's COB-ID comes from, first match: the node's ``sdo:`` write of the COB-ID object,
its ``tpdo:``/``rpdo:`` ``cob_id``, a profile's ``boot.sdo`` write, the pre-defined COB-ID
(``default``), the device file's value (``io.dcf [1800sub1] line 123``, absolute or
``$NODEID``-relative), the profile's layout.

``clashes`` pairs the uses of one COB-ID: ``check`` and every start refuse them
(``canopen_gateway.checks``), so the master's dispatch table (``bus/master.py``) never has two
receivers for one COB-ID; a device's own TPDO and RPDO on one COB-ID (``loops_back``) is a
warning.

Imports: canopen.cia301, config (types), canopen.objref, eds (a file's COB-IDs), profiles.layout, device.resolved, bus.pair.flying_master (the CiA 302-2 COB-IDs of a pair).
No I/O but reading the device files (cached).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from canopen_gateway.bus.pair.flying_master import FLYING_MASTER_COB_IDS
from canopen_gateway.canopen.cia301 import (
    COB_EMCY,
    COB_LSS_MASTER,
    COB_LSS_SLAVE,
    COB_NMT,
    COB_NMT_EC,
    COB_RPDO,
    COB_SDO_RX,
    COB_SDO_TX,
    COB_SYNC,
    COB_TPDO,
)
from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.config import Config
from canopen_gateway.device.resolved import ResolvedNode
from canopen_gateway.eds import EdsError, load_eds
from canopen_gateway.eds.file_cob_ids import file_cob_ids
from canopen_gateway.profiles.layout import pdo_objects

MASTER = "the master"


@dataclass(frozen=True)
class CobUse:
    """One use of a COB-ID: who (a node's key and name, or the master), what for, where it
    comes from, and the config key a problem with it is reported at."""

    cob_id: int
    who: str  # "nodes[0] (wire)" or "the master"
    what: str  # "TPDO1", "EMCY", "heartbeat", "NMT"...
    origin: str  # "nodes[0].tpdo.1.cob_id", "io.dcf [1800sub1] line 123", "default 0x180 + node id 1"
    key: str  # "nodes[0].tpdo.1.cob_id", "nodes[0]", "master.node_id"
    #: the gateway sends on it (RPDO, SDO request, NMT, its SYNC, heartbeat, LSS request)
    sent: bool = False
    node: str = ""  # the node's name; "" for the master

    def __str__(self) -> str:
        return f"{self.who} {self.what} ({self.origin})"


def master_uses(cfg: Config) -> list[CobUse]:
    """The master's own COB-IDs (see the module docstring)."""
    m = cfg.master
    out = [CobUse(COB_NMT, MASTER, "NMT", "CiA 301 7.2.8", "master", sent=True)]
    if m.sync_period_ms:
        out.append(CobUse(COB_SYNC, MASTER, "SYNC", "master.sync_period_ms", "master.sync_period_ms", sent=True))  # fmt: skip
    elif m.sync_external:
        out.append(CobUse(COB_SYNC, MASTER, "SYNC of another master", "master.sync_external", "master.sync_external"))  # fmt: skip
    if m.heartbeat_ms or m.redundancy is not None:  # heartbeat_ms 0: the id is not on the bus
        out.append(
            CobUse(COB_NMT_EC + m.node_id, MASTER, "heartbeat", f"master.node_id {m.node_id}", "master.node_id", sent=True)  # fmt: skip
        )
    out.append(CobUse(COB_LSS_SLAVE, MASTER, "LSS response", "CiA 305", "master"))
    out.append(CobUse(COB_LSS_MASTER, MASTER, "LSS request", "CiA 305", "master", sent=True))
    pair = m.redundancy
    if pair is not None:  # a hot-standby pair (docs/redundancy.md)
        for cob in sorted(FLYING_MASTER_COB_IDS):
            out.append(CobUse(cob, MASTER, f"CiA 302-2 0x{cob:02X}", "master.redundancy", "master.redundancy", sent=True))  # fmt: skip
        for key, own in (("node_id", pair.node_id), ("peer_node_id", pair.peer_node_id)):
            if own is not None:
                out.append(CobUse(COB_NMT_EC + own, MASTER, "a pair member's heartbeat", f"master.redundancy.{key} {own}", f"master.redundancy.{key}", sent=key == "node_id"))  # fmt: skip
    return out


def node_uses(index: int, rn: ResolvedNode) -> list[CobUse]:
    """The COB-IDs of configured node ``nodes[index]`` (see the module docstring)."""
    key = f"nodes[{index}]"
    who = f"{key} ({rn.name})"
    nid = rn.node_id
    out: list[CobUse] = []
    for kind, codecs in (("tpdo", rn.tpdos), ("rpdo", rn.rpdos)):
        for c in codecs:
            origin, at = _pdo_origin(index, rn, kind, c.number, c.cob_id)  # type: ignore[arg-type]
            out.append(CobUse(c.cob_id, who, f"{kind.upper()}{c.number}", origin, at, kind == "rpdo", rn.name))
    for base, what in ((COB_EMCY, "EMCY"), (COB_SDO_TX, "SDO response"), (COB_SDO_RX, "SDO request"),
                       (COB_NMT_EC, "heartbeat")):  # fmt: skip
        origin = f"default 0x{base:03X} + node id {nid}"
        out.append(CobUse(base + nid, who, what, origin, f"{key}.node_id", base == COB_SDO_RX, rn.name))
    return out


def gateway_uses(cfg: Config, nodes: dict[str, ResolvedNode]) -> list[CobUse]:
    """The master's COB-IDs, then each resolved node's in config order."""
    out = master_uses(cfg)
    for i, n in enumerate(cfg.nodes):
        rn = nodes.get(n.name)
        if rn is not None and rn.boot_error is None:
            out += node_uses(i, rn)
    return out


def clashes(uses: list[CobUse]) -> list[tuple[CobUse, CobUse]]:
    """(first use, later use) for every use of a COB-ID an earlier one already has (see
    ``loops_back`` for the pairs that are one device's own)."""
    first: dict[int, CobUse] = {}
    out = []
    for u in uses:
        had = first.setdefault(u.cob_id, u)
        if had is not u:
            out.append((had, u))
    return out


def loops_back(first: CobUse, later: CobUse) -> bool:
    """One device sends on a COB-ID it also receives on (its TPDO and its RPDO, as a real
    Sevcon DCF has it): the gateway has one receiver for it still, so it runs; a write of that
    RPDO puts a second sender on the COB-ID (``check`` warns)."""
    return bool(first.node) and first.node == later.node and first.sent != later.sent


def _pdo_origin(
    index: int, rn: ResolvedNode, kind: Literal["tpdo", "rpdo"], number: int, cob_id: int
) -> tuple[str, str]:
    """(where PDO ``number``'s COB-ID comes from, the config key to report it at)."""
    key = f"nodes[{index}]"
    comm, _ = pdo_objects(rn.lp.profile, kind, number)
    obj = ObjRef(comm, 0x01)
    last = next((s for s in reversed(rn.boot_steps) if s.object == obj), None) if rn.cfg.configure else None
    if last is not None and last.source.startswith("sdo["):
        return f"{key}.{last.source}", f"{key}.{last.source}"
    setting = (rn.cfg.tpdo if kind == "tpdo" else rn.cfg.rpdo).get(number)
    if setting is not None and setting.cob_id is not None:
        return f"{key}.{kind}.{number}.cob_id", f"{key}.{kind}.{number}.cob_id"
    if last is not None and not last.source:
        return f"profile {rn.lp.family} boot.sdo", key
    bases = COB_TPDO if kind == "tpdo" else COB_RPDO
    if number <= len(bases) and cob_id == bases[number - 1] + rn.node_id:
        return f"default 0x{bases[number - 1]:03X} + node id {rn.node_id}", key
    try:
        eds = load_eds(rn.lp.eds_path)
    except EdsError:
        eds = None
    held = next((c for c in file_cob_ids(eds) if c.obj == obj), None) if eds is not None else None
    if held is not None and (held.cob_id + (rn.node_id if held.relative else 0)) == cob_id:
        how = "" if held.relative else ", absolute"
        return f"{held.where(rn.lp.eds_path.name)}{how}", key
    return f"profile {rn.lp.family}", key
