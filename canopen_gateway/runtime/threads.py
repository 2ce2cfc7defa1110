"""Threads the gateway starts, supervised: the one way to start one.

A supervised thread runs its target; an exception that escapes it is logged with its traceback
and recorded, and the gateway's readiness (/healthz) turns not-ready with the thread's name and
the error: no thread dies silently. ``ThreadRegistry.failures()`` lists the dead ones.
``ThreadCount`` is a counter several threads increment, each in its own cell.

On Linux each thread also carries its name in the kernel (``prctl(PR_SET_NAME)``, 15 bytes), so
``top -H``, ``ps -L`` and /proc/PID/task/TID/comm show ``can-reader``, ``zenoh-publish``...
instead of ``python``: what each thread costs can be read without a profiler.

Imports: the standard library only.
"""

from __future__ import annotations

import ctypes
import logging
import sys
import threading
from collections.abc import Callable

log = logging.getLogger("gateway.threads")

PR_SET_NAME = 15  # linux/prctl.h


def set_os_thread_name(name: str) -> bool:
    """Name the calling thread in the kernel (Linux; elsewhere, or if refused, nothing)."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        return bool(libc.prctl(PR_SET_NAME, name.encode()[:15], 0, 0, 0) == 0)
    except (OSError, AttributeError):
        return False


class ThreadRegistry:
    """The gateway's threads and how they ended."""

    def __init__(self) -> None:
        self._failed: dict[str, str] = {}
        self._lock = threading.Lock()

    def start(self, name: str, target: Callable[[], None]) -> threading.Thread:
        def run() -> None:
            set_os_thread_name(name)
            try:
                target()
            except BaseException as exc:  # noqa: BLE001 - recorded and reported, never silent
                log.exception("thread %s died: %r", name, exc)
                with self._lock:
                    self._failed[name] = f"{type(exc).__name__}: {exc}"

        t = threading.Thread(target=run, name=name, daemon=True)
        t.start()
        return t

    def failures(self) -> dict[str, str]:
        with self._lock:
            return dict(self._failed)


class ThreadCount:
    """A count incremented on several threads, exact without a lock: each thread adds to its
    own cell (``add``), a reader sums the cells (``value``)."""

    __slots__ = ("_cells", "_local")

    def __init__(self) -> None:
        self._cells: list[list[int]] = []
        self._local = threading.local()

    def add(self, n: int = 1) -> None:
        try:
            cell: list[int] = self._local.cell
        except AttributeError:
            cell = self._local.cell = [0]
            self._cells.append(cell)  # one append: a reader sums the old list or the new one
        cell[0] += n

    @property
    def value(self) -> int:
        return sum(c[0] for c in list(self._cells))
