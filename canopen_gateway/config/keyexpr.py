"""Checking a Zenoh key expression written in a config file (``zenoh.prefix``,
``zenoh.write_allow[].keys``) without zenoh, naming what is wrong.

Why not ``zenoh.KeyExpr`` here: the configuration is read by the layers that must not import
zenoh (bus, device, runtime, sim...: the import-linter contracts in pyproject.toml hold the
import of zenoh out of them, indirect imports included), so this module cannot import it. It
says what zenoh says (``tests/unit/test_keyexpr.py`` compares the two on generated
expressions) and in words a config file's author reads. Zenoh's check would be faster (0.24
us against this module's 1.3 us for ``canopen/demo/*/set/**``, measured here), which does not
matter once per key at load.

Which keys a rule includes (the write allow-lists, per write) is zenoh's own
``KeyExpr.includes`` (``zenoh_bridge/access.py``): 0.26 us a check against 9.6 us for the
matcher this module had.

The grammar (Zenoh's key-expression language, canonical form): chunks separated by ``/``,
none empty; ``*`` is exactly one chunk; ``**`` is zero or more chunks; ``$*`` inside a chunk
is any run of characters (``set_point$*`` includes ``set_point1``); a chunk starting with
``@`` is verbatim (only matched by itself). ``#`` and ``?`` are not allowed.

Imports: the standard library only.
"""

from __future__ import annotations

FORBIDDEN_CHARS = "#?"


def problem(expr: str) -> str | None:
    """Why ``expr`` is not a canonical key expression, or None when it is one."""
    if not expr:
        return "empty key expression"
    if expr.startswith("/") or expr.endswith("/"):
        return f"{expr!r}: must not start or end with '/'"
    for ch in FORBIDDEN_CHARS:
        if ch in expr:
            return f"{expr!r}: {ch!r} is not allowed in a key expression"
    chunks = expr.split("/")
    for i, c in enumerate(chunks):
        if not c:
            return f"{expr!r}: empty chunk ('//')"
        if c in ("*", "**"):
            if c == "**" and i > 0 and chunks[i - 1] == "**":
                return f"{expr!r}: '**/**' is not canonical, write '**'"
            if c == "*" and i > 0 and chunks[i - 1] == "**":
                return f"{expr!r}: '**/*' is not canonical, write '*/**'"
            continue
        if c == "$*":
            return f"{expr!r}: a chunk '$*' alone is written '*'"
        if c.startswith("@") and "*" in c:
            return f"{expr!r}: a verbatim chunk ({c!r}) has no wildcard"
        if "**" in c:
            return f"{expr!r}: '**' must be a whole chunk"
        if "*" in c.replace("$*", ""):
            return f"{expr!r}: '*' inside a chunk is written '$*' (chunk {c!r})"
        if "$$*" in c or "$*$*" in c:
            return f"{expr!r}: '$*$*' is not canonical, write '$*'"
    return None
