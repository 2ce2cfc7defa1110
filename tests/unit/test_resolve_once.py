"""Each configured node is resolved once, when the config is loaded (``canopen_gateway.device.resolved``):
the commands load, check and serve from that one resolution, and no module but the resolver
loads a node's profile."""

from __future__ import annotations

import ast
from pathlib import Path
from typing import Any

import pytest

from canopen_gateway.cli import main
from canopen_gateway.profiles import node_profile

ROOT = Path(__file__).resolve().parents[2]
DEMO = ROOT / "config" / "demo.yaml"


def _calls_of(name: str) -> set[str]:
    """The modules of canopen_gateway/ that call ``name`` (by that name or as an attribute)."""
    out = set()
    for path in sorted((ROOT / "canopen_gateway").rglob("*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if isinstance(node, ast.Call):
                f = node.func
                called = f.id if isinstance(f, ast.Name) else f.attr if isinstance(f, ast.Attribute) else None
                if called == name:
                    out.add(str(path.relative_to(ROOT)))
    return out


def test_only_the_resolver_loads_a_node_profile() -> None:
    assert _calls_of("load_node_profile") == {"canopen_gateway/device/resolved.py"}


def test_only_the_resolver_builds_boot_steps() -> None:
    assert _calls_of("build_boot_steps") == {"canopen_gateway/device/resolved.py"}


@pytest.mark.parametrize("command", ["check", "registers", "keys"])
def test_a_command_resolves_each_node_once(
    command: str, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """Loading and checking the config, then what the command builds from it (the summary,
    the register map, the key listing), read one resolution: each node's profile is looked
    up once."""
    looked_up: list[int] = []
    real = node_profile._load_node

    def counting(key: str, node: Any, base_dir: Any) -> Any:
        looked_up.append(node.node_id)
        return real(key, node, base_dir)

    monkeypatch.setattr(node_profile, "_load_node", counting)
    assert main([command, "-c", str(DEMO)]) == 0
    capsys.readouterr()
    names = sorted(set(looked_up))
    assert names, "the demo has nodes"
    assert sorted(looked_up) == names, f"looked up more than once: {looked_up}"
