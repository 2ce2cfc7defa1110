"""What the master builds for one configured node (``build_node``): its ``Node`` machine from
the node's resolution (settings, boot steps, codecs built once) with the device features its
profile and settings ask for (``node_features``), the image's record keys bound before any
thread writes a record, and the ``NodeParts`` that hold it all for the master's handlers, inbox
and services (``bus/master.py``). A part of the device's identity (1018h) its file gives nothing
to compare with is logged once, as the node is built.

Imports: logging, bus.node.* (node, features), device.* (boot_steps, settings), bus.error_control.guarding_bit,
device.resolved, image, canopen.objref, pdo.codec, pdo.verify, profiles, config.
Nothing northbound, no python-can (the frames are the master's).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any

from canopen_gateway.bus.error_control.guarding_bit import GuardingBitCheck
from canopen_gateway.bus.node.features import NodeFeature
from canopen_gateway.bus.node.features.guarding_bit import GuardingBitLink
from canopen_gateway.bus.node.features.referencing import ReferencingFeature
from canopen_gateway.bus.node.features.refresh import RefreshOnStart
from canopen_gateway.bus.node.features.rtr_poll import RtrPoll
from canopen_gateway.bus.node.features.sync_wait import SyncWait
from canopen_gateway.bus.node.features.verify_mapping import VerifyMapping
from canopen_gateway.bus.node.node import Node
from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.config import NodeConfig
from canopen_gateway.device.boot_steps import ConfigStep
from canopen_gateway.device.resolved import NamedNode, ResolvedNode
from canopen_gateway.device.settings import NodeSettings
from canopen_gateway.image import NodeImage, ProcessImage, RxCell
from canopen_gateway.pdo.codec import RpdoCodec, TpdoCodec
from canopen_gateway.pdo.verify import MappingMismatch
from canopen_gateway.profiles import LoadedProfile, identity_check

log = logging.getLogger("gateway.master")


@dataclass
class NodeParts(NamedNode):
    """What the master built for one node: its config, profile, image, codecs and machine."""

    cfg: NodeConfig
    lp: LoadedProfile
    image: NodeImage
    settings: NodeSettings
    boot_steps: list[ConfigStep]
    tpdos: list[TpdoCodec]
    rpdos: list[RpdoCodec]
    node: Node
    #: written by the event loop only (after every event of the node), read by the reader
    #: thread: the node is heartbeat-supervised, alive and operational, so a heartbeat
    #: repeating the previous one changes nothing before its deadline and needs no wake-up of
    #: the loop (see ``_control``)
    steady: bool = False
    #: the event loop's cell of the node's receive counters (values read by SDO)
    loop_rx: RxCell = field(init=False)

    def __post_init__(self) -> None:
        self.loop_rx = self.image.rx.new_cell()

    # read-only views of the node's machines (diagnostics and tests)
    @property
    def lifecycle(self) -> Any:
        return self.node.lifecycle

    @property
    def hb(self) -> Any:
        return self.node.hb

    @property
    def guard(self) -> Any:
        return self.node.guard

    @property
    def gbit(self) -> Any:
        return self.node.gbit

    @property
    def emcy(self) -> Any:
        return self.node.emcy

    @property
    def mapping_mismatches(self) -> list[MappingMismatch]:
        return self.node.mapping_mismatches


def node_features(
    rn: ResolvedNode, referencing: dict[str, Any] | None, reference_signal: str | None
) -> list[NodeFeature]:
    """The device features of a node (``bus/node/features/``), in the order they act."""
    settings, tpdos, refresh = rn.settings, rn.tpdos, rn.refresh
    features: list[NodeFeature] = []
    gb = settings.guarding_bit
    if gb is not None:  # AP05 manual 5.5.5
        features.append(GuardingBitLink(GuardingBitCheck(gb.tolerance_missed, gb.tolerance_ms / 1000.0)))
    if refresh:
        features.append(RefreshOnStart(refresh))
    ref = ReferencingFeature(referencing, reference_signal) if referencing else None
    if ref is not None:
        features.append(ref)
    if rn.verify:
        pdo_names = frozenset(
            [n for c in tpdos for n in c.names] + [n for c in rn.rpdos for n in c.names]
        )
        keep = ref.still_invalid if ref is not None else (lambda invalid: set[str]())
        features.append(VerifyMapping(rn.verify, pdo_names, keep))
    if settings.rtr_poll_ms:
        features.append(RtrPoll(settings.rtr_poll_ms, tpdos))
    if rn.sync_tpdos and not settings.sync_producer:
        read = {name for r in refresh for name in r.codec.names}
        wait = SyncWait.of(tpdos, rn.sync_tpdos, read)
        if wait is not None:
            features.append(wait)
    return features


def build_node(rn: ResolvedNode, image: NodeImage, listening: bool = False) -> NodeParts:
    """One node's parts from its resolution (settings, boot steps and codecs built once)."""
    rn.require()
    ncfg, lp, settings = rn.cfg, rn.lp, rn.settings
    steps, tpdos, rpdos, plan = rn.boot_steps, rn.tpdos, rn.rpdos, rn.refresh
    control = status = None
    if settings.guarding_bit is not None:
        cs = lp.profile.signal_for(settings.guarding_bit.control)
        ss = lp.profile.signal_for(settings.guarding_bit.status)
        control, status = (cs.name if cs else None), (ss.name if ss else None)
    ref = lp.profile.features.get("referencing")
    ref_signal = None
    if ref is not None:
        pos = lp.profile.signal_for(ObjRef.parse(ref.get("position", "0x6004:00")))
        ref_signal = pos.name if pos is not None else None
    # The image's record keys are bound now, before any thread writes a record: each TPDO,
    # and each value read by SDO after NMT start (refresh), is a source of its signals.
    for codec in tpdos:
        image.bind(codec.names)
    for r in plan:
        for name, _obj, _type in r.objects:
            image.bind((name,))
    for rc in rpdos:
        image.bind_output(rc.number, tuple(rc.names))
    identity = identity_check(lp) if ncfg.identity_check else None
    for gap in identity.not_checked if identity is not None else ():
        log.info("node %s (id %d): %s", ncfg.name, ncfg.node_id, gap)  # once, when it is built
    node = Node(
        ncfg.name,
        ncfg.node_id,
        settings,
        image.health,
        image=image,
        boot_steps=steps,
        configure=ncfg.configure,
        tpdos=tpdos,
        rpdos=rpdos,
        features=node_features(rn, ref, ref_signal),
        expected_device_type=lp.profile.device_type,
        expected_identity=identity.expected if identity is not None else (),
        emcy_texts=dict(lp.profile.emcy),
        guard_names=(control, status),
        listening=listening,
    )
    return NodeParts(ncfg, lp, image, settings, steps, tpdos, rpdos, node)


def build_node_into(rn: ResolvedNode, image: ProcessImage, listening: bool) -> NodeParts:
    """A node's image added to the process image, and its parts built on it. ``listening``:
    another master manages the node (a pair's member not active yet, a commissioning tool):
    its lifecycle starts LISTENING and its supervision judges what it hears."""
    ncfg, lp = rn.cfg, rn.lp
    names = [s.name for s in lp.profile.signals]
    ni = NodeImage(ncfg.name, ncfg.node_id, lp.family, names, rn.stale_after_s, ncfg.modbus.serve_stale)
    image.add_node(ni)
    return build_node(rn, ni, listening)
