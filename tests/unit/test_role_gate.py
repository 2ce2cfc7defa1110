"""One role gate: the adapters never decide by the pair's role themselves.

A member of a hot-standby pair that does not master the bus refuses commands in one place, the
master's ``require_active`` (reached through the command service); the adapters read the role
only to show it (``CommandService.role``). A new fault mode is then handled once, not in every
adapter that copied the test of ``mastering``."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2] / "canopen_gateway"
ADAPTERS = ("modbus", "zenoh_bridge", "web", "ascii")
#: the master's role state read past the command service
FORBIDDEN = re.compile(r"\.mastering\b|\bmaster\.role\b|\bmaster\.member\b|\bmaster\.pair\b")


def test_no_adapter_reads_the_masters_role_state() -> None:
    found = [
        f"{path.relative_to(ROOT.parent)}:{n}: {line.strip()}"
        for pkg in ADAPTERS
        for path in sorted((ROOT / pkg).rglob("*.py"))
        for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1)
        if FORBIDDEN.search(line)
    ]
    assert found == [], "adapters go through CommandService.role / require_active:\n" + "\n".join(found)


def test_the_master_refuses_commands_in_one_place() -> None:
    text = (ROOT / "bus" / "master.py").read_text(encoding="utf-8")
    assert text.count("raise NotActive(") == 1


def test_the_master_sends_as_master_through_one_gate() -> None:
    """What the master sends as the bus's master (the nodes' frames, the logical heartbeat,
    SYNC) passes ``_send_as_master``, the one place of its send path that reads the role."""
    text = (ROOT / "bus" / "master.py").read_text(encoding="utf-8")
    body = text.split("def _send_as_master", 1)[1].split("\n    def ", 1)[0]
    assert "if not self.mastering" in body
    assert text.count("self.driver.send(") == 2  # the gate's, and nmt()'s after require_bus
