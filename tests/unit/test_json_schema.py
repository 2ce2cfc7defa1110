"""``canopen-gateway schema`` (and ``schema --profile``): a JSON Schema (draft 2020-12) that a
real validator (jsonschema) holds every shipped file to: every config under config/ and deploy/
(the ones the Kubernetes ConfigMaps carry too), the built-in profiles, ``profile init``'s
output; and that refuses what ``check`` refuses of a file's shape: a misspelt key, a wrong
type, a value out of range, a key the CAN interface does not take."""

from __future__ import annotations

import copy
import json
from pathlib import Path
from typing import Any

import pytest
import yaml
from jsonschema import Draft202012Validator

from canopen_gateway.checks.json_schema import config_schema, profile_schema
from canopen_gateway.cli import main
from canopen_gateway.config import ConfigError, parse_config
from canopen_gateway.eds import load_eds
from canopen_gateway.eds.show import overlay_profile
from canopen_gateway.profiles import builtin_profiles

ROOT = Path(__file__).resolve().parents[2]
PROFILES = ROOT / "canopen_gateway" / "profiles"
CORPUS = ROOT / ".." / "shared" / "eds-corpus"


def as_editor_sees(doc: Any) -> Any:
    """A YAML document as a YAML language server hands it to the schema: JSON (numeric keys
    such as ``tpdo: {1: ...}`` become the strings ``"1"``)."""
    return json.loads(json.dumps(doc))


@pytest.fixture(scope="module")
def config_validator() -> Draft202012Validator:
    schema = config_schema()
    Draft202012Validator.check_schema(schema)
    return Draft202012Validator(schema)


@pytest.fixture(scope="module")
def profile_validator() -> Draft202012Validator:
    schema = profile_schema()
    Draft202012Validator.check_schema(schema)
    return Draft202012Validator(schema)


def shipped_configs() -> list[tuple[str, Any]]:
    """Every gateway config in config/ and deploy/: the files, and the ``config.yaml`` each
    Kubernetes ConfigMap carries."""
    out = []
    for path in sorted([*ROOT.glob("config/*.yaml"), *ROOT.glob("deploy/config/*.yaml")]):
        out.append((str(path.relative_to(ROOT)), yaml.safe_load(path.read_text(encoding="utf-8"))))
    for path in sorted(ROOT.glob("deploy/k8s/**/*.yaml")):
        for doc in yaml.safe_load_all(path.read_text(encoding="utf-8")):
            if isinstance(doc, dict) and doc.get("kind") == "ConfigMap":
                for key, text in doc.get("data", {}).items():
                    if key.endswith((".yaml", ".yml")):
                        where = f"{path.relative_to(ROOT)}:{doc['metadata']['name']}/{key}"
                        out.append((where, yaml.safe_load(text)))
    return out


SHIPPED = shipped_configs()


def problems(validator: Draft202012Validator, doc: Any) -> list[str]:
    return [f"{'/'.join(map(str, e.absolute_path))}: {e.message}" for e in validator.iter_errors(as_editor_sees(doc))]


def test_schema_command_prints_draft_2020_12_schemas(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["schema"]) == 0
    schema = json.loads(capsys.readouterr().out)
    assert schema["$schema"] == "https://json-schema.org/draft/2020-12/schema"
    assert schema["additionalProperties"] is False
    assert {"can", "nodes", "modbus", "zenoh"} <= set(schema["properties"])
    assert main(["schema", "--profile"]) == 0
    profile = json.loads(capsys.readouterr().out)
    assert {"signals", "tpdos", "boot", "emcy"} <= set(profile["properties"])


def test_every_shipped_config_and_configmap_validates(config_validator: Draft202012Validator) -> None:
    names = [where for where, _ in SHIPPED]
    assert any("configmap.yaml" in n for n in names) and "config/demo.yaml" in names
    assert len([n for n in names if "k8s" in n]) >= 2  # the gateway's and the pair's
    for where, doc in SHIPPED:
        assert problems(config_validator, doc) == [], where


def test_shipped_configs_read_the_same_in_yaml_1_1_and_1_2() -> None:
    """No YAML 1.1-only boolean (on/off/yes/no: strings in YAML 1.2) in a shipped config, so a
    YAML 1.2 validator (check-jsonschema, as the README suggests for CI) reads them as the
    gateway does."""
    import re

    bare = re.compile(r"^\s*(?:- )?[A-Za-z_]+:\s+(?:on|off|yes|no|On|Off|Yes|No|ON|OFF)\s*(?:#.*)?$")
    files = [*ROOT.glob("config/*.yaml"), *ROOT.glob("deploy/config/*.yaml"), *ROOT.glob("deploy/k8s/**/*.yaml")]
    found = [f"{f.relative_to(ROOT)}:{i}: {line.strip()}" for f in sorted(files)
             for i, line in enumerate(f.read_text(encoding="utf-8").splitlines(), start=1) if bare.match(line)]  # fmt: skip
    assert len(files) >= 8 and found == []


@pytest.mark.parametrize("family", builtin_profiles())
def test_builtin_profiles_validate(profile_validator: Draft202012Validator, family: str) -> None:
    doc = yaml.safe_load((PROFILES / f"{family}.yaml").read_text(encoding="utf-8"))
    assert problems(profile_validator, doc) == []


def test_profile_init_output_validates(profile_validator: Draft202012Validator) -> None:
    files = [PROFILES / "ap05.eds", PROFILES / "msk5000.eds"]
    files += sorted(CORPUS.glob("*.eds"))[:6] if CORPUS.is_dir() else []
    for path in files:
        doc = yaml.safe_load(overlay_profile(load_eds(path), str(path)))
        assert problems(profile_validator, doc) == [], path.name


DEMO = yaml.safe_load((ROOT / "config/demo.yaml").read_text(encoding="utf-8"))


def changed(path: str, value: Any, delete: str | None = None) -> dict[str, Any]:
    """The demo config with one key set (``a.b.0.c``) and optionally one removed."""
    doc = copy.deepcopy(DEMO)
    *parents, last = path.split(".")
    node = doc
    for p in parents:
        node = node[int(p)] if isinstance(node, list) else node.setdefault(p, {})
    node[int(last) if isinstance(node, list) else last] = value
    if delete is not None:
        del node[delete]
    return doc


@pytest.mark.parametrize(
    ("mistake", "doc"),
    [
        ("misspelt top-level section", changed("modbuss", {"port": 502})),
        ("misspelt key in a section", changed("modbus.prot", 502)),
        ("misspelt key of a node", changed("nodes.0.node_idd", 3, delete="node_id")),
        ("misspelt key of a PDO setting", changed("nodes.1.tpdo", {1: {"event_timer": 10}})),
        ("a port as text", changed("modbus.port", "five")),
        ("a port out of range", changed("modbus.port", 70000)),
        ("a node id out of range", changed("nodes.0.node_id", 128)),
        ("a flag that is not a boolean", changed("zenoh.writes", "maybe")),
        ("a word order that does not exist", changed("modbus.word_order", "middle")),
        ("an object that is not an address", changed("nodes.1.sdo", [{"object": "6004-00", "value": 1}])),
        ("a key the CAN interface does not take", changed("can.chanel", "vcan0")),
        ("a CAN interface python-can does not know", changed("can.interface", "virtul")),
        ("a node with neither profile nor eds", changed("nodes.0.profile", None, delete="profile")),
        ("health.tls without its key", changed("health.tls", {"cert": "server.pem"})),
        ("a misspelt key of health.tls", changed("health.tls", {"cert": "s.pem", "key": "k.pem", "ca": "c"})),
        ("an empty health.tls.cert", changed("health.tls", {"cert": "", "key": "k.pem"})),
        ("health.tls.key as a number", changed("health.tls", {"cert": "s.pem", "key": 5})),
    ],
)
def test_schema_refuses_what_check_refuses(
    config_validator: Draft202012Validator, mistake: str, doc: dict[str, Any]
) -> None:
    assert problems(config_validator, doc), f"the schema accepts {mistake}"
    assert check_refuses(doc), f"check accepts {mistake}"


def check_refuses(doc: dict[str, Any]) -> bool:
    """What ``check`` holds a file's shape to: the models, then the ``can:`` section against
    the interface (``cli.load.load_for_bus``)."""
    from canopen_gateway.bus.can_backend import can_section_problems, interface_problem

    try:
        parse_config(doc, "demo.yaml", environ={})
    except ConfigError:
        return True
    nets = doc.get("networks")
    sections = [net.get("can") for net in nets] if nets is not None else [doc.get("can")]
    return any(
        not isinstance(section, dict) or "interface" not in section  # named: load_for_bus
        or bool(interface_problem(section["interface"]) or can_section_problems(section))
        for section in sections
    )


TWO = yaml.safe_load((ROOT / "config/two-networks.yaml").read_text(encoding="utf-8"))


def networks_changed(change: Any) -> dict[str, Any]:
    """config/two-networks.yaml with ``change(doc)`` applied."""
    doc = copy.deepcopy(TWO)
    change(doc)
    return doc


@pytest.mark.parametrize(
    ("mistake", "doc"),
    [
        ("networks: with a top-level can:", networks_changed(lambda d: d.update(can=d["networks"][0]["can"]))),
        ("networks: with a top-level nodes:", networks_changed(lambda d: d.update(nodes=[]))),
        ("networks: with a top-level master:", networks_changed(lambda d: d.update(master={"node_id": 1}))),
        ("an empty networks:", networks_changed(lambda d: d.update(networks=[]))),
        ("a network without its can:", networks_changed(lambda d: d["networks"][1].pop("can"))),
        ("a network without a name", networks_changed(lambda d: d["networks"][1].pop("name"))),
        ("a network name in capitals", networks_changed(lambda d: d["networks"][0].update(name="Line1"))),
        ("a misspelt key of a network", networks_changed(lambda d: d["networks"][0].update(nodess=[]))),
        ("a key a network's CAN interface does not take",
         networks_changed(lambda d: d["networks"][1]["can"].update(chanel="x"))),
        ("a misspelt key of the command socket", changed("command_socket", {"enable": False})),
    ],
)
def test_schema_refuses_what_check_refuses_of_networks(
    config_validator: Draft202012Validator, mistake: str, doc: dict[str, Any]
) -> None:
    assert problems(config_validator, doc), f"the schema accepts {mistake}"
    assert check_refuses(doc), f"check accepts {mistake}"


def test_schema_takes_both_forms_and_the_command_socket(config_validator: Draft202012Validator) -> None:
    assert problems(config_validator, TWO) == []
    assert problems(config_validator, DEMO) == []
    assert problems(config_validator, changed("health.tls", {"cert": "server.pem", "key": "server.key"})) == []
    sock = changed("command_socket", {"enabled": False, "path": "run/gw.sock"})
    assert problems(config_validator, sock) == [] and not check_refuses(sock)
    assert problems(config_validator, networks_changed(lambda d: d.pop("networks")))  # no bus at all


def test_hex_numbers_and_object_addresses_as_files_write_them_validate(
    config_validator: Draft202012Validator,
) -> None:
    doc = changed("nodes.1.tpdo", {1: {"cob_id": "0x190", "mapping": ["0x6004:00"]}})
    doc["nodes"][1]["sdo"] = [{"object": "5115h:00h", "value": 1}, {"object": 0x1017, "value": 100}]
    assert problems(config_validator, doc) == []
    assert problems(config_validator, changed("nodes.1.tpdo", {1: {"cob_id": 0x800}}))
    assert problems(config_validator, changed("nodes.1.tpdo", {"one": {}}))


#: the keys of a closed gateway: connection caps, the CRL, the console's hosts and token file,
#: Zenoh's reads and password file, the ASCII gateway's networks, the command socket
SECURED = {
    "modbus": {"max_connections": 32, "max_connections_per_client": 4, "idle_timeout_s": 120,
               "allowed_networks": ["10.1.0.0/24"],
               "tls": {"cert": "tls/gw.pem", "key": "tls/gw.key", "ca": "tls/ca.pem", "crl": "tls/ca.crl"}},
    "web": {"allowed_hosts": ["gw.plant.example", "10.1.0.5:8080"], "token_file": "secrets/web-token"},
    "zenoh": {"reads": "all", "auth": {"user": "gw1", "password_file": "secrets/zenoh-password"}},
    "ascii": {"allowed_networks": ["10.1.0.0/24"]},
    "command_socket": {"enabled": True, "path": "run/gw.sock"},
}  # fmt: skip


def secured(doc: dict[str, Any], **change: dict[str, Any]) -> dict[str, Any]:
    """``doc`` with the SECURED sections merged in, then ``change`` (section -> keys) over them."""
    out = copy.deepcopy(doc)
    for section, keys in SECURED.items():
        out[section] = {**out.get(section, {}), **copy.deepcopy(keys), **change.get(section, {})}
    return out


@pytest.mark.parametrize("form", ["single", "networks"])
def test_schema_takes_the_keys_of_a_closed_gateway_in_both_forms(
    config_validator: Draft202012Validator, form: str
) -> None:
    doc = secured(DEMO if form == "single" else TWO)
    assert problems(config_validator, doc) == []
    assert not check_refuses(doc)


@pytest.mark.parametrize("form", ["single", "networks"])
@pytest.mark.parametrize(
    ("mistake", "change"),
    [
        ("no connection at all", {"modbus": {"max_connections": 0}}),
        ("a negative idle timeout", {"modbus": {"idle_timeout_s": -1}}),
        ("a misspelt cap", {"modbus": {"max_conections": 8}}),
        ("a CRL without its CA", {"modbus": {"tls": {"cert": "gw.pem", "key": "gw.key", "crl": "ca.crl"}}}),
        ("Zenoh reads that do not exist", {"zenoh": {"reads": "some"}}),
        ("the examples' password", {"zenoh": {"auth": {"user": "gw1", "password": "Change-Me"}}}),
        ("a password and its file", {"zenoh": {"auth": {"user": "gw1", "password": "s3cret-pw",
                                                        "password_file": "pw"}}}),
        ("a token and its file", {"web": {"token": "a-long-enough-token", "token_file": "t"}}),
        ("one allowed host as text", {"web": {"allowed_hosts": "gw.plant.example"}}),
        ("ASCII networks as text", {"ascii": {"allowed_networks": "10.1.0.0/24"}}),
    ],
)
def test_schema_refuses_what_check_refuses_of_a_closed_gateway(
    config_validator: Draft202012Validator, form: str, mistake: str, change: dict[str, Any]
) -> None:
    doc = secured(DEMO if form == "single" else TWO, **change)
    assert problems(config_validator, doc), f"the schema accepts {mistake}"
    assert check_refuses(doc), f"check accepts {mistake}"
