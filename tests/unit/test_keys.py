"""The Zenoh key scheme: keys built for a config, query keys parsed (with what was expected when
they do not parse), and the listing of ``canopen-gateway keys``."""

from __future__ import annotations

import pytest

from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.cli import main
from canopen_gateway.config import parse_config
from canopen_gateway.northbound.keys import (
    BadKey,
    Request,
    all_keys,
    has_wildcard,
    parse_key,
    pdo_key,
    prefix_of,
    render_keys,
    sdo_key,
    short_text,
    tpdo_key,
)
from tests.helpers import with_nodes

P = "canopen/line1"


def config(**zenoh: object) -> object:
    return parse_config(
        {
            "gateway": {"name": "line1"},
            "nodes": [
                {"name": "wire", "node_id": 1, "profile": "sgh10"},
                {"name": "display", "node_id": 125, "profile": "ap05"},
            ],
            "zenoh": zenoh,
        },
        environ={},
    )


def test_prefix_defaults_to_canopen_and_the_gateway_name() -> None:
    assert prefix_of(config()) == "canopen/line1"


def test_prefix_is_configurable_and_a_trailing_slash_is_ignored() -> None:
    assert prefix_of(config(prefix="plant/hall2/")) == "plant/hall2"
    keys = {k.key for k in all_keys(*with_nodes(config(prefix="plant/hall2")))}
    assert "plant/hall2/wire/value/position" in keys
    assert not any(k.startswith("canopen/") for k in keys)


def test_every_process_signal_has_a_value_key_and_every_node_state_emcy_and_alive() -> None:
    keys = {k.key: k for k in all_keys(*with_nodes(config()))}
    for node in ("wire", "display"):
        assert keys[f"{P}/{node}/state"].kind == "event"
        assert keys[f"{P}/{node}/emcy"].kind == "event"
        assert keys[f"{P}/alive/{node}"].kind == "liveliness"
    assert keys[f"{P}/alive/_gateway"].kind == "liveliness"
    assert keys[f"{P}/wire/value/position"].kind == "value"
    assert keys[f"{P}/display/value/status_word"].kind == "value"
    # RPDO outputs are written, not published
    assert f"{P}/display/value/set_point2" not in keys
    assert keys[f"{P}/display/set/set_point2"].description == "write int32 (RPDO)"
    # docs/zenoh.md: every key of a configuration, the AP05 text rows too
    assert keys[f"{P}/display/set/set_point1_text"].description == (
        "write string of up to 6 characters (RPDO, text of row 1)"
    )
    assert f"{P}/display/set/set_point2_text" in keys


def test_raw_pdo_keys_are_listed_only_when_enabled() -> None:
    assert not any("/pdo/" in k.key for k in all_keys(*with_nodes(config())))
    assert any(k.key == f"{P}/wire/pdo/<cob-id hex>" for k in all_keys(*with_nodes(config(raw_pdo=True))))
    assert pdo_key(P, "wire", 0x181) == f"{P}/wire/pdo/181"


def test_pdo_keys_are_listed_with_publish_pdo() -> None:
    assert not any("/tpdo/" in k.key for k in all_keys(*with_nodes(config())))
    assert any(k.key == f"{P}/wire/tpdo/<n>" for k in all_keys(*with_nodes(config(publish="pdo"))))
    assert tpdo_key(P, "wire", 1) == f"{P}/wire/tpdo/1"


def test_a_signal_with_publish_off_has_no_value_key() -> None:
    cfg = parse_config(
        {
            "gateway": {"name": "line1"},
            "nodes": [
                {
                    "name": "wire",
                    "node_id": 1,
                    "profile": "sgh10",
                    "signals": {"velocity": {"publish": "off"}},
                }
            ],
        },
        environ={},
    )
    keys = {k.key for k in all_keys(*with_nodes(cfg))}
    assert f"{P}/wire/value/position" in keys
    assert f"{P}/wire/value/velocity" not in keys


def test_listing_has_one_short_line_per_key_grouped_by_node() -> None:
    text = render_keys(*with_nodes(config()))
    lines = text.splitlines()
    assert lines[0].startswith("# prefix canopen/line1")
    assert "# node wire: sgh10, node id 1" in lines
    assert "# node display: ap05, node id 125" in lines
    body = [line for line in lines if line and not line.startswith("#")]
    assert len(body) == len(all_keys(*with_nodes(config())))
    assert max(len(line) for line in body) < 160
    pos = next(line for line in body if line.startswith(f"{P}/wire/value/position "))
    assert "int32 [mm]" in pos


def test_cli_keys_prints_the_listing(tmp_path: object, capsys: pytest.CaptureFixture[str]) -> None:
    import pathlib

    path = pathlib.Path(str(tmp_path)) / "gw.yaml"
    path.write_text(
        "gateway: {name: line1}\nnodes:\n  - {name: wire, node_id: 1, profile: sgh10}\n"
    )
    assert main(["keys", "-c", str(path)]) == 0
    out = capsys.readouterr().out
    assert f"{P}/wire/value/position" in out
    assert f"{P}/wire/sdo/<index>/<sub>" in out


def test_short_text_keeps_the_first_clause_on_one_line() -> None:
    assert (
        short_text("Position value (4.7.2.29) = measured value\n + calibration")
        == "Position value (4.7.2.29)"
    )
    assert short_text("Velocity in mm/s. More text here.") == "Velocity in mm/s"
    long = short_text("x" * 100, limit=20)
    assert len(long) == 20 and long.endswith("...")


@pytest.mark.parametrize(
    ("key", "expected"),
    [
        (f"{P}/catalog", Request("catalog")),
        (f"{P}/wire/snapshot", Request("snapshot", "wire")),
        (f"{P}/wire/state", Request("state", "wire")),
        (f"{P}/wire/nmt", Request("nmt", "wire")),
        (f"{P}/display/set", Request("set_many", "display")),
        (f"{P}/display/set/set_point2", Request("set", "display", signal="set_point2")),
        (f"{P}/wire/value/position", Request("value", "wire", signal="position")),
        (f"{P}/wire/sdo/6004/00", Request("sdo", "wire", obj=ObjRef(0x6004, 0))),
        (f"{P}/wire/sdo/0x1018/0x4", Request("sdo", "wire", obj=ObjRef(0x1018, 4))),
        (f"{P}/wire/sdo/1008h/0", Request("sdo", "wire", obj=ObjRef(0x1008, 0))),
    ],
)
def test_query_keys_parse_into_requests(key: str, expected: Request) -> None:
    assert parse_key(P, key) == expected


@pytest.mark.parametrize(
    ("key", "words"),
    [
        ("other/prefix/catalog", "not under canopen/line1"),
        (f"{P}/wire", "expected canopen/line1/catalog or"),
        (f"{P}/wire/bogus", "unknown key"),
        (f"{P}/wire/sdo/6004", "sdo/<index hex>/<sub hex>"),
        (f"{P}/wire/sdo/6004/00/1", "sdo/<index hex>/<sub hex>"),
        (f"{P}/wire/sdo/xyz/00", "index 'xyz' is not hexadecimal"),
        (f"{P}/wire/sdo/10000/00", "above 0xFFFF"),
        (f"{P}/wire/sdo/6004/100", "above 0xFF"),
        (f"{P}/alive/wire", "liveliness"),
        (f"{P}/wire/emcy", "subscribe"),
        (f"{P}/wire/pdo/181", "subscribe"),
        (f"{P}/wire/tpdo/1", "subscribe"),
    ],
)
def test_keys_outside_the_scheme_say_what_was_expected(key: str, words: str) -> None:
    with pytest.raises(BadKey, match=None) as exc:
        parse_key(P, key)
    assert words in str(exc.value)


def test_sdo_key_is_lower_case_hex_index_and_sub() -> None:
    assert sdo_key(P, "wire", ObjRef(0x6004, 0)) == f"{P}/wire/sdo/6004/00"
    assert parse_key(P, sdo_key(P, "wire", ObjRef(0x5F0A, 2))).obj == ObjRef(0x5F0A, 2)


def test_wildcards_are_recognised() -> None:
    assert has_wildcard(f"{P}/*/state")
    assert has_wildcard(f"{P}/**")
    assert has_wildcard(f"{P}/wire/value/pos$*")
    assert not has_wildcard(f"{P}/wire/state")
