"""Zenoh key expressions without zenoh: checking one written in a config file, and whether a
concrete key is included in one (for the write allow-lists of ``zenoh.write_allow``).

The grammar (Zenoh's key-expression language, canonical form): chunks separated by ``/``,
none empty; ``*`` is exactly one chunk; ``**`` is zero or more chunks; ``$*`` inside a chunk
is any run of characters (``set_point$*`` includes ``set_point1``); a chunk starting with
``@`` is verbatim (only matched by itself). ``#`` and ``?`` are not allowed. The tests check
``includes`` against zenoh's own ``KeyExpr.includes``.

Imports: the standard library only (the config loader uses this module).
"""

from __future__ import annotations

import re
from functools import cache, lru_cache

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


@lru_cache(maxsize=1024)
def _chunk_re(chunk: str) -> re.Pattern[str]:
    return re.compile(".*".join(re.escape(p) for p in chunk.split("$*")), re.DOTALL)


def _chunk_matches(pattern: str, chunk: str) -> bool:
    if pattern.startswith("@") or chunk.startswith("@"):
        return pattern == chunk
    if pattern == "*":
        return True
    if "$*" not in pattern:
        return pattern == chunk
    return _chunk_re(pattern).fullmatch(chunk) is not None


def includes(expr: str, key: str) -> bool:
    """Is the concrete ``key`` (no wildcard) one of the keys ``expr`` stands for?"""
    pat = expr.split("/")
    ks = key.split("/")

    @cache
    def match(i: int, j: int) -> bool:
        if i == len(pat):
            return j == len(ks)
        if pat[i] == "**":
            # zero chunks, or one more non-verbatim chunk
            return match(i + 1, j) or (
                j < len(ks) and not ks[j].startswith("@") and match(i, j + 1)
            )
        return j < len(ks) and _chunk_matches(pat[i], ks[j]) and match(i + 1, j + 1)

    return match(0, 0)
