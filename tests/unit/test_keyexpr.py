"""Our key-expression matcher (used for ``zenoh.write_allow`` without a session) agrees with
zenoh's own ``KeyExpr.includes``, and the config check names what is wrong."""

from __future__ import annotations

import pytest
import zenoh
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway import keyexpr

CASES = [
    ("canopen/line1/display/set/set_point$*", "canopen/line1/display/set/set_point2", True),
    ("canopen/line1/display/set/set_point$*", "canopen/line1/display/set/control_word", False),
    ("canopen/*/wire/sdo/6000/**", "canopen/line1/wire/sdo/6000/00", True),
    ("canopen/*/wire/sdo/6000/**", "canopen/line1/wire/sdo/6000", True),
    ("canopen/*/wire/sdo/6000/**", "canopen/line1/wire/sdo/6010/01", False),
    ("canopen/**", "canopen", True),
    ("canopen/**/nmt", "canopen/a/b/c/nmt", True),
    ("canopen/*", "canopen/a/b", False),
    ("a/$*b", "a/b", True),
    ("a/**", "a/@adv/x", False),
    ("a/@adv/**", "a/@adv/x", True),
]


@pytest.mark.parametrize("expr,key,expected", CASES)
def test_includes_on_examples_as_zenoh_does(expr: str, key: str, expected: bool) -> None:
    assert keyexpr.includes(expr, key) is expected
    assert zenoh.KeyExpr(expr).includes(zenoh.KeyExpr(key)) is expected


CHUNK = st.sampled_from(["a", "b", "ab", "set", "@x"])
PATTERN_CHUNK = st.sampled_from(["a", "b", "ab", "*", "**", "$*", "a$*", "$*b", "@x"])


def canonical(chunks: list[str]) -> str | None:
    expr = "/".join(chunks)
    return None if keyexpr.problem(expr) else expr


@settings(max_examples=300, deadline=None)
@given(st.lists(PATTERN_CHUNK, min_size=1, max_size=5), st.lists(CHUNK, min_size=1, max_size=5))
def test_includes_agrees_with_zenoh(pattern: list[str], key: list[str]) -> None:
    expr = canonical(pattern)
    k = "/".join(key)
    if expr is None:
        return
    try:
        z = zenoh.KeyExpr(expr).includes(zenoh.KeyExpr(k))
    except zenoh.ZError:  # not canonical for zenoh either: our check must refuse it too
        pytest.fail(f"{expr!r} passed our check but zenoh refuses it")
    assert keyexpr.includes(expr, k) is z, (expr, k)


@pytest.mark.parametrize(
    "expr,words",
    [
        ("", "empty"),
        ("/a", "start or end"),
        ("a/", "start or end"),
        ("a//b", "empty chunk"),
        ("a/b*", "'$*'"),
        ("a/**b", "whole chunk"),
        ("a/**/**", "not canonical"),
        ("a/b?c", "'?'"),
        ("a/#", "'#'"),
    ],
)
def test_problems_say_what_is_wrong(expr: str, words: str) -> None:
    why = keyexpr.problem(expr)
    assert why is not None and words in why
