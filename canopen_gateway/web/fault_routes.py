"""The console's fault injection: ``GET /api/sim`` (the simulated nodes, their faults and who
may inject them) and ``POST /api/sim/<name>/<action>`` (``canopen_gateway.sim.faults``).

Who may (``FaultRoutes.rule``): only nodes simulated inside this process, and

=====================================  =========================================================
``none``                               no node is simulated here; or the simulated nodes are on
                                       a real bus (they send real frames) and ``web.writes`` is
                                       off
``token``                              a token is set (``web.token``): it is needed, as for every
                                       operators' endpoint (``web.access.Operators``)
``open``                               the in-process ``virtual`` bus without a token (the demo):
                                       clients on the gateway's own machine only
=====================================  =========================================================

The ``X-Canopen-Client`` header our own clients send (the console's page, ``canopen-gateway
fault``) says where a fault came from in the log, next to the client's address; it is what
the client says, not checked.

Imports: http.server (request/response types), web.access (the operators' gate), sim.faults
(its actions and errors; the injector itself is given by the application).
"""

from __future__ import annotations

import json
import logging
from http import HTTPStatus
from typing import Any

from canopen_gateway.http.server import JSON_TYPE, Request, Response
from canopen_gateway.web.access import Operators

log = logging.getLogger("gateway.web")

#: The header our own clients send with a simulated fault; anything else is the HTTP API.
CLIENT_HEADER = "x-canopen-client"
FAULT_SOURCES = {
    "console": "the web console as its client says",
    "cli": "canopen-gateway fault as its client says",
}


def _json(status: HTTPStatus, doc: Any) -> Response:
    return Response(status, (json.dumps(doc, default=str) + "\n").encode(), JSON_TYPE)


class FaultRoutes:
    """Fault injection into the nodes simulated in this process (``faults``: the injector)."""

    def __init__(self, faults: Any, virtual_bus: bool, writes: bool, operators: Operators) -> None:
        self.faults = faults
        self.virtual_bus = virtual_bus
        self.writes = writes
        self.operators = operators

    def rule(self) -> str:
        """Who may inject faults: "none", "open" or "token" (see the module docstring)."""
        if self.faults is None or not self.faults.names():
            return "none"
        if not self.virtual_bus and not self.writes:
            return "none"
        return "token" if self.operators.required else "open"

    def doc(self) -> dict[str, Any]:
        from canopen_gateway.sim.faults import ACTIONS

        rule = self.rule()
        names = self.faults.names() if self.faults is not None else []
        return {
            "rule": rule,
            "rule_text": {
                "open": "the bus is the in-process virtual bus: faults need no token, from this "
                "machine only",
                "token": "faults need the operators' token (web.token)",
                "none": "no node is simulated in this gateway"
                if not names
                else "simulated nodes on a real bus: faults need web.writes: true and the token",
            }[rule],
            "actions": ACTIONS if rule != "none" else {},
            "nodes": {n: self.faults.state(n) for n in names} if rule != "none" else {},
        }

    def apply(self, request: Request, rest: str) -> Response | None:
        from canopen_gateway.sim.faults import UnknownFault

        if self.rule() == "none":
            return None  # absent: 404, as if it did not exist
        if request.method != "POST":
            return Response(HTTPStatus.METHOD_NOT_ALLOWED, b"POST only\n", headers={"Allow": "POST"})
        if not request.headers.get("content-type", "").startswith("application/json"):
            return _json(HTTPStatus.UNSUPPORTED_MEDIA_TYPE,
                         {"error": "bad_request", "message": "send Content-Type: application/json"})  # fmt: skip
        refused = self.operators.check(request)
        if refused is not None:
            return refused
        node, _, action = rest.partition("/")
        try:
            result = self.faults.apply(node, action)
        except UnknownFault as exc:
            return _json(HTTPStatus.NOT_FOUND, {"error": "not_found", "message": str(exc)})
        said = FAULT_SOURCES.get(request.headers.get(CLIENT_HEADER, ""), "the HTTP API")
        log.warning("simulated fault: %s %s (from %s, %s)", node, action,
                    self.operators.who(request), said)  # fmt: skip
        return _json(HTTPStatus.OK, result)
