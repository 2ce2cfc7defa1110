"""The simulated devices of a config on the bus, as the gateway, ``simulate`` and the
commissioning tools run them: each network's simulated nodes on their own connection to that
network's bus (one ``sim.runner.SimRunner`` per network), so a device of one network never
sees another network's frames.

``SimulatedBus(cfg, nodes, names)`` builds the nodes (a motion or an option the simulator
refuses is a ``ConfigError`` naming its key); ``start()`` opens every network's bus (or
``start_network(view)`` one), ``stop()`` closes them; ``nodes`` by name, ``runner_of(name)``
the runner of a node's network.

Imports: python-can, bus.can_backend (open_can_bus), config (Config, ConfigError, blame),
device.resolved (types), sim.motion, sim.node, sim.runner.
"""

from __future__ import annotations

from typing import Any

import can

from canopen_gateway.bus.can_backend import open_can_bus
from canopen_gateway.config import Config, ConfigError, blame
from canopen_gateway.device.resolved import ResolvedNode


class SimulatedBus:
    """Simulated nodes of a config, each network's on its own connection to that network's bus
    (one ``SimRunner`` per network)."""

    def __init__(
        self,
        cfg: Config,
        nodes: dict[str, ResolvedNode],
        names: list[str] | None = None,
    ):
        from canopen_gateway.sim.motion import MotionConfig
        from canopen_gateway.sim.node import SimNode

        self.cfg = cfg
        wanted = names if names is not None else [n.name for n in cfg.simulated_nodes()]
        self.nodes: dict[str, Any] = {}
        #: each network's config and the names of its simulated nodes, in configured order
        self.networks: list[tuple[Config, list[str]]] = [
            (view, mine) for view in cfg.network_views()
            if (mine := [n.name for n in view.nodes if n.name in wanted])
        ]  # fmt: skip
        for n in cfg.nodes:
            if n.name not in wanted:
                continue
            # a motion or an option the simulator refuses is a config error naming its key
            key = f"simulate.motion.{n.name}"
            try:
                MotionConfig.from_dict(cfg.simulate.motion.get(n.name))
                key = f"simulate.options.{n.name}"
                self.nodes[n.name] = SimNode(
                    nodes[n.name].lp,
                    n.node_id,
                    motion=cfg.simulate.motion.get(n.name),
                    options=cfg.simulate.options.get(n.name),
                )
            except (ValueError, TypeError) as exc:
                raise ConfigError([f"{blame(key, cfg.source, cfg.env_keys)}: {key}: {exc}"]) from exc
        self.buses: list[can.BusABC] = []
        self.runners: dict[str, Any] = {}  # node name -> the runner of its network

    @property
    def runner(self) -> Any:
        """The first network's runner (None: not started); ``runner_of`` a node's."""
        return next(iter(self.runners.values()), None)

    def runner_of(self, name: str) -> Any:
        """The runner of node ``name``'s network (None: not started)."""
        return self.runners.get(name)

    def start(self) -> None:
        """Open each network's bus and run its simulated nodes there."""
        for view, _ in self.networks:
            self.start_network(view)

    def start_network(self, view: Config) -> None:
        from canopen_gateway.sim.runner import SimRunner

        mine = next(names for v, names in self.networks if v is view)
        bus = open_can_bus(view.can.bus_kwargs())  # socketcand: ours, see can_backend
        self.buses.append(bus)
        runner = SimRunner(bus, [self.nodes[n] for n in mine])
        runner.start()
        self.runners.update(dict.fromkeys(mine, runner))

    def stop(self) -> None:
        for runner in {id(r): r for r in self.runners.values()}.values():
            runner.stop()
        for bus in self.buses:
            bus.shutdown()
        self.runners.clear()
        self.buses.clear()
