"""Who may write south through Zenoh (no I/O): ``zenoh.writes`` and the allow rules of
``zenoh.write_allow``; and which objects an SDO upload may read (``zenoh.reads``).

Three operations change something on the bus: ``set`` (``<node>/set/<signal>`` and
``<node>/set``), ``sdo_write`` (an SDO download: ``<node>/sdo/<index>/<sub>`` with a payload)
and ``nmt``. Reads (values, state, snapshot, catalogue, SDO upload) are not decided here.

=================  ===========================================================================
writes             a write is
=================  ===========================================================================
off (default)      refused, whatever the rules
on, no rules       allowed
on, rules          allowed when one rule matches: its ``operations``, ``nodes`` and ``keys``
                   (key expressions the query key must be included in) all match; an empty
                   list matches everything
=================  ===========================================================================

SDO uploads (``<node>/sdo/<index>/<sub>`` without a payload) read what a device keeps, which
may be more than the operators chose to publish: with ``zenoh.reads: catalog`` (the default)
only the objects the node's catalogue lists (the signals of its profile) are read, any other is
refused ``forbidden``; ``zenoh.reads: all`` reads any object.

Who the client is (user name, certificate) is not visible to the gateway in a query: that is
decided by Zenoh itself (``auth`` and ``access_control`` on the gateway or the router).

Which keys a rule's ``keys`` include is zenoh's own ``KeyExpr.includes``, each rule's key
expressions made ``KeyExpr`` once (0.26 us a check, measured; the pure-Python matcher it
replaced took 9.6 us).

Imports: config (types), zenoh (KeyExpr). Never bus/, modbus/.
"""

from __future__ import annotations

from collections.abc import Collection

import zenoh

from canopen_gateway.config import ZenohSection, ZenohWriteRule


class WriteGate:
    def __init__(self, section: ZenohSection):
        self.writes = section.writes
        self.reads = section.reads
        self.rules: list[ZenohWriteRule] = list(section.write_allow)
        #: each rule's key expressions, made once (checked canonical when the config loaded)
        self.keys = [[zenoh.KeyExpr(k) for k in r.keys] for r in self.rules]

    def read_refusal(self, node: str, obj: object, listed: Collection[object]) -> str | None:
        """None when an SDO upload of ``obj`` may run (``listed``: the node's catalogue
        objects), else the words the client gets."""
        if self.reads == "all" or obj in listed:
            return None
        return (
            f"SDO upload of {obj} on node {node} refused: not an object of its catalogue "
            "(zenoh.reads: catalog; zenoh.reads: all in the gateway's configuration reads any)"
        )

    def refusal(self, operation: str, node: str, key: str) -> str | None:
        """None when the write is allowed, else the words the client gets."""
        if not self.writes:
            return (
                f"Zenoh writes are off on this gateway: {operation} refused "
                "(zenoh.writes: on in the gateway's configuration allows them)"
            )
        if not self.rules:
            return None
        for r, keys in zip(self.rules, self.keys, strict=True):
            if r.operations and operation not in r.operations:
                continue
            if r.nodes and node not in r.nodes:
                continue
            if keys and not any(k.includes(key) for k in keys):
                continue
            return None
        return f"{operation} on node {node} ({key}) is not allowed by zenoh.write_allow"
