"""The output image of a hot-standby pair's members (canopen_gateway.bus.node.outputs, ``pair``) on a
fake clock, with the AP05's RPDOs (manual 5.3.1.2 table 26: set point1 + characters 5-6 +
control word 5F0Ch in RPDO1, set point2 + characters + the same control word in RPDO2; 5.3.2:
control bit 8 the guarding bit): the active member's frames carry every RPDO's content, and a
standby that hears them, whenever it was started, knows each RPDO field for field."""

from __future__ import annotations

from typing import Any

from hypothesis import given, settings
from hypothesis import strategies as st

from canopen_gateway.bus.node.outputs import OutputImage
from tests.helpers import make_config, resolved
from tests.pair_invariants import as_frames, outputs_known_alike

KEEPALIVE_S = 0.5
CONTROL = ("control_word", 8)  # AP05 manual 5.3.2 table 27: the guarding bit


def ap05_rpdos() -> list[Any]:
    cfg = make_config([{"name": "display", "node_id": 2, "profile": "ap05"}])
    return list(resolved(cfg)["display"].rpdos)


def image(pair: bool = True) -> OutputImage:
    return OutputImage("display", ap05_rpdos(), KEEPALIVE_S, None, CONTROL, pair=pair)


def active() -> OutputImage:
    a = image()
    a.own()  # it configured the node: every RPDO's content is its own
    return a


def test_a_control_word_write_in_a_pair_sends_the_other_rpdo_it_changed_right_after() -> None:
    a = active()
    assert a.set({None: {"set_point1": 1000, "control_word": 0x0004}}) == [1, 2]
    # the control word alone goes out in RPDO2; RPDO1 carries it too: in a pair it follows
    assert a.set({None: {"control_word": 0x0304}}) == [2, 1]
    # the same write outside a pair sends RPDO2 only (one RPDO per write)
    single = image(pair=False)
    assert single.set({None: {"control_word": 0x0304}}) == [2]
    # a write that changes nothing else sends nothing more
    assert a.set({None: {"set_point2": 7}}) == [2]


def test_in_a_pair_the_keepalive_goes_round_every_rpdo_in_turn() -> None:
    a = active()
    a.set({None: {"set_point1": 1000, "set_point2": 2000}})
    a.frame(1, 0.0)
    a.frame(2, 0.01)
    t, turns = 0.0, []
    for _ in range(4):
        due = a.keepalive_due(since=0.0)
        assert due is not None
        t = due
        turns.append(a.keepalive(t).cob_id)
    assert turns == [0x202, 0x302, 0x202, 0x302]
    single = image(pair=False)
    single.frame(2, 0.0)
    assert [single.keepalive(s).cob_id for s in (0.5, 1.0)] == [0x302, 0x302]  # the last, again


def test_a_standby_keeps_a_shared_signal_for_an_rpdo_it_never_heard_and_never_sends_that_rpdo() -> None:
    a, b = active(), image()
    a.set({None: {"set_point1": 1000, "set_point2": 2000, "control_word": 0x0204}})
    b.heard(0x302, a.frame(2, 1.0).data, 1.0)  # B started after RPDO1 went out: RPDO2 only
    assert b.unknown == {1}
    assert b.get("control_word", 1) == 0x0204  # from RPDO2: what the device was last told
    assert b.get("set_point1") == 0  # not known
    # B's keep-alive (were it active) repeats RPDO2 only, never the RPDO1 it does not know
    assert [b.keepalive(t).cob_id for t in (2.0, 2.5, 3.0)] == [0x302, 0x302, 0x302]
    b.heard(0x202, a.frame(1, 3.1).data, 3.1)  # the active one's keep-alive round
    assert b.unknown == set() and outputs_known_alike(a, b) == []


def test_a_member_that_knows_no_rpdo_sends_no_keepalive_until_it_configures_the_node() -> None:
    b = image()
    assert b.keepalive_due(since=0.0) is None
    b.resume(1.0)  # adopted at a take-over: still nothing it knows
    assert b.keepalive_due(since=0.0) is None
    b.own()  # configured by it: its defaults are the device's now
    assert b.keepalive_due(since=5.0) == 1.0


def test_an_adopted_node_gets_its_keepalive_at_once() -> None:
    a, b = active(), image()
    a.set({None: {"set_point2": 5}})
    b.heard(0x302, a.frame(2, 10.0).data, 10.0)
    assert b.keepalive_due(since=None) == 10.5
    b.resume(10.2)  # the take-over: the device waited since the old active member's last RPDO
    assert b.keepalive_due(since=None) == 10.2
    b.keepalive(10.2)
    assert b.keepalive_due(since=None) == 10.7


def test_a_heard_rpdo_shows_a_write_when_its_content_changed_or_it_came_sooner_than_a_keepalive() -> None:
    a, b = active(), image()
    a.set({None: {"set_point2": 5, "control_word": 0x0200}})
    first = a.frame(2, 0.0).data
    assert b.heard(0x302, first, 0.0) is False  # B's first frame: a keep-alive for all it knows
    for t in (0.5, 1.0):  # the active member's keep-alive round (RPDO1, then RPDO2 again)
        k = a.keepalive(t)
        assert b.heard(k.cob_id, k.data, t) is False
    toggled = bytearray(first)
    toggled[7] ^= 0x01  # control word bit 8 (byte 7 bit 0): the gateway's guarding bit
    assert b.heard(0x302, bytes(toggled), 1.5) is False
    assert b.heard(0x302, bytes(toggled), 1.6) is True  # sooner than a keep-alive: written again
    a.set({None: {"set_point2": 6}})
    assert b.heard(0x302, a.frame(2, 2.5).data, 2.5) is True  # the value changed
    assert b.heard(0x999, first, 3.0) is None  # not one of this node's RPDOs
    # without a keep-alive every RPDO heard is a write
    c = OutputImage("display", ap05_rpdos(), 0.0, None, CONTROL, pair=True)
    assert c.heard(0x302, first, 0.0) is True


_writes = st.one_of(
    st.tuples(st.just(None), st.sampled_from(["set_point1", "set_point2"]), st.integers(-99999, 99999)),
    st.tuples(st.just(None), st.just("control_word"), st.integers(0, 0xFFFF).map(lambda v: v & ~0x23)),
    # a text row: that RPDO alone with its control word (data identifier bit 7, manual 4.1.2)
    st.tuples(st.sampled_from([1, 2]), st.just("control_word"), st.sampled_from([0x0080, 0x0284])),
    st.tuples(st.just("keepalive"), st.just(""), st.just(0)),
)


@settings(max_examples=60, deadline=None)
@given(st.lists(_writes, max_size=25), st.integers(0, 25))
def test_a_standby_started_at_any_point_knows_every_rpdo_it_heard_as_the_active_member_has_it(
    steps: list[tuple[Any, str, int]], joins: int
) -> None:
    """Writes of every kind (a signal of one RPDO, the shared control word, a text row's own
    control word), keep-alives in between; the standby starts hearing at step ``joins``. After
    every step, every RPDO it knows equals the active member's; after one keep-alive round it
    knows them all."""
    a, b = active(), image()
    t = 0.0
    for i, (pdo, name, value) in enumerate(steps):
        t += 0.6 if pdo == "keepalive" else 0.01
        if pdo == "keepalive":
            frames = [a.keepalive(t)]
        else:
            frames = [a.frame(n, t) for n in a.set({pdo: {name: value}})]
        if i >= joins:
            for cob, data in as_frames(frames):
                b.heard(cob, data, t)
        assert outputs_known_alike(a, b) == []
    if len(steps) > joins:
        for _ in range(2):  # one round of the keep-alive
            t += KEEPALIVE_S
            cob, data = as_frames([a.keepalive(t)])[0]
            b.heard(cob, data, t)
        assert b.unknown == set() and outputs_known_alike(a, b) == []


def test_a_member_that_forgot_what_it_sent_sends_none_of_it_until_it_hears_or_writes_it_again() -> None:
    """Back from its own outage, or another master met while the node was out of its hands:
    the old content may be stale; it learns each RPDO again from another master's frame."""
    a, other = active(), active()
    a.set({None: {"set_point1": 1000, "set_point2": 2000}})
    a.frame(1, 0.0)
    a.forget()
    assert a.unknown == {1, 2} and a.keepalive_due(since=0.0) is None
    assert not a.knows(0x202)
    other.set({None: {"set_point1": 1111}})
    a.heard(0x202, other.frame(1, 1.0).data, 1.0)
    assert a.knows(0x202) and not a.knows(0x302) and a.get("set_point1") == 1111
    assert [a.keepalive(t).cob_id for t in (1.5, 2.0)] == [0x202, 0x202]  # RPDO2 never


def test_a_resumed_node_holds_its_keepalive_until_a_healed_split_would_have_resolved() -> None:
    a = active()
    a.frame(1, 0.0)
    a.frame(2, 0.1)
    a.hold(5.0)
    assert a.holding(4.9) and not a.holding(5.0)
    assert a.keepalive_due(since=0.0) == 5.0  # not at 0.6 s: held
    a.keepalive(5.0)
    assert a.hold_until_s is None and a.keepalive_due(since=0.0) == 5.5
