"""Simulated CANopen devices built from a device profile (EDS + profile YAML).

``SimNode`` (node.py) is a sans-I/O device: frames and the caller's clock in, frames out. It
implements DS-301 (NMT, SDO server, PDOs, SYNC, EMCY, heartbeat, node guarding, store/restore)
and runs the simulator features of its profile's features (features/). ``SimRunner``
(runner.py) drives nodes on a python-can bus in a background thread.

Used by tests, demos and commissioning. Imports: canopen_gateway.profiles, canopen_gateway.eds (default values),
canopen_gateway.canopen.objref, python-can, canopen (EDS types only), canopen_gateway.canopen.states. Nothing of bus/, modbus/
or zenoh_bridge/.
"""

from typing import Any

from canopen_gateway.canopen.states import NmtState

_EXPORTS = {
    "MotionConfig": "canopen_gateway.sim.motion",
    "PersistentStore": "canopen_gateway.sim.objects",
    "SdoAbortError": "canopen_gateway.sim.objects",
    "SimNode": "canopen_gateway.sim.node",
    "SimRunner": "canopen_gateway.sim.runner",
    "build_sim_nodes": "canopen_gateway.sim.runner",
}


def __getattr__(name: str) -> Any:
    """The package's names, imported when first used (the submodules import this package)."""
    import importlib

    if name in _EXPORTS:
        return getattr(importlib.import_module(_EXPORTS[name]), name)
    raise AttributeError(name)


__all__ = [
    "MotionConfig",
    "NmtState",
    "PersistentStore",
    "SdoAbortError",
    "SimNode",
    "SimRunner",
    "build_sim_nodes",
]
