"""No layer only forwards: the Modbus execute path calls the roles that serve a request
(reads, writes, identity) directly; the output watchdog's timer is an object beside the server;
the Zenoh session and the housekeeping know their host by a narrow Protocol, not the bridge."""

from __future__ import annotations

import ast
import inspect
from pathlib import Path

GATEWAY = Path(__file__).resolve().parents[2] / "canopen_gateway"


def _imported_modules(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module:
            out.add(node.module)
        elif isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
    return out


def test_the_datastore_holds_the_roles_and_forwards_nothing() -> None:
    from canopen_gateway.modbus.datastore import ImageDatastore

    methods = {n for n, v in vars(ImageDatastore).items() if callable(v) or isinstance(v, property)}
    assert methods == {"__init__", "count_exception"}


def test_execute_calls_the_roles_directly() -> None:
    from canopen_gateway.modbus import datastore

    src = inspect.getsource(datastore.execute) + inspect.getsource(datastore.execute_now)
    for call in ("store.reads.read(", "store.reads.read_now(", "store.writes.write_registers(",
                 "store.writes.write_coils(", "store.writes.mask_write(",
                 "store.identity.identification("):  # fmt: skip
        assert call in src


def test_the_output_watchdog_is_driven_beside_the_server() -> None:
    from canopen_gateway.modbus.server import ModbusGateway
    from canopen_gateway.modbus.watchdog_driver import OutputWatchdogDriver

    gateway_methods = set(vars(ModbusGateway))
    assert not {"request_seen", "writer_gone", "_trip", "_write_safe"} & gateway_methods
    assert {"request_seen", "writer_connected", "writer_gone", "set_mastering", "stop"} <= set(
        vars(OutputWatchdogDriver)
    )


def test_the_session_and_the_housekeeping_see_their_host_as_a_protocol() -> None:
    from canopen_gateway.zenoh_bridge.housekeeping import HousekeepingHost
    from canopen_gateway.zenoh_bridge.session import SessionHost

    for name in ("session.py", "housekeeping.py"):
        path = GATEWAY / "zenoh_bridge" / name
        assert "canopen_gateway.zenoh_bridge.bridge" not in _imported_modules(path)
        names = {
            n.id
            for n in ast.walk(ast.parse(path.read_text(encoding="utf-8")))
            if isinstance(n, ast.Name)
        }
        assert "ZenohBridge" not in names
    assert getattr(SessionHost, "_is_protocol", False)
    assert getattr(HousekeepingHost, "_is_protocol", False)
