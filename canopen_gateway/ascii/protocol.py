"""The CiA 309-3 ASCII mapping, sans-I/O: text lines in, requests and answer lines out.

Rule 1: everything about the command language lives here and in its two siblings (``grammar``:
error codes, lines and tokens; ``values``: the data types and their text form): the requests,
the answer and event lines, and one client's session state
(default net and node, SDO time-out, the write gate). Rule 2: this module does no I/O and does
not know the command service: it turns a line into a resolved ``Call`` (SDO upload, SDO
download, NMT) or into an immediate answer, and formats what the caller got back.

Grammar (CiA 309-3; the syntax of CANopenNode's ``CO_gateway_ascii`` and Lely's ``coctl``)::

    "[" seq "]" [[net] node] r[ead]  index sub [type]        SDO upload
    "[" seq "]" [[net] node] w[rite] index sub type value    SDO download
    "[" seq "]" [[net] node] start | stop | preop[erational]
    "[" seq "]" [[net] node] reset node | reset comm[unication]
    "[" seq "]" [net] set node N | set sdo_timeout MS
    "[" seq "]" set network N
    "[" seq "]" help [datatype] | info version

Answers: ``[seq] OK``, ``[seq] <value>``, ``[seq] ERROR:0x<abort code>`` (SDO abort, 8 hex
digits) or ``[seq] ERROR:<code>`` (``Iec``). The sequence number is mandatory (as in
CANopenNode and Lely): a line without it is answered ``ERROR:101``, without a sequence.
Lines end CR LF (LF alone is accepted); ``#`` starts a comment where a token may start; an
empty or comment-only line gets no answer. Numbers are decimal or ``0x`` hexadecimal.

Networks: the gateway's CAN networks are numbered 1.. in configured order (``networks:``; a
single-network config is net 1). Without a net a request addresses the connection's default
net (the first, or the one ``set network`` chose); a net past the last is answered
``ERROR:106``, a node that is not on the net ``ERROR:107``.

Events (not answers, no sequence): ``<net> <node> BOOT_UP``,
``<net> <node> EMCY <code> <register> <b0> .. <b4>`` (code and register in hex, manufacturer
bytes in decimal) and ``<net> <node> ERROR <code> (<text>)`` for the error control codes
(200 lost guarding message, 202 heartbeat started, 203 heartbeat lost), as Lely's gateway
prints them.

Imports: the standard library, canopen_gateway.errors, canopen.cia301 (the SDO abort codes), ascii.grammar (error codes,
lines, tokens), ascii.values (data types and their text). Nothing of bus/, commands or a
transport.
"""

from __future__ import annotations

import re
from collections.abc import Collection, Mapping
from dataclasses import dataclass

from canopen_gateway.ascii.grammar import Iec, Overlong, RequestError, peek_seq, tokenize
from canopen_gateway.ascii.values import (
    DATA_TYPES,
    UNSUPPORTED_TYPES,
    DataType,
    LengthMismatch,
    encode_value,
    parse_int,
)
from canopen_gateway.canopen.cia301 import (
    SDO_ABORT_DEVICE_STATE,
    SDO_ABORT_TIMEOUT,
    SDO_ABORT_TYPE_LENGTH,
)
from canopen_gateway.errors import (
    Forbidden,
    NodeUnknown,
    SdoAbort,
    SdoTimeout,
    SupervisionWrite,
    ValueOutOfRange,
)

#: the first CAN network of this gateway, as CiA 309-3 numbers networks (1..65535)
NET = 1


# --------------------------------------------------------------------------- answers
def _prefix(seq: int | None) -> str:
    return "" if seq is None else f"[{seq}] "


def answer_ok(seq: int | None) -> str:
    return f"{_prefix(seq)}OK"


def answer_value(seq: int | None, text: str) -> str:
    return f"{_prefix(seq)}{text}"


def answer_error(seq: int | None, code: Iec) -> str:
    return f"{_prefix(seq)}ERROR:{int(code)}"


def answer_abort(seq: int | None, abort_code: int) -> str:
    return f"{_prefix(seq)}ERROR:0x{abort_code:08X}"


def answer_for_error(seq: int | None, exc: BaseException) -> str:
    """The answer to a request the command service (or the wait for it) failed with."""
    if isinstance(exc, SdoAbort):
        return answer_abort(seq, exc.code)
    if isinstance(exc, (SdoTimeout, TimeoutError)):
        return answer_abort(seq, SDO_ABORT_TIMEOUT)  # an SDO without a reply
    if isinstance(exc, LengthMismatch):
        return answer_abort(seq, SDO_ABORT_TYPE_LENGTH)
    if isinstance(exc, NodeUnknown):
        return answer_error(seq, Iec.UNSUPPORTED_NODE)
    if isinstance(exc, Forbidden):
        return answer_error(seq, Iec.REQUEST_NOT_SUPPORTED)
    if isinstance(exc, SupervisionWrite):
        # a write that would defeat the gateway's supervision of the node
        return answer_abort(seq, SDO_ABORT_DEVICE_STATE)
    if isinstance(exc, ValueOutOfRange):
        return answer_error(seq, Iec.SYNTAX)
    return answer_error(seq, Iec.INTERNAL_STATE)  # not operational, bus down, any other failure


# --------------------------------------------------------------------------- events
def event_boot_up(node_id: int, net: int = NET) -> str:
    return f"{net} {node_id} BOOT_UP"


def event_emcy(node_id: int, code: int, register: int, manufacturer: bytes, net: int = NET) -> str:
    msef = " ".join(str(b) for b in bytes(manufacturer[:5]).ljust(5, b"\0"))
    return f"{net} {node_id} EMCY {code:04X} {register:02X} {msef}"


def event_error(node_id: int, code: Iec, net: int = NET) -> str:
    return f"{net} {node_id} ERROR {int(code)} ({code.text})"


@dataclass(frozen=True)
class HealthSample:
    """What the event lines are derived from: a node's health as the process image has it."""

    alive: bool
    boot_count: int
    emcy_count: int
    supervision: str  # "heartbeat" | "guarding" | "none"
    loss_count: int = 0


class EventTracker:
    """Event lines from successive health samples of each node (one owner: the event loop).

    A boot-up counted since the last sample gives ``BOOT_UP``; a new EMCY gives ``EMCY`` (the
    caller passes the record); a loss counted gives ``ERROR 203`` (heartbeat) or ``ERROR 200``
    (node guarding); alive again without a boot-up gives ``ERROR 202`` (heartbeat) only. The
    counters, not only ``alive``, are compared: a loss and its end reported in one health
    change still give both lines."""

    def __init__(self) -> None:
        self._last: dict[tuple[int, int], HealthSample] = {}

    def update(
        self,
        node_id: int,
        now: HealthSample,
        emcy: tuple[int, int, bytes] | None = None,
        net: int = NET,
    ) -> list[str]:
        before = self._last.get((net, node_id))
        self._last[net, node_id] = now
        if before is None:
            return []
        out: list[str] = []
        booted = now.boot_count != before.boot_count
        if booted:
            out.append(event_boot_up(node_id, net))
        if now.emcy_count != before.emcy_count and emcy is not None:
            out.append(event_emcy(node_id, *emcy, net=net))
        lost = now.loss_count != before.loss_count or (before.alive and not now.alive)
        if lost:
            if now.supervision == "heartbeat":
                out.append(event_error(node_id, Iec.HEARTBEAT_LOST, net))
            elif now.supervision == "guarding":
                out.append(event_error(node_id, Iec.LOST_GUARDING, net))
        if now.alive and (lost or not before.alive) and not booted:
            if now.supervision == "heartbeat":
                out.append(event_error(node_id, Iec.HEARTBEAT_STARTED, net))
        return out


# --------------------------------------------------------------------------- requests
@dataclass(frozen=True)
class _Request:
    """What every request line carries: its sequence number (``[seq]``, echoed in the answer)."""

    seq: int | None


@dataclass(frozen=True)
class _NodeRequest(_Request):
    """A node-level command, ``[seq] [[net] node] command``: None where the line leaves the net
    or the node to the connection's default."""

    net: int | None
    node: int | None


@dataclass(frozen=True)
class Read(_NodeRequest):
    index: int
    sub: int
    dtype: DataType | None


@dataclass(frozen=True)
class Write(_NodeRequest):
    index: int
    sub: int
    dtype: DataType
    data: bytes


@dataclass(frozen=True)
class Nmt(_NodeRequest):
    command: str  # a key of canopen_gateway.canopen.states.NMT_COMMANDS


@dataclass(frozen=True)
class Set(_Request):
    """``[net] set node <id>``, ``set network <net>``, ``[net] set sdo_timeout <ms>``: a
    default of the connection (``value`` in milliseconds for the SDO timeout)."""

    net: int | None  # always None for ``set network``
    what: str  # a key of _SET_MAX
    value: int


@dataclass(frozen=True)
class Help(_Request):
    topic: str


@dataclass(frozen=True)
class InfoVersion(_Request):
    """``info version``: the gateway's identity and version."""


Request = Read | Write | Nmt | Set | Help | InfoVersion

#: the ``set`` commands and the largest value each takes (the smallest is 1)
_SET_MAX = {"network": 0xFFFF, "node": 127, "sdo_timeout": 0xFFFF}
_NMT_WORDS = {"start": "start", "stop": "stop", "preop": "preop", "preoperational": "preop"}
_RESET_WORDS = {"node": "reset", "comm": "reset-comm", "communication": "reset-comm"}
#: commands of CiA 309-3 (or of canopend/coctl) this gateway does not offer: ERROR:100
_NOT_SUPPORTED = frozenset(
    {"led", "log", "init", "enable", "disable", "lss_switch_glob", "lss_switch_sel",
     "lss_set_node", "lss_conf_bitrate", "lss_activate_bitrate", "lss_store",
     "lss_inquire_addr", "lss_get_node", "_lss_fastscan", "lss_allnodes", "set_rpdo",
     "set_tpdo", "read_pdo", "write_pdo"}
)  # fmt: skip


def _number(text: str, lo: int, hi: int, seq: int | None, what: str) -> int:
    try:
        v = parse_int(text)
    except ValueError:
        raise RequestError(seq, Iec.SYNTAX, f"{what}: not a number") from None
    if not lo <= v <= hi:
        raise RequestError(seq, Iec.SYNTAX, f"{what}: {lo}..{hi}")
    return v


def _dtype(word: str, seq: int | None) -> DataType:
    w = word.lower()
    if w in UNSUPPORTED_TYPES:
        raise RequestError(seq, Iec.REQUEST_NOT_SUPPORTED, f"data type {word}")
    t = DATA_TYPES.get(w)
    if t is None:
        raise RequestError(seq, Iec.SYNTAX, f"unknown data type {word!r}")
    return t


def parse_request(line: str) -> Request | None:
    """One request line -> a request (None for an empty or comment line); RequestError for
    a request answered with an internal error code at once."""
    seq = peek_seq(line)
    if any(not 0x20 <= ord(c) <= 0x7E and c != "\t" for c in line):
        raise RequestError(seq, Iec.SYNTAX, "a request is printable ASCII")
    try:
        tokens = tokenize(line)
    except ValueError as exc:
        raise RequestError(seq, Iec.SYNTAX, str(exc)) from None
    if not tokens:
        return None
    m = re.fullmatch(r"\[([0-9]{1,10})\]", tokens[0])
    if m is None or int(m.group(1)) > 0xFFFFFFFF:
        raise RequestError(None, Iec.SYNTAX, "a request starts with [sequence 0..4294967295]")
    seq = int(m.group(1))
    tokens = tokens[1:]
    numbers: list[int] = []
    while tokens and tokens[0][:1].isdigit():
        numbers.append(_number(tokens.pop(0), 0, 0xFFFFFFFF, seq, "net/node"))
    if len(numbers) > 2:
        raise RequestError(seq, Iec.SYNTAX, "at most a net and a node before the command")
    if not tokens:
        raise RequestError(seq, Iec.SYNTAX, "no command")
    cmd, args = tokens[0].lower(), tokens[1:]
    net, node = (None, None)
    if len(numbers) == 2:
        net, node = numbers
    elif len(numbers) == 1:
        node = numbers[0]
    return _command(seq, net, node, numbers, cmd, args)


def _command(
    seq: int, net: int | None, node: int | None, numbers: list[int], cmd: str, args: list[str]
) -> Request:
    """The request of command word ``cmd`` with its ``args``, after ``[seq] [net] [node]``."""

    def need(count: int | tuple[int, ...]) -> None:
        counts = (count,) if isinstance(count, int) else count
        if len(args) not in counts:
            raise RequestError(seq, Iec.SYNTAX, f"{cmd}: {' or '.join(map(str, counts))} arguments")

    if cmd in ("r", "read"):
        need((2, 3))
        index = _number(args[0], 0, 0xFFFF, seq, "index")
        sub = _number(args[1], 0, 0xFF, seq, "sub-index")
        dtype = _dtype(args[2], seq) if len(args) == 3 else None
        return Read(seq, net, node, index, sub, dtype)
    if cmd in ("w", "write"):
        need(4)
        index = _number(args[0], 0, 0xFFFF, seq, "index")
        sub = _number(args[1], 0, 0xFF, seq, "sub-index")
        dtype = _dtype(args[2], seq)
        try:
            data = encode_value(dtype, args[3])
        except ValueError as exc:
            raise RequestError(seq, Iec.SYNTAX, str(exc)) from None
        return Write(seq, net, node, index, sub, dtype, data)
    if cmd in _NMT_WORDS:
        need(0)
        return Nmt(seq, net, node, _NMT_WORDS[cmd])
    if cmd == "reset":
        need(1)
        what = _RESET_WORDS.get(args[0].lower())
        if what is None:
            raise RequestError(seq, Iec.SYNTAX, "reset node | reset comm[unication]")
        return Nmt(seq, net, node, what)
    if cmd == "set":
        if not args:
            raise RequestError(seq, Iec.SYNTAX, "set what?")
        what, args = args[0].lower(), args[1:]
        # a single number before a network-level command is the net (Lely's rule)
        if net is not None:
            raise RequestError(seq, Iec.SYNTAX, "a node before a network-level command")
        net = node
        if what not in _SET_MAX:
            raise RequestError(seq, Iec.REQUEST_NOT_SUPPORTED, f"set {what}")
        need(1)
        if what == "network" and net is not None:
            raise RequestError(seq, Iec.SYNTAX, "set network takes no net before it")
        low = 0 if what == "network" else 1  # net 0 is a number of no network: ERROR:106, as [seq] 0 ...
        return Set(seq, net, what, _number(args[0], low, _SET_MAX[what], seq, what))
    if cmd == "help":
        if numbers or len(args) > 1:
            raise RequestError(seq, Iec.SYNTAX, "help [datatype]")
        return Help(seq, args[0].lower() if args else "")
    if cmd == "info":
        if numbers:
            raise RequestError(seq, Iec.SYNTAX, "info is a gateway-level command")
        if args and args[0].lower() == "version" and len(args) == 1:
            return InfoVersion(seq)
        raise RequestError(seq, Iec.REQUEST_NOT_SUPPORTED, "info version only")
    if cmd in _NOT_SUPPORTED:
        raise RequestError(seq, Iec.REQUEST_NOT_SUPPORTED, cmd)
    raise RequestError(seq, Iec.REQUEST_NOT_SUPPORTED, f"unknown command {cmd!r}")


# --------------------------------------------------------------------------- session
@dataclass(frozen=True)
class SdoUpload:
    """Read ``index:sub`` of a node (``dtype`` None: decoded by the object's EDS type)."""

    seq: int | None
    node_id: int
    index: int
    sub: int
    dtype: DataType | None
    timeout_ms: int | None
    net: int = NET  # the CAN network (1..)


@dataclass(frozen=True)
class SdoDownload:
    seq: int | None
    node_id: int
    index: int
    sub: int
    data: bytes
    timeout_ms: int | None
    net: int = NET


@dataclass(frozen=True)
class NmtCommand:
    """An NMT command to a node (``node_id`` 0: every configured node of network ``net``)."""

    seq: int | None
    node_id: int
    command: str
    net: int = NET


Call = SdoUpload | SdoDownload | NmtCommand

HELP_TEXT = """\
[seq] [[net] node] r[ead] <index> <sub> [<type>]       SDO upload
[seq] [[net] node] w[rite] <index> <sub> <type> <value> SDO download (ascii.writes)
[seq] [[net] node] start | stop | preop[erational]     NMT (ascii.writes; node 0 = all)
[seq] [[net] node] reset node | reset comm[unication]  NMT (ascii.writes; node 0 = all)
[seq] [net] set node <1..127>                          default node
[seq] set network <net>                                default net (1..: the configured networks)
[seq] [net] set sdo_timeout <ms>                       longest wait for an SDO answer
[seq] help [datatype]
[seq] info version
answers: [seq] OK | <value> | ERROR:0x<abort code> | ERROR:<code>"""

HELP_DATATYPES = """\
b                  boolean (0 or 1)
i8 i16 i32 i64     signed integers
u8 u16 u32 u64     unsigned integers
x8 x16 x32 x64     unsigned integers shown in hexadecimal
r32 r64            reals
vs                 visible string (in double quotes when it has blanks)
os d               octet string, domain (base64, RFC 2045, one line)"""


class Session:
    """One client's session: default net and node, SDO time-out and the write gate.

    ``handle(line)`` returns the answer lines to send at once, or a ``Call`` for the caller to
    perform (then ``answer_*`` formats what it got), or nothing for an empty line."""

    def __init__(
        self,
        node_ids: Collection[int],
        *,
        writes: bool,
        version: str,
        networks: Mapping[int, Collection[int]] | None = None,
    ) -> None:
        #: net number -> the node ids configured on that network (``node_ids``: of net 1)
        self.networks = {k: frozenset(v) for k, v in (networks or {NET: node_ids}).items()}
        self.node_ids = self.networks.get(NET, frozenset())
        self.writes = writes
        self.version = version
        self.default_net: int | None = NET  # one network: the default is set from the start
        self.default_node: int | None = None
        self.sdo_timeout_ms: int | None = None  # None: the gateway's own SDO time-out
        self.refused = 0  # writes and NMT commands refused by the write gate

    def handle(self, line: str | Overlong) -> list[str] | Call:
        if isinstance(line, Overlong):
            return [answer_error(line.seq, Iec.SYNTAX)]
        try:
            req = parse_request(line)
            if req is None:
                return []
            return self._resolve(req)
        except RequestError as exc:
            return [answer_error(exc.seq, exc.code)]

    def _net(self, seq: int | None, net: int | None) -> int:
        """The net a request addresses: its own, else the default; ERROR:106 past the last."""
        if net is None:
            if self.default_net is None:
                raise RequestError(seq, Iec.NO_DEFAULT_NET)
            net = self.default_net
        if net not in self.networks:
            raise RequestError(seq, Iec.UNSUPPORTED_NET)
        return net

    def _node(self, req: _NodeRequest, *, all_ok: bool) -> tuple[int, int]:
        """The net and node id ``req`` addresses (its own or the defaults; node 0, all nodes
        of the net, if ``all_ok``); ERROR:107 for a node not on that net."""
        seq, node = req.seq, req.node
        net = self._net(seq, req.net)
        if node is None:
            if self.default_node is None:
                raise RequestError(seq, Iec.NO_DEFAULT_NODE)
            node = self.default_node
        if node == 0 and all_ok:
            return net, 0
        if node not in self.networks[net]:
            raise RequestError(seq, Iec.UNSUPPORTED_NODE)
        return net, node

    def _node_to_change(self, req: _NodeRequest, *, all_ok: bool) -> tuple[int, int]:
        """The node a write or an NMT command addresses (``_node``); while writes are off the
        request is refused (ERROR:100) and counted."""
        net_node = self._node(req, all_ok=all_ok)
        if not self.writes:
            self.refused += 1
            raise RequestError(req.seq, Iec.REQUEST_NOT_SUPPORTED, "writes are off")
        return net_node

    def _resolve(self, req: Request) -> list[str] | Call:
        seq = req.seq
        if isinstance(req, Read):
            net, node = self._node(req, all_ok=False)
            return SdoUpload(seq, node, req.index, req.sub, req.dtype, self.sdo_timeout_ms, net)
        if isinstance(req, Write):
            net, node = self._node_to_change(req, all_ok=False)
            return SdoDownload(seq, node, req.index, req.sub, req.data, self.sdo_timeout_ms, net)
        if isinstance(req, Nmt):
            net, node = self._node_to_change(req, all_ok=True)
            return NmtCommand(seq, node, req.command, net)
        if isinstance(req, Set):
            if req.what == "network":
                if req.value not in self.networks:
                    raise RequestError(seq, Iec.UNSUPPORTED_NET)
                self.default_net = req.value
            elif req.what == "node":
                net = self._net(seq, req.net)
                if req.value not in self.networks[net]:
                    raise RequestError(seq, Iec.UNSUPPORTED_NODE)
                self.default_node = req.value
            else:
                self._net(seq, req.net)
                self.sdo_timeout_ms = req.value
            return [answer_ok(seq)]
        if isinstance(req, Help):
            if req.topic not in ("", "datatype"):
                raise RequestError(seq, Iec.REQUEST_NOT_SUPPORTED, f"help {req.topic}")
            text = HELP_DATATYPES if req.topic == "datatype" else HELP_TEXT
            return [f"# {t}" for t in text.splitlines()] + [answer_ok(seq)]
        # InfoVersion: vendor-id, product code, revision, serial number, gateway class (3: the
        # gateway is the NMT master), protocol version, implementation version (Lely's order)
        major_minor = ".".join(self.version.split(".")[:2])
        return [answer_value(seq, f"0 0 {major_minor} 0 3 3.0 {major_minor}")]
