"""Which CANopen nodes are on the bus, and what they are (``canopen-gateway scan``).

Passive: listen for ``listen_s`` and collect the node ids that send frames a node sends itself
(heartbeat and boot-up, EMCY, TPDOs, SDO answers; CiA 301 7.3.3), with the NMT state of their
last heartbeat. Active (``--active``): an SDO upload of 1000h (device type) to every node id
1..127, then for each id that answered: 1008h (device name) and 1018h:01..04 (identity:
vendor, product, revision, serial), one node after the other.

The requests go out paced by the bit rate (``can.bitrate``; ``ASSUMED_BITRATE_BPS`` when it is
not set): groups of ``TX_GROUP`` frames, each group after the wire has had time for the
previous one's requests and their answers, so a SocketCAN transmit queue (10 frames by
default) does not overflow; a request the interface still refuses (ENOBUFS, "transmit buffer
full": ``can.CanOperationError``) is sent again after one group's wire time. The answers are
awaited for the wire time of every request and its answer (``FRAME_BITS_MAX`` each) plus
``sdo_timeout_s`` (the devices' own response time): 0.37 s at 125 kbit/s for 127 ids, 0.13 s at
1 Mbit/s, on an otherwise quiet bus.

Each node found is compared with the built-in profiles (device type, vendor, product, name) and
with the configured node of its id. A configured node that is not found is listed too: a wrong
node id shows as one id configured but silent and another talking but not configured.

Uses python canopen's SDO client on the given python-can bus (an SDO client that is not the
gateway's, so a scan runs without the master). ``scan_beside`` scans while the gateway runs, on
its own connection (``bus.tap_bus``, no second connection: every interface) and leaves the
configured node ids to the master's SDO client (the command service reads their identity), so
no answer meant for the master's transfers is sent to them by the scan. Imports: python-can,
canopen, config, profiles, bus.bus_peers, bus.driver, bus.tap_bus, states.
"""

from __future__ import annotations

import errno
import threading
import time
from collections.abc import Callable, Collection
from dataclasses import dataclass, field
from typing import Any

import can
import canopen

from canopen_gateway.bus.driver import BusDriver
from canopen_gateway.bus.tap_bus import TapBus
from canopen_gateway.canopen.connection_set import talking_node_id
from canopen_gateway.canopen.states import NmtState
from canopen_gateway.config import Config
from canopen_gateway.profiles import builtin_profiles, load_profile

#: CiA 301 device type (1000h) bits 0..15: the device profile number
PROFILE_NAMES = {301: "CiA 301", 401: "DS-401 I/O", 402: "DS-402 drive", 406: "DS-406 encoder",
                 410: "DS-410 inclinometer", 418: "DS-418 battery"}  # fmt: skip
ALL_NODE_IDS = range(1, 128)
#: ISO 11898-1: an 8-byte standard data frame is 108 bits, 24 stuff bits at most, then the
#: 3-bit intermission: the wire time of one SDO request or answer, at worst
FRAME_BITS_MAX = 135
#: the bit rate assumed when ``can.bitrate`` is not set (SocketCAN takes it from ``ip link``):
#: 125 kbit/s; a slower bus needs its ``can.bitrate`` for the scan to wait long enough
ASSUMED_BITRATE_BPS = 125_000
#: requests handed to the interface back-to-back: fewer than the 10 frames of a SocketCAN
#: interface's default transmit queue (txqueuelen), leaving room for the gateway's own frames
TX_GROUP = 8
#: attempts at a request the interface refuses (its transmit queue full), one group's wire
#: time apart; then the scan fails with the interface's error
SEND_ATTEMPTS = 10


@dataclass
class Found:
    """One node id on the bus and what is known about it."""

    node_id: int
    cob_ids: set[int] = field(default_factory=set)
    state: str | None = None
    device_type: int | None = None
    name: str | None = None
    vendor: int | None = None
    product: int | None = None
    revision: int | None = None
    serial: int | None = None

    def doc(self) -> dict[str, Any]:
        return {
            "node_id": self.node_id,
            "state": self.state,
            "device_type": self.device_type,
            "name": self.name,
            "vendor": self.vendor,
            "product": self.product,
            "revision": self.revision,
            "serial": self.serial,
            "cob_ids": sorted(self.cob_ids),
        }


def _state_word(byte: int) -> str:
    if byte == 0:
        return "pre-operational (boot-up)"  # CiA 301: a node is pre-operational after boot-up
    try:
        return NmtState(byte & 0x7F).name.lower().replace("_", "-")
    except ValueError:
        return f"state 0x{byte:02X}"


class _Seen(can.Listener):
    """Collects node ids from frames (runs on the notifier's thread; read after ``stop``)."""

    def __init__(self) -> None:
        self.found: dict[int, Found] = {}
        self.lock = threading.Lock()

    def on_message_received(self, msg: can.Message) -> None:
        cob = msg.arbitration_id
        node_id = talking_node_id(cob)
        if node_id is None or msg.is_remote_frame or msg.is_error_frame:
            return
        with self.lock:
            f = self.found.setdefault(node_id, Found(node_id))
            f.cob_ids.add(cob)
            if cob & 0x780 == 0x700 and msg.data:
                f.state = _state_word(msg.data[0])

    def snapshot(self) -> dict[int, Found]:
        with self.lock:
            return dict(self.found)


def scan(
    bus: can.BusABC,
    *,
    listen_s: float = 1.5,
    active: bool = False,
    sdo_timeout_s: float = 0.1,
    node_ids: range | list[int] = ALL_NODE_IDS,
    on_listening: Callable[[], None] | None = None,
    bitrate_bps: int | None = None,
) -> dict[int, Found]:
    """Scan the bus (see the module docstring); returns the nodes found by node id.
    ``bitrate_bps``: the bus's bit rate (``can.bitrate``), None when unknown."""
    seen = _Seen()
    network = canopen.Network(bus)
    answered: set[int] = set()
    answer_event = threading.Event()

    class _Answers(can.Listener):
        def on_message_received(self, msg: can.Message) -> None:
            cob = msg.arbitration_id
            if cob & 0x780 == 0x580 and msg.data and msg.data[1:4] == b"\x00\x10\x00":
                answered.add(cob & 0x7F)
                answer_event.set()

    network.notifier = can.Notifier(bus, [*network.listeners, seen, _Answers()], 0.1)
    try:
        if on_listening is not None:
            on_listening()
        time.sleep(listen_s)  # the passive window: frames the nodes send on their own
        found = seen.snapshot()
        if active:
            send_probes(bus, node_ids, bitrate_bps=bitrate_bps, timeout_s=sdo_timeout_s)
            _identify(network, found, answered, node_ids, sdo_timeout_s)
            found = {**seen.snapshot(), **found}
    finally:
        network.notifier.stop()
    return found


def scan_beside(
    driver: BusDriver,
    *,
    configured: Collection[int],
    listen_s: float = 1.0,
    sdo_timeout_s: float = 0.1,
) -> dict[int, Found]:
    """An active scan on a running gateway's own connection (blocking: run it in a worker
    thread), paced by the driver's ``bitrate``. The ``configured`` node ids are only listened
    to, never probed here."""
    bus = TapBus(driver)
    try:
        return scan(
            bus,
            listen_s=listen_s,
            active=True,
            sdo_timeout_s=sdo_timeout_s,
            node_ids=[i for i in ALL_NODE_IDS if i not in configured],
            bitrate_bps=driver.bus_kwargs.get("bitrate"),
        )
    finally:
        bus.shutdown()


def _request_pair_s(bitrate_bps: int | None) -> float:
    """The wire time of one request and its answer at the bit rate (the assumed one if None)."""
    return 2 * FRAME_BITS_MAX / (bitrate_bps or ASSUMED_BITRATE_BPS)


def send_probes(
    bus: can.BusABC,
    node_ids: range | list[int],
    *,
    bitrate_bps: int | None,
    timeout_s: float,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], Any] = time.sleep,
) -> None:
    """An SDO upload of 1000h:00 to each id, paced by the bit rate, then the wait for the last
    answers (see the module docstring). Raises the interface's ``can.CanError`` when a request
    is refused ``SEND_ATTEMPTS`` times."""
    pair_s = _request_pair_s(bitrate_bps)
    ids = list(node_ids)
    group_start = clock()
    for i in range(0, len(ids), TX_GROUP):
        group = ids[i : i + TX_GROUP]
        if i:  # the previous group's requests and answers have had the wire
            due = group_start + TX_GROUP * pair_s
            _sleep_until(due, clock, sleep)
            group_start = max(due, clock())
        for node_id in group:
            # CiA 301 7.2.4.3.6: initiate upload request, 1000h:00
            msg = can.Message(arbitration_id=0x600 + node_id, data=b"\x40\x00\x10\x00" + bytes(4),
                              is_extended_id=False)  # fmt: skip
            _send_retrying(bus, msg, TX_GROUP * pair_s, sleep)
        last_group = len(group)
    if ids:  # the last group's requests and answers, then the devices' response time
        _sleep_until(group_start + last_group * pair_s + timeout_s, clock, sleep)


def _sleep_until(
    deadline: float, clock: Callable[[], float], sleep: Callable[[float], Any]
) -> None:
    while (left := deadline - clock()) > 0:
        sleep(left)


def _send_retrying(
    bus: can.BusABC, msg: can.Message, retry_s: float, sleep: Callable[[float], Any]
) -> None:
    for attempt in range(1, SEND_ATTEMPTS + 1):
        try:
            bus.send(msg)
            return
        except (can.CanOperationError, OSError) as exc:
            if isinstance(exc, OSError) and exc.errno != errno.ENOBUFS:
                raise
            if attempt == SEND_ATTEMPTS:
                raise can.CanOperationError(
                    f"the scan's SDO request to node id {msg.arbitration_id - 0x600} was "
                    f"refused {SEND_ATTEMPTS} times: {exc}"
                ) from exc
            sleep(retry_s)  # the transmit queue drains meanwhile


def _identify(
    network: canopen.Network,
    found: dict[int, Found],
    answered: set[int],
    node_ids: range | list[int],
    timeout_s: float,
) -> None:
    """Device type, name and identity of each id that answered the probe."""
    for node_id in sorted(answered & set(node_ids)):  # an answer to another client: not ours
        f = found.setdefault(node_id, Found(node_id))
        remote = canopen.RemoteNode(node_id, canopen.ObjectDictionary())
        remote.sdo.RESPONSE_TIMEOUT = max(timeout_s, 0.05)
        remote.sdo.MAX_RETRIES = 0
        network.add_node(remote)
        f.device_type = _read_int(remote, 0x1000, 0)
        raw = _read(remote, 0x1008, 0)
        f.name = raw.rstrip(b"\0").decode("ascii", errors="replace") if raw is not None else None
        f.vendor, f.product, f.revision, f.serial = (
            _read_int(remote, 0x1018, sub) for sub in (1, 2, 3, 4)
        )
        network.nodes.pop(node_id, None)


def _read(remote: canopen.RemoteNode, index: int, sub: int) -> bytes | None:
    try:
        return bytes(remote.sdo.upload(index, sub))
    except (canopen.SdoAbortedError, canopen.SdoCommunicationError):
        return None


def _read_int(remote: canopen.RemoteNode, index: int, sub: int) -> int | None:
    raw = _read(remote, index, sub)
    return int.from_bytes(raw[:4], "little") if raw else None


# --------------------------------------------------------------------------- matching


@dataclass(frozen=True)
class Identity:
    device_type: int | None
    vendor: int | None
    product: int | None
    name: str | None


def _builtin_identities() -> dict[str, Identity]:
    out = {}
    for name in builtin_profiles():
        od = load_profile(name).od

        def default(index: int, sub: int | None = None, od: Any = od) -> Any:
            try:
                return (od[index] if sub is None else od[index][sub]).default
            except KeyError:
                return None

        out[name] = Identity(default(0x1000), default(0x1018, 1), default(0x1018, 2), default(0x1008))
    return out


def matching_profile(f: Found, identities: dict[str, Identity] | None = None) -> str | None:
    """The built-in profile whose EDS identity fits the node best (device type and vendor must
    match; then the product code unless the EDS leaves it open, then the device name)."""
    best, best_score = None, 0
    for name, ident in (identities or _builtin_identities()).items():
        if f.device_type is None or ident.device_type != f.device_type or ident.vendor != f.vendor:
            continue
        score = 1
        if ident.product not in (None, 0xFFFFFFFF, 0x0FFFFFFF) and ident.product == f.product:
            score += 1
        if ident.name and f.name and ident.name == f.name:
            score += 2
        if score > best_score:
            best, best_score = name, score
    return best


def device_type_text(value: int | None) -> str:
    if value is None:
        return "-"
    profile = value & 0xFFFF
    return f"0x{value:08X} ({PROFILE_NAMES.get(profile, f'profile {profile}')})"


def _hex(value: int | None) -> str:
    return "-" if value is None else f"0x{value:08X}"


def report(found: dict[int, Found], cfg: Config, active: bool, beside: bool = False) -> list[str]:
    """The scan as lines: one per node found, then the configured nodes that were not found.
    ``beside``: the scan ran on the gateway's own connection (``scan_beside``), which does not
    receive what the gateway sends: a node found with its ``master.node_id`` is another one."""
    configured = {n.node_id: n for n in cfg.nodes}
    identities = _builtin_identities() if active else {}
    lines = [
        f"{'id':>3}  {'state':<25} {'device type':<28} {'vendor':<10} {'product':<10} "
        f"{'name':<12} match"
    ]
    for node_id in sorted(found):
        f = found[node_id]
        profile = matching_profile(f, identities) if active else None
        match = []
        if profile:
            match.append(f"profile {profile}")
        n = configured.get(node_id)
        if node_id == cfg.master.node_id and n is None:
            match.append(
                f"not the gateway but another node with its master.node_id {node_id}: a node id conflict"
                if beside
                else f"a master with this config's master.node_id {node_id} (the gateway?)"
            )
        elif n is not None:
            agrees = profile is None or n.profile in (None, profile)
            match.append(
                f"config node {n.name} ({n.device})" + ("" if agrees else f", but the device looks like {profile}")
            )
        else:
            match.append("not in the config")
        lines.append(
            f"{node_id:>3}  {(f.state or '-'):<25} {device_type_text(f.device_type):<28} "
            f"{_hex(f.vendor):<10} {_hex(f.product):<10} {(f.name or '-'):<12} {'; '.join(match)}"
        )
    silent = [n for node_id, n in sorted(configured.items()) if node_id not in found]
    for n in silent:
        lines.append(f"{n.node_id:>3}  not found: config node {n.name} ({n.device})")
    unknown = set(found) - set(configured) - {cfg.master.node_id}
    if silent and unknown:
        others = ", ".join(str(i) for i in sorted(unknown))
        lines.append(f"configured but not found: {', '.join(n.name for n in silent)}; "
                     f"found but not configured: node id {others} (a wrong node_id?)")  # fmt: skip
    if not found:
        lines.append("no node found" + ("" if active else " (try --active: nodes without a heartbeat)"))
    return lines
