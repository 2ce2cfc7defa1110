"""Every module header that lists what the module imports ("Imports: ...") names every module of
the gateway it really imports: the headers are the documented layering, and they stay true.
Every module makes the claim (a module without an ``Imports:`` line fails: nothing is skipped).

A claim names a module by its dotted path below ``gateway`` (``device.settings``), by a
prefix of it (``profiles`` covers ``profiles.schema``; ``bus.*`` or ``bus/`` covers all of
``bus``), or by its last part (``settings``) for a sibling in the same package.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

GATEWAY = Path(__file__).resolve().parents[2] / "canopen_gateway"


def _modules() -> list[Path]:
    return sorted(GATEWAY.rglob("*.py"))


def _claims(doc: str) -> str | None:
    """The text of the "Imports:" paragraph (None: the module makes no claim)."""
    m = re.search(r"\bImports?:(.*?)(?:\n\s*\n|\Z)", doc, re.S)
    if m is None:
        return None
    return m.group(1).replace("gateway.", "").replace("``", "")


def _module_name(path: Path) -> list[str]:
    parts = list(path.relative_to(GATEWAY.parent).with_suffix("").parts)
    return parts[:-1] if parts[-1] == "__init__" else parts


def _gateway_imports(tree: ast.Module, path: Path) -> set[str]:
    """Dotted names below ``gateway`` of every gateway module imported (at any depth)."""
    here = _module_name(path)
    package = here if path.name == "__init__.py" else here[:-1]
    out: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[: len(package) - node.level + 1]
                mod = ".".join([*base, *([node.module] if node.module else [])])
            else:
                mod = node.module or ""
            if mod == "gateway":  # a module of the package, not an attribute (__version__)
                out.update(
                    a.name
                    for a in node.names
                    if (GATEWAY / f"{a.name}.py").exists() or (GATEWAY / a.name).is_dir()
                )
            elif mod.startswith("gateway."):
                below = mod[len("gateway.") :]
                base = GATEWAY.joinpath(*below.split("."))
                submodules = [
                    a.name
                    for a in node.names
                    if (base / f"{a.name}.py").exists() or (base / a.name).is_dir()
                ]
                # ``from canopen_gateway.bus.lss import master``: the module imported is bus.lss.master
                out.update(f"{below}.{m}" for m in submodules)
                if len(submodules) < len(node.names):
                    out.add(below)
        elif isinstance(node, ast.Import):
            out.update(a.name[len("gateway.") :] for a in node.names if a.name.startswith("gateway."))
    return out


def _named(module: str, text: str, own_package: str) -> bool:
    parts = module.split(".")
    names = {".".join(parts[: i + 1]) for i in range(len(parts))}
    names.add(module.replace(".", "/"))
    if module.startswith(own_package + ".") or not own_package:
        names.add(parts[-1])  # a sibling by its own name
    for n in names:
        if re.search(r"(?<![\w.])" + re.escape(n) + r"(?![\w])(?!\.\w)", text):
            return True
    return any(
        re.search(r"(?<![\w.])" + re.escape(".".join(parts[:i])) + r"(\.\*|/)", text)
        for i in range(1, len(parts))
    )


@pytest.mark.parametrize("path", _modules(), ids=lambda p: str(p.relative_to(GATEWAY.parent)))
def test_the_imports_a_module_header_claims_are_the_ones_it_makes(path: Path) -> None:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    text = _claims(ast.get_docstring(tree) or "")
    assert text is not None, f"{path.name}: the module docstring has no Imports: line"
    here = _module_name(path)
    package = ".".join((here if path.name == "__init__.py" else here[:-1])[1:])
    missing = sorted(
        m
        for m in _gateway_imports(tree, path)
        if m != ".".join(here[1:]) and not _named(m, text, package)
    )
    assert not missing, f"{path.name}: header does not name {', '.join(missing)}"
