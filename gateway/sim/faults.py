"""Faults a user can inject into a simulated device of a running demo, by name.

The demo is there to show that the gateway never lies; these faults make it visible within a
minute: a device unplugged (its heartbeat and PDOs stop: lost, values stale, Modbus exception
0x0B, Zenoh quality ``stale``), an EMCY (the device's own sensor error where its profile names
one, else a generic error 1000h), a reboot (boot-up: values stale until the next TPDO after the
gateway started it again).

``FAULTS`` is the table the web console and the command line read; ``inject(runner, node,
fault)`` applies one under the runner's lock (the runner thread owns the simulated devices) and
returns what happened in words.

Imports: sim.node (types) only.
"""

from __future__ import annotations

from typing import Any

#: fault name -> what it does (shown by the console and ``canopen-gateway fault --help``)
FAULTS: dict[str, str] = {
    "unplug": "leave the bus: no heartbeat, no PDO, no SDO answer (as with a cut cable)",
    "plug": "back on the bus in the same NMT state",
    "emcy": "raise an error: the device's sensor error EMCY, else generic error 1000h",
    "clear-emcy": "the error goes away: EMCY 0000h",
    "reboot": "power off and on: boot-up, pre-operational, stored configuration",
}

GENERIC_ERROR = 0x1000  # CiA 301 7.2.7.1 table 21: generic error
ERROR_REGISTER_GENERIC = 0x01  # 1001h bit 0


def inject(runner: Any, node: Any, fault: str) -> str:
    """Apply ``fault`` to the simulated ``node`` (a SimNode run by ``runner``)."""
    if fault not in FAULTS:
        raise KeyError(fault)

    def apply(now: float) -> Any:
        if fault == "unplug":
            node.silence()
            return "unplugged"
        if fault == "plug":
            node.unsilence(now)
            return "plugged back in"
        if fault == "emcy":
            if node.inject_fault("sensor_error", True, now):
                return "sensor error raised (EMCY)"
            node.raise_emcy(GENERIC_ERROR, ERROR_REGISTER_GENERIC, now=now)
            return "generic error 0x1000 raised (EMCY)"
        if fault == "clear-emcy":
            if node.faults.get("sensor_error"):
                node.inject_fault("sensor_error", False, now)
            else:
                node.clear_emcy(GENERIC_ERROR, now=now)
            return "error cleared (EMCY 0x0000)"
        return node.power_cycle(now)  # frames returned: the runner sends them

    result = runner.call(apply)
    return result if isinstance(result, str) else "rebooted (boot-up sent)"
