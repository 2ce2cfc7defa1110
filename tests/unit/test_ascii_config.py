"""The ``ascii:`` section: off unless given, on with its defaults when given, turned on from
the environment, and its errors named by key path."""

from __future__ import annotations

import pytest

from canopen_gateway.config import ConfigError, parse_config

NODES = [{"name": "wire", "node_id": 1, "profile": "sgh10"}]


def test_the_ascii_gateway_is_off_unless_its_section_is_given() -> None:
    assert parse_config({"nodes": NODES}, environ={}).ascii is None


def test_an_empty_section_turns_it_on_with_the_defaults() -> None:
    a = parse_config({"nodes": NODES, "ascii": {}}, environ={}).ascii
    assert a is not None
    assert (a.enabled, a.host, a.port, a.writes, a.events) == (True, "127.0.0.1", 60000, False, False)
    off = parse_config({"nodes": NODES, "ascii": {"enabled": False}}, environ={}).ascii
    assert off is not None and not off.enabled


def test_a_port_from_the_environment_turns_it_on() -> None:
    cfg = parse_config({"nodes": NODES}, environ={"CANOPEN_GATEWAY__ASCII__PORT": "60001"})
    assert cfg.ascii is not None and cfg.ascii.enabled and cfg.ascii.port == 60001


def test_a_bad_key_or_port_is_named_by_its_path() -> None:
    with pytest.raises(ConfigError) as err:
        parse_config({"nodes": NODES, "ascii": {"port": 70000, "write": True}}, environ={})
    text = str(err.value)
    assert "ascii.port" in text and "ascii.write" in text
