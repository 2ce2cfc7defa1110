"""The test bus of the pair (``tests/pair_bus.py``): the gateway's socketcand client (a python-can
bus) on every side, frames attributed to their sender, no echo, a cut cable and a lost adapter per member."""

from __future__ import annotations

from collections.abc import Iterator

import can
import pytest

from tests.helpers import wait_until_sync
from tests.pair_bus import PairBus


@pytest.fixture
def bus() -> Iterator[PairBus]:
    with PairBus() as b:
        yield b


def send(b: can.BusABC, cob_id: int, data: bytes = b"") -> None:
    b.send(can.Message(arbitration_id=cob_id, data=data, is_extended_id=False))


def next_frame(b: can.BusABC) -> can.Message:
    msg = b.recv(timeout=10.0)
    assert msg is not None, "no frame within 10 s"
    return msg


def test_every_frame_is_attributed_to_its_sender_and_reaches_every_other_member(bus: PairBus) -> None:
    a, b, c = bus.open_bus("a"), bus.open_bus("b"), bus.open_bus("c")
    send(a, 0x181, b"\x01\x02")
    bus.wait_for(lambda f: f.cob_id == 0x181)  # two connections: order them at the relay
    send(b, 0x702, b"\x05")
    for rx in (b, c):
        got = next_frame(rx)
        assert (got.arbitration_id, bytes(got.data)) == (0x181, b"\x01\x02")
    got = next_frame(c)
    assert (got.arbitration_id, bytes(got.data)) == (0x702, b"\x05")
    bus.wait_for(lambda f: f.cob_id == 0x702)
    assert [(f.sender, f.cob_id, f.data, f.delivered) for f in bus.frames] == [
        ("a", 0x181, b"\x01\x02", True),
        ("b", 0x702, b"\x05", True),
    ]
    assert [f.cob_id for f in bus.sent_by("b")] == [0x702]
    assert bus.sent_by("a", 0x702) == []
    assert bus.can_section("a") == {
        "interface": "socketcand", "host": "127.0.0.1", "port": bus.port, "channel": "a"
    }


def test_a_member_never_hears_its_own_frames(bus: PairBus) -> None:
    a, b = bus.open_bus("a"), bus.open_bus("b")
    send(a, 0x181, b"\xaa")
    assert next_frame(b).arbitration_id == 0x181
    send(b, 0x182, b"\xbb")
    # the first frame a hears is b's: its own 181h never came back
    got = next_frame(a)
    assert (got.arbitration_id, bytes(got.data)) == (0x182, b"\xbb")


def test_a_cut_member_hears_nothing_and_reaches_no_one(bus: PairBus) -> None:
    a, b, c = bus.open_bus("a"), bus.open_bus("b"), bus.open_bus("c")
    bus.cut("b")
    assert bus.connected("b")  # a cut cable leaves the connection open
    send(a, 0x181, b"\x01")
    send(b, 0x182, b"\x02")  # the send succeeds: b cannot tell
    assert next_frame(c).arbitration_id == 0x181
    bus.wait_for(lambda f: f.sender == "b")
    assert bus.sent_by("b")[0].delivered is False
    assert bus.sent_by("a")[0].delivered is True
    bus.mend("b")
    send(a, 0x183, b"\x03")
    bus.wait_for(lambda f: f.cob_id == 0x183)  # two connections: order them at the relay
    send(b, 0x184, b"\x04")
    # b heard nothing while cut: its first frame is the one sent after the mend
    assert next_frame(b).arbitration_id == 0x183
    # c heard nothing of b while cut: after a's 181h and 183h comes b's 184h
    assert next_frame(c).arbitration_id == 0x183
    assert next_frame(c).arbitration_id == 0x184
    # a heard b's 184h only
    assert next_frame(a).arbitration_id == 0x184
    assert [f.delivered for f in bus.sent_by("b")] == [False, True]


def test_an_unplugged_member_reads_eof_and_is_refused_until_plugged(bus: PairBus) -> None:
    a = bus.open_bus("a")
    bus.open_bus("b")
    bus.unplug("b")
    assert not bus.connected("b")
    # a reconnect of that name is closed as soon as it names its channel
    with pytest.raises(can.CanError):
        can.Bus(interface="socketcand", host="127.0.0.1", port=bus.port, channel="b")
    assert bus.refused["b"] == 1
    send(a, 0x181, b"\x01")
    frame = bus.wait_for(lambda f: f.cob_id == 0x181)
    assert frame.delivered is False  # nobody else on the bus
    bus.plug("b")
    b2 = bus.open_bus("b")
    assert bus.connected("b")
    send(a, 0x182, b"\x02")
    assert next_frame(b2).arbitration_id == 0x182


def test_unplug_closes_the_connection_the_client_sees_eof(bus: PairBus) -> None:
    """What a socketcand client makes of the EOF is the client's business
    (``canopen_gateway.bus.socketcand_bus``); here: the relay closed its side (a raw read gets 0 bytes)."""
    import socket

    with socket.create_connection(("127.0.0.1", bus.port), timeout=10) as s:
        assert s.recv(64) == b"< hi >"
        s.sendall(b"< open raw >")
        assert s.recv(64) == b"< ok >"
        s.sendall(b"< rawmode >")
        assert s.recv(64) == b"< ok >"
        assert wait_connected(bus, "raw")
        bus.unplug("raw")
        assert s.recv(64) == b""


def wait_connected(bus: PairBus, name: str) -> bool:
    return bool(wait_until_sync(lambda: bus.connected(name), 10.0, f"{name} connected"))


def test_connections_of_one_member_hear_each_other_also_when_it_is_cut(bus: PairBus) -> None:
    """A gateway and its in-process simulated devices on one ``can:`` section: two sockets on one
    SocketCAN interface (its local loopback); one member for cut and unplug."""
    a = bus.open_bus("a")
    b1, b2 = bus.open_bus("b"), bus.open_bus("b")
    assert bus.joins["b"] == 2
    bus.cut("b")
    send(b1, 0x181, b"\x01")
    assert next_frame(b2).arbitration_id == 0x181
    assert bus.wait_for(lambda f: f.cob_id == 0x181).delivered is False  # no other member
    send(a, 0x182, b"\x02")
    bus.wait_for(lambda f: f.cob_id == 0x182)  # relayed while b is cut
    bus.mend("b")
    send(a, 0x183, b"\x03")
    assert next_frame(b1).arbitration_id == 0x183  # a's 182h reached neither while cut
    assert next_frame(b2).arbitration_id == 0x183
    bus.unplug("b")
    assert not bus.connected("b")
    for rx in (b1, b2):  # each connection of the unplugged member reads the EOF as an error
        with pytest.raises(can.CanOperationError, match="closed the connection"):
            rx.recv(timeout=5.0)


def test_wait_for_looks_from_an_index_and_times_out(bus: PairBus) -> None:
    a, _ = bus.open_bus("a"), bus.open_bus("b")
    send(a, 0x181, b"\x01")
    bus.wait_for(lambda f: f.cob_id == 0x181)
    mark = len(bus.frames)
    send(a, 0x181, b"\x02")
    assert bus.wait_for(lambda f: f.cob_id == 0x181, after=mark).data == b"\x02"
    with pytest.raises(TimeoutError):
        bus.wait_for(lambda f: f.cob_id == 0x7FF, timeout_s=0.05)


def test_a_muted_member_hears_everything_and_reaches_no_one(bus: PairBus) -> None:
    a, b = bus.open_bus("a"), bus.open_bus("b")
    bus.mute("a")
    send(a, 0x181, b"\x01")  # lost
    bus.wait_for(lambda f: f.cob_id == 0x181)  # the relay took it before b's (two connections)
    send(b, 0x182, b"\x02")
    assert next_frame(a).arbitration_id == 0x182  # a still hears
    bus.unmute("a")
    send(a, 0x183, b"\x03")
    assert next_frame(b).arbitration_id == 0x183  # b never got 181h
    bus.wait_for(lambda f: f.cob_id == 0x183)
    assert [(f.sender, f.cob_id, f.delivered, f.to) for f in bus.frames] == [
        ("a", 0x181, False, frozenset()),
        ("b", 0x182, True, frozenset({"a"})),
        ("a", 0x183, True, frozenset({"b"})),
    ]


def test_a_split_bus_carries_frames_only_within_each_part(bus: PairBus) -> None:
    a, b, c, d = (bus.open_bus(n) for n in "abcd")
    bus.split({"a", "c"}, {"b", "d"})
    send(a, 0x181)
    send(b, 0x182)
    assert next_frame(c).arbitration_id == 0x181 and next_frame(d).arbitration_id == 0x182
    bus.wait_for(lambda f: f.cob_id == 0x182)
    assert {f.cob_id: f.to for f in bus.frames} == {0x181: frozenset({"c"}), 0x182: frozenset({"d"})}
    bus.heal()
    send(a, 0x183)
    for rx in (b, c, d):
        assert next_frame(rx).arbitration_id == 0x183
