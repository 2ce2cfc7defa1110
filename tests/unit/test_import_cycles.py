"""No runtime import cycle in ``canopen_gateway/``: the imports a module runs when it is loaded (those at
its top level, not under ``if TYPE_CHECKING:`` and not inside functions) form no cycle, so every
module can be imported first and each reads top-down as what it builds on."""

from __future__ import annotations

import ast
from pathlib import Path

GATEWAY = Path(__file__).resolve().parents[2] / "canopen_gateway"


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(GATEWAY.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for p in GATEWAY.rglob("*.py")}


def _top_level_imports(path: Path, name: str, known: set[str]) -> set[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out: set[str] = set()
    for node in tree.body:
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            continue
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names if a.name in known}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join([*up, *([base] if base else [])])
            for a in node.names:
                sub = f"{base}.{a.name}"
                if sub in known:
                    out.add(sub)  # a submodule imported from its package
                elif base in known:
                    out.add(base)
    out.discard(name)
    return out


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    state: dict[str, int] = {}  # 1 on the path, 2 done
    path: list[str] = []

    def visit(m: str) -> list[str] | None:
        state[m] = 1
        path.append(m)
        for n in sorted(graph.get(m, ())):
            if state.get(n) == 1:
                return path[path.index(n) :] + [n]
            if n not in state and (found := visit(n)):
                return found
        path.pop()
        state[m] = 2
        return None

    for m in sorted(graph):
        if m not in state and (found := visit(m)):
            return found
    return None


def test_no_module_of_gateway_takes_part_in_an_import_cycle() -> None:
    modules = _modules()
    known = set(modules)
    graph = {name: _top_level_imports(path, name, known) for name, path in modules.items()}
    # a package's __init__ that re-exports its submodules is imported by them as their parent,
    # which Python does first anyway: the edge submodule -> parent package is not a cycle
    for name in graph:
        graph[name] = {m for m in graph[name] if not name.startswith(m + ".")}
    assert _cycle(graph) is None, " -> ".join(_cycle(graph) or [])


def _package(name: str, modules: dict[str, Path]) -> str:
    return name if modules[name].name == "__init__.py" else name.rpartition(".")[0]


def test_no_two_packages_of_gateway_import_each_other() -> None:
    """Packages neither of which holds the other (``bus.node`` and ``bus.sdo``, ``bus`` and
    ``canopen``) depend one way at most: what both read lives where both can read it (the
    bus's output vocabulary in ``bus/events.py``), and a part is told what it should expect
    rather than importing its caller (the supervision is told the NMT state to expect)."""
    modules = _modules()
    known = set(modules)
    packages = {_package(n, modules) for n in modules}
    uses: set[tuple[str, str]] = set()
    for name, path in modules.items():
        for target in _top_level_imports(path, name, known):
            a, b = _package(name, modules), _package(target, modules)
            for pa in packages:
                for pb in packages:
                    if (a == pa or a.startswith(pa + ".")) and (b == pb or b.startswith(pb + ".")):
                        if not (pa == pb or pa.startswith(pb + ".") or pb.startswith(pa + ".")):
                            uses.add((pa, pb))
    both = sorted(f"{a} <-> {b}" for a, b in uses if (b, a) in uses and a < b)
    assert not both, both
