"""What the gateway heard is on its disk whatever the cloud, the disk or the clock do, and the
journal never stops the live path: real gateway processes on a CAN bus shared through
python-can-remote, EMCY frames sent as the device would, faults made for real.

* the router absent at start, the gateway killed and started again during the outage with its
  wall clock 30 s behind (an LD_PRELOAD library shifts ``clock_gettime(CLOCK_REALTIME)``):
  every event is journaled, ``seq`` goes on, history comes back in order and a client resuming
  after the last time it saw gets every later event; once the router is there, the events of
  the outage are published too (an advanced subscriber gets them from the publisher's cache);
* the journal on a small filesystem (a 2 MB ext4 image, loop-mounted) filled up: the oldest
  entries go, the newest are kept, ``/healthz`` names the full disk; then the filesystem frozen
  (``fsfreeze``): events are still published, ``/healthz`` says the journal does not answer,
  and once it is thawed the events of the freeze are journaled;
* a second gateway on the same ``journal.path`` exits 2 with one line naming ``journal.path``
  and the pid of the gateway that holds it.

The filesystem sequence needs root (mount, fsfreeze) and skips without it."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml
import zenoh
import zenoh.ext

from canopen_gateway.journal import Journal
from tests.helpers import free_port, stop_process, wait_ready, wait_until_sync
from tests.integration.test_journal_processes import Bus, kill
from tests.zenoh_client import open_router, session_config

pytest.importorskip("can_remote")

P = "canopen/jf"
KEY = f"{P}/wire/emcy"
ROOT = Path(__file__).resolve().parents[2]


def write_config(tmp: Path, bus: Bus, journal: Path, zenoh_section: dict[str, Any], name: str = "jf") -> Path:
    raw = {
        "gateway": {"name": name},
        "can": {"interface": "remote", "channel": bus.url},
        "nodes": [{"name": "wire", "node_id": 1, "profile": "sgh10"}],
        "modbus": {"port": free_port()},  # ready without the cloud: the PLC's side serves
        "zenoh": {"prefix": P, **zenoh_section},
        "health": {"port": free_port()},
        "journal": {"path": str(journal)},
    }
    path = tmp / f"{name}.yaml"
    path.write_text(yaml.safe_dump(raw), encoding="utf-8")
    return path


def start(config: Path, env: dict[str, str] | None = None) -> subprocess.Popen[str]:
    """A gateway process; its log lines (an EMCY flood logs thousands) go to a file beside
    the config, never to a pipe nobody reads (a full pipe stops the gateway's loop)."""
    log = open(config.with_suffix(".log"), "a", encoding="utf-8")
    try:
        return subprocess.Popen(
            [sys.executable, "-m", "canopen_gateway", "run", "-c", str(config), "--log-level", "warning"],
            cwd=ROOT, stdout=subprocess.PIPE, stderr=log, text=True,
            env={**os.environ, **(env or {})},
        )  # fmt: skip
    finally:
        log.close()


def health(config: Path) -> dict[str, Any]:
    port = yaml.safe_load(config.read_text())["health"]["port"]
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/healthz", timeout=5) as r:
            return json.loads(r.read())
    except urllib.error.HTTPError as e:  # 503 when not ready: the document all the same
        return json.loads(e.read())


def seqs(journal: Path, key: str = KEY) -> list[int]:
    """The seq of every entry of ``key``, in the journal's (history's) order."""
    if not (journal / "journal.sqlite3").exists():
        return []
    return [r.seq for r in Journal(journal).read([key])]


@pytest.fixture(scope="module")
def clock_shift(tmp_path_factory: pytest.TempPathFactory) -> Path | None:
    """The LD_PRELOAD library of tests/faults/clockshift.c, built here (None: no compiler)."""
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        return None
    out = tmp_path_factory.mktemp("clockshift") / "clockshift.so"
    src = ROOT / "tests" / "faults" / "clockshift.c"
    done = subprocess.run([cc, "-shared", "-fPIC", "-O2", "-o", str(out), str(src), "-ldl"], capture_output=True)
    return out if done.returncode == 0 else None


def gateway_seen(client: zenoh.Session) -> bool:
    return any(r.ok is not None for r in client.liveliness().get(f"{P}/alive/_gateway", timeout=1.0))


def history(client: zenoh.Session, selector: str) -> list[tuple[int, Any]]:
    """(seq, timestamp) of every reply (an error reply fails the test)."""
    out = []
    for r in client.get(selector, timeout=10.0):
        assert r.ok is not None, r.err.payload.to_string()
        out.append((json.loads(r.ok.payload.to_bytes())["seq"], r.ok.timestamp))
    return out


def test_router_absent_at_start_restart_during_the_outage_and_a_clock_step(tmp_path, clock_shift):
    bus = Bus()
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    journal = tmp_path / "journal"
    cfg = write_config(tmp_path, bus, journal, {"mode": "client", "listen": [], "connect": [endpoint]})
    gw = start(cfg)
    router = client = None
    try:
        wait_ready(gw)  # no router: the bus and Modbus run, Zenoh retries in the background
        bus.events(10)
        wait_until_sync(lambda: seqs(journal) == list(range(1, 11)), 20, "10 events journaled")
        status = health(cfg)
        assert status["zenoh"] is False and status["journal"]["journaling"] is True
        assert status["journal"]["written"] >= 10 and status["journal"]["dropped"] == 0

        kill(gw)  # a restart during the outage, the wall clock now 30 s behind
        shifted = {"LD_PRELOAD": str(clock_shift), "CLOCK_SHIFT_NS": str(-30 * 10**9)}
        gw = start(cfg, shifted if clock_shift is not None else None)
        wait_ready(gw)
        bus.events(10)
        wait_until_sync(lambda: seqs(journal) == list(range(1, 21)), 20, "20 events journaled in order")

        router = open_router(endpoint)
        client = zenoh.open(session_config("client", connect=[endpoint]))
        wait_until_sync(lambda: gateway_seen(client), 30, "the gateway through the router")
        replies = history(client, f"{KEY}?_time=[..]")
        assert [s for s, _ in replies] == list(range(1, 21))  # by the journal's clock, not the wall's
        tenth = replies[9][1].get_time_as_ntp64().to_string_rfc3339_lossy()
        assert [s for s, _ in history(client, f"{KEY}?_time=]{tenth}..]")] == list(range(11, 21))
        assert [s for s, _ in history(client, f"{KEY}?_time=[{tenth}..{tenth}]")] == [10]

        # the events of the outage were published once the session opened: in the cache
        got: list[int] = []
        sub = zenoh.ext.declare_advanced_subscriber(
            client, KEY, lambda s: got.append(json.loads(s.payload.to_bytes())["seq"]),
            history=zenoh.ext.HistoryConfig(detect_late_publishers=True),
        )  # fmt: skip
        wait_until_sync(lambda: got == list(range(11, 21)), 20, f"the outage's events published: {got}")
        sub.undeclare()
    finally:
        stop_process(gw)
        if client is not None:
            client.close()
        if router is not None:
            router.close()
        bus.close()


@pytest.fixture
def small_disk(tmp_path: Path) -> Iterator[Path]:
    """A 2 MB ext4 filesystem, loop-mounted (root only)."""
    if os.geteuid() != 0 or not all(shutil.which(t) for t in ("mkfs.ext4", "mount", "fsfreeze")):
        pytest.skip("needs root, mkfs.ext4, mount and fsfreeze")
    image, mnt = tmp_path / "disk.img", tmp_path / "disk"
    mnt.mkdir()
    with open(image, "wb") as f:
        f.truncate(2 << 20)
    subprocess.run(["mkfs.ext4", "-q", "-O", "^has_journal", "-N", "64", str(image)], check=True)
    if subprocess.run(["mount", "-o", "loop", str(image), str(mnt)], capture_output=True).returncode:
        pytest.skip("a loop mount is not possible here")
    try:
        yield mnt
    finally:
        subprocess.run(["fsfreeze", "-u", str(mnt)], capture_output=True)
        subprocess.run(["umount", "-l", str(mnt)], capture_output=True)


def test_a_full_then_frozen_journal_filesystem_never_stops_the_events(tmp_path, small_disk):
    bus = Bus()
    listen = f"tcp/127.0.0.1:{free_port()}"
    journal = small_disk / "journal"
    cfg = write_config(tmp_path, bus, journal, {"listen": [listen]})
    gw = start(cfg)
    client = None
    frozen = False
    try:
        wait_ready(gw)
        client = zenoh.open(session_config("peer", connect=[listen]))
        got: list[int] = []
        sub = client.declare_subscriber(KEY, lambda s: got.append(json.loads(s.payload.to_bytes())["seq"]))
        bus.events(2)
        wait_until_sync(lambda: len(got) == 2, 20, "the subscriber matched")

        sent = 2
        while not health(cfg)["journal"]["disk_full"]:  # fill the disk
            assert sent < 40_000, "the disk never filled"
            bus.events(1000)
            sent += 1000
            wait_until_sync(lambda n=sent: len(got) >= n, 30, f"{sent} events published")
        full = health(cfg)["journal"]
        assert "disk full" in full["error"] and full["journaling"] is True
        wait_until_sync(lambda: seqs(journal)[-1:] == [sent], 20, "the newest event journaled")
        kept = seqs(journal)
        assert kept[0] > 1 and kept == list(range(kept[0], sent + 1))  # the oldest went first

        subprocess.run(["fsfreeze", "-f", str(small_disk)], check=True)
        frozen = True
        bus.events(20)  # published while the journal's disk does not answer
        wait_until_sync(lambda: got[-1:] == [sent + 20], 20, "the events of the freeze published")
        stalled = wait_until_sync(
            lambda: (h := health(cfg)["journal"])["journaling"] is False and h, 10, "the stall shown"
        )
        assert "does not answer" in stalled["error"] and stalled["published_unjournaled"] >= 1
        subprocess.run(["fsfreeze", "-u", str(small_disk)], check=True)
        frozen = False
        wait_until_sync(lambda: seqs(journal)[-1:] == [sent + 20], 20, "the freeze's events journaled")
        assert got == list(range(1, sent + 21))  # every event published once, in order
        sub.undeclare()
    finally:
        if frozen:
            subprocess.run(["fsfreeze", "-u", str(small_disk)], capture_output=True)
        stop_process(gw)
        if client is not None:
            client.close()
        bus.close()


def test_a_second_gateway_on_the_same_journal_exits_2_naming_the_path_and_the_holder(tmp_path):
    bus = Bus()
    journal = tmp_path / "journal"
    first = start(write_config(tmp_path, bus, journal, {"listen": [f"tcp/127.0.0.1:{free_port()}"]}))
    try:
        wait_ready(first)
        second = start(
            write_config(tmp_path, bus, journal, {"listen": [f"tcp/127.0.0.1:{free_port()}"],
                                                  "prefix": f"{P}2"}, name="jf2")
        )  # fmt: skip
        second.communicate(timeout=30)
        err = (tmp_path / "jf2.log").read_text(encoding="utf-8")
        assert second.returncode == 2, err
        lines = [line for line in err.splitlines() if "journal.path" in line]
        assert len(lines) == 1 and "Traceback" not in err, err
        assert str(journal) in lines[0] and f"pid {first.pid}" in lines[0]
        assert first.poll() is None  # the first one goes on
        assert not list(journal.glob("*.damaged-*"))  # a lock is not damage
    finally:
        stop_process(first)
        bus.close()


def test_the_same_config_started_twice_names_its_ports_and_its_journal_at_once(tmp_path):
    """A second start of one config: every port in use and the journal's holder in one refusal
    (fixing the ports alone would only meet the journal at the next start)."""
    bus = Bus()
    journal = tmp_path / "journal"
    config = write_config(tmp_path, bus, journal, {"listen": [f"tcp/127.0.0.1:{free_port()}"]})
    first = start(config)
    try:
        wait_ready(first)
        log = config.with_suffix(".log")
        seen = len(log.read_text(encoding="utf-8"))
        second = start(config)
        second.communicate(timeout=30)
        err = log.read_text(encoding="utf-8")[seen:]
        assert second.returncode == 2, err
        keys = [line.split(": ")[2] for line in err.splitlines() if line.startswith("error: ")]
        assert keys == ["modbus.port", "zenoh.listen", "health.port", "journal.path"], err
        (held,) = [line for line in err.splitlines() if "journal.path" in line]
        assert str(journal) in held and f"pid {first.pid}" in held
        assert first.poll() is None
    finally:
        stop_process(first)
        bus.close()


def test_commissioning_commands_beside_the_gateway_of_their_config_on_a_shared_bus(tmp_path):
    """``sdo`` and ``nmt`` with the running gateway's own config (a shared bus, a journal, a
    ``simulate:`` section): they open their own connection, never the journal the gateway holds,
    and run no simulated devices of their own (the gateway's are on the bus: no second boot-up)."""
    bus = Bus()
    config = write_config(tmp_path, bus, tmp_path / "journal", {"listen": [f"tcp/127.0.0.1:{free_port()}"]})
    raw = yaml.safe_load(config.read_text(encoding="utf-8"))
    raw["simulate"] = {"nodes": "all"}
    config.write_text(yaml.safe_dump(raw), encoding="utf-8")
    gw = start(config)
    try:
        wait_ready(gw)
        while bus.bus.recv(timeout=0) is not None:
            pass  # what the gateway and its devices said so far
        for argv in (["sdo", "read", "-c", str(config), "wire", "0x1008:00"],
                     ["nmt", "-c", str(config), "start", "wire"]):  # fmt: skip
            r = subprocess.run([sys.executable, "-m", "canopen_gateway", *argv], cwd=ROOT,
                               capture_output=True, text=True, timeout=60)  # fmt: skip
            assert r.returncode == 0, r.stderr
        assert "SGH10" in subprocess.run(
            [sys.executable, "-m", "canopen_gateway", "sdo", "read", "-c", str(config), "wire", "0x1008:00"],
            cwd=ROOT, capture_output=True, text=True, timeout=60,
        ).stdout  # fmt: skip
        boot_ups = []
        while (msg := bus.bus.recv(timeout=0)) is not None:
            if msg.arbitration_id == 0x701 and bytes(msg.data) == b"\x00":
                boot_ups.append(msg)
        assert boot_ups == []  # no device of the commands' own
        assert gw.poll() is None
    finally:
        stop_process(gw)
        bus.close()
