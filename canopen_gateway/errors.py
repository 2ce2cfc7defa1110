"""Typed errors of the command service, shared by every adapter.

Each carries the words a user needs; adapters translate them into their protocol's error
(Modbus exception code, Zenoh reply_err). Imports only the SDO abort text table.

Imports: canopen.cia301 (the abort texts).
"""

from __future__ import annotations

from typing import Any


class GatewayError(Exception):
    """Base of every error a northbound client can receive. ``kind`` is a stable short name."""

    kind = "error"


class SdoAbort(GatewayError):
    kind = "sdo_abort"

    def __init__(self, code: int, node: str | None = None, obj: str | None = None):
        from canopen_gateway.canopen.cia301 import abort_text

        self.code = code
        self.text = abort_text(code)
        self.node = node
        self.obj = obj
        where = f" at {obj}" if obj else ""
        on = f" on node {node}" if node else ""
        super().__init__(f"SDO abort 0x{code:08X} ({self.text}){where}{on}")


class SdoTimeout(GatewayError):
    kind = "sdo_timeout"

    def __init__(self, node: str, obj: str, detail: str = ""):
        self.node, self.obj = node, obj
        super().__init__(f"no SDO response from node {node} for {obj}" + (f" ({detail})" if detail else ""))


class NodeNotOperational(GatewayError):
    kind = "node_not_operational"

    def __init__(self, node: str, why: str = ""):
        self.node = node
        super().__init__(f"node {node} is not operational" + (f": {why}" if why else ""))


class NodeUnknown(GatewayError):
    kind = "node_unknown"

    def __init__(self, node: str, known: list[str] | None = None):
        self.node = node
        hint = f"; configured nodes: {', '.join(known)}" if known else ""
        super().__init__(f"no node named {node!r}{hint}")


class NetworkUnknown(NodeUnknown):
    """A CAN network the gateway does not have (answered as an unknown node is)."""

    kind = "network_unknown"

    def __init__(self, network: str, known: list[str]):
        self.node = network
        GatewayError.__init__(self, f"no network named {network!r}; networks: {', '.join(known)}")


class BusDown(GatewayError):
    kind = "bus_down"

    def __init__(self, detail: str = "CAN bus is down"):
        super().__init__(detail)


class NotActive(GatewayError):
    """This gateway is the standby of a hot-standby pair: commands go to the active one."""

    kind = "not_active"

    def __init__(self, detail: str = "this gateway is the standby of a pair"):
        super().__init__(detail)


class ValueOutOfRange(GatewayError):
    kind = "value_out_of_range"

    def __init__(self, name: str, value: Any, allowed: str):
        self.name, self.value, self.allowed = name, value, allowed
        super().__init__(f"{name}: value {value!r} not allowed, expected {allowed}")


class SupervisionWrite(ValueOutOfRange):
    """A write that would defeat the gateway's supervision of a node (1017h, 100Ch/100Dh,
    1016h of the master): refused with the reason, as a value out of range is."""

    kind = "supervision_write"

    def __init__(self, name: str, value: Any, why: str):
        self.name, self.value, self.allowed = name, value, why
        GatewayError.__init__(self, f"{name}: write of {value!r} refused: {why}")


class ReadOnly(GatewayError):
    kind = "read_only"


class Unmapped(GatewayError):
    kind = "unmapped"


class Forbidden(GatewayError):
    """A write the configuration does not allow for this client (e.g. ``zenoh.writes: off``)."""

    kind = "forbidden"


class LssFailed(GatewayError):
    """An LSS service (CiA 305) got no answer from a slave in time."""

    kind = "lss_failed"


class LssConflict(GatewayError):
    """Another LSS session is running, or the service needs another LSS state (SGH10 manual
    4.6, Table 10)."""

    kind = "lss_state"
