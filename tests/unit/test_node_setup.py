"""The device knowledge reads a node's configuration as one config-free record: ``NodeSetup``,
built in one place (``NodeConfig.setup``). No module below the config mirrors config fields as
a Protocol or reads a node's fields by ``getattr``; every field of the record is the config
entry's field of the same name, carried over as given."""

from __future__ import annotations

import ast
import dataclasses
from pathlib import Path

import pytest

from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.config import NodeConfig, PdoSetting
from canopen_gateway.device.boot_steps import build_boot_steps
from canopen_gateway.profiles import (
    ExternalHeartbeatSetup,
    NodeSetup,
    PdoSetup,
    SdoSetup,
    load_node_profile,
)

GATEWAY = Path(__file__).resolve().parents[2] / "canopen_gateway"
#: the packages that read a node's configuration only through ``NodeSetup``
DEVICE_KNOWLEDGE = ("profiles", "device", "pdo", "eds")


def _modules() -> list[Path]:
    return [p for pkg in DEVICE_KNOWLEDGE for p in sorted((GATEWAY / pkg).rglob("*.py"))]


def test_no_module_of_the_device_knowledge_mirrors_config_fields_as_a_protocol() -> None:
    found = []
    for path in _modules():
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ClassDef) and any(
                getattr(b, "id", getattr(b, "attr", "")) == "Protocol" for b in node.bases
            ):
                found.append(f"{path.relative_to(GATEWAY)}: {node.name}")
    assert found == []


def test_no_module_of_the_device_knowledge_reads_a_node_by_getattr() -> None:
    found = []
    for path in _modules():
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if (
                isinstance(node, ast.Call)
                and getattr(node.func, "id", "") == "getattr"
                and getattr(node.args[0], "id", "") in ("node", "ncfg", "master")
            ):
                found.append(f"{path.relative_to(GATEWAY)}:{node.lineno}")
    assert found == []


def test_every_field_of_the_record_is_the_config_entrys_field_of_that_name() -> None:
    for record, entry in ((NodeSetup, NodeConfig), (PdoSetup, PdoSetting)):
        names = {f.name for f in dataclasses.fields(record)}
        assert names <= set(entry.model_fields), names - set(entry.model_fields)


def test_the_setup_carries_the_entry_as_given() -> None:
    entry = NodeConfig.model_validate(
        {
            "name": "valve",
            "node_id": 125,
            "profile": "ap05",
            "eds": "ap05.eds",
            "configure": False,
            "tpdo": {2: {"enabled": False}, 1: {"transmission": 1, "event_timer_ms": 50,
                                                "inhibit_ms": 1.5, "mapping": ["6004h:00"]}},
            "rpdo": {1: {"cob_id": "0x201", "sync_start": 3}},
            "sdo": [{"object": "1017h:00", "value": 500, "type": "uint16"}],
            "supervision": "guarding",
            "heartbeat_ms": 0,
            "guard_time_ms": 250,
            "life_time_factor": 4,
            "pdo_variant": 2,
            "external_heartbeat": {"interval_ms": 200, "source": "sync"},
            "verify_mapping": False,
        }
    )  # fmt: skip
    assert entry.setup == NodeSetup(
        node_id=125,
        profile="ap05",
        eds="ap05.eds",
        pdo_variant=2,
        configure=False,
        tpdo={
            1: PdoSetup(transmission=1, event_timer_ms=50, inhibit_ms=1.5, mapping=("6004h:00",)),
            2: PdoSetup(enabled=False),
        },
        rpdo={1: PdoSetup(cob_id=0x201, sync_start=3)},
        sdo=(SdoSetup(ObjRef(0x1017, 0), 500, "uint16"),),
        supervision="guarding",
        heartbeat_ms=0,
        guard_time_ms=250,
        life_time_factor=4,
        external_heartbeat=ExternalHeartbeatSetup(200, "sync"),
        verify_mapping=False,
    )
    assert not entry.setup.eds_only


def test_the_record_is_frozen() -> None:
    setup = NodeSetup(node_id=1, profile="sgh10")
    with pytest.raises(dataclasses.FrozenInstanceError):
        setup.node_id = 2  # type: ignore[misc]


def test_a_record_built_directly_configures_as_the_entry_does() -> None:
    """The loader and the boot steps need no config: a record written by hand gives what the
    same node's entry gives."""
    entry = NodeConfig.model_validate(
        {"name": "enc", "node_id": 3, "profile": "sgh10", "supervision": "guarding",
         "guard_time_ms": 200, "life_time_factor": 3,
         "sdo": [{"object": "6200h:00", "value": "0x14"}]}
    )  # fmt: skip
    by_hand = NodeSetup(
        node_id=3, profile="sgh10", supervision="guarding", guard_time_ms=200,
        life_time_factor=3, sdo=(SdoSetup(ObjRef(0x6200, 0), "0x14"),),
    )  # fmt: skip
    lp = load_node_profile(by_hand)
    assert lp is load_node_profile(entry.setup)  # one cached result for equal setups
    steps = build_boot_steps(lp, by_hand)
    assert steps == build_boot_steps(lp, entry.setup)
    assert [(s.object, s.value) for s in steps[:3]] == [
        (ObjRef(0x1017, 0), 0), (ObjRef(0x100C, 0), 200), (ObjRef(0x100D, 0), 3)
    ]  # fmt: skip
