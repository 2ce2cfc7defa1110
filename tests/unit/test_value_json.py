"""The templated value payload is byte for byte the json.dumps of the generic payload."""

from __future__ import annotations

import json

from hypothesis import given
from hypothesis import strategies as st

from canopen_gateway.image import Quality, SignalValue
from canopen_gateway.northbound.scaling import Scaling
from canopen_gateway.profiles import load_profile
from canopen_gateway.zenoh_bridge.payloads import value_json, value_payload

SIG = load_profile("sgh10").profile.signal("position")


@given(
    raw=st.one_of(st.integers(-(2**31), 2**31 - 1), st.floats(allow_nan=False, allow_infinity=False)),
    ts=st.floats(0, 2e9),
    seq=st.integers(1, 2**40),
    scale=st.sampled_from([1.0, 0.1, 0.005]),
    quality=st.sampled_from(list(Quality)),
)
def test_template_matches_json_dumps(raw, ts, seq, scale, quality) -> None:
    sc = Scaling(unit="mm", scale=scale, offset=0.0)
    sv = SignalValue("position", raw, ts, 0.0, seq)
    assert value_json(SIG, sv, quality, sc) == json.dumps(value_payload(SIG, sv, quality, sc))
