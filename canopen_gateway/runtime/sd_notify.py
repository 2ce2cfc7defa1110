"""systemd's service notification (``sd_notify(3)``), without a library: one datagram per
message to the AF_UNIX socket systemd names in ``NOTIFY_SOCKET`` (a path, or ``@name`` in the
abstract namespace). Nothing is sent when the variable is unset (not under systemd, or
``Type=`` other than ``notify``): every method is then a no-op.

* ``READY=1`` once the gateway serves (every listener open, the health port accepting), with
  ``STATUS=`` the start-up banner;
* ``STATUS=...`` whenever what it says changes (nodes operational, the bus), at most once per
  ``STATUS_PERIOD_S``;
* ``WATCHDOG=1`` every half of ``WATCHDOG_USEC`` (``WatchdogSec=`` of the unit) when
  ``WATCHDOG_PID`` is unset or this process, and only while the event loop turns (the pings
  are sent from it) and ``alive()`` says the bus reader goes round: a hung loop or reader is
  restarted by systemd;
* ``STOPPING=1`` when SIGTERM (or SIGINT) starts the stop.

Imports: the standard library only.
"""

from __future__ import annotations

import asyncio
import logging
import os
import socket
from collections.abc import Callable, Mapping

log = logging.getLogger("gateway.systemd")

#: how often the status line is looked at (and sent when it changed) without a watchdog
STATUS_PERIOD_S = 1.0


class SystemdNotifier:
    """Messages to systemd's notification socket (see the module docstring)."""

    def __init__(self, address: str | None, watchdog_s: float | None = None):
        #: the socket's address ("\\0name" for the abstract namespace); None: not under systemd
        self.address = address
        #: seconds between WATCHDOG=1 (half of WATCHDOG_USEC); None: no watchdog
        self.watchdog_s = watchdog_s
        self._sock: socket.socket | None = None
        self._status: str | None = None

    @classmethod
    def from_env(cls, environ: Mapping[str, str] | None = None, pid: int | None = None) -> SystemdNotifier:
        env = os.environ if environ is None else environ
        path = env.get("NOTIFY_SOCKET") or None
        if path is not None and path.startswith("@"):
            path = "\0" + path[1:]
        watchdog_s = None
        usec = env.get("WATCHDOG_USEC", "")
        owner = env.get("WATCHDOG_PID", "")
        ours = not owner or owner == str(os.getpid() if pid is None else pid)
        if path is not None and usec.isdigit() and int(usec) > 0 and ours:
            watchdog_s = int(usec) / 2e6
        return cls(path, watchdog_s)

    def __bool__(self) -> bool:
        return self.address is not None

    def send(self, *lines: str) -> bool:
        """One datagram of ``KEY=value`` lines; False (logged once) when it cannot be sent."""
        if self.address is None:
            return False
        try:
            if self._sock is None:
                self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
            self._sock.sendto("\n".join(lines).encode("utf-8", "replace"), self.address)
        except OSError as exc:
            log.warning("systemd notification to %r failed: %s; no more are sent", self.address, exc)
            self.close()
            self.address = None
            return False
        return True

    def ready(self, status: str) -> None:
        self._status = status
        self.send("READY=1", f"STATUS={_one_line(status)}")

    def status(self, status: str) -> None:
        """``STATUS=`` when the text changed since the last one sent."""
        if status != self._status:
            self._status = status
            self.send(f"STATUS={_one_line(status)}")

    def stopping(self) -> None:
        self.send("STOPPING=1", "STATUS=stopping")

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    async def supervise(self, alive: Callable[[], bool], status: Callable[[], str]) -> None:
        """Until cancelled: WATCHDOG=1 every ``watchdog_s`` while ``alive()``, and the status
        line when it changes. Runs on the event loop, so a loop that no longer turns stops the
        pings."""
        if self.address is None:
            return
        loop = asyncio.get_running_loop()
        cadence = Cadence(self.watchdog_s, loop.time())
        silent = False
        while True:
            ping, look, wait_s = cadence.turn(loop.time())
            if ping:
                if alive():
                    self.send("WATCHDOG=1")
                    silent = False
                elif not silent:
                    silent = True
                    log.error("the CAN reader does not go round: no systemd watchdog ping")
            if look:
                self.status(status())
            await asyncio.sleep(wait_s)


class Cadence:
    """When ``supervise`` pings (every ``watchdog_s``, on time: not rounded to the status
    period) and looks at the status (every ``STATUS_PERIOD_S``); a plain clock-driven class."""

    def __init__(self, watchdog_s: float | None, now: float):
        self.watchdog_s = watchdog_s
        self.next_ping = now if watchdog_s is not None else None
        self.next_status = now

    def turn(self, now: float) -> tuple[bool, bool, float]:
        """(ping now, look at the status now, seconds until the next of either)."""
        ping = self.next_ping is not None and now >= self.next_ping
        if ping and self.watchdog_s is not None:
            self.next_ping = now + self.watchdog_s
        look = now >= self.next_status
        if look:
            self.next_status = now + STATUS_PERIOD_S
        wake = self.next_status if self.next_ping is None else min(self.next_status, self.next_ping)
        return ping, look, max(0.0, wake - now)


def _one_line(text: str) -> str:
    return " ".join(text.split())
