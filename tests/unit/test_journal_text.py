"""The console journal's one-line text of an audit record (``web.journal_log.text_of``): the
parts the record has, never an empty node or ``= null``."""

from __future__ import annotations

import json

from canopen_gateway.journal import Row
from canopen_gateway.web.journal_log import text_of


def audit(doc: dict[str, object], node: str | None) -> Row:
    return Row(1, 0, "audit", "p/audit", node, 1, json.dumps(doc).encode(), None)


def test_an_audit_line_names_what_the_record_has() -> None:
    write = {"who": "modbus 127.0.0.1", "op": "set", "what": "set_point1", "value": 4321, "outcome": "ok"}
    assert text_of(audit(write, "display")) == "modbus 127.0.0.1: set display set_point1 = 4321: ok"
    login = {"who": "web 127.0.0.7", "op": "login", "what": "/api/journal", "value": None,
             "outcome": "refused: wrong token"}  # fmt: skip
    assert text_of(audit(login, None)) == "web 127.0.0.7: login /api/journal: refused: wrong token"
