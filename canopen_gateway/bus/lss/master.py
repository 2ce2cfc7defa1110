"""CiA 305 LSS (layer setting services) master: frame encoders/decoders and request matching.

LSS sets the node id and bit rate of a device over the bus, addressed by its LSS address (the
identity object 1018h). Frames are always 8 bytes, byte 0 the command specifier (cs), unused
bytes 00h (SGH10 manual 4.6). The master sends on 7E5h, slaves answer on 7E4h.

Rule 1: every LSS frame the gateway sends or reads is built or parsed here, each service next to
its manual section (the numbers of the protocol, shared with the simulated slave, are
``cia305``'s).
Rule 2: no I/O, no clock. ``LssMaster.send`` returns the frames to put on 7E5h; the caller feeds
7E4h frames to ``on_frame`` and calls ``poll(now)`` for the answer timeout.

Imports: canopen_gateway.canopen.cia301 (the LSS COB-IDs), canopen_gateway.canopen.cia305 (the command specifiers, the bit
timing table, the frame layout) and the standard library. Must not import python-can, canopen
or other gateway modules.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from enum import StrEnum

from canopen_gateway.canopen.cia301 import COB_LSS_MASTER, COB_LSS_SLAVE
from canopen_gateway.canopen.cia305 import (
    BIT_TIMING_KBPS,
    BIT_TIMING_TABLE_DS301,
    CS_ACTIVATE_BIT_TIMING,
    CS_CONFIGURE_BIT_TIMING,
    CS_CONFIGURE_NODE_ID,
    CS_INQUIRE_NODE_ID,
    CS_INQUIRE_PRODUCT_CODE,
    CS_INQUIRE_REVISION,
    CS_INQUIRE_SERIAL,
    CS_INQUIRE_VENDOR_ID,
    CS_STORE_CONFIGURATION,
    CS_SWITCH_GLOBAL,
    CS_SWITCH_SELECTIVE_ANSWER,
    CS_SWITCH_SELECTIVE_PRODUCT,
    CS_SWITCH_SELECTIVE_REVISION,
    CS_SWITCH_SELECTIVE_SERIAL,
    CS_SWITCH_SELECTIVE_VENDOR,
    MODE_CONFIGURATION,
    MODE_WAITING,
    lss_frame,
)

#: SGH10 manual 4.6: "LSS (rx) (LSS master -> SGH10): 7E5h", "LSS (tx) (SGH10 -> master): 7E4h".
COB_ID_MASTER_TO_SLAVE = COB_LSS_MASTER
COB_ID_SLAVE_TO_MASTER = COB_LSS_SLAVE

#: Error codes of the configure / store answers (4.6.2.1, 4.6.2.2, 4.6.2.4).
_CONFIG_ERRORS: dict[int, dict[int, str]] = {
    CS_CONFIGURE_NODE_ID: {0x01: "no valid node id (01h..7Fh)"},
    CS_CONFIGURE_BIT_TIMING: {0x01: "no valid baud rate (bit timing not supported)"},
    CS_STORE_CONFIGURATION: {
        0x01: "store configuration is not supported",
        0x02: "error occurred during storing",
    },
}
_IMPLEMENTATION_ERROR = 0xFF

SERVICE_NAMES: dict[int, str] = {
    CS_SWITCH_GLOBAL: "switch state global",
    CS_SWITCH_SELECTIVE_ANSWER: "switch state selective",
    CS_CONFIGURE_NODE_ID: "configure node id",
    CS_CONFIGURE_BIT_TIMING: "configure bit timing",
    CS_ACTIVATE_BIT_TIMING: "activate bit timing",
    CS_STORE_CONFIGURATION: "store configuration",
    CS_INQUIRE_VENDOR_ID: "inquire vendor id",
    CS_INQUIRE_PRODUCT_CODE: "inquire product code",
    CS_INQUIRE_REVISION: "inquire revision number",
    CS_INQUIRE_SERIAL: "inquire serial number",
    CS_INQUIRE_NODE_ID: "inquire node id",
}


def bit_timing_index(kbps: int) -> int:
    """Table index of a bit rate in the DS-301 table (SGH10 manual 4.6.2.2)."""
    for index, rate in BIT_TIMING_KBPS.items():
        if rate == kbps:
            return index
    raise ValueError(
        f"{kbps} kbit/s is not in the CiA 305 bit timing table "
        f"({', '.join(str(r) for r in BIT_TIMING_KBPS.values())} kbit/s)"
    )


# --------------------------------------------------------------------------- requests


class LssMode(StrEnum):
    """The LSS state the master has put the slave(s) in (SGH10 manual 4.6, Table 10)."""

    WAITING = (
        "waiting"  # after power-on (manual 4.6: "the device will be in the LSS waiting state")
    )
    CONFIGURATION = "configuration"


@dataclass(frozen=True)
class LssRequest:
    """One LSS service: the frames to send on 7E5h and the cs of the expected answer."""

    service: str
    frames: tuple[bytes, ...]
    answer_cs: int | None  # None: the slaves do not answer
    needs_configuration: bool  # SGH10 manual 4.6 Table 10: only in LSS configuration state


def switch_state_global(configuration: bool) -> LssRequest:
    """04h mode: all slaves to LSS configuration (01h) or waiting (00h); no answer (4.6.1.1)."""
    mode = MODE_CONFIGURATION if configuration else MODE_WAITING
    return LssRequest(
        "switch state global", (lss_frame(CS_SWITCH_GLOBAL, bytes([mode])),), None, False
    )


def switch_state_selective(
    vendor_id: int, product_code: int, revision: int, serial: int
) -> LssRequest:
    """40h..43h with the four parts of the LSS address (1018h:01..04, each UNSIGNED32 LE,
    bytes 1-4); the addressed slave answers 44h (4.6.1.2)."""
    frames = tuple(
        lss_frame(cs, struct.pack("<I", value))
        for cs, value in (
            (CS_SWITCH_SELECTIVE_VENDOR, vendor_id),
            (CS_SWITCH_SELECTIVE_PRODUCT, product_code),
            (CS_SWITCH_SELECTIVE_REVISION, revision),
            (CS_SWITCH_SELECTIVE_SERIAL, serial),
        )
    )
    return LssRequest("switch state selective", frames, CS_SWITCH_SELECTIVE_ANSWER, False)


def configure_node_id(node_id: int) -> LssRequest:
    """11h NID, NID 01h..7Fh (4.6.2.1); answer 11h error code, spec error."""
    if not 1 <= node_id <= 127:
        raise ValueError(f"node id {node_id} out of range 1..127 (SGH10 manual 4.6.2.1)")
    return LssRequest(
        "configure node id",
        (lss_frame(CS_CONFIGURE_NODE_ID, bytes([node_id])),),
        CS_CONFIGURE_NODE_ID,
        True,
    )


def configure_bit_timing(index: int, table: int = BIT_TIMING_TABLE_DS301) -> LssRequest:
    """13h table selector, table index (4.6.2.2); answer 13h error code, spec error."""
    if table == BIT_TIMING_TABLE_DS301 and index not in BIT_TIMING_KBPS:
        raise ValueError(
            f"bit timing index {index} is not in the DS-301 table "
            f"(indices {sorted(BIT_TIMING_KBPS)}; 5 is reserved)"
        )
    if not 0 <= index <= 0xFF or not 0 <= table <= 0xFF:
        raise ValueError("table selector and index are one byte each")
    return LssRequest(
        "configure bit timing",
        (lss_frame(CS_CONFIGURE_BIT_TIMING, bytes([table, index])),),
        CS_CONFIGURE_BIT_TIMING,
        True,
    )


def activate_bit_timing(switch_delay_ms: int) -> LssRequest:
    """15h switch delay (UNSIGNED16 LE, ms): the slave switches after d1 and boots after d2,
    both of this length, and is silent meanwhile (4.6.2.3); no answer."""
    if not 0 <= switch_delay_ms <= 0xFFFF:
        raise ValueError(f"switch delay {switch_delay_ms} ms out of range 0..65535")
    return LssRequest(
        "activate bit timing",
        (lss_frame(CS_ACTIVATE_BIT_TIMING, struct.pack("<H", switch_delay_ms)),),
        None,
        True,
    )


def store_configuration() -> LssRequest:
    """17h (4.6.2.4); answer 17h error code, spec error. Only one slave may be in
    configuration state."""
    return LssRequest(
        "store configuration",
        (lss_frame(CS_STORE_CONFIGURATION),),
        CS_STORE_CONFIGURATION,
        True,
    )


_INQUIRE = {
    "vendor_id": CS_INQUIRE_VENDOR_ID,
    "product_code": CS_INQUIRE_PRODUCT_CODE,
    "revision": CS_INQUIRE_REVISION,
    "serial": CS_INQUIRE_SERIAL,
    "node_id": CS_INQUIRE_NODE_ID,
}


def inquire(what: str) -> LssRequest:
    """5Ah vendor id, 5Bh product code, 5Ch revision, 5Dh serial, 5Eh node id (4.6.3); the
    answer repeats the cs with the value (UNSIGNED32 LE in bytes 1-4, node id in byte 1)."""
    cs = _INQUIRE.get(what)
    if cs is None:
        raise ValueError(f"cannot inquire {what!r}; one of {', '.join(_INQUIRE)}")
    return LssRequest(SERVICE_NAMES[cs], (lss_frame(cs),), cs, True)


# --------------------------------------------------------------------------- answers


@dataclass(frozen=True)
class ConfigAnswer:
    """Answer of configure node id / configure bit timing / store configuration."""

    cs: int
    error_code: int
    spec_error: int

    @property
    def ok(self) -> bool:
        return self.error_code == 0x00

    @property
    def text(self) -> str:
        if self.ok:
            return "ok"
        if self.error_code == _IMPLEMENTATION_ERROR:
            return f"implementation-specific error, spec error 0x{self.spec_error:02X}"
        known = _CONFIG_ERRORS.get(self.cs, {}).get(self.error_code)
        return known or f"error code 0x{self.error_code:02X}"


LssValue = ConfigAnswer | int | None


def decode_answer(data: bytes) -> tuple[int, LssValue]:
    """(cs, value) of a 7E4h frame: a ConfigAnswer, an inquired number, or None for 44h."""
    if len(data) < 1:
        raise ValueError("empty LSS frame")
    d = bytes(data).ljust(8, b"\0")
    cs = d[0]
    if cs in (CS_CONFIGURE_NODE_ID, CS_CONFIGURE_BIT_TIMING, CS_STORE_CONFIGURATION):
        return cs, ConfigAnswer(cs, d[1], d[2])
    if CS_INQUIRE_VENDOR_ID <= cs <= CS_INQUIRE_SERIAL:
        return cs, struct.unpack_from("<I", d, 1)[0]
    if cs == CS_INQUIRE_NODE_ID:
        return cs, d[1]
    if cs == CS_SWITCH_SELECTIVE_ANSWER:
        return cs, None
    raise ValueError(f"unknown LSS answer command specifier 0x{cs:02X}")


# --------------------------------------------------------------------------- master machine


#: what ``inquire`` asks, in the order a session asks it (CiA 305 inquire services)
INQUIRE_ORDER = ("vendor_id", "product_code", "revision", "serial", "node_id")


class LssStateError(Exception):
    """A service was requested in an LSS state where the slave ignores it (Table 10)."""


class LssBusy(Exception):
    """Another request is still waiting for its answer."""


@dataclass(frozen=True)
class LssAnswered:
    request: LssRequest
    value: LssValue


@dataclass(frozen=True)
class LssTimedOut:
    request: LssRequest
    timeout_s: float


@dataclass(frozen=True)
class LssIgnored:
    """A 7E4h frame that answers nothing pending (late, duplicate, or another master's)."""

    data: bytes
    reason: str


LssEvent = LssAnswered | LssTimedOut | LssIgnored


class LssMaster:
    """One LSS request at a time, matched to its answer, with a timeout.

    =================  ====================================  ============  ====================
    pending            event                                 next          output
    =================  ====================================  ============  ====================
    none               send (answer expected)                request       frames for 7E5h
    none               send (no answer: 04h, 15h)            none          frames for 7E5h
    request            send                                  request       LssBusy raised
    request            7E4h frame with the expected cs       none          LssAnswered
    request            7E4h frame with another cs            request       LssIgnored
    none               7E4h frame                            none          LssIgnored
    request            poll, now > sent + timeout            none          LssTimedOut
    =================  ====================================  ============  ====================

    ``mode`` is the LSS state the master has put the slaves in: switch global sets it, a
    confirmed selective switch sets configuration. Services Table 10 allows only in the
    configuration state raise ``LssStateError`` in the waiting state instead of being sent to
    slaves that would ignore them.
    """

    def __init__(self, timeout_s: float = 1.0):
        if timeout_s <= 0:
            raise ValueError("timeout_s must be > 0")
        self.timeout_s = timeout_s
        self.mode: LssMode = LssMode.WAITING
        self.pending: LssRequest | None = None
        self.sent_at_s: float | None = None
        self.timeouts = 0

    @property
    def deadline_s(self) -> float | None:
        if self.pending is None or self.sent_at_s is None:
            return None
        return self.sent_at_s + self.timeout_s

    def next_deadline(self) -> float | None:
        return self.deadline_s

    def resume(self, mode: LssMode) -> None:
        """The slaves are already in ``mode``: a previous session left them there (the CLI
        keeps what each command leaves behind, see ``canopen_gateway.tools.lss``)."""
        self.mode = mode

    def send(self, request: LssRequest, now: float) -> list[bytes]:
        """The frames to send on 7E5h for ``request``, in order."""
        if self.pending is not None:
            raise LssBusy(f"LSS {self.pending.service} is still waiting for its answer")
        if request.needs_configuration and self.mode is not LssMode.CONFIGURATION:
            raise LssStateError(
                f"LSS {request.service} needs the LSS configuration state (SGH10 manual 4.6, "
                "Table 10); switch state global or selective first"
            )
        if request.frames[0][0] == CS_SWITCH_GLOBAL:
            mode = request.frames[0][1]
            self.mode = LssMode.CONFIGURATION if mode == MODE_CONFIGURATION else LssMode.WAITING
        if request.answer_cs is not None:
            self.pending = request
            self.sent_at_s = now
        return list(request.frames)

    def on_frame(self, data: bytes, now: float) -> list[LssEvent]:
        """A frame received on 7E4h."""
        data = bytes(data)
        if self.pending is None:
            return [LssIgnored(data, "no LSS request pending")]
        if not data or data[0] != self.pending.answer_cs:
            return [LssIgnored(data, f"not an answer to {self.pending.service}")]
        try:
            _cs, value = decode_answer(data)
        except ValueError as exc:
            return [LssIgnored(data, str(exc))]
        request = self.pending
        self.pending = None
        self.sent_at_s = None
        if data[0] == CS_SWITCH_SELECTIVE_ANSWER:
            self.mode = LssMode.CONFIGURATION
        return [LssAnswered(request, value)]

    def cancel(self) -> None:
        """Forget the pending request (its answer, if one comes, is ignored)."""
        self.pending = None
        self.sent_at_s = None

    def poll(self, now: float) -> list[LssEvent]:
        deadline = self.deadline_s
        if deadline is not None and now > deadline and self.pending is not None:
            request = self.pending
            self.pending = None
            self.sent_at_s = None
            self.timeouts += 1
            return [LssTimedOut(request, self.timeout_s)]
        return []
