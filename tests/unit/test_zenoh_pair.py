"""The Zenoh side of a hot-standby pair, pure: who may start under a prefix already in use, the
highest seq heard of the other gateway, and the offset that keeps a key's seq from going back
at a take-over (``canopen_gateway/zenoh_bridge/pair.py``)."""

from __future__ import annotations

import json

from canopen_gateway.zenoh_bridge.pair import HeardSeq, active_key, member_key, refusal, seq_offset
from tests.helpers import gateway_of

P = "canopen/line1"
GW = f"{P}/alive/_gateway"


def test_an_empty_prefix_lets_anyone_start() -> None:
    assert refusal([], P, None) is None
    assert refusal([f"{P}/alive/wire"], P, (100, 101)) is None


def test_a_stranger_is_refused_by_a_single_gateway_and_by_a_pair() -> None:
    assert refusal([GW], P, None) == GW
    assert refusal([GW, member_key(P, 100, 101), active_key(P, 101)], P, None) == GW


def test_the_partner_of_a_pair_member_is_let_in() -> None:
    tokens = [GW, member_key(P, 100, 101), active_key(P, 101), f"{P}/alive/wire"]
    assert refusal(tokens, P, (100, 102)) is None


def test_a_pair_member_is_refused_by_a_gateway_outside_a_pair() -> None:
    assert refusal([GW], P, (100, 102)) == GW


def test_a_pair_member_is_refused_by_another_pairs_gateway() -> None:
    """Another logical master (master.node_id) under the same prefix is not a partner."""
    assert refusal([GW, member_key(P, 50, 101)], P, (100, 102)) == GW


def test_the_same_member_started_twice_is_refused() -> None:
    own = member_key(P, 100, 101)
    assert refusal([GW, own], P, (100, 101)) == own


def test_member_keys_do_not_match_a_longer_master_id() -> None:
    """``_pair/10/...`` is no partner of master 1 (the id is a whole chunk)."""
    assert refusal([GW, member_key(P, 10, 101)], P, (1, 102)) == GW


def test_heard_seq_keeps_the_highest_per_key_of_the_keys_it_watches() -> None:
    heard = HeardSeq([f"{P}/wire/value/position", f"{P}/wire/state"])
    heard.on_sample(f"{P}/wire/value/position", json.dumps({"value": 1, "seq": 7}).encode())
    heard.on_sample(f"{P}/wire/value/position", json.dumps({"value": 1, "seq": 5}).encode())
    heard.on_sample(f"{P}/wire/state", b'{"seq": 3}')
    assert heard.get(f"{P}/wire/value/position") == 7
    assert heard.get(f"{P}/wire/state") == 3
    assert heard.get(f"{P}/wire/emcy") == 0


def test_heard_seq_ignores_what_is_not_a_sample_with_a_seq() -> None:
    heard = HeardSeq([f"{P}/wire/value/position", f"{P}/wire/pdo/181"])
    for key, payload in [
        (f"{P}/wire/pdo/181", b"\x01\x02\xff"),  # raw PDO bytes
        (f"{P}/wire/value/position", b"not json"),
        (f"{P}/wire/value/position", b"[1, 2]"),
        (f"{P}/wire/value/position", b'{"seq": "9"}'),
        (f"{P}/other/value/x", b'{"seq": 99}'),  # not one of ours
    ]:
        heard.on_sample(key, payload)
    assert heard.highest == {} and heard.samples == 0


def test_the_seq_after_a_take_over_goes_above_what_was_heard() -> None:
    # the other gateway published seq 590; this one's image counted 580 frames of the signal
    off = seq_offset(0, heard=590, own=580)
    assert 581 + off > 590  # the next frame
    assert 580 + off >= 590  # a republication of the current value does not go back
    # this one counted more than was heard: its own numbers already go on
    assert seq_offset(0, heard=590, own=600) == 0
    # a second take-over never lowers the offset: its own earlier samples stay below
    assert seq_offset(10, heard=0, own=700) == 10


class _Capture:
    """A publisher and a session stand-in: what was put, no network."""

    def __init__(self) -> None:
        self.payloads: list[dict[str, object]] = []

    def put(self, payload: str, timestamp: object = None) -> None:
        self.payloads.append(json.loads(payload))

    def new_timestamp(self) -> None:
        return None


def test_a_take_over_numbers_value_keys_and_pdo_records_above_what_was_heard() -> None:
    """The bridge of a gateway that stood by and takes over (no session, no bus: the
    publication path with captured puts)."""
    from tests.helpers import make_config

    wire = {"name": "wire", "node_id": 1, "profile": "sgh10",
            "signals": {"position": {"publish": "change"}}}  # fmt: skip
    gw = gateway_of(make_config([wire], zenoh={"publish": "pdo"}, modbus={"enabled": False}), False)
    bridge = gw.zenoh
    assert bridge is not None
    node = gw.image.nodes["wire"]
    sp = bridge.pubs[("wire", "position")]
    pp = next(iter(bridge.pdo_pubs.values()))
    assert pp.names == ("position", "velocity")
    sp.pub, pp.pub, bridge.link.session = _Capture(), _Capture(), _Capture()  # type: ignore[assignment]
    gw.image.value_listeners.append(bridge._on_values)  # as the bridge's start does
    bridge.set_mastering(False)
    for k in range(30):  # frames heard while standing by: 30 in this gateway's image
        gw.image.update(node, pp.names, (k, 0), 1.0)
    bridge._values.flush()
    assert sp.pub.payloads == [] and pp.pub.payloads == []  # nothing published
    # the other gateway had published up to 95 (value) and 90 (record)
    bridge.heard.on_sample(sp.key, b'{"seq": 95}')
    bridge.heard.on_sample(pp.key, b'{"seq": 90}')
    assert bridge.seq_of("wire", "position", 30) == 95  # a get on the standby: not below
    bridge.set_mastering(True)
    gw.image.update(node, pp.names, (31, 0), 1.0)  # the first frame after the take-over
    bridge._values.flush()
    assert [p["seq"] for p in sp.pub.payloads] == [96]
    assert [p["seq"] for p in pp.pub.payloads] == [91]
    assert bridge.seq_of("wire", "position", 31) == 96  # a get answers the same number


def test_a_pair_per_network_publishes_only_the_nodes_of_the_networks_it_masters() -> None:
    """A gateway active on line1 and standby on line2 (``set_mastering(True, silent)``): line2's
    node is neither published nor given a liveliness token; taking line2 over later, its keys
    go on above what was heard of the other member."""
    from tests.helpers import parse_checked_config, unique_channel

    def net(name: str, node: dict[str, object]) -> dict[str, object]:
        return {"name": name, "can": {"interface": "virtual", "channel": unique_channel()},
                "nodes": [node]}  # fmt: skip

    cfg = parse_checked_config({"networks": [
        net("line1", {"name": "wire", "node_id": 1, "profile": "sgh10"}),
        net("line2", {"name": "rotary", "node_id": 1, "profile": "sgh10", "modbus": {"unit_id": 101}}),
    ], "modbus": {"enabled": False}}, environ={})  # fmt: skip
    gw = gateway_of(cfg, False)
    bridge = gw.zenoh
    assert bridge is not None
    wire, rotary = gw.image.nodes["wire"], gw.image.nodes["rotary"]
    pubs = {n: bridge.pubs[(n, "position")] for n in ("wire", "rotary")}
    for sp in pubs.values():
        sp.pub = _Capture()  # type: ignore[assignment]
    bridge.link.session = _Capture()  # type: ignore[assignment]
    gw.image.value_listeners.append(bridge._on_values)
    bridge.set_mastering(True, frozenset({"rotary"}))
    names = ("position", "velocity")
    for k in range(3):
        gw.image.update(wire, names, (k, 0), 1.0)
        gw.image.update(rotary, names, (k, 0), 1.0)
    bridge._values.flush()
    assert len(pubs["wire"].pub.payloads) >= 1 and pubs["rotary"].pub.payloads == []
    assert not bridge.node_alive(rotary)
    bridge.on_heard(pubs["rotary"].key, b'{"seq": 40}', None)  # the other member's sample
    bridge.on_heard(pubs["wire"].key, b'{"seq": 99}', None)  # its own: not taken as heard
    assert bridge.heard.get(pubs["wire"].key) == 0
    bridge.set_mastering(True)  # line2 taken over
    gw.image.update(rotary, names, (9, 0), 1.0)
    bridge._values.flush()
    assert [p["seq"] for p in pubs["rotary"].pub.payloads] == [41]
