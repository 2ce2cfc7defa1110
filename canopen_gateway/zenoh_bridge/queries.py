"""Zenoh queries: every answer of the gateway's queryable on ``<prefix>/**``.

The PLC comes first: no query is answered on the event loop, where the Modbus server runs. The
zenoh callback (``on_query``) only queues the query in the queries' own worker
(``worker.QueryWorker``, thread ``zenoh-queries``: bounded, round robin between querying
sessions); a full queue is answered at once with ``reply_err`` ``busy`` and a ``retry_after_ms``
hint, and counted. On the worker, the one dispatch point (``_job``) sends each query to its
answer: reads the process image gives (state, snapshot, latest value, catalogue, wildcards) are
produced there, one reply per step of a lazy iterator (``Replies``) so that a long answer gives
way between replies; commands (SDO, set points, NMT, a value read by SDO) are handed to the
event loop, where the command service runs them (at most ``COMMANDS_MAX`` at once, else
``busy``), and the loop answers and finalises them. Every query is finalised with a reply or a
``reply_err``. Nothing a client sends may crash the gateway: a bad request is answered with its
error kind. Writes (``set``, SDO download, ``nmt``) pass the write gate first (``zenoh.writes``,
``zenoh.write_allow``); a refused one is answered ``forbidden``, counted in ``refused``
(``zenoh_refused_total``) and logged at most once per period per operation. A key expression
with wildcards gets the read-only answers it matches, never a command.

The publishing side (``bridge.py``) owns the session and the publishers; this side reads the
session through a function and knows the published value keys and their scaling as given at
construction.

Imports: zenoh, commands, errors, image, config, runtime.ratelimit, runtime.threads, profiles.schema,
profiles.derived, northbound.keys, northbound.scaling, payloads, access, worker, history
(``_time`` queries), commands.audit (who asked). Nothing of bus/ or modbus/.
"""

from __future__ import annotations

import asyncio
import json
import logging
import threading
import time
from collections.abc import Callable, Collection, Iterator, Mapping, Sequence
from dataclasses import KW_ONLY, dataclass, field
from typing import Any

import zenoh

from canopen_gateway import __version__
from canopen_gateway.commands import CommandService
from canopen_gateway.commands.audit import acting_as
from canopen_gateway.config import Config
from canopen_gateway.errors import Forbidden, GatewayError
from canopen_gateway.image import NodeImage, ProcessImage
from canopen_gateway.northbound.keys import (
    Request,
    alive_key,
    catalog_key,
    emcy_key,
    has_wildcard,
    is_writable,
    nmt_key,
    parse_key,
    set_key,
    snapshot_key,
    state_key,
    value_key,
)
from canopen_gateway.northbound.scaling import Scaling, engineering, to_raw
from canopen_gateway.profiles.derived import text_rows_as_signals
from canopen_gateway.profiles.schema import Signal
from canopen_gateway.runtime.ratelimit import RateLimitedLog
from canopen_gateway.runtime.threads import ThreadCount, ThreadRegistry
from canopen_gateway.zenoh_bridge.access import WriteGate
from canopen_gateway.zenoh_bridge.history import AnswerCut, HistoryService, Stamped, has_time_range
from canopen_gateway.zenoh_bridge.payloads import (
    add_names,
    error_payload,
    nmt_command,
    reply_value,
    sdo_write_body,
    set_body,
    set_many_body,
    state_payload,
    value_payload,
)
from canopen_gateway.zenoh_bridge.worker import ANONYMOUS, QueryWorker

#: a history answer's lane (beside its session's short queries) and its replies per turn
HISTORY_LANE = "history"
HISTORY_PER_TURN = 16

log = logging.getLogger("gateway.zenoh")

JSON = zenoh.Encoding.APPLICATION_JSON
REFUSAL_LOG_PERIOD_S = 10.0
#: commands (SDO, set points, NMT) handed to the event loop and not answered yet: past it, busy
COMMANDS_MAX = 32
#: a read answer: its replies, (key, body) one at a time; a body of bytes or str goes out as it
#: is, anything else as JSON. Produced lazily, never held whole (history: thousands of samples)
Replies = Iterator[tuple[str, Any]]
#: ``read_now``'s answer for a request that is not a read of the image
NOT_A_READ: Any = object()


class Busy(Exception):
    """Refused for now: the queries' queue (or the commands in flight) is full."""

    def __init__(self, message: str, retry_after_s: float) -> None:
        super().__init__(message)
        self.retry_after_s = retry_after_s


def busy_payload(key: str, exc: Busy) -> dict[str, Any]:
    return {
        "error": "busy",
        "message": str(exc),
        "key": key,
        "retry_after_ms": max(1, round(exc.retry_after_s * 1000)),
    }


def lane_of(query: zenoh.Query) -> str:
    """The querying session when the query says (``source_info``), else the anonymous lane."""
    si = query.source_info
    return ANONYMOUS if si is None else str(si.source_id.zid)


def zenoh_hint(query: zenoh.Query) -> str | None:
    """What a query says of its sender: the session id it chose to send (``source_info``),
    recorded by the audit as a hint, never as the identity (a query does not authenticate)."""
    lane = lane_of(query)
    return None if lane == ANONYMOUS else f"zenoh session {lane}"


def write_operation(req: Request, payload: bytes | None) -> str | None:
    """The write a request is (``zenoh.write_allow`` operations), or None for a read."""
    if req.kind in ("set", "set_many"):
        return "set"
    if req.kind == "nmt":
        return "nmt"
    if req.kind == "sdo" and payload:
        return "sdo_write"
    return None


@dataclass(eq=False, repr=False)
class QueryService:
    """The answers of the queryable (see the module docstring)."""

    cfg: Config
    image: ProcessImage
    commands: CommandService
    prefix: str
    _: KW_ONLY
    session: Callable[[], zenoh.Session | None]
    scaling: Callable[[str, Signal], Scaling]
    #: per node, the published value keys and their signals (the publishing side's plan)
    value_keys: Mapping[str, Sequence[tuple[str, Signal]]]
    catalog_fn: Callable[[], dict[str, Any]] | None = None
    #: (node, signal, the image's seq) -> the seq its value key shows (a pair's take-over
    #: continues the other gateway's numbers: ``ZenohBridge.seq_of``)
    seq_of: Callable[[str, str, int], int] | None = None
    #: set when the bridge starts
    loop: asyncio.AbstractEventLoop | None = field(default=None, init=False)
    #: refused writes by operation (``zenoh_refused_total{operation}``)
    refused: dict[str, int] = field(default_factory=dict, init=False)
    #: history by time range (``history.py``), set when the gateway has a journal
    history: HistoryService | None = field(default=None, init=False)

    def __post_init__(self) -> None:
        self.published: Collection[tuple[str, str]] = frozenset(
            (node, sig.name) for node, keys in self.value_keys.items() for _key, sig in keys
        )
        self.gate = WriteGate(self.cfg.zenoh)
        self._refusal_log = RateLimitedLog(log, REFUSAL_LOG_PERIOD_S)
        self._answers: set[asyncio.Future[Any]] = set()
        #: the queries' own worker (``worker.py``): the thread ``zenoh-queries``
        self.worker: QueryWorker[zenoh.Query] = QueryWorker(self._job)
        #: commands handed to the event loop and not answered yet (``COMMANDS_MAX``)
        self._command_slots = threading.BoundedSemaphore(COMMANDS_MAX)
        #: queries answered (a reply, or a reply_err other than busy) and refused busy, each
        #: counted on the thread that answered it (``zenoh_queries_*_total``)
        self._answered = ThreadCount()
        self._busy = ThreadCount()
        #: the catalogue as sent (JSON), built once: it is made of the configuration only, and
        #: building it took about 18 ms, one reply that cannot give way
        self._catalog_json: str | None = None

    @property
    def answered(self) -> int:
        return self._answered.value

    @property
    def busy(self) -> int:
        return self._busy.value

    # ------------------------------------------------------------------ the worker
    def start(self, threads: ThreadRegistry) -> None:
        """The session starts: the catalogue is built, the worker's thread runs
        (``zenoh-queries``)."""
        self.catalog_json()
        self.worker.start_thread(threads)

    def catalog_json(self) -> str:
        """The catalogue's reply, built at the first call (the start) and kept."""
        if self._catalog_json is None:
            self._catalog_json = json.dumps(self.catalog())
        return self._catalog_json

    def stop(self) -> None:
        """The session stops (any thread but the loop: it joins the worker): queries not
        answered yet get ``reply_err`` ``busy``."""
        self.worker.stop()
        for query in self.worker.drain():
            self._refuse(query, Busy("the gateway's Zenoh session is stopping", 1.0))

    def on_query(self, query: zenoh.Query) -> None:
        """Zenoh thread: queue the query for the worker, or answer ``busy``; never block here."""
        loop = self.loop
        if loop is None or loop.is_closed() or self.session() is None:
            query.drop()
            return
        lane: Any = lane_of(query)
        if has_time_range(query):  # a long answer: its own lane, never ahead of short ones
            ok = self.worker.submit((lane, HISTORY_LANE), query, HISTORY_PER_TURN)
        else:
            ok = self.worker.submit(lane, query)
        if not ok:
            retry = self.worker.retry_after_s()
            why = f"{self.worker.depth} queries are waiting; ask again in {retry:.2f} s"
            self._refuse(query, Busy(why, retry))

    def _refuse(self, query: zenoh.Query, exc: Busy) -> None:
        self._busy.add()
        try:
            query.reply_err(json.dumps(busy_payload(str(query.key_expr), exc)), encoding=JSON)
        except zenoh.ZError:
            pass
        finally:
            query.drop()

    def _reply(self, query: zenoh.Query, key: str, result: Any) -> None:
        if isinstance(result, Stamped):  # a journaled sample: its payload and its own time
            query.reply(key, result.payload, encoding=JSON, timestamp=result.timestamp)
            return
        s = self.session()
        query.reply(
            key,
            result if isinstance(result, (bytes, str)) else json.dumps(result),
            encoding=JSON,
            timestamp=s.new_timestamp() if s is not None else None,
        )

    def _reply_err(self, query: zenoh.Query, key: str, exc: Exception) -> None:
        if isinstance(exc, Busy):
            self._busy.add()
            body = busy_payload(key, exc)
        elif isinstance(exc, AnswerCut):
            body = exc.body(key)
        else:
            if not isinstance(exc, (GatewayError, ValueError, KeyError, TypeError)):
                log.error("zenoh query %s failed", key, exc_info=exc)
            body = error_payload(exc, key)
        try:
            query.reply_err(json.dumps(body), encoding=JSON)
        except zenoh.ZError:
            pass

    def _job(self, query: zenoh.Query) -> Iterator[None]:
        """The worker's job for one query: the one dispatch point. A read is answered here,
        a reply per step; a command goes to the event loop, which answers and finalises it."""
        key = str(query.key_expr)
        handed = answered = False
        try:
            replies = self._read_replies(query, key)
            if replies is None:
                handed = self._hand_to_loop(query, key)
                return
            for rkey, body in replies:
                self._reply(query, rkey, body)
                yield
            answered = True
        except Exception as exc:  # noqa: BLE001 - nothing a client sends may crash the gateway
            self._reply_err(query, key, exc)
            answered = not isinstance(exc, Busy)
        finally:
            if not handed:
                if answered:
                    self._answered.add()
                query.drop()

    def _read_replies(self, query: zenoh.Query, key: str) -> Replies | None:
        """The replies of a read (history, wildcards, and what ``read_now`` answers), lazily;
        None for a command (the event loop's)."""
        if has_time_range(query):  # history by time range, from the journal
            if self.history is None:
                raise ValueError("_time: this gateway keeps no history (journal.path unset)")
            return self.history.stamped_replies(query, key)
        if has_wildcard(key):
            return self._wildcard(key)
        payload = query.payload.to_bytes() if query.payload is not None else None
        req = parse_key(self.prefix, key)
        if req.kind == "catalog":
            return iter(((key, self.catalog_json()),))
        doc = self.read_now(req, payload)
        if doc is NOT_A_READ:
            return None
        return iter(((key, doc),))

    def _hand_to_loop(self, query: zenoh.Query, key: str) -> bool:
        """A command to the event loop (True: the loop answers and finalises it)."""
        loop = self.loop
        if loop is None or loop.is_closed():
            raise Busy("the gateway is stopping", 1.0)
        if not self._command_slots.acquire(blocking=False):
            raise Busy(f"{COMMANDS_MAX} commands are running; ask again in 0.5 s", 0.5)
        try:
            loop.call_soon_threadsafe(self._spawn_command, query, key)
        except RuntimeError:
            self._command_slots.release()
            raise Busy("the gateway is stopping", 1.0) from None
        return True

    def _spawn_command(self, query: zenoh.Query, key: str) -> None:
        fut = asyncio.ensure_future(self._command(query, key))
        self._answers.add(fut)
        fut.add_done_callback(self._answers.discard)

    async def _command(self, query: zenoh.Query, key: str) -> None:
        """Event loop: run a command through the command service, answer, finalise."""
        try:
            payload = query.payload.to_bytes() if query.payload is not None else None
            type_param = query.parameters.get("type")
            with acting_as("zenoh", zenoh_hint(query)):  # the audit: the querier's id a hint
                result = await self.dispatch(key, payload, type_param)
            self._reply(query, key, result)
        except Exception as exc:  # noqa: BLE001 - nothing a client sends may crash the gateway
            self._reply_err(query, key, exc)
        finally:
            self._answered.add()
            self._command_slots.release()
            query.drop()

    def _wildcard(self, key: str) -> Replies:
        """A key expression with wildcards gets the read-only answers it matches (catalogue,
        states, snapshots, latest values), one at a time; commands and SDO never run on a
        wildcard."""
        ke = zenoh.KeyExpr(key)
        p = self.prefix
        if ke.intersects(catalog_key(p)):
            yield catalog_key(p), self.catalog_json()
        for name, node in self.image.nodes.items():
            if ke.intersects(state_key(p, name)):
                yield state_key(p, name), state_payload(node)
            if ke.intersects(snapshot_key(p, name)):
                yield snapshot_key(p, name), self.snapshot(node)
            for vkey, sig in self.value_keys.get(name, ()):
                if ke.intersects(vkey):
                    yield vkey, self._value_now(node, sig)

    def read_now(self, req: Request, payload: bytes | None) -> Any:
        """The answer of a read the process image gives at once (any thread: the image's
        reads are snapshots): catalogue, snapshot, state, the latest value of a published or
        output signal; ``NOT_A_READ`` for anything else (commands, reads by SDO)."""
        if write_operation(req, payload) is not None:
            return NOT_A_READ
        if req.kind == "catalog":
            return self.catalog()
        if req.kind not in ("snapshot", "state", "value"):
            return NOT_A_READ
        rt = self.commands.node(req.node)
        if req.kind == "snapshot":
            return self.snapshot(rt.image)
        if req.kind == "state":
            return state_payload(rt.image)
        sig = self.commands.signal(rt, req.signal)
        if sig.transport == "sdo":
            return NOT_A_READ
        return self._value_now(rt.image, sig)

    async def dispatch(self, key: str, payload: bytes | None, type_param: str | None = None) -> Any:
        """Answer one concrete query key (event loop; also usable without zenoh, e.g. from
        tests)."""
        req = parse_key(self.prefix, key)
        op = write_operation(req, payload)
        if op is not None:
            self._authorize(op, req.node, key)
            self.commands.require_active()  # a pair's standby: the active one takes writes
        doc = self.read_now(req, payload)
        if doc is not NOT_A_READ:
            return doc
        rt = self.commands.node(req.node)
        node = rt.image
        if req.kind == "nmt":
            cmd = nmt_command(payload)
            await self.commands.nmt(req.node, cmd)
            return {"ok": True, "node": req.node, "nmt": cmd}
        if req.kind == "sdo":
            return await self._sdo(req, payload, type_param, key)
        if req.kind == "value":
            sig = self.commands.signal(rt, req.signal)
            if sig.transport == "sdo":
                raw = await self.commands.read_signal(req.node, req.signal)
                sc = self.scaling(req.node, sig)
                doc = {
                    "value": engineering(sig, raw, sc),
                    "unit": sc.unit,
                    "ts": time.time(),
                    "quality": "good",
                    "seq": None,
                    "source": "sdo",
                }
                return add_names(doc, sig, raw)
            return self._value_now(node, sig)
        if req.kind == "set":
            return await self._set(req, payload)
        if req.kind == "set_many":
            body = set_many_body(payload)
            raws = {}
            for name, value in body.items():
                sig = self.commands.signal(rt, name)
                raws[name] = to_raw(sig, value, self.scaling(req.node, sig))
            await self.commands.write_signals(req.node, raws)
            return {"ok": True, "node": req.node, "written": raws}
        raise ValueError(f"unsupported request {req.kind}")  # pragma: no cover

    def _authorize(self, operation: str, node: str, key: str) -> None:
        """Raise ``Forbidden`` (counted, logged at most once per period per operation) unless
        the configuration allows this write."""
        why = self.gate.refusal(operation, node, key)
        if why is not None:
            self._refuse_op(operation, node, key, why)

    def _refuse_op(self, operation: str, node: str, key: str, why: str) -> None:
        """Raise ``Forbidden``: counted by operation, logged at most once per period, audited."""
        self.refused[operation] = self.refused.get(operation, 0) + 1
        self.commands.refusals.refused(operation, node, key, None, why)
        self._refusal_log.warning(
            ("zenoh_refused", operation),
            "Zenoh %s refused on %s: %s (refused so far: %d)",
            operation,
            key,
            why,
            self.refused[operation],
        )
        raise Forbidden(why)

    async def _sdo(self, req: Request, payload: bytes | None, type_param: str | None, key: str) -> Any:
        assert req.obj is not None
        obj = str(req.obj)
        if payload:
            value, typ = sdo_write_body(payload)
            await self.commands.sdo_write(req.node, req.obj, value, typ or type_param)
            return {"ok": True, "node": req.node, "object": obj, "value": reply_value(value)}
        listed = {sig.object for sig in self.commands.node(req.node).lp.profile.signals}
        why = self.gate.read_refusal(req.node, req.obj, listed)  # zenoh.reads
        if why is not None:
            self._refuse_op("sdo_read", req.node, key, why)
        value = await self.commands.sdo_read(req.node, req.obj, type_param)
        return {"node": req.node, "object": obj, "value": reply_value(value)}

    async def _set(self, req: Request, payload: bytes | None) -> Any:
        rt = self.commands.node(req.node)
        sig = self.commands.signal(rt, req.signal)
        body = set_body(payload)
        via = "rpdo" if rt.is_output(req.signal) else "sdo"
        done = {"ok": True, "node": req.node, "signal": req.signal}
        if body.bits is not None:
            named = {b.name: b for b in sig.bits}
            bits: dict[int, bool] = {}
            for bname, on in body.bits.items():
                b = named.get(bname)
                if b is None:
                    raise ValueError(f"{req.signal} has no bit {bname!r}; bits: {sorted(named)}")
                if not b.writable or b.width != 1:
                    writable = sorted(n for n, x in named.items() if x.writable and x.width == 1)
                    raise ValueError(
                        f"bit {bname} of {req.signal} is not writable; writable: {writable}"
                    )
                bits[b.bit] = on
            await self.commands.write_bits(req.node, req.signal, bits)
            return {**done, "bits": body.bits, "via": via}
        raw = body.value if body.raw else to_raw(sig, body.value, self.scaling(req.node, sig))
        await self.commands.write_signal(req.node, req.signal, raw)
        return {**done, "value": body.value, "raw": raw, "via": via}

    # ------------------------------------------------------------------ read-only answers
    def _value_now(self, node: NodeImage, sig: Signal) -> dict[str, Any]:
        """A TPDO value from the image's records (also of an output a TPDO carries too: the
        device's value); an RPDO output or text row from its output section (as last written)."""
        rt = self.commands.node(node.name)
        if rt.is_output(sig.name) and not any(sig.name in names for _, names in rt.tpdo_records):
            sv = self.commands.output_sample(node.name, sig.name)
        else:
            sv = node.signals[sig.name]
            if self.seq_of is not None and sv.seq:
                sv = sv._replace(seq=self.seq_of(node.name, sig.name, sv.seq))
        return value_payload(sig, sv, node.quality(sv), self.scaling(node.name, sig))

    def snapshot(self, node: NodeImage) -> dict[str, Any]:
        rt = self.commands.node(node.name)
        names = [sig.name for sig in rt.lp.profile.signals if sig.transport == "pdo"]
        names += sorted(n for n in rt.outputs if n not in names)  # text rows
        values = {n: self._value_now(node, self.commands.signal(rt, n)) for n in names}
        return {"node": node.name, "state": state_payload(node), "values": values}

    def catalog(self) -> dict[str, Any]:
        """The app's catalogue (types, units, Modbus addresses) with this node's Zenoh keys and
        the scaling in force (overrides applied)."""
        cat = dict(self.catalog_fn()) if self.catalog_fn else {"nodes": {}}
        p = self.prefix
        cat.setdefault("gateway", self.cfg.gateway.name)
        cat.setdefault("version", __version__)
        cat["prefix"] = p
        can_kw = self.cfg.can.bus_kwargs()
        cat["can"] = {
            k: can_kw[k] for k in ("interface", "channel", "bitrate") if can_kw.get(k) is not None
        }
        cat["writes"] = self.cfg.zenoh.writes
        for name, n in cat.get("nodes", {}).items():
            try:
                rt = self.commands.node(name)
            except GatewayError:
                continue
            n["keys"] = {
                "alive": alive_key(p, name),
                "state": state_key(p, name),
                "emcy": emcy_key(p, name),
                "snapshot": snapshot_key(p, name),
                "nmt": nmt_key(p, name),
                "set": set_key(p, name),
            }
            texts = {t.name: t for t in text_rows_as_signals(rt.lp.profile)}
            for sname, s in n.get("signals", {}).items():
                try:
                    sig = texts.get(sname) or rt.lp.profile.signal(sname)
                except KeyError:
                    continue
                sc = self.scaling(name, sig)
                s["unit"], s["scale"], s["offset"] = sc.unit, sc.scale, sc.offset
                keys: dict[str, str] = {}
                if (name, sname) in self.published:
                    keys["value"] = value_key(p, name, sname)
                elif sig.transport == "sdo" and sig.access != "wo":
                    keys["get"] = value_key(p, name, sname)
                if is_writable(sig):
                    keys["set"] = set_key(p, name, sname)
                s["zenoh"] = keys
        return cat
