"""The shipped router configuration (deploy/zenoh/*.json5), loaded as it is into a router-mode
eclipse-zenoh session with a users file of the test's own: every gateway prefix of the shipped
configurations (config/, deploy/) belongs to that gateway's login alone. A ``viewer`` login
reads (subscribes, gets, sees liveliness) but cannot put a value, announce a gateway
(``alive/_gateway``), answer a query, send a command or ask the audit under any of them; the
``operator`` login sends commands and asks the audit; each gateway's login publishes under its prefix and no other, and an
advanced subscriber gets the history of an advanced publisher through the router."""

from __future__ import annotations

import json
import queue
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml
import zenoh
import zenoh.ext

from tests.helpers import free_port

ROOT = Path(__file__).resolve().parents[2]
ROUTER_CONFIGS = sorted((ROOT / "deploy" / "zenoh").glob("*.json5"))
WAIT_S = 5.0


def shipped_prefixes() -> list[str]:
    """The Zenoh prefix of every gateway configuration in config/ and deploy/ (the k8s
    ConfigMaps included)."""
    docs: list[Any] = []
    for path in [*(ROOT / "config").glob("*.yaml"), *(ROOT / "deploy" / "config").glob("*.yaml")]:
        docs.append(yaml.safe_load(path.read_text()))
    for path in (ROOT / "deploy" / "k8s").rglob("configmap.yaml"):
        for value in yaml.safe_load(path.read_text())["data"].values():
            docs.append(yaml.safe_load(value))
    prefixes = {
        (d.get("zenoh") or {}).get("prefix") or f"canopen/{d['gateway']['name']}" for d in docs
    }
    return sorted(prefixes)


def login(endpoint: str, user: str, mode: str = "router") -> zenoh.Config:
    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps(mode))
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("transport/auth/usrpwd/user", json.dumps(user))
    conf.insert_json5("transport/auth/usrpwd/password", json.dumps(f"{user}-secret"))
    return conf


def gateway_user(prefix: str) -> str:
    return "gateway-" + prefix.removeprefix("canopen/")


@pytest.fixture(params=ROUTER_CONFIGS, ids=lambda p: p.name)
def router(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[str]:
    """The shipped file, its users file and listen endpoint replaced by the test's."""
    users = ["viewer", "observer", "operator", *map(gateway_user, shipped_prefixes())]
    users_file = tmp_path / "users.txt"
    users_file.write_text("".join(f"{u}:{u}-secret\n" for u in users))
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    conf = zenoh.Config.from_file(str(request.param))
    conf.insert_json5("listen/endpoints", json.dumps([endpoint]))
    conf.insert_json5("transport/auth/usrpwd/dictionary_file", json.dumps(str(users_file)))
    session = zenoh.open(conf)
    try:
        yield endpoint
    finally:
        session.close()


def open_as(endpoint: str, user: str) -> zenoh.Session:
    return zenoh.open(login(endpoint, user, mode="client"))


def round_trip(s: zenoh.Session) -> None:
    """Everything this session sent before has reached the router (one link, in order)."""
    list(s.get("canopen/_/round-trip", timeout=2.0))


def test_the_shipped_router_configs_exist() -> None:
    assert ROUTER_CONFIGS and shipped_prefixes()


def test_a_viewer_cannot_speak_for_any_shipped_gateway(router: str) -> None:
    viewer, observer, operator = (open_as(router, u) for u in ("viewer", "observer", "operator"))
    sessions = [viewer, observer, operator]
    held: list[Any] = []  # declarations live as long as their objects
    try:
        for prefix in shipped_prefixes():
            gateway = open_as(router, gateway_user(prefix))
            sessions.append(gateway)
            received: queue.Queue[tuple[str, str]] = queue.Queue()
            held.append(observer.declare_subscriber(
                f"{prefix}/**",
                lambda s, received=received: received.put((str(s.key_expr), s.payload.to_string())),
            ))
            asked: list[str] = []
            held.append(gateway.declare_queryable(
                f"{prefix}/**",
                lambda q, asked=asked: (asked.append(str(q.key_expr)), q.reply(str(q.key_expr), "real"), q.drop()),
            ))
            held.append(gateway.liveliness().declare_token(f"{prefix}/alive/_gateway"))
            round_trip(gateway)
            # the viewer tries to speak for the gateway
            viewer.put(f"{prefix}/wire/value/position", "forged")
            held.append(viewer.liveliness().declare_token(f"{prefix}/alive/_gateway/forged"))
            held.append(viewer.liveliness().declare_token(f"{prefix}/**"))
            assert list(viewer.get(f"{prefix}/wire/set/set_point", payload="1", timeout=1.0)) == []
            held.append(viewer.declare_queryable(
                f"{prefix}/**", lambda q: (q.reply(str(q.key_expr), "rogue"), q.drop())
            ))
            round_trip(viewer)
            gateway.put(f"{prefix}/wire/value/position", "real")
            got = received.get(timeout=WAIT_S)
            assert got == (f"{prefix}/wire/value/position", "real"), (prefix, got)
            assert received.empty(), (prefix, received.get())
            tokens = {str(r.ok.key_expr) for r in observer.liveliness().get(f"{prefix}/**", timeout=2) if r.ok}
            assert tokens == {f"{prefix}/alive/_gateway"}, prefix
            answers = [r.ok.payload.to_string() for r in observer.get(f"{prefix}/wire/snapshot", timeout=2) if r.ok]
            assert answers == ["real"], prefix
            assert f"{prefix}/wire/set/set_point" not in asked  # the viewer's command was dropped
            ok = [r.ok.payload.to_string() for r in operator.get(f"{prefix}/wire/nmt", payload="stop", timeout=2) if r.ok]
            assert ok == ["real"], prefix  # the operator's command reached the gateway
        # a gateway's login is confined to its own prefix
        a, b = shipped_prefixes()[:2]
        intruder = open_as(router, gateway_user(a))
        sessions.append(intruder)
        seen: queue.Queue[str] = queue.Queue()
        held.append(observer.declare_subscriber(f"{b}/intrusion", lambda s: seen.put(s.payload.to_string())))
        intruder.put(f"{b}/intrusion", "from another gateway")
        round_trip(intruder)
        with pytest.raises(queue.Empty):
            seen.get(timeout=0.3)
    finally:
        for s in sessions:
            s.close()


def test_only_the_operator_may_ask_a_shipped_gateways_audit(router: str) -> None:
    viewer, operator = open_as(router, "viewer"), open_as(router, "operator")
    sessions, held = [viewer, operator], []
    try:
        asked: list[str] = []
        for prefix in shipped_prefixes():
            gateway = open_as(router, gateway_user(prefix))
            sessions.append(gateway)
            held.append(gateway.declare_queryable(
                f"{prefix}/**",
                lambda q: (asked.append(str(q.key_expr)), q.reply(str(q.key_expr), "audit"), q.drop()),
            ))  # fmt: skip
            round_trip(gateway)
        # every prefix asked at once: the denied gets end together, at their timeout
        denied = [viewer.get(f"{p}/audit?_time=[..]", timeout=1.0) for p in shipped_prefixes()]
        allowed = [operator.get(f"{p}/audit?_time=[..]", timeout=2.0) for p in shipped_prefixes()]
        assert [[r.ok.payload.to_string() for r in a if r.ok] for a in allowed] == [["audit"]] * len(allowed)
        assert [list(d) for d in denied] == [[]] * len(denied)
        assert sorted(asked) == [f"{p}/audit" for p in shipped_prefixes()]  # the operator's only
    finally:
        for s in sessions:
            s.close()


def test_an_advanced_subscriber_gets_a_gateways_history_through_the_router(router: str) -> None:
    prefix = shipped_prefixes()[0]
    gateway, observer = open_as(router, gateway_user(prefix)), open_as(router, "observer")
    try:
        pub = zenoh.ext.declare_advanced_publisher(
            gateway, f"{prefix}/wire/state", cache=zenoh.ext.CacheConfig(10),
            sample_miss_detection=zenoh.ext.MissDetectionConfig(heartbeat=0.5),
            publisher_detection=True,
        )  # as the gateway declares its event publishers (zenoh_bridge.session)
        for i in range(3):
            pub.put(str(i))
        got: list[str] = []
        done = threading.Event()

        def on_sample(s: zenoh.Sample) -> None:
            got.append(s.payload.to_string())
            if len(got) == 3:
                done.set()

        sub = zenoh.ext.declare_advanced_subscriber(
            observer, f"{prefix}/**", on_sample,
            history=zenoh.ext.HistoryConfig(detect_late_publishers=True),
        )  # fmt: skip
        assert done.wait(WAIT_S), got
        sub.undeclare()
        assert got == ["0", "1", "2"]
    finally:
        observer.close()
        gateway.close()
