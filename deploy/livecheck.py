"""Live checks of a running gateway from the outside, for deploy/container-test.sh.

Each subcommand talks to the gateway the way a user's tools do (HTTP, a pymodbus client, a Zenoh
peer) with bounded waits, prints what it saw and exits 0 on success, 1 with a reason otherwise:

    livecheck.py free-port 5020                   # 5020 if free on 127.0.0.1, else a free port
    livecheck.py pick-register < registers.csv    # "unit:address:count" of a position register
    livecheck.py wait-healthy URL TIMEOUT_S       # until GET URL answers 200
    livecheck.py metrics URL                      # /metrics has counted CAN frames
    livecheck.py modbus-changes HOST PORT UNIT:ADDRESS:COUNT
    livecheck.py zenoh-samples tcp/127.0.0.1:7447 [KEYEXPR]
    livecheck.py journal URL PATH                 # /healthz shows the journal at PATH, writing
    livecheck.py history tcp/127.0.0.1:7447 KEYEXPR UNTIL   # get KEYEXPR?_time=[..UNTIL] answers

Polling with sleeps is acceptable here: this script waits on another process in a container,
not on code in its own process. Imports: the standard library, pymodbus, zenoh and prometheus_client (from .venv);
nothing of the gateway package, so it checks the image as a stranger would.
"""

from __future__ import annotations

import argparse
import asyncio
import csv
import json
import queue
import socket
import sys
import time
import urllib.error
import urllib.request


def free_port(preferred: int) -> int:
    """``preferred`` when nothing listens on it on 127.0.0.1, else an ephemeral free port."""
    with socket.socket() as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind(("127.0.0.1", preferred))
            return preferred
        except OSError:
            pass
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def pick_register(lines: list[str]) -> str | None:
    """The first input register of a signal named like a position, as ``unit:address:count``."""
    for row in csv.DictReader(lines):
        if row.get("table") != "input register" or "position" not in row.get("signal", ""):
            continue
        first, _, last = row["address"].partition("-")
        count = int(last) - int(first) + 1 if last else 1
        # The Modbus unit id column: "unit_id" (older tables called it "unit").
        unit_id = row.get("unit_id") or row.get("unit", "")
        if not unit_id.isdigit():
            continue
        return f"{unit_id}:{first}:{count}"
    return None


def wait_healthy(url: str, timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    last = "no answer"
    while time.monotonic() < deadline:
        try:
            with urllib.request.urlopen(url, timeout=2) as response:
                body = json.loads(response.read())
                print(f"{url}: {response.status} {body.get('status')}")
                return True
        except urllib.error.HTTPError as error:
            last = f"{error.code} {error.read()[:300]!r}"
        except (OSError, ValueError) as error:
            last = repr(error)
        time.sleep(0.5)
    print(f"{url}: not ready after {timeout_s:.0f} s, last answer: {last}")
    return False


def metrics_count_frames(url: str) -> bool:
    """``/metrics`` answers in the Prometheus format and has counted received CAN frames."""
    from prometheus_client.parser import text_string_to_metric_families

    with urllib.request.urlopen(url, timeout=5) as response:
        text = response.read().decode()
    values = {
        sample.name: sample.value
        for family in text_string_to_metric_families(text)
        for sample in family.samples
        if not sample.labels
    }
    frames_in = values.get("canopen_gateway_frames_in_total", 0.0)
    print(f"metrics: {len(text.splitlines())} lines, frames_in_total {frames_in:.0f}")
    return frames_in > 0


async def modbus_changes(host: str, port: int, spec: str, timeout_s: float = 10.0) -> bool:
    """Reads the input registers until two reads differ (the position moves)."""
    from pymodbus.client import AsyncModbusTcpClient

    unit, address, count = (int(x) for x in spec.split(":"))
    client = AsyncModbusTcpClient(host, port=port, timeout=2, retries=1)
    if not await client.connect():
        print(f"modbus: cannot connect to {host}:{port}")
        return False
    try:
        first = None
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            reply = await client.read_input_registers(address, count=count, device_id=unit)
            if reply.isError():
                print(f"modbus: unit {unit} input register {address}: error {reply}")
                return False
            if first is None:
                first = list(reply.registers)
                print(f"modbus: unit {unit} input registers {address}+{count}: {first}")
            elif list(reply.registers) != first:
                print(f"modbus: changed to {list(reply.registers)}")
                return True
            await asyncio.sleep(0.2)
        print(f"modbus: value stayed {first} for {timeout_s:.0f} s")
        return False
    finally:
        client.close()


def zenoh_samples(endpoint: str, key_expr: str, want: int = 3, timeout_s: float = 10.0) -> bool:
    import zenoh

    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("listen/endpoints", '["tcp/127.0.0.1:0"]')
    conf.insert_json5("scouting/multicast/enabled", "false")
    received: queue.Queue[str] = queue.Queue()
    with zenoh.open(conf) as session:
        # The callback runs on a zenoh thread: hand the key over, nothing else.
        subscriber = session.declare_subscriber(
            key_expr, lambda sample: received.put(str(sample.key_expr))
        )
        keys: list[str] = []
        deadline = time.monotonic() + timeout_s
        while len(keys) < want and time.monotonic() < deadline:
            try:
                keys.append(received.get(timeout=max(0.0, deadline - time.monotonic())))
            except queue.Empty:
                break
        subscriber.undeclare()
    if len(keys) < want:
        print(f"zenoh: {len(keys)} samples on {key_expr} via {endpoint} in {timeout_s:.0f} s")
        return False
    print(f"zenoh: {len(keys)} samples, e.g. {', '.join(sorted(set(keys))[:3])}")
    return True


def journal_writing(url: str, path: str, timeout_s: float = 20.0) -> bool:
    """``/healthz`` (200 or 503) has the ``journal`` block of the directory ``path`` (its
    database file in it), with entries written and no error."""
    deadline = time.monotonic() + timeout_s
    last: object = "no answer"
    while time.monotonic() < deadline:
        try:
            with urllib.request.urlopen(url, timeout=2) as response:
                body = json.loads(response.read())
        except urllib.error.HTTPError as error:
            body = json.loads(error.read() or b"{}")
        except (OSError, ValueError) as error:
            last = repr(error)
            time.sleep(0.5)
            continue
        last = body.get("journal")
        if isinstance(last, dict) and str(last.get("path")).rpartition("/")[0] == path.rstrip("/"):
            if last.get("error") is not None:
                print(f"journal: {last}")
                return False
            if last.get("written", 0) > 0:
                print(f"journal: {last}")
                return True
        time.sleep(0.5)
    print(f"journal: after {timeout_s:.0f} s /healthz shows {last!r}, expected path {path} written")
    return False


def zenoh_history(endpoint: str, key_expr: str, until: str, timeout_s: float = 10.0) -> bool:
    """``get <key_expr>?_time=[..<until>]`` answers at least one journaled sample, no error."""
    import zenoh

    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("listen/endpoints", '["tcp/127.0.0.1:0"]')
    conf.insert_json5("scouting/multicast/enabled", "false")
    selector = f"{key_expr}?_time=[..{until}]"
    seqs: dict[str, list[int]] = {}
    with zenoh.open(conf) as session:
        for reply in session.get(selector, timeout=timeout_s):
            if reply.ok is None:
                print(f"history: {selector}: reply_err {reply.err.payload.to_string()}")
                return False
            body = json.loads(reply.ok.payload.to_bytes())
            seqs.setdefault(str(reply.ok.key_expr), []).append(body.get("seq"))
    if not seqs:
        print(f"history: {selector}: no reply")
        return False
    count = sum(len(s) for s in seqs.values())
    last = ", ".join(f"{k} up to seq {max(s, default=None)}" for k, s in sorted(seqs.items())[:3])
    print(f"history: {selector}: {count} samples of {len(seqs)} keys ({last}, ...)")
    return True


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser("free-port").add_argument("preferred", type=int)
    sub.add_parser("pick-register")
    p = sub.add_parser("wait-healthy")
    p.add_argument("url")
    p.add_argument("timeout_s", type=float)
    sub.add_parser("metrics").add_argument("url")
    p = sub.add_parser("modbus-changes")
    p.add_argument("host")
    p.add_argument("port", type=int)
    p.add_argument("register", help="unit:address:count")
    p = sub.add_parser("zenoh-samples")
    p.add_argument("endpoint")
    p.add_argument("key_expr", nargs="?", default="canopen/**")
    p = sub.add_parser("journal")
    p.add_argument("url")
    p.add_argument("path")
    p = sub.add_parser("history")
    p.add_argument("endpoint")
    p.add_argument("key_expr")
    p.add_argument("until", help="the range's end: an RFC 3339 time")
    args = parser.parse_args(argv)

    if args.command == "free-port":
        print(free_port(args.preferred))
        return 0
    if args.command == "pick-register":
        found = pick_register(sys.stdin.read().splitlines())
        if found is None:
            return 1
        print(found)
        return 0
    if args.command == "wait-healthy":
        return 0 if wait_healthy(args.url, args.timeout_s) else 1
    if args.command == "metrics":
        return 0 if metrics_count_frames(args.url) else 1
    if args.command == "modbus-changes":
        return 0 if asyncio.run(modbus_changes(args.host, args.port, args.register)) else 1
    if args.command == "zenoh-samples":
        return 0 if zenoh_samples(args.endpoint, args.key_expr) else 1
    if args.command == "journal":
        return 0 if journal_writing(args.url, args.path) else 1
    if args.command == "history":
        return 0 if zenoh_history(args.endpoint, args.key_expr, args.until) else 1
    return 2


if __name__ == "__main__":
    sys.exit(main())
