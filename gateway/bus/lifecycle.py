"""The life of one node as the master sees it: waiting, booting, configuring, operational.

Rule 1: every decision about when to configure a node, which SDO write comes next, when to
retry a failed write and when to start the node lives here, in the table of ``NodeLifecycle``.
Rule 2: nothing here does I/O or reads a clock. The driver asks ``next_action(now)`` what to do
(an SDO write, an NMT command, or wait), does it, and reports the outcome
(``on_step_result``, ``on_nmt_sent``); it also reports what it observed (``on_bootup``,
``on_found``, ``on_lost``) and calls ``poll(now)`` for the boot timeout. Every event method
returns the list of changes it caused.

``build_boot_steps`` derives the ordered configuration from a device profile and the node's
settings (supervision, TPDO transmission, PDO remapping, the profile's and the user's writes).

Imports: gateway.objref, gateway.bus.sdo_text, gateway.profiles (schema and LoadedProfile, for
the step builder) and the standard library. Must not import python-can, asyncio, logging, config or any northbound
module.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from typing import TYPE_CHECKING, Any, Literal, NamedTuple, Protocol

from gateway.bus.sdo_text import abort_text
from gateway.eds.pdos import default_value
from gateway.objref import ObjRef
from gateway.profiles.layout import pdo_cob_id, pdo_objects
from gateway.profiles.schema import Pdo, default_cob_id

if TYPE_CHECKING:
    from gateway.profiles import LoadedProfile

# --------------------------------------------------------------------------- steps

_PACK: dict[str, str] = {
    "bool": "<B",  # DS-301 BOOLEAN travels as one byte in an SDO
    "int8": "<b",
    "uint8": "<B",
    "int16": "<h",
    "uint16": "<H",
    "int32": "<i",
    "uint32": "<I",
    "int64": "<q",
    "uint64": "<Q",
    "float32": "<f",
}

#: canopen / DS-301 data type codes -> profile type names.
OD_TYPE_NAMES: dict[int, str] = {
    0x0001: "bool",
    0x0002: "int8",
    0x0003: "int16",
    0x0004: "int32",
    0x0005: "uint8",
    0x0006: "uint16",
    0x0007: "uint32",
    0x0008: "float32",
    0x0009: "string",
    0x000A: "bytes",
    0x0010: "int24",
    0x0015: "int64",
    0x0016: "uint24",
    0x001B: "uint64",
}


def encode_value(value: int | float | str | bytes, type_: str) -> bytes:
    """Little-endian bytes of ``value`` as DS-301 type ``type_`` (profile type names)."""
    if isinstance(value, bytes):
        return value
    if type_ in ("string", "bytes"):
        return str(value).encode("ascii")
    if type_ in ("int24", "uint24"):
        return int(value).to_bytes(3, "little", signed=type_ == "int24")
    fmt = _PACK.get(type_)
    if fmt is None:
        raise ValueError(f"unknown type {type_!r}")
    try:
        return struct.pack(fmt, float(value) if type_ == "float32" else int(value))
    except struct.error:
        raise ValueError(f"value {value!r} does not fit {type_}") from None


def decode_value(data: bytes, type_: str) -> Any:
    """The value of an SDO upload's bytes as DS-301 type ``type_`` (profile type names).

    Strings are cut at the first trailing NUL (the SGH10 pads 1008h, manual 4.4.1.4)."""
    if type_ == "string":
        return data.rstrip(b"\0").decode("ascii", errors="replace")
    if type_ == "bytes":
        return data
    if type_ in ("int24", "uint24"):
        return int.from_bytes(data[:3], "little", signed=type_ == "int24")
    fmt = _PACK[type_]
    size = struct.calcsize(fmt)
    return struct.unpack(fmt, data[:size].ljust(size, b"\0"))[0]


@dataclass(frozen=True)
class ConfigStep:
    """One SDO download of the boot configuration."""

    object: ObjRef
    value: int | float | str
    type: str  # profile type name: uint8, uint16, uint32, int32, string, ...
    description: str = ""
    optional: bool = False  # a refusal (SDO abort) is reported and the step skipped
    #: the node config key it comes from, e.g. "heartbeat_ms", "tpdo.1.mapping" (for messages)
    source: str = field(default="", compare=False)

    @property
    def data(self) -> bytes:
        """The bytes of the download (little endian, as DS-301 sends them)."""
        return encode_value(self.value, self.type)

    @property
    def size(self) -> int:
        return len(self.data)

    def __str__(self) -> str:
        v = self.value
        shown = (
            f"{v} (0x{v:X})"
            if isinstance(v, int) and v > 9
            else repr(v)
            if isinstance(v, str)
            else v
        )
        text = f"{self.object} = {shown} {self.type}"
        return f"{text}: {self.description}" if self.description else text


# --------------------------------------------------------------------------- machine


class LifecycleState(StrEnum):
    WAITING = "waiting"  # not seen yet, or lost: waiting for a boot-up / to be found
    BOOTING = "booting"  # seen; an NMT command must go out before configuring
    CONFIGURING = "configuring"  # applying the SDO steps
    OPERATIONAL = "operational"  # configured and NMT start sent


@dataclass(frozen=True)
class Backoff:
    """Exponential retry delay: ``initial_s * factor ** (attempt - 1)``, capped at ``max_s``."""

    initial_s: float = 0.5
    factor: float = 2.0
    max_s: float = 30.0

    def delay_s(self, attempt: int) -> float:
        if attempt < 1:
            return 0.0
        return min(self.max_s, self.initial_s * self.factor ** (attempt - 1))


# -- actions (what the driver must do); NamedTuples so ``action[0]`` is the kind


class Wait(NamedTuple):
    """Nothing to do for ``seconds`` (a retry is scheduled)."""

    kind: Literal["wait"]
    seconds: float


class WriteStep(NamedTuple):
    """Download ``step`` (SDO) and report with ``on_step_result(..., token=token)``."""

    kind: Literal["sdo"]
    step: ConfigStep
    index: int
    token: int


class SendNmt(NamedTuple):
    """Send NMT ``command`` to the node (SGH10 manual 4.2.1.2 table 3), then ``on_nmt_sent``."""

    kind: Literal["nmt_preop", "nmt_start"]
    command: int


Action = Wait | WriteStep | SendNmt

#: SGH10 manual 4.2.1.2 table 3 / AP05 manual 5.2.1.2 table 23: NMT command specifiers.
NMT_START = 0x01
NMT_STOP = 0x02
NMT_ENTER_PRE_OPERATIONAL = 0x80
NMT_RESET_NODE = 0x81
NMT_RESET_COMMUNICATION = 0x82

# -- changes (what happened)


@dataclass(frozen=True)
class StateChanged:
    old: LifecycleState
    new: LifecycleState
    reason: str


@dataclass(frozen=True)
class StepFailed:
    """A configuration step failed; it is retried after ``retry_in_s``."""

    index: int
    step: ConfigStep
    abort_code: int | None  # None: no answer (timeout) or the bus refused to send
    attempt: int
    retry_in_s: float
    message: str


@dataclass(frozen=True)
class StepSkipped:
    """An optional step was refused by the device and skipped."""

    index: int
    step: ConfigStep
    abort_code: int
    message: str


@dataclass(frozen=True)
class BootTimeout:
    """The node did not appear within the boot timeout (reported once per waiting period)."""

    waited_s: float


@dataclass(frozen=True)
class WrongDevice:
    """The node found has another device type (1000h) than the profile expects."""

    expected: int
    found: int


@dataclass(frozen=True)
class Configured:
    """All steps done and NMT start sent."""

    duration_s: float


Change = StateChanged | StepFailed | StepSkipped | BootTimeout | WrongDevice | Configured


def _step_error(step: ConfigStep, abort_code: int | None) -> str:
    what = step.description or "configuration step"
    if abort_code is None:
        return f"{step.object} ({what}): no SDO answer"
    return f"{step.object} ({what}): SDO abort 0x{abort_code:08X} ({abort_text(abort_code)})"


class NodeLifecycle:
    """Boot-up handling and configuration of one node (DS-301 NMT; SGH10 manual 4.2).

    ===========  ============================================  ===========  =========================
    state        event                                         next         action / change
    ===========  ============================================  ===========  =========================
    WAITING      start                                         WAITING      boot timeout armed
    WAITING      poll, now > armed + boot timeout              WAITING      BootTimeout (once)
    WAITING      found running (probe of 1000h / supervision)  BOOTING      action: NMT pre-operational
    WAITING      found, 1000h != expected device type          WAITING      WrongDevice
    BOOTING      NMT pre-operational sent                      CONFIGURING  action: step 0
    any          boot-up                                       CONFIGURING  (via BOOTING) action: step 0
    CONFIGURING  step i ok                                     CONFIGURING  action: step i + 1
    CONFIGURING  step i failed (abort / timeout)               CONFIGURING  StepFailed; action: Wait, then step i again
    CONFIGURING  optional step i refused (abort)               CONFIGURING  StepSkipped; action: step i + 1
    CONFIGURING  last step ok                                  CONFIGURING  action: NMT start
    CONFIGURING  NMT start sent                                OPERATIONAL  Configured
    not WAITING  lost (from supervision)                       WAITING      boot timeout re-armed
    ===========  ============================================  ===========  =========================

    After a boot-up the node is PRE-OPERATIONAL (SGH10 manual 4.2.1.1) and configuration starts
    at once. A node found already running may be OPERATIONAL, where COB-IDs and mappings cannot
    be changed (SGH10 manual 4.2.1.1, 4.1): it is first sent to PRE-OPERATIONAL. A boot-up in
    any state restarts the configuration from step 0; an SDO answer still in flight from before
    carries an old token and is ignored. Failed steps are retried with exponential backoff,
    without a limit: ``last_error`` says what fails.
    """

    def __init__(
        self,
        steps: Sequence[ConfigStep],
        *,
        boot_timeout_s: float = 10.0,
        backoff: Backoff | None = None,
        expected_device_type: int | None = None,
    ):
        self.steps: tuple[ConfigStep, ...] = tuple(steps)
        self.boot_timeout_s = boot_timeout_s
        self.backoff = backoff or Backoff()
        self.expected_device_type = expected_device_type
        self.state: LifecycleState = LifecycleState.WAITING
        self.last_error: str | None = None
        self.step_index = 0
        self.attempt = 0  # failures of the current step
        self.boots = 0
        self.losses = 0
        self.configurations = 0
        self.step_failures = 0
        self._token = 0
        self._in_flight: int | None = None  # token of the WriteStep handed out
        self._retry_at: float | None = None
        self._preop_pending = False
        self._boot_deadline: float | None = None
        self._waiting_since: float | None = None
        self._config_started: float | None = None

    # -- queries
    @property
    def boot_deadline_s(self) -> float | None:
        """Last instant before the boot timeout fires (None: not armed or already fired)."""
        return self._boot_deadline

    @property
    def retry_at_s(self) -> float | None:
        return self._retry_at

    def next_deadline(self) -> float | None:
        times = [t for t in (self._boot_deadline, self._retry_at) if t is not None]
        return min(times) if times else None

    def next_action(self, now: float) -> Action | None:
        """What the driver must do now; the same action again until its outcome is reported."""
        if self.state is LifecycleState.BOOTING and self._preop_pending:
            return SendNmt("nmt_preop", NMT_ENTER_PRE_OPERATIONAL)
        if self.state is not LifecycleState.CONFIGURING:
            return None
        if self._retry_at is not None:
            if now < self._retry_at:
                return Wait("wait", self._retry_at - now)
            self._retry_at = None
        if self.step_index >= len(self.steps):
            return SendNmt("nmt_start", NMT_START)
        if self._in_flight is None:
            self._token += 1
            self._in_flight = self._token
        return WriteStep("sdo", self.steps[self.step_index], self.step_index, self._in_flight)

    # -- events
    def start(self, now: float) -> list[Change]:
        """The gateway starts supervising this node: the boot timeout runs from now."""
        self._arm_boot_timeout(now)
        return []

    def poll(self, now: float) -> list[Change]:
        if (
            self.state is LifecycleState.WAITING
            and self._boot_deadline is not None
            and now > self._boot_deadline
        ):
            self._boot_deadline = None
            waited = now - (self._waiting_since if self._waiting_since is not None else now)
            self.last_error = f"node did not appear (no boot-up) within {self.boot_timeout_s:g} s"
            return [BootTimeout(waited)]
        return []

    def on_bootup(self, now: float) -> list[Change]:
        self.boots += 1
        out: list[Change] = []
        if self.state is not LifecycleState.BOOTING:
            out.append(self._to(LifecycleState.BOOTING, "boot-up received"))
        self._preop_pending = False  # SGH10 manual 4.2.1.1: after boot-up it is PRE-OPERATIONAL
        out.append(self._begin_configuring(now, "node is pre-operational after boot-up"))
        return out

    def on_found(self, now: float, device_type: int | None = None) -> list[Change]:
        """The node answers although no boot-up was seen (gateway restarted, cable replugged)."""
        if self.state is not LifecycleState.WAITING:
            return []
        if (
            self.expected_device_type is not None
            and device_type is not None
            and device_type != self.expected_device_type
        ):
            self.last_error = (
                f"device type (1000h) is 0x{device_type:08X}, the profile expects "
                f"0x{self.expected_device_type:08X}: not configured"
            )
            self._boot_deadline = None  # it did appear: no "no boot-up" report on top
            return [WrongDevice(self.expected_device_type, device_type)]
        self._boot_deadline = None
        self._preop_pending = True
        self._reset_progress()
        return [self._to(LifecycleState.BOOTING, "found running")]

    def on_lost(self, now: float) -> list[Change]:
        if self.state is LifecycleState.WAITING:
            return []
        self.losses += 1
        self._preop_pending = False
        self._reset_progress()
        self._arm_boot_timeout(now)
        return [self._to(LifecycleState.WAITING, "lost (supervision)")]

    def on_nmt_sent(self, now: float) -> list[Change]:
        """The NMT command of the last ``SendNmt`` action went out."""
        if self.state is LifecycleState.BOOTING and self._preop_pending:
            self._preop_pending = False
            return [self._begin_configuring(now, "NMT pre-operational sent")]
        if self.state is LifecycleState.CONFIGURING and self.step_index >= len(self.steps):
            self.configurations += 1
            self.last_error = None
            started = self._config_started if self._config_started is not None else now
            return [
                self._to(LifecycleState.OPERATIONAL, "configured, NMT start sent"),
                Configured(now - started),
            ]
        return []

    def on_step_result(
        self,
        now: float,
        ok: bool,
        abort_code: int | None = None,
        token: int | None = None,
    ) -> list[Change]:
        """Outcome of the last ``WriteStep``; ``abort_code`` None with ``ok`` False = timeout.

        A result for another token than the step in flight (e.g. from before a boot-up) is
        ignored. Without a token the result applies to the step in flight.
        """
        if self.state is not LifecycleState.CONFIGURING or self._in_flight is None:
            return []
        if token is not None and token != self._in_flight:
            return []
        self._in_flight = None
        index = self.step_index
        step = self.steps[index]
        if ok:
            self.step_index += 1
            self.attempt = 0
            return []
        message = _step_error(step, abort_code)
        if step.optional and abort_code is not None:
            self.step_index += 1
            self.attempt = 0
            return [StepSkipped(index, step, abort_code, message)]
        self.attempt += 1
        self.step_failures += 1
        delay = self.backoff.delay_s(self.attempt)
        self._retry_at = now + delay
        self.last_error = message
        return [StepFailed(index, step, abort_code, self.attempt, delay, message)]

    # -- internals
    def _to(self, new: LifecycleState, reason: str) -> StateChanged:
        old, self.state = self.state, new
        return StateChanged(old, new, reason)

    def _reset_progress(self) -> None:
        self.step_index = 0
        self.attempt = 0
        self._in_flight = None
        self._retry_at = None

    def _begin_configuring(self, now: float, reason: str) -> StateChanged:
        self._boot_deadline = None
        self._reset_progress()
        self._config_started = now
        return self._to(LifecycleState.CONFIGURING, reason)

    def _arm_boot_timeout(self, now: float) -> None:
        self._waiting_since = now
        self._boot_deadline = now + self.boot_timeout_s


# --------------------------------------------------------------------------- step builder

#: DS-301 communication objects the builder writes (types per DS-301).
OBJ_HEARTBEAT_PRODUCER = ObjRef(0x1017, 0x00)  # UNSIGNED16, ms; SGH10 manual 4.7.2.14
OBJ_GUARD_TIME = ObjRef(0x100C, 0x00)  # UNSIGNED16, ms; SGH10 manual 4.7.2.9
OBJ_LIFE_TIME_FACTOR = ObjRef(0x100D, 0x00)  # UNSIGNED8; SGH10 manual 4.7.2.10
#: DS-301: bit 31 of a PDO COB-ID = PDO not valid (MSK5000 manual 4.3.1.2 step 2).
COB_ID_INVALID = 0x80000000


class WriteLike(Protocol):
    """A profile ``boot.sdo`` entry or a node config ``sdo`` entry."""

    @property
    def object(self) -> ObjRef: ...
    @property
    def value(self) -> Any: ...
    @property
    def type(self) -> str | None: ...


class NodeSettingsLike(Protocol):
    """What the builder reads of a node's configuration (``gateway.config.NodeConfig``)."""

    @property
    def node_id(self) -> int: ...
    @property
    def pdo_variant(self) -> int | None: ...
    @property
    def sdo(self) -> Sequence[Any]: ...


@dataclass
class _Builder:
    lp: LoadedProfile
    steps: list[ConfigStep] = field(default_factory=list)
    derived: set[int] = field(default_factory=set)  # indexes of plain derived writes

    def od_type(self, obj: ObjRef, where: str) -> tuple[str, Any]:
        var = self.lp.od_var(obj)
        if var is None:
            raise ValueError(f"{where}: {obj} is not in {self.lp.eds_path.name}")
        type_name = OD_TYPE_NAMES.get(var.data_type)
        if type_name is None:
            raise ValueError(f"{where}: {obj} has a data type the gateway cannot write")
        return type_name, var

    def add(
        self,
        obj: ObjRef,
        value: int,
        description: str,
        where: str,
        *,
        derived: bool = False,
        source: str = "",
    ) -> None:
        """Add a write computed by the builder, checked against the EDS."""
        type_name, var = self.od_type(obj, where)
        if not var.writable:
            default = var.default
            if default is not None and int(default) == value:
                return  # read-only and already what we want
            raise ValueError(
                f"{where}: {obj} is read-only ({var.access_type}) in {self.lp.eds_path.name}, "
                f"cannot set it to {value}"
            )
        if derived:
            self.derived.add(len(self.steps))
        self.steps.append(ConfigStep(obj, value, type_name, description, source=source))

    def add_explicit(self, w: Any, where: str, source: str = "") -> None:
        """A write from the profile's boot.sdo or the node's sdo list."""
        obj = ObjRef.parse(w.object)
        od_type, var = self.od_type(obj, where)
        if not var.writable:
            raise ValueError(
                f"{where}: {obj} is read-only ({var.access_type}) in {self.lp.eds_path.name}"
            )
        type_name = w.type or od_type
        value = _coerce(w.value, type_name, f"{where} ({obj})")
        note = getattr(w, "note", "") or ""
        self.steps.append(ConfigStep(obj, value, type_name, note or where, source=source))

    def result(self) -> list[ConfigStep]:
        """Steps, dropping derived plain writes that an explicit write sets again later."""
        out = []
        for i, s in enumerate(self.steps):
            if i in self.derived and any(t.object == s.object for t in self.steps[i + 1 :]):
                continue
            out.append(s)
        return out


def _coerce(value: Any, type_name: str, where: str) -> int | float | str:
    """A config/profile value as the number or text to download.

    A text for a numeric type is a number (``"0x10"``) or a 4-character signature such as
    ``"save"`` (1010h) / ``"load"`` (1011h), sent as its ASCII bytes: ``"save"`` is
    0x65766173 little endian (BEI manual, 1010h).
    """
    if type_name in ("string", "bytes"):
        return str(value)
    if isinstance(value, str):
        try:
            return int(value.replace("_", ""), 0)
        except ValueError:
            raw = value.encode("ascii", errors="strict")
            size = len(encode_value(0, type_name))
            if len(raw) != size:
                raise ValueError(
                    f"{where}: {value!r} is neither a number nor a {size}-character signature"
                ) from None
            return int.from_bytes(raw, "little")
    if type_name == "float32":
        return float(value)
    if isinstance(value, float):
        if not value.is_integer():
            raise ValueError(f"{where}: {value} is not an integer ({type_name})")
        return int(value)
    return int(value)


def _mapping_entry(obj: ObjRef, bits: int) -> int:
    """DS-301 mapping entry: index << 16 | sub << 8 | length in bits (MSK5000 manual 4.3.1.2)."""
    return (obj.index << 16) | (obj.sub << 8) | bits


def _pdo_sequence(
    b: _Builder,
    kind: Literal["tpdo", "rpdo"],
    pdo: Pdo,
    comm: int,
    mapping: int,
    node_id: int,
    where: str,
    *,
    params: Sequence[tuple[int, int, str, str]] = (),
    remap: bool = True,
) -> None:
    """The CiA 301 sequence that (re)configures one PDO in PRE-OPERATIONAL (CiA 301 7.5.2.35 ..
    7.5.2.38; MSK5000 manual 4.3.1.2 steps 2-6): COB-ID with bit 31 set (PDO not valid), the
    communication ``params`` (sub, value, description, config key), mapping sub 00h = 0,
    the entries 01h.., sub 00h = n, COB-ID with bit 31 clear. The one builder of this sequence:
    the remappable_tpdo feature and the nodes' ``tpdo:``/``rpdo:`` settings both use it.
    """
    name = f"{kind.upper()}{pdo.number}"
    cob_id = pdo_cob_id(kind, pdo, node_id)
    b.add(ObjRef(comm, 0x01), cob_id | COB_ID_INVALID, f"{name} off (COB-ID bit 31 = 1)", where, source=f"{where}.cob_id")  # fmt: skip
    for sub, value, text, key in params:
        b.add(ObjRef(comm, sub), value, f"{name} {text}", where, source=key)
    if remap:
        b.add(ObjRef(mapping, 0x00), 0, f"{name} mapping off", where, source=f"{where}.mapping")
        for i, e in enumerate(pdo.mapping, start=1):
            b.add(
                ObjRef(mapping, i),
                _mapping_entry(e.object, e.bits),
                f"{name} entry {i}: {e.object}, {e.bits} bit",
                where,
                source=f"{where}.mapping[{i - 1}]",
            )
        b.add(
            ObjRef(mapping, 0x00),
            len(pdo.mapping),
            f"{name} mapping on, {len(pdo.mapping)} entries",
            where,
            source=f"{where}.mapping",
        )
    b.add(ObjRef(comm, 0x01), cob_id, f"{name} on (COB-ID bit 31 = 0)", where, source=f"{where}.cob_id")  # fmt: skip


def build_boot_steps(
    lp: LoadedProfile,
    node: NodeSettingsLike,
    supervision: str | None = None,
    heartbeat_ms: int | None = None,
    guard_time_ms: int | None = None,
    life_time_factor: int | None = None,
) -> list[ConfigStep]:
    """The ordered SDO writes that configure a node at boot.

    1. supervision: producer heartbeat 1017h; or node guarding 100Ch/100Dh with 1017h = 0
       (DS-301: a producer heartbeat time other than 0 takes precedence over guarding);
    2. the external heartbeat objects when the node config asks for it (feature
       ``external_heartbeat``, AP05 manual 5.5.4, 5F09h: source, then interval);
    3. the PDO layout selector when a variant is chosen (feature ``pdo_type_selector``);
    4. per PDO the node's ``tpdo:``/``rpdo:`` settings name: the CiA 301 sequence
       (``_pdo_sequence``): COB-ID with bit 31 set, the parameters given (transmission type,
       inhibit time, event timer, SYNC start), mapping sub 00h = 0, the entries, sub 00h = n,
       COB-ID with bit 31 clear; or only the COB-ID with bit 31 set for ``enabled: false``.
       Per TPDO of the profile's own layout: transmission type 180xh:02 and event timer
       180xh:05; then, when the profile has ``remappable_tpdo`` (or a non-default inhibit
       time), the same sequence (MSK5000 manual 4.3.1.2). PDOs taken from the EDS as they are
       need no writes;
    5. the profile's ``boot.sdo`` writes;
    6. the node config's ``sdo`` writes.

    Derived writes of 1.-4. that 5. or 6. write again are left out (the explicit value wins).
    Objects are checked against the EDS: a missing object or a read-only one the profile wants
    changed raises ValueError naming it. Types come from the EDS (1A00h:00 is UNSIGNED8, so it
    is written with one byte).
    """
    p = lp.profile
    b = _Builder(lp)
    node_id = node.node_id
    supervision = supervision or p.boot.supervision
    hb_ms = p.boot.heartbeat_ms if heartbeat_ms is None else heartbeat_ms
    gt_ms = p.boot.guard_time_ms if guard_time_ms is None else guard_time_ms
    ltf = p.boot.life_time_factor if life_time_factor is None else life_time_factor

    # 1. supervision
    if supervision == "heartbeat":
        b.add(
            OBJ_HEARTBEAT_PRODUCER, hb_ms, "producer heartbeat time (ms)", "heartbeat", derived=True,
            source="heartbeat_ms" if heartbeat_ms is not None else "",
        )  # fmt: skip
    elif supervision == "guarding":
        if lp.od_var(OBJ_HEARTBEAT_PRODUCER) is not None:
            b.add(
                OBJ_HEARTBEAT_PRODUCER,
                0,
                "heartbeat off: node guarding is used",
                "guarding",
                derived=True,
            )
        b.add(OBJ_GUARD_TIME, gt_ms, "guard time (ms)", "guarding", derived=True,
              source="guard_time_ms" if guard_time_ms is not None else "")  # fmt: skip
        b.add(OBJ_LIFE_TIME_FACTOR, ltf, "life time factor", "guarding", derived=True,
              source="life_time_factor" if life_time_factor is not None else "")  # fmt: skip

    # 2. external heartbeat (AP05 manual 5.5.4 / 5.7.2.31)
    ext = getattr(node, "external_heartbeat", None)
    feat = p.features.get("external_heartbeat")
    if ext is not None and ext.interval_ms:
        if feat is None:
            raise ValueError(
                f"external_heartbeat: profile {p.family} has no feature external_heartbeat"
            )
        codes = {str(v): int(k) for k, v in (feat.get("sources") or {0: "rpdo", 1: "sync"}).items()}
        if ext.source not in codes:
            raise ValueError(
                f"external_heartbeat.source: {ext.source!r} not one of {sorted(codes)}"
            )
        b.add(
            ObjRef.parse(feat["source"]),
            codes[ext.source],
            f"external heartbeat source = {ext.source}",
            "external_heartbeat",
            derived=True,
            source="external_heartbeat.source",
        )
        b.add(
            ObjRef.parse(feat["interval"]),
            int(ext.interval_ms),
            "external heartbeat interval (ms)",
            "external_heartbeat",
            derived=True,
            source="external_heartbeat.interval_ms",
        )

    # 3. PDO layout selector (BEI 2005h)
    variant = getattr(node, "pdo_variant", None)
    if p.pdo_variants is not None and variant is not None:
        b.add(
            p.pdo_variants.selector,
            int(variant),
            f"PDO layout variant {variant}",
            "pdo_variant",
            derived=True,
            source="pdo_variant",
        )

    # 4. PDOs. The node's tpdo:/rpdo: settings: the CiA 301 sequence from the node's layout
    #    (gateway.profiles.layout resolved it; the codecs are compiled from the same layout).
    #    The profile's own TPDOs: transmission type and event timer, and the same sequence when
    #    the profile has remappable_tpdo (or a non-default inhibit time).
    tpdos, rpdos = p.layout(variant)
    remap = p.features.get("remappable_tpdo")
    settings: dict[str, Any] = {
        "tpdo": getattr(node, "tpdo", None) or {},
        "rpdo": getattr(node, "rpdo", None) or {},
    }
    for kind, pdos in (("tpdo", tpdos), ("rpdo", rpdos)):
        k: Literal["tpdo", "rpdo"] = kind  # type: ignore[assignment]
        by_number = {x.number: x for x in pdos}
        for number in sorted(set(by_number) | set(settings[k])):
            pdo = by_number.get(number)
            setting = settings[k].get(number)
            comm, mapping = pdo_objects(p, k, number)
            if setting is not None:
                where = f"{k}.{number}"
                if pdo is None:  # enabled: false
                    held = default_value(lp.od_var(ObjRef(comm, 0x01)), node_id)
                    if held is None:
                        held = default_cob_id(k, number) + node_id if number <= 4 else 0
                    b.add(
                        ObjRef(comm, 0x01),
                        int(held) | COB_ID_INVALID,
                        f"{k.upper()}{number} disabled (COB-ID bit 31 = 1)",
                        where,
                        source=f"{where}.enabled",
                    )
                    continue
                params: list[tuple[int, int, str, str]] = []
                if setting.transmission is not None:
                    params.append((0x02, pdo.transmission_type, "transmission type", f"{where}.transmission"))  # fmt: skip
                if k == "tpdo" and setting.inhibit_ms is not None:
                    params.append((0x03, pdo.inhibit_time_100us or 0, "inhibit time (100 us)", f"{where}.inhibit_ms"))  # fmt: skip
                if setting.event_timer_ms is not None:
                    params.append((0x05, pdo.event_timer_ms or 0, "event timer (ms)", f"{where}.event_timer_ms"))  # fmt: skip
                if k == "tpdo" and setting.sync_start is not None:
                    params.append((0x06, pdo.sync_start or 0, "SYNC start value", f"{where}.sync_start"))  # fmt: skip
                _pdo_sequence(b, k, pdo, comm, mapping, node_id, where, params=params,
                              remap=setting.mapping is not None or pdo.origin == "config")  # fmt: skip
                continue
            if k != "tpdo" or pdo is None or pdo.origin != "profile":
                continue  # an EDS PDO as the device holds it: nothing to write
            where = f"tpdos[{pdo.number}]"
            b.add(
                ObjRef(comm, 0x02),
                pdo.transmission_type,
                f"TPDO{pdo.number} transmission type",
                where,
                derived=True,
            )
            if pdo.event_timer_ms is not None:
                b.add(
                    ObjRef(comm, 0x05),
                    pdo.event_timer_ms,
                    f"TPDO{pdo.number} event timer (ms)",
                    where,
                    derived=True,
                )
            inhibit = pdo.inhibit_time_100us
            inhibit_var = lp.od_var(ObjRef(comm, 0x03)) if inhibit is not None else None
            write_inhibit = (
                inhibit is not None
                and inhibit_var is not None
                and not (inhibit_var.default is not None and int(inhibit_var.default) == inhibit)
            )
            if inhibit is not None and inhibit_var is None and inhibit != 0:
                raise ValueError(f"{where}: {ObjRef(comm, 0x03)} is not in {lp.eds_path.name}")
            if not (remap is not None or write_inhibit):
                continue
            inhibit_param = (
                [(0x03, int(inhibit), "inhibit time (100 us)", where)] if write_inhibit else []  # type: ignore[arg-type]
            )
            _pdo_sequence(b, k, pdo, comm, mapping, node_id, where, params=inhibit_param,
                          remap=remap is not None)  # fmt: skip

    # 5. the profile's boot writes, 6. the node's own writes
    for i, w in enumerate(p.boot.sdo):
        b.add_explicit(w, f"profile {p.family} boot.sdo[{i}]")
    for i, w in enumerate(getattr(node, "sdo", ()) or ()):
        b.add_explicit(w, f"node sdo[{i}]", source=f"sdo[{i}]")
    return b.result()
