"""Fault injection into the simulated nodes of a running gateway (demos, training, tests): the
faults a plant has, on devices that do not exist, so a user can watch stale, lost and bad
values reach Modbus, Zenoh and the web console.

=================  ==========================================================================
action             what the simulated device does
=================  ==========================================================================
``unplug``         leaves the bus (a cut cable): sends nothing, answers nothing
``plug``           comes back restarted (off and on again): boot-up, then the gateway
                   configures and starts it as after any boot
``heartbeat-off``  stops its heartbeat, or its answers to node guarding; PDOs continue
``heartbeat-on``   heartbeat / guarding answers again
``emcy``           raises an EMCY: the first fault its profile's simulator hints list
                   (``sim: faults:``), else 1000h generic error (error register bit 0)
``emcy-clear``     clears it (EMCY 0000h, as the device does when the error goes away)
=================  ==========================================================================

Only nodes simulated in this process can be reached: the injector holds their ``SimNode``
objects and calls them through ``SimRunner.call`` (under the runner's lock; the frames they
cause go out on the simulator thread). Nothing here sends a frame itself or talks to a real
device. Who may call it (the web console's rule) is the caller's decision.

Imports: sim.node (types), nothing of the gateway's bus, Modbus, Zenoh or web parts.
"""

from __future__ import annotations

from typing import Any

ACTIONS: dict[str, str] = {
    "unplug": "off the bus: sends and answers nothing (a cut cable)",
    "plug": "back on the bus, restarted (boot-up; the gateway configures and starts it)",
    "heartbeat-off": "stops its heartbeat / node-guarding answers; process data continue",
    "heartbeat-on": "heartbeat / node-guarding answers again",
    "emcy": "raises an EMCY (a fault of its profile, else 1000h generic error)",
    "emcy-clear": "clears that EMCY (EMCY 0000h)",
}
GENERIC_EMCY = 0x1000  # DS-301 table 21: generic error
GENERIC_REGISTER = 0x01  # DS-301 1001h bit 0: generic error


class UnknownFault(ValueError):
    """A node that is not simulated here, or an action that does not exist."""


class FaultInjector:
    """The ``ACTIONS`` on the nodes of a running simulator (``SimulatedBus``: ``.nodes`` name ->
    ``SimNode``, ``.runner_of(name)`` the ``SimRunner`` of the node's network)."""

    def __init__(self, sim: Any):
        self.sim = sim
        self._emcy: dict[str, str | int] = {}  # node -> active fault name or EMCY code

    def names(self) -> list[str]:
        return list(self.sim.nodes)

    def state(self, name: str) -> dict[str, Any]:
        node = self._node(name)
        active = self._emcy.get(name)
        return {
            "unplugged": bool(node.silenced),
            "heartbeat": not node.error_control.off,
            "emcy": None if active is None else self._emcy_words(node, active),
        }

    def apply(self, name: str, action: str) -> dict[str, Any]:
        node = self._node(name)
        if action not in ACTIONS:
            raise UnknownFault(f"no fault {action!r}; one of {', '.join(ACTIONS)}")
        runner = self.sim.runner_of(name)
        if runner is None:
            raise UnknownFault("the simulator is not running")
        if action == "unplug":
            runner.call(lambda now: node.silence())
        elif action == "plug":
            self._emcy.pop(name, None)
            runner.call(lambda now: node.power_cycle(now))
        elif action == "heartbeat-off":
            runner.call(lambda now: node.stop_error_control())
        elif action == "heartbeat-on":
            runner.call(lambda now: node.resume_error_control(now))
        elif action == "emcy":
            fault = self._emcy.get(name) or self._profile_fault(node) or GENERIC_EMCY
            self._emcy[name] = fault
            if isinstance(fault, str):
                runner.call(lambda now: node.inject_fault(fault, True, now))
            else:
                runner.call(lambda now: node.raise_emcy(fault, GENERIC_REGISTER, now=now))
        elif action == "emcy-clear":
            active = self._emcy.pop(name) if name in self._emcy else None
            if isinstance(active, str):
                runner.call(lambda now: node.inject_fault(active, False, now))
            elif active is not None:
                runner.call(lambda now: node.clear_emcy(active, now))
        return {"ok": True, "node": name, "action": action, "state": self.state(name)}

    # ------------------------------------------------------------------ helpers
    def _node(self, name: str) -> Any:
        node = self.sim.nodes.get(name)
        if node is None:
            simulated = ", ".join(self.sim.nodes) or "none"
            raise UnknownFault(f"node {name!r} is not simulated in this gateway (simulated: {simulated})")
        return node

    @staticmethod
    def _profile_fault(node: Any) -> str | None:
        for fault, spec in node.hints.faults.items():
            if "emcy" in spec:
                return str(fault)
        return None

    @staticmethod
    def _emcy_words(node: Any, active: str | int) -> str:
        if isinstance(active, str):
            code = int(node.hints.faults[active]["emcy"])
            return f"0x{code:04X} ({active})"
        return f"0x{active:04X} (generic error)"
