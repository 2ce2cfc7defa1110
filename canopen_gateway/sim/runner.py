"""Drives simulated nodes on a python-can bus in a background thread.

``SimRunner(bus, nodes)`` owns the I/O the nodes do not: it receives frames with a short
timeout, hands each to the nodes that act on its COB-ID (``SimNode.listening``: a dispatch
table rebuilt when a node's node id or COB-IDs change; extended and error frames go to every
node), ticks the nodes about every millisecond with the real monotonic clock, and sends what
they return. Frames one node sends are also given to the other nodes of the same runner (on a
real bus every node sees every frame). ``call(fn)`` runs
``fn(now)`` under the runner's lock, so tests and demos can inject faults from any thread; the
frames it causes go out on the runner thread. The thread is usable from sync and async code
alike (nothing here blocks an event loop except ``stop()``, which joins within ``timeout_s``).

Imports: python-can, canopen_gateway.sim.node, canopen_gateway.sim.motion, canopen_gateway.sim.objects,
canopen_gateway.profiles (types only).
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable
from typing import Any, TypeVar

import can

from canopen_gateway.profiles import LoadedProfile
from canopen_gateway.sim.motion import MotionConfig
from canopen_gateway.sim.node import SimNode
from canopen_gateway.sim.objects import PersistentStore

log = logging.getLogger(__name__)
T = TypeVar("T")

_MAX_LOOPBACK_ROUNDS = 4  # node-to-node echoes handled per received frame (no ping-pong)


class SimRunner:
    """Background thread running ``nodes`` on ``bus`` with the monotonic clock."""

    def __init__(
        self,
        bus: can.BusABC,
        nodes: Iterable[SimNode],
        *,
        tick_s: float = 0.001,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.bus = bus
        self.nodes = list(nodes)
        self.tick_s = tick_s
        self.clock = clock
        self.lock = threading.RLock()
        self._outbox: deque[tuple[SimNode | None, can.Message]] = deque()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.error: BaseException | None = None
        self.sent = 0
        self.send_errors = 0
        self.received = 0
        # COB-ID -> the nodes acting on it, in runner order; None: rebuild before the next frame
        self._dispatch: dict[int, tuple[SimNode, ...]] | None = None
        self._every: tuple[SimNode, ...] = ()  # nodes that take every frame
        for node in self.nodes:
            node.on_listening_changed = self._listening_changed

    # -- lifecycle ---------------------------------------------------------------------------
    def start(self) -> SimRunner:
        if self._thread is not None:
            raise RuntimeError("runner already started")
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="sim-runner", daemon=True)
        self._thread.start()
        return self

    def stop(self, timeout_s: float = 1.0) -> None:
        """Stop the thread and wait for it (at most ``timeout_s``)."""
        self._stop.set()
        t = self._thread
        if t is not None:
            t.join(timeout_s)
            if t.is_alive():
                log.warning("simulator thread did not stop within %.1f s", timeout_s)
        self._thread = None

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def __enter__(self) -> SimRunner:
        return self.start()

    def __exit__(self, *exc: Any) -> None:
        self.stop()

    # -- access from other threads -----------------------------------------------------------
    def call(self, fn: Callable[[float], T]) -> T:
        """Run ``fn(now)`` under the runner's lock (e.g. ``lambda now: node.silence()``).

        Frames the nodes queue meanwhile are sent by the runner thread.
        """
        with self.lock:
            result = fn(self.clock())
            if isinstance(result, list) and any(isinstance(m, can.Message) for m in result):
                # frames returned rather than queued (e.g. power_cycle): send them too
                for msg in result:
                    if isinstance(msg, can.Message):
                        self._outbox.append((None, msg))
            for node in self.nodes:
                for msg in node.drain():
                    self._outbox.append((node, msg))
        return result

    def node(self, node_id: int) -> SimNode:
        for n in self.nodes:
            if n.node_id == node_id:
                return n
        raise KeyError(f"no simulated node {node_id}")

    # -- the thread --------------------------------------------------------------------------
    def _run(self) -> None:
        next_tick = self.clock()
        try:
            while not self._stop.is_set():
                timeout = max(0.0, min(self.tick_s, next_tick - self.clock()))
                msg = self.bus.recv(timeout=timeout)
                with self.lock:
                    now = self.clock()
                    if msg is not None:
                        self.received += 1
                        self._deliver(None, msg, now)
                    if now >= next_tick:
                        for node in self.nodes:
                            for out in node.tick(now):
                                self._outbox.append((node, out))
                        next_tick = now + self.tick_s
                    self._flush(now)
        except Exception as exc:  # keep the reason for the test that waits on us
            self.error = exc
            log.exception("simulator thread failed")

    def _listening_changed(self) -> None:
        self._dispatch = None

    def _build_dispatch(self) -> dict[int, tuple[SimNode, ...]]:
        sets = [(node, node.listening()) for node in self.nodes]
        self._every = tuple(node for node, cobs in sets if cobs is None)
        all_cobs = set().union(*(cobs for _, cobs in sets if cobs is not None))
        dispatch = {
            cob: tuple(node for node, cobs in sets if cobs is None or cob in cobs)
            for cob in all_cobs
        }
        self._dispatch = dispatch
        return dispatch

    def _deliver(self, source: SimNode | None, msg: can.Message, now: float) -> None:
        if msg.is_extended_id or msg.is_error_frame:
            targets: tuple[SimNode, ...] | list[SimNode] = self.nodes
        else:
            dispatch = self._dispatch
            if dispatch is None:
                dispatch = self._build_dispatch()
            targets = dispatch.get(msg.arbitration_id, self._every)
        outbox = self._outbox
        for node in targets:
            if node is source:
                continue
            for out in node.handle(msg, now):
                outbox.append((node, out))

    def _flush(self, now: float) -> None:
        rounds = 0
        while self._outbox:
            batch = list(self._outbox)
            self._outbox.clear()
            for source, out in batch:
                try:
                    self.bus.send(out)
                except can.CanError as exc:  # e.g. a full transmit queue: drop, keep running
                    self.send_errors += 1
                    if self.send_errors == 1 or self.send_errors % 1000 == 0:
                        log.warning("simulator send failed (%d so far): %s", self.send_errors, exc)
                    continue
                self.sent += 1
                if len(self.nodes) > 1 and rounds < _MAX_LOOPBACK_ROUNDS:
                    self._deliver(source, out, now)
            rounds += 1


def build_sim_nodes(
    specs: Iterable[tuple[LoadedProfile, int, dict[str, Any] | None]],
) -> list[SimNode]:
    """SimNodes from (profile, node id, options) triples.

    Options are the node's simulator options (override the profile's ``sim:`` hints); the keys
    ``motion`` (dict or MotionConfig) and ``store`` (PersistentStore) are taken out first.
    """
    nodes: list[SimNode] = []
    for profile, node_id, options in specs:
        opts = dict(options or {})
        motion: MotionConfig | dict[str, Any] | None = opts.pop("motion", None)
        store: PersistentStore | None = opts.pop("store", None)
        nodes.append(SimNode(profile, node_id, motion=motion, store=store, options=opts))
    return nodes
