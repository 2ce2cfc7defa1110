"""The JSON Schemas (draft 2020-12) of the gateway's configuration file and of a device profile
file, for editors with a YAML language server and for CI checks (``canopen-gateway schema``,
``schema --profile``).

Generated from the pydantic models that load the files (``canopen_gateway.config.Config``,
``canopen_gateway.profiles.schema.Profile``), so a key the loader refuses (``extra="forbid"``) is
``additionalProperties: false`` here too, then made to say what the loader says where the
models alone cannot:

* numbers the files may write in hex (``cob_id: 0x181``, ``"0x181"``, ``"181h"``) and object
  addresses (``"0x6004:00"``) keep their ranges and accept the written forms;
* mappings keyed by numbers (``tpdo: {1: ...}``, ``emcy: {0x1000: ...}``) name their keys;
* either form of the CAN networks: a top-level ``can:`` (one network), or ``networks:``, each
  with its name and its own ``can:``, and then no top-level ``can:``, ``master:`` or ``nodes:``;
* ``can:`` takes, per interface, the keys python-can's bus class of that interface takes on this
  install (what ``check`` holds the section to, ``canopen_gateway.bus.can_backend``), and must name its
  interface; a node names a profile or an EDS;
* the rules between keys of one section the loader holds a file to: ``web.token`` or
  ``web.token_file``, not both (``zenoh.auth.password`` / ``password_file`` alike), never the
  examples' placeholder as ``zenoh.auth.password``, ``modbus.tls.crl`` only with its ``ca``;
* a profile's ``features`` are the known feature names.

What one file cannot say of itself (duplicate node ids, network names or buses, two nodes on
one Modbus unit, a profile that does not exist, an object the EDS lacks) stays ``check``'s, and
so do the rules JSON Schema cannot compare or parse (``modbus.max_connections_per_client`` at
most ``modbus.max_connections``, ``allowed_networks`` entries that are IP networks).

Imports: canopen_gateway.config (Config, model: NETWORK_KEYS, zenoh: PLACEHOLDER_PASSWORDS), canopen_gateway.profiles.schema (Profile, KNOWN_FEATURES),
canopen_gateway.bus.can_backend (interface_keys, TIMING_KEYS), python-can (the interface names), pydantic.
"""

from __future__ import annotations

import logging
from typing import Any

import can.interfaces
from pydantic.json_schema import GenerateJsonSchema, JsonSchemaValue
from pydantic_core import core_schema

from canopen_gateway.bus.can_backend import TIMING_KEYS, interface_keys
from canopen_gateway.config import Config
from canopen_gateway.config.model import NETWORK_KEYS
from canopen_gateway.config.zenoh import PLACEHOLDER_PASSWORDS
from canopen_gateway.profiles.schema import KNOWN_FEATURES, Profile

DRAFT = "https://json-schema.org/draft/2020-12/schema"

#: a whole number as the files may write it: 1234, "1234", "0x4D2", "4D2h" (profiles.schema._parse_int)
INT_TEXT = r"^\s*(-?[0-9_]+|0[xX][0-9A-Fa-f_]+|0[oO][0-7_]+|0[bB][01_]+|[0-9A-Fa-f_]+[hH])\s*$"
#: an object address: 0x6004:00, 6004:0, 6004h:00h, 0x6004 (canopen.objref)
OBJ_TEXT = r"^\s*(0x)?[0-9A-Fa-f]{1,4}h?\s*(:\s*(0x)?[0-9A-Fa-f]{1,2}h?)?\s*$"
#: a PDO mapping entry: object and length in bits, 0x6004:00/32
ENTRY_TEXT = r"^\s*(0x)?[0-9A-Fa-f]{1,4}h?\s*(:\s*(0x)?[0-9A-Fa-f]{1,2}h?)?\s*/\s*[0-9]+\s*$"
_RANGE_KEYS = {"ge": "minimum", "le": "maximum", "gt": "exclusiveMinimum", "lt": "exclusiveMaximum"}


class _Generator(GenerateJsonSchema):
    """pydantic's generator, with the written forms of hex numbers and object addresses."""

    def function_before_schema(self, schema: core_schema.BeforeValidatorFunctionSchema) -> JsonSchemaValue:
        name = getattr(schema["function"].get("function"), "__name__", "")
        if name == "_parse_int":  # profiles.schema.HexInt
            return {"anyOf": [{"type": "integer"}, {"type": "string", "pattern": INT_TEXT}]}
        if name in ("_obj", "_parse_obj"):  # config.node.Obj, profiles.schema.Obj
            return {
                "anyOf": [
                    {"type": "string", "pattern": OBJ_TEXT},
                    {"type": "integer", "minimum": 0, "maximum": 0xFFFF},
                    *([_OBJ_PAIR] if name == "_parse_obj" else []),
                ],
                "description": "an object address, e.g. 0x6004:00",
            }
        if name == "_parse_entry":  # profiles.schema: a PDO entry "0x6004:00/32" or its mapping
            inner = self.generate_inner(schema["schema"])
            return {"anyOf": [{"type": "string", "pattern": ENTRY_TEXT}, inner]}
        if name == "_constraint":  # profiles.schema: "0 or 10..65535", or {allowed, note}
            inner = self.generate_inner(schema["schema"])
            return {"anyOf": [{"type": ["string", "integer"]}, inner]}
        if name == "_pdo_numbers":  # config.node.PdoSettings: {1: {...}, 2: {...}}
            inner = self.generate_inner(schema["schema"])
            return {**inner, "propertyNames": {"pattern": r"^[0-9]+$"}}
        return super().function_before_schema(schema)

    def dict_schema(self, schema: core_schema.DictSchema) -> JsonSchemaValue:
        out = super().dict_schema(schema)
        keys = schema.get("keys_schema")
        if keys is not None and keys.get("type") in ("int", "function-before"):
            names = self.generate_inner(keys)
            out["propertyNames"] = (
                {"pattern": INT_TEXT}
                if "anyOf" in names and names["anyOf"][0].get("type") == "integer"
                else names
            )
            if "anyOf" in names and names["anyOf"][0].get("pattern") == OBJ_TEXT:
                out["propertyNames"] = {"pattern": OBJ_TEXT}
        return out


_OBJ_PAIR = {"type": "array", "prefixItems": [{"type": "integer"}, {"type": "integer"}], "minItems": 2, "maxItems": 2}


def _ranges(node: Any) -> Any:
    """pydantic writes ``ge``/``le`` beside a type it could not put them in (the hex numbers):
    move them into the number's branch as JSON Schema's own words."""
    if isinstance(node, list):
        return [_ranges(v) for v in node]
    if not isinstance(node, dict):
        return node
    out = {k: _ranges(v) for k, v in node.items()}
    bounds = {_RANGE_KEYS[k]: out.pop(k) for k in list(out) if k in _RANGE_KEYS}
    if bounds:
        for branch in out.get("anyOf", []):
            if branch.get("type") == "integer":
                branch.update(bounds)
        if out.get("type") in ("integer", "number"):
            out.update(bounds)
    return out


def _can_section(section: dict[str, Any]) -> dict[str, Any]:
    """``can:``: the interface named, one of python-can's; per interface the keys it takes."""
    names = sorted(can.interfaces.BACKENDS)
    section["properties"]["interface"] = {
        "type": "string",
        "enum": names,
        "description": "the python-can interface (socketcan, pcan, kvaser, ixxat, remote; "
        "virtual for simulated devices without hardware)",
    }
    section["properties"].pop("reopen_backoff_s", None)
    section["properties"]["reopen_backoff_s"] = {
        "type": "number", "exclusiveMinimum": 0, "maximum": 60,
        "description": "seconds between attempts to reopen a lost bus",
    }  # fmt: skip
    section["required"] = ["interface"]
    rules = []
    before = logging.root.manager.disable
    logging.disable(logging.WARNING)  # backends that cannot load say so as they import
    try:
        keys_of = {name: interface_keys(name) for name in names}
    finally:
        logging.disable(before)
    for name in names:
        keys = keys_of[name]
        if keys is None:  # its module does not load here: check says so, not the schema
            continue
        rules.append(
            {
                "if": {"properties": {"interface": {"const": name}}, "required": ["interface"]},
                "then": {"propertyNames": {"enum": sorted(keys | TIMING_KEYS)}},
            }
        )
    section["allOf"] = rules
    return section


def _networks(schema: dict[str, Any], network: dict[str, Any]) -> None:
    """Either form: the single network's top-level ``can:`` (with ``master:`` and ``nodes:``),
    or ``networks:``, a list of 1 to 8 networks each with its name and its own ``can:``, and
    then none of the top-level three (the loader's refusals, ``config.networks``)."""
    nets = schema["properties"]["networks"]
    (listed,) = [branch for branch in nets.pop("anyOf") if branch.get("type") == "array"]
    nets.pop("default", None)
    nets.update(listed, minItems=1, description="several CAN networks, each with its own can:, "
                "master: and nodes: (instead of the top-level ones)")  # fmt: skip
    network["required"] = ["name", "can"]
    schema.pop("required", None)
    schema["if"] = {"required": ["networks"]}
    schema["then"] = {"properties": {key: False for key in NETWORK_KEYS}}
    schema["else"] = {"required": ["can"]}


def _not_both(a: str, b: str) -> dict[str, Any]:
    """Keys ``a`` and ``b`` not both given (a null is not given)."""
    return {"not": {"properties": {a: {"type": "string"}, b: {"type": "string"}}, "required": [a, b]}}


def _placeholder_text() -> str:
    """The examples' placeholder passwords (``config.zenoh.placeholder_problem``), in any case
    and with blanks around, as one pattern (ECMA-262 has no flag for case)."""
    def any_case(word: str) -> str:
        return "".join(f"[{c.lower()}{c.upper()}]" if c.isalpha() else f"[{c}]" for c in word)
    return r"^\s*(" + "|".join(any_case(p) for p in sorted(PLACEHOLDER_PASSWORDS)) + r")\s*$"


def _section_rules(defs: dict[str, Any]) -> None:
    """The rules between keys of one section (see the module docstring)."""
    defs["WebSection"]["allOf"] = [_not_both("token", "token_file")]
    auth = defs["ZenohAuth"]
    auth["allOf"] = [_not_both("password", "password_file")]
    (text,) = [b for b in auth["properties"]["password"]["anyOf"] if b.get("type") == "string"]
    text["not"] = {"pattern": _placeholder_text()}  # never the examples' change-me
    defs["ModbusTls"]["allOf"] = [{
        "if": {"properties": {"crl": {"type": "string"}}, "required": ["crl"]},
        "then": {"properties": {"ca": {"type": "string"}}, "required": ["ca"]},
    }]  # fmt: skip


def config_schema() -> dict[str, Any]:
    """The schema of a gateway configuration file."""
    schema = _ranges(Config.model_json_schema(schema_generator=_Generator))
    for internal in ("source", "env_keys", "key_prefix"):  # the loader's, never in a file
        schema["properties"].pop(internal, None)
    defs = schema["$defs"]
    _can_section(defs["CanSection"])
    _networks(schema, defs["NetworkSection"])
    _section_rules(defs)
    defs["NodeConfig"]["anyOf"] = [{"required": ["profile"]}, {"required": ["eds"]}]
    return {
        "$schema": DRAFT,
        "title": "canopen-gateway configuration",
        "description": "The gateway's YAML configuration (docs: README.md, Configuration). "
        "`canopen-gateway check -c FILE` checks what a file cannot say of itself.",
        **{k: v for k, v in schema.items() if k != "title"},
    }


def profile_schema() -> dict[str, Any]:
    """The schema of a device profile file (an overlay on an EDS, docs/devices.md)."""
    schema = _ranges(Profile.model_json_schema(schema_generator=_Generator))
    schema["properties"]["features"]["propertyNames"] = {"enum": sorted(KNOWN_FEATURES)}
    return {
        "$schema": DRAFT,
        "title": "canopen-gateway device profile",
        "description": "A device profile: an overlay on the device's EDS (docs/devices.md).",
        **{k: v for k, v in schema.items() if k != "title"},
    }
