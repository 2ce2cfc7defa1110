"""Simulated CANopen devices built from a device profile (EDS + profile YAML).

``SimNode`` (node.py) is a sans-I/O device: frames and the caller's clock in, frames out. It
implements DS-301 (NMT, SDO server, PDOs, SYNC, EMCY, heartbeat, node guarding, store/restore)
and runs the device behaviours of its profile's features (behaviours/). ``SimRunner``
(runner.py) drives nodes on a python-can bus in a background thread.

Used by tests, demos and commissioning. Imports: gateway.profiles, gateway.objref, python-can,
canopen (EDS types only). Nothing of bus/, modbus/ or zenoh_bridge/.
"""

from gateway.sim.motion import MotionConfig
from gateway.sim.node import NmtState, SimNode
from gateway.sim.objects import PersistentStore, SdoAbortError
from gateway.sim.runner import SimRunner, build_sim_nodes

__all__ = [
    "MotionConfig",
    "NmtState",
    "PersistentStore",
    "SdoAbortError",
    "SimNode",
    "SimRunner",
    "build_sim_nodes",
]
