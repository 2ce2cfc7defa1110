"""``check``'s warnings for the device timeouts a take-over of a hot-standby pair can outlast
(canopen_gateway.checks.takeover): each names the node, the object, the time and the fix, for the
timeouts the devices' manuals and CiA 301 define: a heartbeat consumer of the logical master
(1016h) set in the device's own file, the AP05's external heartbeat (manual 5.5.4, 5F09h),
an RPDO's deadline (its event timer, CiA 301: RPDO timeout, EMCY 8250h) and SYNC-driven
outputs on a device given a SYNC cycle (1006h). The guarding life time and the 1016h boot
step are tests/unit/test_pair_check.py's.

Member B of the pair (priority 1, pair id 102, ``heartbeat_ms: 100``, the default slots) has
the worst take-over 300 + 1 x 200 + 102 x 2 + 100 = 804 ms; A (priority 0, id 101) 602 ms.
"""

from __future__ import annotations

import copy
import subprocess
import sys
from pathlib import Path
from typing import Any

import yaml

from canopen_gateway.checks import config_warnings
from canopen_gateway.config import parse_config
from tests.helpers import resolved

ROOT = Path(__file__).resolve().parents[2]
PROFILES = ROOT / "canopen_gateway" / "profiles"


def member_b(nodes: list[dict[str, Any]], **master: Any) -> dict[str, Any]:
    return {
        "can": {"interface": "remote", "channel": "ws://127.0.0.1:54701/"},
        "master": {
            "node_id": 100,
            "heartbeat_ms": 100,
            "redundancy": {"node_id": 102, "priority": 1, "peer_node_id": 101},
            **master,
        },
        "nodes": nodes,
    }


def warnings_of(raw: dict[str, Any], base: Path | None = None) -> list[tuple[str, str]]:
    cfg = parse_config(copy.deepcopy(raw), str(base / "B.yaml") if base else "B.yaml", {})
    return config_warnings(cfg, resolved(cfg))


def eds_with(tmp: Path, name: str, changes: dict[str, dict[str, str]]) -> str:
    """A copy of a bundled EDS with ``changes`` (section -> key -> value; a new section is
    appended and listed among the optional objects)."""
    text = (PROFILES / name).read_text(encoding="utf-8")
    for section, keys in changes.items():
        head = f"[{section}]"
        if head in text:
            start = text.index(head)
            end = text.find("\n[", start + 1)
            end = len(text) if end < 0 else end
            body = text[start:end]
            for k, v in keys.items():
                body = "\n".join(f"{k}={v}" if line.startswith(f"{k}=") else line for line in body.split("\n"))
            text = text[:start] + body + text[end:]
        else:
            text += "\n" + head + "\n" + "".join(f"{k}={v}\n" for k, v in keys.items())
            count = int(text.split("[OptionalObjects]\nSupportedObjects=")[1].split("\n")[0])
            text = text.replace(
                f"[OptionalObjects]\nSupportedObjects={count}\n",
                f"[OptionalObjects]\nSupportedObjects={count + 1}\n{count + 1}=0x{section}\n",
            )
    path = tmp / f"{Path(name).stem}-changed.eds"
    path.write_text(text, encoding="utf-8")
    return str(path)


def test_an_ap05_external_heartbeat_fed_by_rpdos_shorter_than_a_takeover_and_a_keepalive_is_a_warning() -> None:
    def of(interval_ms: int, **eh: Any) -> list[tuple[str, str]]:
        node = {"name": "display", "node_id": 2, "profile": "ap05",
                "external_heartbeat": {"interval_ms": interval_ms, **eh}}  # fmt: skip
        return [w for w in warnings_of(member_b([node])) if "external heartbeat" in w[1]]

    ((key, text),) = of(600)  # keep-alive every 300 ms (half the interval): 804 + 300
    assert key == "nodes[0].external_heartbeat.interval_ms"
    assert text.startswith("node display: external heartbeat (0x5F09:01) 600 ms, fed by RPDOs")
    assert "the keep-alive every 300 ms" in text and "shorter than the 1104 ms" in text
    assert "804 ms" in text and "the device goes pre-operational at a take-over" in text
    assert text.endswith("make external_heartbeat.interval_ms at least 1104 ms")
    assert of(1200) != []  # keep-alive 500 ms (the guarding bit's): 1304 ms
    assert of(1400) == []
    assert of(1000, keepalive_ms=100) == []  # 804 + 100


def test_an_ap05_external_heartbeat_fed_by_sync_counts_two_sync_periods() -> None:
    def of(interval_ms: int, **master: Any) -> list[tuple[str, str]]:
        node = {"name": "display", "node_id": 2, "profile": "ap05",
                "external_heartbeat": {"interval_ms": interval_ms, "source": "sync"}}  # fmt: skip
        return [w for w in warnings_of(member_b([node], **master)) if "external heartbeat" in w[1]]

    ((_key, text),) = of(800, sync_period_ms=50)
    assert "fed by SYNC (every 50 ms)" in text and "904 ms" in text
    assert of(1000, sync_period_ms=50) == []


def test_a_consumer_of_the_logical_heartbeat_set_in_the_devices_file_is_a_warning(tmp_path: Path) -> None:
    eds = eds_with(tmp_path, "posi_plus.eds", {"1016sub1": {"DefaultValue": "0x00640190"}})  # 100, 400 ms
    node = {"name": "enc", "node_id": 3, "profile": "posi_plus", "eds": eds}
    ((key, text),) = [w for w in warnings_of(member_b([node])) if "consumer" in w[1]]
    assert key == "nodes[0].eds"
    assert text.startswith("node enc: its posi_plus-changed.eds sets 0x1016:01, its consumer of the ")
    assert "(node 100), to 400 ms, shorter than the worst take-over" in text and "804 ms" in text
    assert "0x1016:01 = 0x00640324" in text  # what to write instead: 804 ms
    # a boot step that writes a long enough consumer over it: no warning
    node["sdo"] = [{"object": "0x1016:01", "value": (100 << 16) | 1000}]
    assert [w for w in warnings_of(member_b([node])) if "consumer" in w[1]] == []


def test_an_rpdo_deadline_shorter_than_a_takeover_and_a_keepalive_round_is_a_warning(tmp_path: Path) -> None:
    eds = eds_with(tmp_path, "ap05.eds", {"1401sub5": {"AccessType": "rw", "DefaultValue": "1500"}})
    node = {"name": "display", "node_id": 2, "profile": "ap05", "eds": eds}
    ((key, text),) = [w for w in warnings_of(member_b([node])) if "event timer" in w[1]]
    assert key == "nodes[0].eds"
    assert "sets the event timer of RPDO2 (0x1401:05), the device's deadline for it, to 1500 ms" in text
    # two RPDOs in turn, a keep-alive every 500 ms (the guarding bit's): 804 + 2 x 500
    assert "shorter than the 1804 ms" in text and "2 x 500 ms" in text
    assert "RPDO timeout (EMCY 8250h)" in text and text.endswith("make it 0 (no deadline) or at least 1804 ms")
    node["guarding_bit"] = {"period_ms": 200}  # 804 + 2 x 200
    assert [w for w in warnings_of(member_b([node])) if "event timer" in w[1]] == []


def test_sync_driven_outputs_of_a_device_given_a_sync_cycle_are_a_warning(tmp_path: Path) -> None:
    eds = eds_with(tmp_path, "ap05.eds", {"1006": {
        "ParameterName": "Communication Cycle Period", "ObjectType": "0x7", "DataType": "0x0007",
        "AccessType": "rw", "DefaultValue": "50000", "PDOMapping": "0"}})  # fmt: skip
    node = {"name": "display", "node_id": 2, "profile": "ap05", "eds": eds, "rpdo": {1: {"transmission": 1}}}
    ((key, text),) = [w for w in warnings_of(member_b([node], sync_period_ms=50)) if "SYNC-driven" in w[1]]
    assert key == "nodes[0].eds"
    assert text.startswith("node display: RPDO1 is SYNC-driven (transmission type 1, 0x1400:02)")
    assert "sets 0x1006:00, the SYNC cycle the device expects, to 50000 us" in text
    assert "904 ms without SYNC" in text and "asynchronous (transmission type 254 or 255)" in text
    # another master's SYNC does not pause at a take-over; RPDOs acted on at once do not wait
    assert [w for w in warnings_of(member_b([node], sync_external=True)) if "SYNC-driven" in w[1]] == []
    del node["rpdo"]
    assert [w for w in warnings_of(member_b([node], sync_period_ms=50)) if "SYNC-driven" in w[1]] == []


def test_cli_check_prints_each_device_timeout_as_a_warning_line(tmp_path: Path) -> None:
    raw = member_b([
        {"name": "display", "node_id": 2, "profile": "ap05", "external_heartbeat": {"interval_ms": 600}},
        {"name": "wire", "node_id": 1, "profile": "sgh10", "supervision": "guarding",
         "guard_time_ms": 100, "life_time_factor": 3},
    ])  # fmt: skip
    path = tmp_path / "B.yaml"
    path.write_text(yaml.safe_dump(raw))
    done = subprocess.run(
        [sys.executable, "-m", "canopen_gateway", "check", "-c", str(path)], capture_output=True, text=True, cwd=ROOT
    )
    assert done.returncode == 0, done.stderr
    lines = [line for line in done.stdout.splitlines() if line.startswith("  warning: node ")]
    assert any("node display: external heartbeat (0x5F09:01) 600 ms" in line for line in lines), lines
    assert any("node wire: node guarding life time 100 ms x 3 = 300 ms" in line for line in lines), lines
