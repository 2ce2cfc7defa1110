"""Other-master detection with a bus that echoes our own frames (``receive_own_messages``):
what the gateway sent and is waiting for its echo stays bounded whatever the run time, each
echo answers one frame we sent, and a second gateway with our node id (the same heartbeat
payload) is seen after an hour as in the first second. A fake clock: an hour is simulated."""

from __future__ import annotations

from canopen_gateway.bus.bus_peers import ECHO_PENDING_MAX, BusPeers

OWN_ID = 127
OWN_HB_COB = 0x700 + OWN_ID
OPERATIONAL = b"\x05"
HEARTBEAT_S = 0.1  # master.heartbeat_ms 100
HOUR_S = 3600.0


def test_an_hour_of_echoed_heartbeats_leaves_nothing_behind_and_a_second_gateway_is_seen() -> None:
    peers = BusPeers(OWN_ID, {1}, echo=True)
    now = 1000.0
    most = 0
    for i in range(int(HOUR_S / HEARTBEAT_S)):  # 36,000 heartbeats, each echoed by the bus
        now = 1000.0 + i * HEARTBEAT_S
        peers.sent(OWN_HB_COB, OPERATIONAL, now)
        most = max(most, peers.echoes_pending)
        assert peers.on_own_heartbeat(OPERATIONAL, wall=0.0, now=now + 0.0002) is None
    assert most == 1  # each echo took its frame
    assert peers.echoes_pending == 0
    assert "heartbeat" not in peers.other_master

    # a second gateway configured with our node id: operational too, the same payload
    now += HEARTBEAT_S
    peers.sent(OWN_HB_COB, OPERATIONAL, now)
    assert peers.on_own_heartbeat(OPERATIONAL, wall=0.0, now=now + 0.0001) is None  # our echo
    text = peers.on_own_heartbeat(OPERATIONAL, wall=0.0, now=now + 0.03)  # the other's
    assert text is not None and "node id 127" in text
    assert peers.other_master["heartbeat"].count == 1


def test_the_other_gateways_heartbeat_before_our_echo_is_seen_all_the_same() -> None:
    """Its frame takes our pending entry; our echo then has none left: one of the two is
    reported, never both taken as ours."""
    peers = BusPeers(OWN_ID, {1}, echo=True)
    peers.sent(OWN_HB_COB, OPERATIONAL, 10.0)
    assert peers.on_own_heartbeat(OPERATIONAL, wall=0.0, now=10.0001) is None  # the other's
    assert peers.on_own_heartbeat(OPERATIONAL, wall=0.0, now=10.0002) is not None  # ours, late


def test_frames_whose_echo_never_comes_are_not_kept() -> None:
    """``receive_own_messages`` set on a backend that does not echo: an hour of heartbeats and
    NMT commands with no frame coming back keeps at most the echo window's worth."""
    peers = BusPeers(OWN_ID, {1}, echo=True, echo_window_s=1.0)
    for i in range(int(HOUR_S / HEARTBEAT_S)):
        now = i * HEARTBEAT_S
        peers.sent(OWN_HB_COB, OPERATIONAL, now)
        peers.sent(0x000, b"\x01\x00", now)
    assert peers.echoes_pending <= 2 * (1.0 / HEARTBEAT_S + 1)
    for _ in range(10 * ECHO_PENDING_MAX):  # a storm of NMT commands within one window
        peers.sent(0x000, b"\x81\x00", 5000.0)
    assert peers.echoes_pending == ECHO_PENDING_MAX


def test_with_the_echo_off_our_own_payload_from_the_bus_is_another_device() -> None:
    """Without the echo the gateway never receives its own frames: a heartbeat on its COB-ID,
    whatever its payload, is another device's."""
    peers = BusPeers(OWN_ID, {1}, echo=False)
    peers.sent(OWN_HB_COB, OPERATIONAL, 10.0)
    assert peers.echoes_pending == 0
    assert peers.on_own_heartbeat(OPERATIONAL, wall=0.0, now=10.0) is not None
