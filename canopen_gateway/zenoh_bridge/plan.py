"""What the Zenoh bridge publishes, planned once when it is built: one ``SignalPub`` per signal
published on its value key (key, scaling, report policy), one ``PdoPub`` per TPDO published as
one sample (``publish: pdo``), and the route of each TPDO's record (what the reader marks and
what it publishes at once for every frame). The objects are the publications' state, used by
``bridge.py`` on whichever thread publishes, each under its own lock.

Imports: config, image, commands, profiles.schema, profiles.layout, northbound.keys, northbound.scaling,
zenoh_bridge.policy. Never zenoh (the publishers are set on these objects by ``session.py``),
modbus/ nor bus/.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from typing import Any

from canopen_gateway.commands import CommandService
from canopen_gateway.config import Config
from canopen_gateway.image import ProcessImage
from canopen_gateway.northbound.keys import is_published, tpdo_key, value_key
from canopen_gateway.northbound.scaling import Scaling
from canopen_gateway.profiles.layout import tpdo_objects
from canopen_gateway.profiles.schema import Signal
from canopen_gateway.zenoh_bridge.policy import ReportPolicy


class SignalPub:
    """One published signal: its key, engineering scaling, report policy and publisher."""

    __slots__ = (
        "sig", "key", "scaling", "policy", "lock", "pub", "last_seq", "seq_offset", "last_pub",
    )  # fmt: skip

    def __init__(self, sig: Signal, key: str, scaling: Scaling, policy: ReportPolicy):
        self.sig = sig
        self.key = key
        self.scaling = scaling
        self.policy = policy
        self.lock = threading.Lock()
        self.pub: Any = None
        self.last_seq = 0  # seq of the last sample published
        #: added to the image's seq in the payload: a hot-standby pair's take-over (pair.py)
        self.seq_offset = 0
        #: (seq, payload) of the last sample published, set under the lock: the journal's
        #: value history keeps this payload when it is of the frame it journals (journaling.py)
        self.last_pub: tuple[int, str] | None = None


class PdoPub:
    """One received PDO published as one sample (``publish: pdo``): the record key (the
    signals one frame carries), the signals published in it, its publisher, and what was last
    published (the record's ``seq`` and the qualities), kept under its own lock."""

    __slots__ = (
        "key", "names", "entries", "lock", "pub", "last_seq", "last_quality", "count", "seq_offset"
    )  # fmt: skip

    def __init__(
        self, key: str, names: tuple[str, ...], entries: list[tuple[Signal, int, Scaling]]
    ):
        self.key = key
        self.names = names  # the record key (``NodeImage.records``)
        self.entries = entries  # (signal, index in the record, scaling)
        self.lock = threading.Lock()
        self.pub: Any = None
        self.last_seq = 0
        self.last_quality: tuple[Any, ...] = ()
        self.count = 0  # samples published, under the lock
        self.seq_offset = 0  # as ``SignalPub.seq_offset``


@dataclass
class PublicationPlan:
    """The publications of every node, by key and by node."""

    pubs: dict[tuple[str, str], SignalPub] = field(default_factory=dict)
    by_node: dict[str, list[SignalPub]] = field(default_factory=dict)
    #: ``publish: pdo``: (node, record key) -> its PDO publication
    pdo_pubs: dict[tuple[str, tuple[str, ...]], PdoPub] = field(default_factory=dict)
    pdo_by_node: dict[str, list[PdoPub]] = field(default_factory=dict)
    #: (node, record key of a TPDO) -> (publications to mark, ``publish: every`` signals):
    #: the reader's work per frame, planned once
    routes: dict[tuple[str, tuple[str, ...]], tuple[tuple[Any, ...], tuple[Any, ...]]] = field(
        default_factory=dict
    )


def plan_publications(
    cfg: Config, image: ProcessImage, commands: CommandService, prefix: str
) -> PublicationPlan:
    """Every node's publications from its profile and the config's ``publish`` modes."""
    plan = PublicationPlan()
    pubs, by_node, pdo_pubs = plan.pubs, plan.by_node, plan.pdo_pubs
    pdo_by_node, routes = plan.pdo_by_node, plan.routes
    default_mode = cfg.zenoh.publish
    for name in image.nodes:
        rt = commands.node(name)
        sps: list[SignalPub] = []
        in_pdo: dict[str, tuple[Signal, Scaling]] = {}
        inputs = tpdo_objects(rt.lp.profile, rt.cfg.pdo_variant)
        for sig in rt.lp.profile.signals:
            if not is_published(sig, inputs):
                continue
            ov = rt.cfg.signals.get(sig.name)
            mode = (ov.publish if ov is not None and ov.publish else None) or default_mode
            if mode == "off":
                continue
            sc = Scaling.of(sig, ov)
            if mode == "pdo":
                in_pdo[sig.name] = (sig, sc)
                continue
            policy = ReportPolicy(
                mode,
                deadband=ov.deadband if ov is not None else 0.0,
                scale=sc.scale,
                max_rate_hz=ov.max_rate_hz if ov is not None else None,
            )
            sp = SignalPub(sig, value_key(prefix, name, sig.name), sc, policy)
            pubs[(name, sig.name)] = sp
            sps.append(sp)
        by_node[name] = sps
        pps = []
        for number, names in rt.tpdo_records:
            entries = [(in_pdo[n][0], i, in_pdo[n][1]) for i, n in enumerate(names) if n in in_pdo]
            if entries:
                pp = PdoPub(tpdo_key(prefix, name, number), names, entries)
                pdo_pubs[(name, names)] = pp
                pps.append(pp)
        pdo_by_node[name] = pps
        for _number, names in rt.tpdo_records:
            pdo_pub = pdo_pubs.get((name, names))
            sps_of = [pubs[(name, n)] for n in names if (name, n) in pubs]
            every = tuple(sp for sp in sps_of if sp.policy.mode == "every")
            marks = tuple(sp for sp in sps_of if sp.policy.mode != "every")
            routes[(name, names)] = ((pdo_pub, *marks) if pdo_pub is not None else marks, every)
    return plan


def value_keys(plan: PublicationPlan, prefix: str) -> dict[str, list[tuple[str, Signal]]]:
    """Per node, the value keys a get answers from the image: every published signal's,
    whether its samples go out on its value key or in its PDO's sample."""
    out: dict[str, list[tuple[str, Signal]]] = {}
    for name, sps in plan.by_node.items():
        keys = [(sp.key, sp.sig) for sp in sps]
        for pp in plan.pdo_by_node.get(name, ()):
            keys += [(value_key(prefix, name, sig.name), sig) for sig, _i, _sc in pp.entries]
        out[name] = keys
    return out
