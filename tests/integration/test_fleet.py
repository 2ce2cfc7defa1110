"""A fleet: three gateway processes (``canopen-gateway run``, each with its own virtual CAN bus
and simulated devices) on one Zenoh router. A subscriber on ``canopen/**`` gets values from all
three; fleet-wide queries are answered by every gateway; a query for one gateway reaches its
bus only; a gateway killed takes only its own tokens away; a fourth gateway with a prefix
already in use is refused with a one-line error (exit 2)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import yaml

from tests.helpers import free_port, unique_channel, wait_until
from tests.zenoh_client import ZClient, open_router

ROOT = Path(__file__).resolve().parents[2]
LINES = ("line1", "line2", "line3")


def fleet_config(tmp: Path, name: str, endpoint: str, mode: str = "client") -> Path:
    raw = {
        "gateway": {"name": name},
        "can": {"interface": "virtual", "channel": unique_channel()},
        "master": {"heartbeat_ms": 200, "boot_timeout_s": 5},
        "nodes": [{"name": "wire", "node_id": 1, "profile": "sgh10"}],
        "modbus": {"enabled": False},
        "zenoh": {"mode": mode, "listen": [], "connect": [endpoint], "writes": True},
        "simulate": {"nodes": "all", "motion": {"wire": {"kind": "ramp", "speed": 500}}},
    }
    path = tmp / f"{name}-{mode}.yaml"
    path.write_text(yaml.safe_dump(raw))
    return path


def start_gateway(cfg: Path) -> subprocess.Popen[str]:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.Popen(
        [sys.executable, "-m", "canopen_gateway", "run", "-c", str(cfg)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        cwd=ROOT,
    )


def wait_started(p: subprocess.Popen[str]) -> str:
    """The summary line the gateway prints once started (blocking read, bounded by the test's
    own timeouts through the process dying)."""
    assert p.stdout is not None
    line = p.stdout.readline()
    assert "canopen-gateway" in line, f"gateway did not start: {line!r} {p.poll()}"
    return line


@contextmanager
def fleet(tmp: Path) -> Iterator[tuple[str, dict[str, subprocess.Popen[str]]]]:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = open_router(endpoint)
    procs: dict[str, subprocess.Popen[str]] = {}
    try:
        for name in LINES:
            procs[name] = start_gateway(fleet_config(tmp, name, endpoint))
        for p in procs.values():
            wait_started(p)
        yield endpoint, procs
    finally:
        for p in procs.values():
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
        for p in procs.values():
            try:
                p.communicate(timeout=10)
            except subprocess.TimeoutExpired:
                p.kill()
                p.communicate()
        router.close()


class Tokens:
    """The liveliness tokens present under ``canopen/*/alive/**``, kept up to date from a
    liveliness subscriber (history: the ones present when it starts, then every change)."""

    def __init__(self, z: ZClient) -> None:
        self.q = z.watch_liveliness("canopen/*/alive/**")
        self.present: set[str] = set()

    def now(self) -> set[str]:
        while not self.q.empty():
            s = self.q.get_nowait()
            if s.kind == "PUT":
                self.present.add(s.key)
            else:
                self.present.discard(s.key)
        return set(self.present)


async def test_three_gateways_on_one_router(tmp_path: Path) -> None:
    with fleet(tmp_path) as (endpoint, procs):
        z = ZClient([endpoint], mode="client")
        try:
            everyone = {f"canopen/{n}/alive/{t}" for n in LINES for t in ("_gateway", "wire")}
            tokens = Tokens(z)
            # each gateway's node becomes usable on its own bus
            await wait_until(lambda: everyone <= tokens.now(), 15, f"tokens {sorted(everyone)}")

            # a subscriber on canopen/** gets values from all three
            q = z.subscribe("canopen/**")
            seen: set[str] = set()

            def values_from_all() -> bool:
                while not q.empty():
                    s = q.get_nowait()
                    if "/value/" in s.key:
                        seen.add(s.key.split("/")[1])
                return seen >= set(LINES)

            await wait_until(values_from_all, 10, "values from line1, line2 and line3")

            # fleet-wide queries: every gateway answers
            cats = await z.get("canopen/*/catalog")
            assert sorted(r.body["gateway"] for r in cats if r.ok) == list(LINES)
            for r in cats:
                assert r.body["version"] and r.body["can"]["interface"] == "virtual"
                assert list(r.body["nodes"]) == ["wire"] and r.body["prefix"] == r.key[:-8]
            states = await z.get("canopen/*/*/state")
            assert sorted(r.key for r in states if r.ok) == [f"canopen/{n}/wire/state" for n in LINES]

            # a query for one gateway reaches that gateway's bus only
            w = await z.get("canopen/line2/wire/set/operating_parameters",
                            payload='{"bits": {"counting_direction_descending": true}}')  # fmt: skip
            assert len(w) == 1 and w[0].ok, w
            for n in LINES:
                r = await z.get_one(f"canopen/{n}/wire/sdo/6000/00")
                assert r.ok
                assert bool(r.body["value"] & 0x8) is (n == "line2"), (n, r.body)

            # one gateway killed: only its tokens go
            procs["line3"].kill()
            procs["line3"].wait(10)
            gone = {"canopen/line3/alive/_gateway", "canopen/line3/alive/wire"}
            await wait_until(lambda: not tokens.now() & gone, 10, "line3's tokens gone")
            assert tokens.now() == everyone - gone

            # a second gateway under a prefix in use starts without Zenoh and says why
            dup = start_gateway(fleet_config(tmp_path, "line1", endpoint, mode="peer"))
            try:
                wait_started(dup)
                assert dup.stderr is not None
                line = ""
                while "another participant announces" not in line:
                    line = dup.stderr.readline()
                    assert line, f"no duplicate-prefix line: {dup.poll()}"
                assert "canopen/line1" in line and "ERROR" in line
                assert dup.poll() is None  # runs on (Modbus and the bus), Zenoh closed
            finally:
                dup.terminate()
                dup.communicate(timeout=30)
            assert tokens.now() == everyone - gone  # the first line1 runs on, untouched
        finally:
            z.close()
