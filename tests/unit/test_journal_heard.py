"""A pair's standby journals what it hears (``ZenohBridge.on_heard``): the other member's state
and EMCY events as published, once each (a late joiner's history repeats the cache), its values
in the value windows; nothing else. And the bridge's seq goes on from the journal
(``use_journal``)."""

from __future__ import annotations

import json
import time

from canopen_gateway.journal import Entry, Journal, ntp64_of_time, parse_time_range
from tests.helpers import gateway_of, make_config

P = "canopen/test"
T0 = time.time() - 3600.0  # an hour ago: within keep_days (the writer removes older entries)


def bridge_with_journal(tmp_path):
    cfg = make_config([{"name": "wire", "node_id": 1, "profile": "sgh10"}])
    gw = gateway_of(cfg, simulate=False)
    j = Journal(tmp_path / "j", values_ms=3_600_000)
    j.start()
    assert gw.zenoh is not None
    gw.zenoh.use_journal(j)
    return gw.zenoh, j


def test_heard_events_and_values_are_journaled_once(tmp_path):
    bridge, j = bridge_with_journal(tmp_path)

    def hear(key, seq, t):
        bridge.on_heard(key, json.dumps({"seq": seq}).encode(), ntp64_of_time(1.8e9 + t))

    for seq in (1, 2, 3):
        hear(f"{P}/wire/emcy", seq, seq)
    for seq in (1, 2, 3):  # the history of the other one's advanced publisher, again
        hear(f"{P}/wire/emcy", seq, seq)
    hear(f"{P}/wire/state", 7, 4)
    hear(f"{P}/wire/value/position", 40, 5)
    hear(f"{P}/wire/value/position", 41, 6)
    hear(f"{P}/wire/snapshot", 1, 7)  # not a published key of ours
    bridge.on_heard(f"{P}/wire/emcy", b"not json", ntp64_of_time(1.8e9))
    j.stop()
    rows = [(r.kind, r.key, r.seq) for r in Journal(tmp_path / "j").read()]
    assert rows == [
        ("emcy", f"{P}/wire/emcy", 1),
        ("emcy", f"{P}/wire/emcy", 2),
        ("emcy", f"{P}/wire/emcy", 3),
        ("state", f"{P}/wire/state", 7),
        ("value", f"{P}/wire/value/position", 41),
    ]
    assert bridge.heard.get(f"{P}/wire/emcy") == 3


def test_a_heard_seq_out_of_range_is_refused_and_the_writer_goes_on(tmp_path):
    bridge, j = bridge_with_journal(tmp_path)
    try:
        for seq in (2**64, 2**63, -1, True):
            bridge.on_heard(f"{P}/wire/emcy", json.dumps({"seq": seq}).encode(), ntp64_of_time(T0))
        bridge.on_heard(f"{P}/wire/emcy", b'{"seq": 3}', ntp64_of_time(T0 + 1))
        assert j.wait(j.append(Entry(ntp64_of_time(T0 + 2), "emcy", "k", None, 1, b"{}")), 10)
        assert bridge.heard.get(f"{P}/wire/emcy") == 3  # the others never counted
        assert j.counts.refused == 3 and j.status()["journaling"]  # -1 is no event: not offered
        assert [r.seq for r in j.read([f"{P}/wire/emcy"])] == [3]
    finally:
        j.stop()


def test_seq_of_every_key_goes_on_from_the_journal(tmp_path):
    bridge, j = bridge_with_journal(tmp_path)
    bridge.on_heard(f"{P}/wire/emcy", b'{"seq": 12}', ntp64_of_time(1.8e9))
    bridge.on_heard(f"{P}/wire/value/position", b'{"seq": 99}', ntp64_of_time(1.8e9))
    j.stop()
    again, j2 = bridge_with_journal(tmp_path)
    try:
        assert again.events.seq[f"{P}/wire/emcy"] == 12
        sp = again.pubs[("wire", "position")]
        assert again.seq_of("wire", "position", 1) == 1 + 99 and sp.seq_offset == 99
    finally:
        j2.stop()


def test_the_value_history_takes_each_changed_value_once_from_the_image(tmp_path):
    """Whether a session is open or not: the writer's window reads the image."""
    from canopen_gateway.journal import HybridClock
    from canopen_gateway.zenoh_bridge.journaling import ValueHistory

    bridge, j = bridge_with_journal(tmp_path)
    try:
        assert bridge.session is None
        history = ValueHistory(bridge.image, bridge.value_history, lambda node: True, HybridClock)
        assert history.window() == []  # nothing received yet
        node = bridge.image.nodes["wire"]
        _, names = next(r for r in bridge.commands.node("wire").tpdo_records if "position" in r[1])
        for _ in range(5):  # five frames, none published (no session)
            node.put(names, tuple(0 for _ in names), 1.8e9, time.monotonic())
        got = history.window()
        position = [e for e in got if e.key == f"{P}/wire/value/position"]
        assert [(e.node, e.seq, e.kind) for e in position] == [("wire", 5, "value")]
        assert json.loads(position[0].payload)["seq"] == 5
        assert [e for e in history.window() if e.key == position[0].key] == []  # taken once
    finally:
        j.stop()


def test_a_history_answer_stops_at_its_time_limit_and_says_where_to_resume(tmp_path):
    """Zenoh does not tell a queryable that its getter gave up: the answer stops after the
    limit (a fake clock) with where the rest starts, exclusive of what was sent."""
    from canopen_gateway.journal import TimeRange
    from canopen_gateway.zenoh_bridge.history import AnswerCut, HistoryService

    bridge, j = bridge_with_journal(tmp_path)
    try:
        t = ntp64_of_time(T0)
        last = 0
        for seq in range(1, 6):
            last = j.append(Entry(t + seq * 2**32, "emcy", f"{P}/wire/emcy", "wire", seq, b"{}"))
        assert j.wait(last, 10)
        now = [0.0]

        def clock() -> float:
            now[0] += 1.0  # each reply takes a second
            return now[0]

        service = HistoryService(j, P, [f"{P}/wire/emcy"], b"\x01" * 16, clock=clock, limit_s=2.5)

        class Query:
            parameters = {"_time": "[..]"}

        sent = []
        try:
            for _key, stamped in service.stamped_replies(Query(), f"{P}/wire/emcy"):  # type: ignore[arg-type]
                sent.append(stamped)
        except AnswerCut as cut:
            rest = parse_time_range(f"]{cut.resume}..]", 0)
            assert isinstance(rest, TimeRange) and cut.body("k")["error"] == "cut"
        assert len(sent) == 2
        lo, _ = rest.ntp64_bounds()
        assert [r.seq for r in j.read(t_from=lo)] == [3, 4, 5]  # the rest, nothing twice
    finally:
        j.stop()


def test_a_pair_per_network_journals_its_own_network_from_the_bus_and_the_other_as_heard(tmp_path):
    """Active on line1 and standby on line2, with no session open: line1's node's events and
    values are journaled from the bus side (its state names its network), line2's node only as
    heard of the other member; a heard sample of line1's node is its own, not journaled again."""
    from canopen_gateway.zenoh_bridge.journaling import ValueHistory
    from tests.helpers import parse_checked_config, unique_channel

    def net(name: str, node: dict[str, object]) -> dict[str, object]:
        return {"name": name, "can": {"interface": "virtual", "channel": unique_channel()},
                "nodes": [node]}  # fmt: skip

    cfg = parse_checked_config({"networks": [
        net("line1", {"name": "wire", "node_id": 1, "profile": "sgh10"}),
        net("line2", {"name": "rotary", "node_id": 1, "profile": "sgh10", "modbus": {"unit_id": 101}}),
    ], "modbus": {"enabled": False}}, environ={})  # fmt: skip
    bridge = gateway_of(cfg, simulate=False).zenoh
    assert bridge is not None and bridge.session is None
    j = Journal(tmp_path / "j", values_ms=3_600_000)
    j.start()
    try:
        bridge.use_journal(j)
        bridge.set_mastering(True, frozenset({"rotary"}))
        p, nodes = bridge.prefix, bridge.image.nodes
        for name in ("wire", "rotary"):
            bridge._on_health(nodes[name], "state")
        history = ValueHistory(bridge.image, bridge.value_history, bridge.publishes, lambda: bridge.hlc)
        for name in ("wire", "rotary"):
            _, names = next(r for r in bridge.commands.node(name).tpdo_records if "position" in r[1])
            nodes[name].put(names, tuple(0 for _ in names), 1.8e9, time.monotonic())
        assert {e.node for e in history.window()} == {"wire"}
        heard = json.dumps({"seq": 7, "network": "line2"}).encode()
        bridge.on_heard(f"{p}/rotary/state", heard, ntp64_of_time(T0))
        bridge.on_heard(f"{p}/wire/state", b'{"seq": 50}', ntp64_of_time(T0))  # its own network
    finally:
        j.stop()
    rows = {(r.key, r.seq): json.loads(r.payload) for r in Journal(tmp_path / "j").read(kinds=["state"])}
    assert sorted(rows) == [(f"{p}/rotary/state", 7), (f"{p}/wire/state", 1)]
    assert rows[f"{p}/wire/state", 1]["network"] == "line1"
    assert bridge.heard.get(f"{p}/wire/state") == 0
