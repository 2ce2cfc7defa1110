"""The config's key-expression check (``canopen_gateway.config.keyexpr``, without zenoh: the layers
that read the config may not import it) accepts exactly what zenoh's ``KeyExpr`` accepts and
names what is wrong; the write allow-lists match keys with zenoh's own ``KeyExpr.includes``."""

from __future__ import annotations

import pytest
import zenoh
from hypothesis import given, settings
from hypothesis import strategies as st

from canopen_gateway.config import ZenohSection, keyexpr
from canopen_gateway.zenoh_bridge.access import WriteGate

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
def test_a_rules_keys_include_a_key_as_zenoh_says(expr: str, key: str, expected: bool) -> None:
    assert keyexpr.problem(expr) is None
    gate = WriteGate(ZenohSection.model_validate({"writes": True, "write_allow": [{"keys": [expr]}]}))
    assert (gate.refusal("set", "n", key) is None) is expected
    assert zenoh.KeyExpr(expr).includes(zenoh.KeyExpr(key)) is expected


PATTERN_CHUNK = st.sampled_from(["a", "b", "ab", "*", "**", "$*", "a$*", "$*b", "@x", "a*", "$$*",
                                 "$*$*", "**b", "", "a#", "b?"])  # fmt: skip


@settings(max_examples=400, deadline=None)
@given(st.lists(PATTERN_CHUNK, min_size=1, max_size=5))
def test_the_config_check_accepts_exactly_what_zenoh_accepts(chunks: list[str]) -> None:
    expr = "/".join(chunks)
    try:
        zenoh.KeyExpr(expr)
        zenoh_ok = True
    except zenoh.ZError:
        zenoh_ok = False
    assert (keyexpr.problem(expr) is None) is zenoh_ok, (expr, keyexpr.problem(expr))


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
