"""Each object owns its state: no class of the gateway binds a function of another module as
its method (``open = session.open`` in a class body), and code reaches into another object's
private attributes (``other._x``) at most a handful of times in all of ``canopen_gateway/``.
"""

from __future__ import annotations

import ast
import importlib
import re
import types
from pathlib import Path

GATEWAY = Path(__file__).resolve().parents[2] / "canopen_gateway"

#: the most reaches into another object's private attributes allowed in all of ``canopen_gateway/``
MAX_PRIVATE_REACHES = 4
#: ``x._y`` where ``x`` is not ``self``/``cls``; namedtuple's public API starts with "_"
REACH = re.compile(r"\b([a-z_][a-zA-Z0-9_]*)\._[a-z][a-zA-Z0-9_]*")
NAMEDTUPLE_API = re.compile(r"\._(replace|asdict|fields|make|field_defaults)\b")


def _modules() -> list[Path]:
    return sorted(GATEWAY.rglob("*.py"))


def _dotted(path: Path) -> str:
    parts = list(path.relative_to(GATEWAY.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imported_names(tree: ast.Module) -> set[str]:
    """Names the module binds by an import (modules and the names taken from them)."""
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names |= {(a.asname or a.name).split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            names |= {a.asname or a.name for a in node.names}
    return names


def _root(expr: ast.expr) -> str | None:
    while isinstance(expr, ast.Attribute):
        expr = expr.value
    return expr.id if isinstance(expr, ast.Name) else None


def _function(value: object) -> types.FunctionType | None:
    if isinstance(value, (staticmethod, classmethod)):
        value = value.__func__
    return value if isinstance(value, types.FunctionType) else None


def bound_foreign_functions() -> list[str]:
    """``module:Class.name`` for every class attribute that is a function of another module,
    assigned in the class body from an imported name."""
    found = []
    for path in _modules():
        tree = ast.parse(path.read_text(encoding="utf-8"))
        imported = _imported_names(tree)
        module = None
        for cls in (n for n in ast.walk(tree) if isinstance(n, ast.ClassDef)):
            for stmt in cls.body:
                targets: list[ast.expr] = []
                if isinstance(stmt, ast.Assign):
                    targets, value = stmt.targets, stmt.value
                elif isinstance(stmt, ast.AnnAssign) and stmt.value is not None:
                    targets, value = [stmt.target], stmt.value
                if not targets or _root(value) not in imported:
                    continue
                module = module or importlib.import_module(_dotted(path))
                owner = getattr(module, cls.name, None)
                for target in targets:
                    if not isinstance(target, ast.Name) or owner is None:
                        continue
                    fn = _function(vars(owner).get(target.id))
                    if fn is not None and fn.__module__ != module.__name__:
                        found.append(f"{module.__name__}:{cls.name}.{target.id} = {fn.__module__}")
    return found


def private_reaches() -> list[str]:
    """``file:line: x._y`` for every reach into another object's private attribute."""
    found = []
    for path in _modules():
        rel = path.relative_to(GATEWAY.parent)
        for lineno, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            for m in REACH.finditer(line):
                if m.group(1) in ("self", "cls") or NAMEDTUPLE_API.match(line, m.end(1)):
                    continue
                found.append(f"{rel}:{lineno}: {m.group(0)}")
    return found


def test_no_class_binds_a_function_of_another_module_as_its_method() -> None:
    assert bound_foreign_functions() == []


def test_private_attributes_of_other_objects_are_reached_at_most_four_times() -> None:
    reaches = private_reaches()
    assert len(reaches) <= MAX_PRIVATE_REACHES, "\n".join(reaches)
