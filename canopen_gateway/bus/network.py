"""One CAN network of the gateway, and the router of the gateway's networks by node name.

A network is the unit the bus layer is built for (``Network``): its own bus connection and
reader thread (``BusDriver``), its own master (``Master``: NMT, boot-up configuration, SYNC,
heartbeat with its own ``master.node_id``, LSS, scan, bus-peer diagnostics, a hot-standby
pair's role) and its bus state, built from the network's own config
(``Config.network_view``: its ``can``, ``master`` and ``nodes``), so the master and the driver
read it as they read a single-network config. Nothing of one network waits on another's:
each has its threads, its timers on the event loop, its SDO channels and its reconnection.

Above it, everything addresses nodes by name (unique in the gateway): ``Networks`` routes an
operation on a node to the master of the node's network (the command service holds it where
it held the one master), and an operation on a network (NMT to all, LSS, the scan) to the one
named, the first by default.

Imports: bus.driver, bus.master, bus.node.parts (types), config, device.resolved (types),
canopen.objref (types), image, runtime.threads, errors, logging.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterator, Mapping
from typing import Any

from canopen_gateway.bus.driver import BusDriver, BusOpenFailed
from canopen_gateway.bus.master import Master
from canopen_gateway.bus.node.parts import NodeParts
from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.config import Config
from canopen_gateway.device.resolved import ResolvedNode
from canopen_gateway.errors import NetworkUnknown, NodeUnknown, NotActive
from canopen_gateway.image import ProcessImage
from canopen_gateway.runtime.threads import ThreadRegistry

log = logging.getLogger("gateway.master")


class NetworkOpenFailed(BusOpenFailed):
    """The bus of one network could not be opened by a start that needs it: ``cfg`` is that
    network's config (its ``can:`` is what the one line names)."""

    def __init__(self, cause: BaseException, cfg: Config):
        super().__init__(cause)
        self.cfg = cfg


class Network:
    """One CAN network: its config, driver and master (see the module docstring)."""

    def __init__(
        self,
        index: int,
        cfg: Config,
        image: ProcessImage,
        nodes: Mapping[str, ResolvedNode],
        *,
        threads: ThreadRegistry,
        passive: bool = False,
        named: bool = False,
    ):
        (section,) = cfg.network_sections()
        #: the network's name (``default`` in the single-network form)
        self.name = section.name
        #: CiA 309-3 numbers networks 1.. in configured order
        self.number = index + 1
        #: the network's own config: its can, master and nodes; the shared sections
        self.cfg = cfg
        self.driver = BusDriver(
            cfg.can.bus_kwargs(), image, cfg.can.reopen_backoff_s, threads=threads,
            network=self.name, named=named,
        )  # fmt: skip
        self.master = Master(
            cfg, image, self.driver, passive=passive, nodes={n.name: nodes[n.name] for n in cfg.nodes}
        )
        for n in cfg.nodes:  # before any thread runs: the network each node's values come from
            image.nodes[n.name].network = self.name
        if named:  # several networks: a pair's role change says which network's
            self.master.role_listeners.append(self._role_said)

    def _role_said(self, role: str, reason: str) -> None:
        log.info("network %s: pair role %s (%s)", self.name, role, reason)

    @property
    def state(self) -> str:
        """The bus state: ``ok``, ``error`` (error passive, bus off) or ``down``."""
        return self.driver.state

    @property
    def detail(self) -> str:
        """Why the bus is down or in error (the last reason it gave); empty once it is ok
        again (an old reason is history, not the bus's state)."""
        return "" if self.state == "ok" else self.driver.last_error

    def open(self, *, must_open: bool = False) -> None:
        """Open the bus and start its reader and sender (``BusDriver.open``); a bus that must
        open and cannot raises ``NetworkOpenFailed`` naming this network."""
        try:
            self.driver.open(must_open=must_open)
        except BusOpenFailed as exc:
            raise NetworkOpenFailed(exc.cause, self.cfg) from exc

    def bus_doc(self) -> dict[str, Any]:
        """``{"state", "detail"}`` as /healthz says it (``ok`` when the bus is up)."""
        return {"state": self.state, "detail": self.detail}


class Networks:
    """Every network of the gateway, in configured order; routes by node name."""

    def __init__(self, networks: list[Network]):
        assert networks, "a gateway has at least one network"
        self.all = networks
        self.by_name = {net.name: net for net in networks}
        self._of: dict[str, Network] = {n: net for net in networks for n in net.master.nodes}
        #: every node of every network, by name (names are unique in the gateway)
        self.nodes: dict[str, NodeParts] = {
            name: p for net in networks for name, p in net.master.nodes.items()
        }
        #: the first network (the only one of a single-network gateway): the default of the
        #: operations on a network (LSS, the scan) and of the gateway-wide pair registers
        self.first = networks[0]

    def __iter__(self) -> Iterator[Network]:
        return iter(self.all)

    def __len__(self) -> int:
        return len(self.all)

    @property
    def names(self) -> list[str]:
        return [net.name for net in self.all]

    def of(self, node: str) -> Network:
        """The network of node ``node`` (``NodeUnknown`` otherwise)."""
        net = self._of.get(node)
        if net is None:
            raise NodeUnknown(node, sorted(self.nodes))
        return net

    def named(self, name: str | None) -> Network:
        """Network ``name`` (None: the first); ``NetworkUnknown`` names the networks otherwise."""
        if name is None:
            return self.first
        net = self.by_name.get(name)
        if net is None:
            raise NetworkUnknown(name, self.names)
        return net

    def master_of(self, node: str) -> Master:
        return self.of(node).master

    # ------------------------------------------------------------------ a node's operations
    def part(self, node: str) -> NodeParts:
        return self.master_of(node).part(node)

    def write_outputs(
        self, node: str, per_pdo: dict[int | None, dict[str, Any]], *, safe: bool = False
    ) -> None:
        self.master_of(node).write_outputs(node, per_pdo, safe=safe)

    async def sdo(
        self, node: str, obj: ObjRef, data: bytes | None, *, check_state: bool = True
    ) -> bytes:
        return await self.master_of(node).sdo(node, obj, data, check_state=check_state)

    def nmt(self, node: str, command: str, network: str | None = None) -> None:
        """NMT ``command`` to node ``node``, or with ``all`` to every node of ``network``
        (None: of every network, one broadcast on each bus)."""
        if node != "all":
            self.master_of(node).nmt(node, command)
            return
        for net in self.all if network is None else [self.named(network)]:
            net.master.nmt("all", command)

    def require_active(self, node: str | None = None) -> None:
        """The role gate before a command (a pair's standby refuses, ``NotActive``): of the
        node's network; without a node, at least one network must be mastered here (each
        master's own gate refuses the nodes of a network this gateway stands by on)."""
        if node is not None:
            self.master_of(node).require_active()
            return
        refused: NotActive | None = None
        for net in self.all:
            try:
                net.master.require_active()
            except NotActive as exc:
                refused = refused or exc
            else:
                return
        assert refused is not None
        raise refused

    def master_node_id(self, node: str) -> int:
        """``master.node_id`` of the node's network (the heartbeat its consumers watch)."""
        return self.of(node).cfg.master.node_id

    def on_sdo(self, hook: Callable[[str, str, float, int | None], None] | None) -> None:
        """Every master's SDO hook (metrics)."""
        for net in self.all:
            net.master.on_sdo = hook
