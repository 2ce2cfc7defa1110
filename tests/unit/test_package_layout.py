"""The package's rooms: the root of ``canopen_gateway/`` keeps the entry points and the few basics every
layer uses (at most 8 modules); the CANopen facts live in ``canopen_gateway/canopen/``, the HTTP server
in ``canopen_gateway/http/``, the running basics in ``canopen_gateway/runtime/``; what the adapters share
(``northbound/``) imports nothing of the bus (also held by an import-linter contract)."""

from __future__ import annotations

import ast
from pathlib import Path

GATEWAY = Path(__file__).resolve().parents[2] / "canopen_gateway"


def test_the_package_root_keeps_at_most_8_modules() -> None:
    root = sorted(p.name for p in GATEWAY.glob("*.py"))
    assert len(root) <= 8, f"canopen_gateway/ holds {len(root)} modules: {', '.join(root)}"


def test_the_cia_facts_the_http_server_and_the_running_basics_have_their_packages() -> None:
    for package, modules in {
        "canopen": ("cia301", "cia305", "states", "objref", "code_text", "connection_set", "emcy"),
        "http": ("server", "metrics"),
        "runtime": ("threads", "ratelimit", "turns", "startup"),
    }.items():
        for m in modules:
            assert (GATEWAY / package / f"{m}.py").is_file(), f"canopen_gateway/{package}/{m}.py"
            assert not (GATEWAY / f"{m}.py").exists(), f"canopen_gateway/{m}.py is still in the root"


def _imported(path: Path) -> set[str]:
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom) and node.module and not node.level:
            out.add(node.module)
            out.update(f"{node.module}.{a.name}" for a in node.names)
        elif isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
    return out


def test_northbound_imports_nothing_of_the_bus() -> None:
    found = {
        f"{path.relative_to(GATEWAY.parent)}: {name}"
        for path in (GATEWAY / "northbound").rglob("*.py")
        for name in _imported(path)
        if name == "canopen_gateway.bus" or name.startswith("canopen_gateway.bus.")
    }
    assert not found, sorted(found)
