"""The per-node machine (canopen_gateway.bus.node.node.Node) on a fake clock, against a device scripted in
the test from the manuals' frames: boot-up, configuration, supervision, probes, freshness of
values, refresh of change-only TPDOs, keep-alive, NMT expectations."""

from __future__ import annotations

import heapq
import itertools
import logging
import math
import struct
from collections.abc import Callable
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from canopen_gateway.bus.events import Note, Send, ValuesRead
from canopen_gateway.bus.node.parts import NodeParts, build_node
from canopen_gateway.canopen.states import LinkState, NmtState
from canopen_gateway.image import NodeImage, Quality, SignalValue
from canopen_gateway.profiles import expected_identity
from tests.helpers import make_config, resolved


class Device:
    """A scripted device: SDO server answering every request after ``sdo_delay_s``, NMT
    state machine, node-guarding answers with the DS-301 toggle."""

    def __init__(
        self, node_id: int, device_type: int, sdo_delay_s: float = 0.001,
        identity: dict[tuple[int, int], int] | None = None,
    ):  # fmt: skip
        self.node_id = node_id
        self.device_type = device_type
        self.identity = identity or {}  # 1018h sub-indices: the product it is
        self.sdo_delay_s = sdo_delay_s
        self.state = NmtState.PRE_OPERATIONAL
        self.toggle = 0
        self.powered = True
        self.answer_sdo = True
        self.downloads: list[tuple[int, int, bytes]] = []
        self.uploads: list[tuple[int, int]] = []
        self.objects: dict[tuple[int, int], int] = {}  # upload answers other than 0x1234

    def on_frame(self, s: Send) -> list[tuple[float, int, bytes]]:
        """(delay, COB-ID, data) the device sends in answer to a frame of the gateway."""
        if not self.powered:
            return []
        if s.cob_id == 0x000 and s.data[1] in (0, self.node_id):
            self.state = {
                0x01: NmtState.OPERATIONAL,
                0x02: NmtState.STOPPED,
                0x80: NmtState.PRE_OPERATIONAL,
            }.get(s.data[0], self.state)
            return []
        if s.cob_id == 0x700 + self.node_id and s.rtr:
            byte = self.toggle << 7 | int(self.state)
            self.toggle ^= 1
            return [(0.0005, 0x700 + self.node_id, bytes([byte]))]
        if s.cob_id == 0x600 + self.node_id and self.answer_sdo:
            cmd, index, sub = s.data[0], *struct.unpack_from("<HB", s.data, 1)
            if cmd & 0xE0 == 0x20:  # initiate download (expedited)
                size = 4 - (cmd >> 2 & 3)
                self.downloads.append((index, sub, bytes(s.data[4 : 4 + size])))
                return [
                    (
                        self.sdo_delay_s,
                        0x580 + self.node_id,
                        bytes([0x60]) + s.data[1:4] + b"\0" * 4,
                    )
                ]
            if cmd == 0x40:
                self.uploads.append((index, sub))
                value = self.device_type if (index, sub) == (0x1000, 0) else self.identity.get((index, sub), 0x1234)
                value = self.objects.get((index, sub), value)
                return [
                    (
                        self.sdo_delay_s,
                        0x580 + self.node_id,
                        bytes([0x43]) + s.data[1:4] + struct.pack("<I", value),
                    )
                ]
        return []

    def boot(self) -> None:
        self.powered = True
        self.state = NmtState.PRE_OPERATIONAL
        self.toggle = 0


class Harness:
    """The node, the device and a fake clock; events happen in time order."""

    def __init__(
        self, profile: str, node_id: int = 3, master: dict[str, Any] | None = None, **node: Any
    ):
        cfg = make_config(
            [{"name": "n", "node_id": node_id, "profile": profile, **node}],
            master={"boot_timeout_s": 5, "heartbeat_timeout_multiple": 1.5, **(master or {})},
        )
        rn = resolved(cfg)[cfg.nodes[0].name]
        lp = rn.lp
        self.image = NodeImage("n", node_id, lp.family, [s.name for s in lp.profile.signals])
        self.parts: NodeParts = build_node(rn, self.image)
        self.node = self.parts.node
        ident = {(o.index, o.sub): v for o, v in expected_identity(lp)}
        self.device = Device(node_id, lp.profile.device_type or 0, identity=ident)
        self.now = 0.0
        self.sent: list[tuple[float, Send]] = []
        self.read: list[ValuesRead] = []
        self.notes: list[tuple[float, Note]] = []
        self._events: list[tuple[float, int, Callable[[], list[Any]]]] = []
        self._seq = itertools.count()

    # -- plumbing
    def _take(self, outs: list[Any]) -> None:
        for o in outs:
            if isinstance(o, Send):
                self.sent.append((self.now, o))
                for delay, cob, data in self.device.on_frame(o):
                    self.at(self.now + delay, self._rx(cob, data))
            elif isinstance(o, ValuesRead):
                self.read.append(o)
            elif isinstance(o, Note):
                self.notes.append((self.now, o))

    def _rx(self, cob: int, data: bytes) -> Callable[[], list[Any]]:
        def deliver() -> list[Any]:
            if cob >= 0x700:
                return self.node.on_nmt_ec(data[0], self.now)
            if cob >= 0x580:
                return self.node.on_sdo_response(data, self.now)
            return self.node.on_emcy(data, 0.0, self.now)

        return deliver

    def at(self, t: float, fn: Callable[[], list[Any]]) -> None:
        heapq.heappush(self._events, (t, next(self._seq), fn))

    def run_until(self, t_end: float) -> None:
        for _ in range(200_000):
            dl = self.node.next_deadline()
            if dl is not None and dl <= self.now:
                # timeouts expire strictly after their deadline: the next instant
                dl = math.nextafter(self.now, math.inf)
            ev = self._events[0][0] if self._events else None
            nxt = min((x for x in (dl, ev) if x is not None), default=None)
            if nxt is None or nxt > t_end:
                break
            self.now = max(self.now, nxt)
            if ev is not None and ev <= self.now:
                _, _, fn = heapq.heappop(self._events)
                self._take(fn())
            else:
                self._take(self.node.tick(self.now))
        self.now = max(self.now, t_end)

    # -- device actions
    def start(self, probe: bool = False) -> None:
        self._take(self.node.start(self.now, probe=probe))

    def bootup(self, at: float) -> None:
        def boot() -> list[Any]:
            self.device.boot()
            return self.node.on_nmt_ec(0x00, self.now)

        self.at(at, boot)

    def heartbeats(self, start: float, end: float, period: float = 0.1) -> None:
        t = start
        while t <= end:
            self.at(t, lambda: self.node.on_nmt_ec(int(self.device.state), self.now))
            t += period

    def frames(self, cob: int, after: float = -1.0) -> list[tuple[float, Send]]:
        return [(t, s) for t, s in self.sent if s.cob_id == cob and t > after]

    def nmt_start_time(self, after: float = -1.0) -> float:
        return next(t for t, s in self.frames(0x000, after) if s.data[0] == 0x01)


def sgh10(**kw: Any) -> Harness:
    return Harness("sgh10", node_id=1, **kw)


# --------------------------------------------------------------------------- freshness (13.1)


def test_values_of_the_previous_boot_are_stale_until_a_frame_after_nmt_start() -> None:
    h = sgh10()
    h.start()
    h.bootup(1.0)
    h.heartbeats(1.01, 3.0)
    h.run_until(2.0)
    started = h.nmt_start_time()
    assert h.image.health.fresh_since == started
    node = h.image
    node.set_value(SignalValue("position", 7, 0.0, started - 0.5, 1))  # before
    assert node.quality(node.signals["position"], started + 0.1) == Quality.STALE
    node.set_value(SignalValue("position", 8, 0.0, started + 0.01, 2))  # after
    assert node.quality(node.signals["position"], started + 0.1) == Quality.GOOD
    # a second boot-up invalidates everything again, before any reconfiguration
    h.bootup(2.5)
    h.run_until(2.5)
    assert h.image.health.fresh_since is None
    assert node.quality(node.signals["position"], 2.6) == Quality.STALE


def test_a_loss_invalidates_values_and_the_nmt_state_is_unknown() -> None:
    h = sgh10()
    h.start()
    h.bootup(1.0)
    h.heartbeats(1.01, 2.0)
    h.run_until(2.0)
    assert h.image.health.nmt_state == NmtState.OPERATIONAL and h.image.health.alive
    h.run_until(2.5)  # last heartbeat at 1.91 + 150 ms consumer timeout
    hl = h.image.health
    assert not hl.alive and hl.loss_count == 1
    assert hl.nmt_state == NmtState.UNKNOWN  # Modbus IR 1 reads 65535
    assert hl.fresh_since is None
    assert hl.lifecycle == "waiting"


def test_a_loss_says_why_in_last_error_at_once_and_the_return_clears_it() -> None:
    """Only the heartbeat stops (the device answers SDO and sends its TPDOs all along): the
    node is lost, and ``last_error`` (``/healthz``, the Zenoh state, the console) says why
    from that instant, not after a boot timeout."""
    h = sgh10()
    h.start()
    h.bootup(1.0)
    h.heartbeats(1.01, 2.0)
    h.run_until(2.0)
    assert h.image.health.last_error == ""
    h.run_until(2.5)  # last heartbeat at 1.91 + 150 ms
    hl = h.image.health
    assert not hl.alive
    assert hl.last_error == "lost (no heartbeat for more than 150 ms)"
    h.heartbeats(2.6, 3.0)  # the heartbeat again
    h.run_until(2.65)
    assert hl.alive and hl.last_error == ""


# --------------------------------------------------------------------------- probes (13.5)


def test_a_lost_node_is_probed_on_the_documented_cadence_counted_from_the_loss() -> None:
    h = sgh10()
    h.start()
    h.bootup(1.0)
    h.heartbeats(1.01, 2.0)
    h.device.answer_sdo = True
    h.run_until(2.0)
    h.device.powered = False
    h.run_until(20.0)
    loss_at = 1.91 + 0.15
    probes = [t for t, s in h.frames(0x601) if s.data[:4] == bytes([0x40, 0x00, 0x10, 0x00])]
    period = h.parts.settings.probe_period_s
    # not at the instant of the loss: one period after it, then every period
    assert probes[0] > loss_at + period - 0.01
    assert probes[0] <= loss_at + period + 0.01
    # each probe is one upload and its retry (sdo_retries 1); the next starts a period later
    starts = [probes[0]] + [b for a, b in itertools.pairwise(probes) if b - a > 1.1]
    assert len(starts) >= 3
    assert all(abs(b - a - period) < 1e-6 for a, b in itertools.pairwise(starts))


def test_a_boot_up_cancels_a_probe_in_flight_and_configuration_starts_at_once() -> None:
    h = sgh10()
    h.device.powered = False
    h.start(probe=True)  # probe at 0: the device is off, the upload of 1000h waits
    h.run_until(0.0)
    assert h.frames(0x601)[0][1].data[:4] == bytes([0x40, 0x00, 0x10, 0x00])
    h.bootup(0.05)  # the device comes up while the probe waits for its answer
    h.run_until(0.05)
    first_step = h.frames(0x601, after=0.0)
    # the configuration starts at once, not after 0.5 s: with the identity read (1018h:01,
    # the vendor its EDS gives), then 1017h
    assert first_step and first_step[0][0] == 0.05
    assert first_step[0][1].data[:4] == bytes([0x40, 0x18, 0x10, 0x01])
    h.run_until(0.06)
    writes = [s for _, s in h.frames(0x601, after=0.0) if s.data[0] == 0x2B]
    assert writes and writes[0].data[1:3] == b"\x17\x10"


def test_a_refused_device_sending_heartbeats_is_checked_again_only_after_minutes() -> None:
    """Another vendor's device at the node id (1018h:01 differs), heartbeat every 100 ms, for
    an hour: it is checked at its boot-up and then after 1, 2, 4, 8, 16, 16 minutes, not at
    each heartbeat (before: NMT pre-operational and three SDO requests every second)."""
    h = Harness("posi_plus", node_id=3, heartbeat_ms=100)
    h.device.identity[(0x1018, 1)] = 0x999  # another vendor
    h.start()
    h.bootup(1.0)
    h.heartbeats(1.01, 3600.0)
    h.run_until(3600.0)
    preops = [t for t, s in h.frames(0x000) if s.data[0] == 0x80]
    assert preops == pytest.approx([61.0, 181.0, 421.0, 901.0, 1861.0, 2821.0], abs=0.11)
    requests = h.frames(0x603)
    assert len(requests) == 2 + 3 * len(preops)  # 1018h:01/02; then 1000h and 1018h:01/02
    errors = [n.text for _, n in h.notes if n.level >= logging.ERROR]
    assert len(errors) == 1 + len(preops)  # one line per check
    assert errors[0].endswith("not configured; checked again at its next boot-up or in 60 s")
    assert h.image.health.lifecycle == "waiting" and "wrong device" in h.image.health.last_error
    # the right device replaces it: its boot-up is checked at once
    h.device.identity[(0x1018, 1)] = 0x184
    h.bootup(3600.5)
    h.run_until(3601.0)
    assert h.nmt_start_time(after=3600.0) < 3601.0


# --------------------------------------------------------------------------- guarding (13.4)


def test_a_guarded_node_reconfigured_slowly_after_a_reboot_is_never_lost() -> None:
    h = Harness(
        "posi_plus", node_id=3, supervision="guarding", guard_time_ms=120, life_time_factor=4
    )
    h.start()
    h.bootup(0.5)
    h.run_until(3.0)
    assert h.image.health.nmt_state == NmtState.OPERATIONAL
    h.device.sdo_delay_s = 0.1  # each SDO answered in 100 ms: 6 steps take longer than...
    assert 6 * 0.1 > 0.48 * 1.0  # ...the life time (120 ms x 4) would allow with no answer
    h.bootup(3.0)
    h.run_until(6.0)
    hl = h.image.health
    assert hl.loss_count == 0
    assert hl.boot_count == 2
    started = h.nmt_start_time(after=3.0)
    assert started - 3.0 <= 1.0  # boot-up to NMT start
    assert hl.alive and hl.nmt_state == NmtState.OPERATIONAL


def test_nmt_commands_move_the_state_guarding_expects() -> None:
    h = Harness(
        "posi_plus", node_id=3, supervision="guarding", guard_time_ms=100, life_time_factor=3
    )
    h.start()
    h.bootup(0.5)
    h.run_until(2.0)
    h.node.on_nmt_command("stop")
    h._take([Send(0x000, bytes([0x02, 3]))])  # the frame the master sends
    h.run_until(4.0)
    assert h.image.health.nmt_state == NmtState.STOPPED
    assert h.image.health.alive and h.image.health.loss_count == 0


# --------------------------------------------------------------------------- refresh (13.1)


def test_a_change_only_tpdo_is_asked_by_rtr_right_after_nmt_start() -> None:
    h = sgh10(sdo=[{"object": "0x1800:05", "value": 0}])  # TPDO1: 254, no event timer
    h.start()
    h.bootup(1.0)
    h.run_until(1.5)
    started = h.nmt_start_time()
    rtrs = [(t, s) for t, s in h.frames(0x181) if s.rtr]
    assert rtrs and rtrs[0][0] == started and rtrs[0][1].dlc == 6


def test_a_change_only_tpdo_without_rtr_is_read_by_sdo_object_by_object() -> None:
    # COB-ID bit 30 set: no RTR allowed on TPDO1 (DS-301 1800h:01)
    h = sgh10(
        sdo=[{"object": "0x1800:05", "value": 0}, {"object": "0x1800:01", "value": 0x40000181}]
    )
    h.start()
    h.bootup(1.0)
    h.run_until(1.5)
    started = h.nmt_start_time()
    assert not [s for t, s in h.frames(0x181) if s.rtr]
    uploads = [
        (t, s.data[1:4]) for t, s in h.frames(0x601, after=started - 1e-9) if s.data[0] == 0x40
    ]
    tpdo1 = next(c for c in h.parts.tpdos if c.number == 1)
    expected = [struct.pack("<HB", f.obj.index, f.obj.sub) for f in tpdo1.fields if f.signal]
    assert [u for _, u in uploads] == expected  # one upload per mapped object, in order
    assert [r.names for r in h.read] == [(f.signal,) for f in tpdo1.fields if f.signal]


def test_refresh_can_be_turned_off_per_node() -> None:
    h = sgh10(sdo=[{"object": "0x1800:05", "value": 0}], refresh_on_start=False)
    h.start()
    h.bootup(1.0)
    h.run_until(1.5)
    assert not [s for t, s in h.frames(0x181) if s.rtr]


# --------------------------------------------------------------------------- outputs and link


def test_the_guarding_bit_toggles_once_per_echo_and_the_keepalive_feeds_the_device() -> None:
    h = Harness("ap05", node_id=1)
    h.start()
    h.bootup(1.0)
    h.heartbeats(1.01, 5.0)
    h.run_until(1.2)
    assert h.image.health.link == LinkState.UNKNOWN
    rpdos = [(t, s) for t, s in h.sent if s.rpdo]
    assert rpdos, "a first RPDO right after start (guarding bit period)"
    period = h.parts.settings.keepalive_ms / 1000.0
    h.run_until(1.2 + 3 * period)
    again = [t for t, s in h.sent if s.rpdo]
    assert len(again) >= 3
    assert all(abs(b - a - period) < 1e-9 for a, b in itertools.pairwise(again))
    # no echo: the bit stays 1 (one toggle in flight) and the link faults after tolerance_ms
    cw = [int.from_bytes(s.data[6:8], "little") >> 8 & 1 for t, s in h.sent if s.rpdo]
    assert set(cw) == {1}
    h.run_until(3.0)
    assert h.image.health.link == LinkState.FAULT
    # the echo returns: link OK
    h._take(h.node.on_echo(1, h.now))
    assert h.image.health.link == LinkState.OK


def test_outputs_are_refused_and_unchanged_when_the_node_is_not_operational() -> None:
    import pytest

    from canopen_gateway.errors import NodeNotOperational

    h = Harness("ap05", node_id=1, guarding_bit={"enabled": False})
    h.start()
    with pytest.raises(NodeNotOperational):
        h.node.write_outputs({None: {"set_point2": 5}}, 0.0)
    assert h.node.output("set_point2") == 0
    assert h.image.outputs.seq == 0 and h.image.output("set_point2") == 0


def test_the_image_outputs_are_what_the_rpdos_carry_set_by_the_node_in_one_record() -> None:
    h = Harness("ap05", node_id=1)
    h.start()
    h.bootup(1.0)
    h.heartbeats(1.01, 5.0)
    h.run_until(1.2)
    control = h.node.control_signal
    assert control is not None
    before = h.image.outputs
    codec = next(c for c in h.parts.rpdos if c.index_of("set_point1") is not None)
    n = codec.number
    outs = h.node.write_outputs(
        {None: {"set_point2": 5}, n: {"set_point1": 0x4C4C4548}}, h.now, wall=1234.5
    )
    assert not [o for o in outs if isinstance(o, ValuesRead)]  # no echo into the records
    after = h.image.outputs
    assert after is not before and before.seq == after.seq - 1  # one new record per write
    assert (after.timestamp, after.monotonic) == (1234.5, h.now)
    assert h.image.output("set_point2") == 5 and h.image.output("set_point1", n) == 0x4C4C4548
    for s in (o for o in outs if isinstance(o, Send)):  # the image holds what went out
        sent = next(c for c in h.parts.rpdos if c.cob_id == s.cob_id)
        assert sent.encode(after.rpdos[sent.number]) == s.data
    # the keep-alive toggles the guarding bit of the control word: the image follows it
    h._take(h.node.on_echo(1, h.now))
    period = h.parts.settings.keepalive_ms / 1000.0
    written = len([s for t, s in h.sent if s.rpdo])
    h.run_until(h.now + period)
    assert len([s for t, s in h.sent if s.rpdo]) > written  # a keep-alive went out
    last = [s for t, s in h.sent if s.rpdo][-1]
    sent = next(c for c in h.parts.rpdos if c.cob_id == last.cob_id)
    assert sent.encode(h.image.outputs.rpdos[sent.number]) == last.data
    assert h.image.outputs.seq == after.seq  # a keep-alive is not a write


# --------------------------------------------------------------------------- producers


def test_sync_and_heartbeat_producers_are_due_every_period_and_catch_up_once() -> None:
    from canopen_gateway.bus.producers import Periodic

    p = Periodic(0.02, 100.0)
    assert p.due(100.0) and p.next_deadline() == 100.02
    assert not p.due(100.019)
    assert p.due(100.02) and abs(p.next_deadline() - 100.04) < 1e-12
    # paused for 1 s: one frame, then every period from now (no burst of 50)
    assert p.due(101.05) and abs(p.next_deadline() - 101.07) < 1e-12
    assert not p.due(101.06)
    assert p.sent == 3


def test_every_rpdo_sent_pushes_the_keepalive_back() -> None:
    """AP05 manual 5.5.4: any RPDO feeds the external heartbeat; the keep-alive re-sends the
    last RPDO only when none went out for keepalive_s."""
    from canopen_gateway.bus.node.outputs import OutputImage

    h = Harness("ap05", node_id=1, guarding_bit={"enabled": False}, external_heartbeat={"interval_ms": 100})
    out = OutputImage("n", h.parts.rpdos, keepalive_s=0.05)
    assert out.keepalive_due(since=2.0) == 2.0  # nothing sent yet: due at once
    out.set({None: {"set_point2": 1}})
    out.frame(2, 2.0)
    out.frame(2, 2.04)
    assert out.keepalive_due(since=2.0) == pytest.approx(2.09)
    frame = out.keepalive(2.09)
    assert frame.cob_id == 0x301 and frame.rpdo  # the last RPDO sent, again


# --------------------------------------------------------------------------- robustness

_events = st.lists(
    st.one_of(
        st.tuples(st.just("nmt_ec"), st.integers(0, 255)),
        st.tuples(st.just("sdo"), st.binary(min_size=0, max_size=8)),
        st.tuples(st.just("emcy"), st.binary(min_size=0, max_size=8)),
        st.tuples(st.just("echo"), st.integers(0, 1)),
        st.tuples(st.just("tick"), st.floats(0.0, 2.0)),
    ),
    max_size=60,
)


@settings(max_examples=150, deadline=None)
@given(_events)
def test_no_sequence_of_frames_a_device_sends_makes_the_node_raise(events: list) -> None:
    for profile, extra in (("ap05", {}), ("posi_plus", {"supervision": "guarding"})):
        h = Harness(profile, node_id=1, **extra)
        h.start(probe=True)
        now = 0.0
        for kind, arg in events:
            if kind == "nmt_ec":
                h.node.on_nmt_ec(arg, now)
            elif kind == "sdo":
                h.node.on_sdo_response(arg, now)
            elif kind == "emcy":
                h.node.on_emcy(arg, 0.0, now)
            elif kind == "echo":
                h.node.on_echo(arg, now)
            else:
                now += arg
                h.node.tick(now)
        deadline = h.node.next_deadline()
        assert deadline is None or deadline >= 0.0


# --------------------------------------------------------------------------- queued work runs


def test_an_emcy_starts_the_referencing_read_at_once_between_heartbeats() -> None:
    """MSK5000 (manual 001, 5115h; EMCY FF10h): after an EMCY the reference state is read at
    once, not when an unrelated timer fires. Heartbeats every 200 ms keep pushing the node's
    supervision deadline on, so a queued read that waited for a tick would never start."""
    h = Harness("msk5000", node_id=37, heartbeat_ms=200)
    h.device.objects[(0x5115, 0)] = 1  # referenced
    h.start()
    h.bootup(1.0)
    h.heartbeats(1.05, 8.05, period=0.2)
    h.run_until(3.0)
    assert "position" not in h.image.health.invalid_signals  # referenced after configuration

    def reference_lost() -> list[Any]:
        h.device.objects[(0x5115, 0)] = 0
        return h.node.on_emcy(bytes([0x10, 0xFF, 0x81, 0, 0, 0, 0, 0]), 0.0, h.now)

    h.at(3.05, reference_lost)
    h.run_until(8.05)
    reads = [(t, s) for t, s in h.frames(0x625, after=3.0) if s.data[:4] == b"\x40\x15\x51\x00"]
    assert reads and reads[0][0] == 3.05  # the upload of 5115h goes out with the EMCY
    assert "position" in h.image.health.invalid_signals  # and the position is not valid
    assert not h.node.sdo.busy


def _queued_work_waits(node: Any, now: float) -> bool:
    """An SDO job is queued, none runs, and the node would not be ticked before ``later``."""
    if not node.sdo.jobs or not node.sdo.idle:
        return False
    deadline = node.next_deadline()
    return deadline is None or deadline > now


_work_events = st.lists(
    st.one_of(
        st.tuples(st.just("hb"), st.sampled_from([0x00, 0x05, 0x7F, 0x04])),
        st.tuples(st.just("emcy"), st.sampled_from([b"\x10\xff\x81\0\0\0\0\0", b"\0\0\0"])),
        st.tuples(st.just("sdo_answer"), st.integers(0, 1)),
        st.tuples(st.just("sdo_req"), st.integers(0, 1)),
        st.tuples(st.just("tick"), st.floats(0.0, 0.5)),
        st.tuples(st.just("wait"), st.floats(0.0, 0.5)),
    ),
    max_size=50,
)


@settings(max_examples=150, deadline=None)
@given(_work_events)
def test_queued_sdo_work_is_never_left_waiting_for_an_unrelated_deadline(events: list) -> None:
    """After any sequence of events: if an SDO job is queued and no transfer runs, the node's
    next deadline is not later than now (the driver ticks it at once)."""
    for profile, extra in (("msk5000", {"node_id": 37}), ("posi_plus", {"supervision": "guarding"})):
        h = Harness(profile, **extra)
        h.start(probe=True)
        now = 0.0
        for kind, arg in events:
            if kind == "hb":
                h.node.on_nmt_ec(arg, now)
            elif kind == "emcy":
                h.node.on_emcy(arg, 0.0, now)
            elif kind == "sdo_answer" and h.node.sdo.running is not None:
                job, _tr = h.node.sdo.running
                cmd = 0x60 if job.data is not None else 0x4F
                raw = bytes([cmd]) + job.obj.index.to_bytes(2, "little") + bytes([job.obj.sub])
                h.node.on_sdo_response(raw + bytes([arg, 0, 0, 0]), now)
            elif kind == "sdo_req":
                from canopen_gateway.canopen.objref import ObjRef

                h.node.request_sdo(ObjRef(0x1018, 1), None if arg else b"\x01", now)
            elif kind == "tick":
                now += arg
                h.node.tick(now)
            else:
                now += arg  # time passes without a tick
                dl = h.node.next_deadline()
                if dl is not None and dl <= now:
                    h.node.tick(now)
            assert not _queued_work_waits(h.node, now), (kind, arg, now)
