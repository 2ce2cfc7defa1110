"""How the long-running commands write their log lines: text (``2026-12-07 10:00:00,123 INFO
gateway.master: ...``) or JSON, one object per line, for log shippers (journald's
``journalctl -o cat``, Fluent Bit, Loki, Elasticsearch):

    {"time": "2026-12-07T10:00:00.123Z", "level": "info", "logger": "gateway.master",
     "message": "node wire: booting -> configuring (boot-up)", "node": "wire"}

``time`` is UTC (ISO 8601, milliseconds), ``level`` the Python level in lower case, ``node``
the configured node a line concerns: the record's ``node`` attribute when the caller gave one
(``extra={"node": ...}``), else the name the gateway's own wording starts with (``node wire:``,
``node wire (id 1):``); absent otherwise. A traceback is one string, ``exc``. The start-up
banner and a start that fails are lines of the same kind (``json_line``).

``log_format(given)``: the format asked for, ``--log-format`` or the environment variable
``CANOPEN_GATEWAY_LOG_FORMAT`` (``text`` or ``json``).

Imports: the standard library only.
"""

from __future__ import annotations

import json
import logging
import os
import re
import time
from typing import Any

LOG_FORMAT_ENV = "CANOPEN_GATEWAY_LOG_FORMAT"
LOG_FORMATS = ("text", "json")
TEXT_FORMAT = "%(asctime)s %(levelname)-7s %(name)s: %(message)s"

#: the gateway's wording of a line about one node: "node wire: ...", "node wire (id 1): ..."
_NODE = re.compile(r"^node ([a-z][a-z0-9_\-]*)(?=[: (])")


def log_format(given: str | None, environ: Any = None) -> str:
    """``given`` (``--log-format``), else ``CANOPEN_GATEWAY_LOG_FORMAT``, else text; ValueError
    naming the variable for a value that is neither."""
    if given:
        return given
    value = (os.environ if environ is None else environ).get(LOG_FORMAT_ENV, "").strip().lower()
    if value in ("", "text"):
        return "text"
    if value == "json":
        return "json"
    raise ValueError(f"{LOG_FORMAT_ENV}={value!r}: allowed: {', '.join(LOG_FORMATS)}")


def utc_time(t: float) -> str:
    """``2026-12-07T10:00:00.123Z``."""
    return time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(t)) + f".{int(t % 1 * 1000):03d}Z"


def json_line(message: str, level: str = "info", logger: str = "gateway", t: float | None = None,
              **fields: Any) -> str:  # fmt: skip
    """One JSON log object for a line written outside logging (the banner, a failed start)."""
    doc: dict[str, Any] = {
        "time": utc_time(time.time() if t is None else t),
        "level": level,
        "logger": logger,
        "message": message,
    }
    node = _NODE.match(message)
    if node is not None and "node" not in fields:
        doc["node"] = node.group(1)
    doc.update(fields)
    return json.dumps(doc, ensure_ascii=False, default=str)


class JsonFormatter(logging.Formatter):
    """A log record as one JSON object on one line (see the module docstring)."""

    def format(self, record: logging.LogRecord) -> str:
        message = record.getMessage()
        fields: dict[str, Any] = {}
        node = getattr(record, "node", None)
        if node is not None:
            fields["node"] = str(node)
        if record.exc_info:
            fields["exc"] = self.formatException(record.exc_info)
        elif record.exc_text:
            fields["exc"] = record.exc_text
        return json_line(message, record.levelname.lower(), record.name, record.created, **fields)
