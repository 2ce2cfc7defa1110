"""Start-up failures in one line: the setting, its value, and what went wrong.

The gateway opens its listeners (Modbus TCP, Zenoh, health/web) and its files at start. When one
of them fails, the user needs the key of the configuration to change, not a traceback:
``modbus.port: 5020 on 127.0.0.1 is already in use (another gateway or program listens there)``.
``startup_step(key, value)`` wraps one step of the start and turns the exceptions of sockets,
files and Zenoh into a ``StartupError`` that carries the key, the value and the reason; the
command line prints it as one line and exits 2 after the gateway has released what it opened.

Imports: the standard library only (Zenoh's errors are recognised by their text, so this module
does not import zenoh).
"""

from __future__ import annotations

import errno
import re
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

#: What an errno of bind/connect/open means for a user, in words.
_ERRNO_TEXT = {
    errno.EADDRINUSE: "is already in use (another gateway or program listens there)",
    errno.EADDRNOTAVAIL: "is not an address of this machine",
    errno.EACCES: "is not allowed (ports below 1024 need privileges)",
    errno.ENOENT: "does not exist",
}

#: Zenoh's error texts (zenoh.ZError) and what they mean.
_ZENOH_TEXT = (
    (re.compile(r"address already in use", re.I), _ERRNO_TEXT[errno.EADDRINUSE]),
    (re.compile(r"cannot assign requested address", re.I), _ERRNO_TEXT[errno.EADDRNOTAVAIL]),
    (re.compile(r"permission denied", re.I), _ERRNO_TEXT[errno.EACCES]),
)


class StartupError(Exception):
    """A part of the gateway could not start: ``key`` of the config, its ``value``, ``reason``."""

    def __init__(self, key: str, value: Any, reason: str):
        self.key, self.value, self.reason = key, value, reason
        super().__init__(f"{key}: {value} {reason}")

    def line(self, source: str) -> str:
        """The one line the command line prints, naming the config file."""
        return f"error: {source}: {self}"


def zenoh_reason(message: str) -> str:
    """The first clause of a Zenoh error, without the Rust source locations it appends."""
    for pattern, text in _ZENOH_TEXT:
        if pattern.search(message):
            return text
    first = message.splitlines()[0] if message else "failed"
    first = re.sub(r"\s+at /\S+", "", first)
    return f"failed: {first.strip()}"


def os_reason(exc: OSError) -> str:
    text = _ERRNO_TEXT.get(exc.errno or 0)
    if text is not None:
        return text
    return f"failed: {exc.strerror or exc}"


@contextmanager
def startup_step(key: str, value: Any, files: dict[str, str] | None = None) -> Iterator[None]:
    """Run one step of the start; any failure leaves as ``StartupError`` naming ``key``.

    ``files`` maps the keys of file settings of this step to their paths, so that a missing
    file is blamed on its own key (``zenoh.auth.password_file``)."""
    try:
        yield
    except StartupError:
        raise
    except FileNotFoundError as exc:
        for file_key, path in (files or {}).items():
            if exc.filename is not None and str(exc.filename).endswith(str(path)):
                raise StartupError(file_key, exc.filename, "does not exist") from None
        raise StartupError(key, exc.filename or value, "does not exist") from None
    except OSError as exc:
        raise StartupError(key, value, os_reason(exc)) from None
    except Exception as exc:
        if type(exc).__name__ == "ZError":  # zenoh.ZError, recognised without importing zenoh
            bound = re.search(r"bound to (\S+?):\s*\[", str(exc))
            where = bound.group(1) if bound else value
            raise StartupError(key, where, zenoh_reason(str(exc))) from None
        if type(exc).__name__ == "CanInterfaceNotImplementedError":  # python-can: cannot load
            reason = str(exc).splitlines()[0] if str(exc) else "is not available"
            raise StartupError(key, value, f"cannot be loaded: {reason}") from None
        raise
