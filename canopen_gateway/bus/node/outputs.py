"""A node's output image: the last values sent in each RPDO, bits included, and the frames
that carry them.

The node's working copy of its output values (the process image's output section is the copy
``Node`` makes after each change, read north). ``set`` changes values (all RPDOs mapping a
signal, or one RPDO) once every RPDO they touch encodes (a value an RPDO entry cannot carry
changes nothing); ``frame`` encodes an RPDO, with the guarding bit the link check asks for
(AP05 manual 5.5.5: control-word bit 8 toggles only when the previous toggle was echoed); the
keep-alive re-sends the last RPDO when none went out for ``keepalive_s`` (AP05 manual 5.5.4
external heartbeat fed by RPDOs; the guarding bit exercised when the PLC writes nothing).

In a hot-standby pair (``pair``) the bus carries every RPDO's content, so that the standby,
which learns the outputs from the frames it hears (``heard``, field for field), knows each
RPDO as the active gateway would send it, whenever it was started:

* a write that changes an RPDO it does not send (a signal mapped in several RPDOs, the AP05
  control word of RPDO1 and RPDO2) sends that RPDO too, right after the one it sends;
* the keep-alive goes round the RPDOs, each in turn, instead of repeating the last;
* an RPDO this gateway neither sent nor heard is ``unknown``: the keep-alive never sends it
  (the device holds the old active gateway's values, not our defaults); a signal it shares
  with an RPDO heard is kept from that one, so that a write of its other signals sends what
  the device was last told;
* ``heard`` says whether the frame shows a write (content changed but the guarding bit, or
  sooner than a keep-alive comes): the output watchdog of a member that takes over counts
  from the last one (``published``' times);
* what another master may have sent since is not known (``forget``: a member back from its own
  outage, or one that met another master while the node was out of its hands): every RPDO is
  unknown again until heard or written; a node a member resumes (lost while it ran, heard
  running again) holds its keep-alive a moment (``hold``), in which a healed split resolves.

It also keeps the record of the writes (``published``: the values of each RPDO, the time of
the last write, the number of writes) that the node puts in the process image.

Imports: pdo.codec, bus.events, bus.error_control.guarding_bit (the guarding-bit check),
errors, image (the record). No I/O.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from canopen_gateway.bus.error_control.guarding_bit import GuardingBitCheck
from canopen_gateway.bus.events import Send
from canopen_gateway.errors import Unmapped, ValueOutOfRange
from canopen_gateway.image import SentOutputs
from canopen_gateway.pdo.codec import FieldValueError, RpdoCodec, TpdoCodec

#: an RPDO heard sooner than this share of the keep-alive period after the node's previous
#: one is no keep-alive (those come a full period apart): a write
KEEPALIVE_EARLY = 0.9


class OutputImage:
    def __init__(
        self,
        node: str,
        rpdos: Sequence[RpdoCodec],
        keepalive_s: float = 0.0,
        gbit: GuardingBitCheck | None = None,
        control: tuple[str, int] | None = None,  # (control word signal, guarding bit number)
        *,
        pair: bool = False,
    ):
        self.node = node
        self.rpdos = list(rpdos)
        self.values: dict[int, list[Any]] = {r.number: r.initial_values() for r in self.rpdos}
        self.by_signal: dict[str, list[RpdoCodec]] = {}
        for r in self.rpdos:
            for n in r.names:
                self.by_signal.setdefault(n, []).append(r)
        self.keepalive_s = keepalive_s
        self.gbit = gbit
        self.control = control
        self.last_sent_s: dict[int, float] = {}
        self.sent = 0
        self.pair = pair
        #: RPDO numbers whose content this gateway neither sent nor heard (a pair's member
        #: until it hears them, or configures the node itself: ``own``)
        self.unknown: set[int] = {r.number for r in self.rpdos} if pair else set()
        self._resume_s: float | None = None  # a keep-alive due at once (``resume``)
        self.hold_until_s: float | None = None  # no keep-alive before (``hold``)
        self._record = SentOutputs({})
        #: the RPDOs by COB-ID, each with a decoder of its frames (a pair's standby learns the
        #: outputs from the frames the active gateway sends)
        self._heard = {r.cob_id: (r, TpdoCodec(r.cob_id, r.number, r.fields)) for r in self.rpdos}

    @property
    def cob_ids(self) -> tuple[int, ...]:
        return tuple(self._heard)

    def knows(self, cob_id: int) -> bool:
        """The content of the RPDO on ``cob_id`` is known here (sent or heard); False for an
        unknown one, or not an RPDO of this node."""
        entry = self._heard.get(cob_id)
        return entry is not None and entry[0].number not in self.unknown

    def heard(self, cob_id: int, data: bytes, now: float) -> bool | None:
        """An RPDO frame another master sent at ``now``: its values become the output image's,
        as if sent here. Returns whether it shows a write (see the module docstring); None:
        not one of ours, or shorter than its mapping."""
        entry = self._heard.get(cob_id)
        if entry is None:
            return None
        codec, decoder = entry
        try:
            named = iter(decoder.decode(data))
        except ValueError:
            return None
        number = codec.number
        old = self.values[number]
        values = [next(named) if f.signal else old[i] for i, f in enumerate(codec.fields)]
        previous = max(self.last_sent_s.values(), default=None)
        wrote = (
            not self.keepalive_s
            or (number not in self.unknown and self.masked(codec, old) != self.masked(codec, values))
            or (previous is not None and now - previous < KEEPALIVE_EARLY * self.keepalive_s)
        )
        self.values[number] = values
        self.unknown.discard(number)
        self.last_sent_s[number] = now
        self._share(codec, values)
        if self.gbit is not None and self.control is not None:
            i = codec.index_of(self.control[0])
            if i is not None:  # the link check follows the bit the other master sent
                self.gbit.heard((int(values[i]) >> self.control[1]) & 1, now)
        return wrote

    def content(self, number: int) -> list[Any]:
        """RPDO ``number``'s values as a write sets them (the guarding bit, the gateway's, 0)."""
        return self.masked(self._codec(number), self.values[number])

    def masked(self, codec: RpdoCodec, values: list[Any]) -> list[Any]:
        """``values`` of ``codec``'s RPDO with the guarding bit (the gateway's) masked out."""
        i = codec.index_of(self.control[0]) if self.control is not None else None
        if i is None or self.control is None:
            return values
        masked = list(values)
        masked[i] = int(masked[i]) & ~(1 << self.control[1])
        return masked

    def _share(self, codec: RpdoCodec, values: list[Any]) -> None:
        """The signals of an RPDO heard, into the unknown RPDOs that map them too."""
        for other in self.rpdos:
            if other.number in self.unknown:
                mine = self.values[other.number]
                for name in other.names:
                    i = codec.index_of(name)
                    if i is not None:
                        mine[other.index_of(name)] = values[i]  # type: ignore[index]

    def is_output(self, name: str) -> bool:
        return name in self.by_signal

    def get(self, name: str, pdo: int | None = None) -> Any:
        """The last value sent for ``name`` (in RPDO ``pdo``, default: the last one)."""
        codecs = self.by_signal.get(name)
        if not codecs:
            raise Unmapped(f"node {self.node}: {name} is not in an RPDO")
        codec = next((c for c in codecs if c.number == pdo), codecs[-1])
        return self.values[codec.number][codec.index_of(name)]  # type: ignore[index]

    def set(self, per_pdo: dict[int | None, dict[str, Any]]) -> list[int]:
        """Change values; returns the RPDO numbers to send.

        Every RPDO the change touches is encoded first: a value one of them cannot carry (out
        of the range of its mapped width) raises ValueOutOfRange and changes nothing.

        ``per_pdo[None]`` applies to every RPDO mapping the signal, ``per_pdo[n]`` to RPDO n
        only. The RPDOs to send: those carrying a signal mapped only there (or named by n); a
        signal mapped in several RPDOs (a shared control word) alone goes out in the last. In a
        pair, every other RPDO whose content the change alters goes out after them."""
        names = [n for vals in per_pdo.values() for n in vals]
        for n in names:
            if n not in self.by_signal:
                raise Unmapped(f"node {self.node}: {n} is not in an RPDO")
        numbers: list[int] = []
        for pdo, vals in per_pdo.items():
            for n in vals:
                cs = self.by_signal[n]
                if pdo is not None:
                    numbers.append(pdo)
                elif len(cs) == 1:
                    numbers.append(cs[0].number)
        if not numbers and names:
            numbers.append(self.by_signal[names[0]][-1].number)
        new: dict[int, list[Any]] = {}
        for pdo, vals in per_pdo.items():
            for n, v in vals.items():
                for c in self.by_signal[n]:
                    if pdo is None or c.number == pdo:
                        new.setdefault(c.number, list(self.values[c.number]))[c.index_of(n)] = v  # type: ignore[index]
        for number, values in new.items():  # every changed RPDO encodes before any changes
            try:
                self._codec(number).encode(values)
            except FieldValueError as exc:
                raise ValueOutOfRange(exc.field.signal or str(exc.field.obj), exc.value, exc.allowed) from None
        changed = sorted(
            n for n, v in new.items()
            if n not in numbers and self.masked(self._codec(n), v) != self.masked(self._codec(n), self.values[n])
        )  # fmt: skip
        self.values.update(new)
        self.unknown -= set(new)
        # in a pair, an RPDO the write changed but does not send goes out too (the standby
        # hears every RPDO's content)
        return sorted(set(numbers)) + (changed if self.pair else [])

    def _codec(self, number: int) -> RpdoCodec:
        return next(c for c in self.rpdos if c.number == number)

    def snapshot(self) -> dict[int, tuple[Any, ...]]:
        """The values of every RPDO, immutable (for the process image's output section)."""
        return {n: tuple(v) for n, v in self.values.items()}

    def published(self, written: tuple[float, float] | None = None) -> SentOutputs:
        """The record of the output image as set now (for the process image's output section):
        ``written`` (wall-clock, bus-clock time) counts one more write; without it, the times
        and count of the last write stay."""
        record = self._record
        if written is not None:
            record = SentOutputs({}, written[0], written[1], record.seq + 1)
        self._record = record._replace(rpdos=self.snapshot())
        return self._record

    def frame(self, number: int, now: float) -> Send:
        """RPDO ``number`` as it goes out now (guarding bit applied)."""
        codec = self._codec(number)
        values = self.values[number]
        if self.gbit is not None and self.control is not None:
            i = codec.index_of(self.control[0])
            if i is not None:
                bit = self.control[1]
                values[i] = (int(values[i]) & ~(1 << bit)) | (self.gbit.next_bit(now) << bit)
        self.last_sent_s[number] = now
        self.unknown.discard(number)
        self._resume_s = self.hold_until_s = None
        self.sent += 1
        return Send(codec.cob_id, codec.encode(values), rpdo=True)

    def own(self) -> None:
        """This gateway configured the node: every RPDO's content is its own."""
        self.unknown.clear()

    def forget(self) -> None:
        """Another master may have sent anything since: every RPDO is unknown until heard or
        written (the keep-alive sends none of them meanwhile)."""
        self.unknown = {r.number for r in self.rpdos}
        self._resume_s = self.hold_until_s = None

    def hold(self, until_s: float) -> None:
        """No keep-alive before ``until_s`` (a resumed node: a healed split resolves first)."""
        self.hold_until_s = until_s

    def holding(self, now: float) -> bool:
        return self.hold_until_s is not None and now < self.hold_until_s

    def resume(self, now: float) -> None:
        """A take-over adopted the node: the keep-alive goes out at once (the device's RPDO
        watchdog has been waiting since the old active gateway's last)."""
        self._resume_s = now

    def keepalive_due(self, since: float | None) -> float | None:
        """When the keep-alive RPDO is due (``since``: when sending became possible); None:
        no keep-alive, or no RPDO this gateway knows."""
        if not self.keepalive_s or len(self.unknown) == len(self.rpdos):
            return None
        if self._resume_s is not None:
            return self._resume_s
        last = max(self.last_sent_s.values(), default=None)
        due = last + self.keepalive_s if last is not None else (since or 0.0)
        return due if self.hold_until_s is None else max(due, self.hold_until_s)

    def keepalive(self, now: float) -> Send:
        """The keep-alive RPDO: the last one sent again, in a pair the next known one in turn."""
        last = self.last_sent_s
        if not self.pair:
            return self.frame(max(last, key=last.__getitem__) if last else self.rpdos[-1].number, now)
        known = [r.number for r in self.rpdos if r.number not in self.unknown]
        latest = max((n for n in known if n in last), key=last.__getitem__, default=None)
        turn = 0 if latest is None else (known.index(latest) + 1) % len(known)
        return self.frame(known[turn], now)
