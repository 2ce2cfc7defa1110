"""How a configuration problem is reported: ``ConfigError`` (one line per problem), the key
path of a problem (``nodes[2].node_id``), what a pydantic error means in the words of the file
(``unknown key (typo?)``, ``must be one of ...``, ``got 70000, must be <= 65535``) and, for an
unknown key, the nearest key its section allows.

Imports: pydantic, config.model (the sections, to find the keys a section allows).
"""

from __future__ import annotations

import difflib
import typing
from collections.abc import Mapping
from typing import Annotated, Any

from pydantic import BaseModel

from canopen_gateway.config.model import Config


class ConfigError(Exception):
    """One or more configuration problems, one line each."""

    def __init__(self, problems: list[str]):
        self.problems = problems
        super().__init__("\n".join(problems))


def key_path(loc: tuple[Any, ...]) -> str:
    """``("nodes", 2, "node_id")`` -> ``nodes[2].node_id``."""
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += ("." if out else "") + str(part)
    return out or "(top level)"


#: pydantic's type errors, as what the key takes
_TYPE_WORDS = {
    "int_parsing": "a whole number", "int_type": "a whole number", "int_from_float": "a whole number",
    "float_parsing": "a number", "float_type": "a number",
    "bool_parsing": "true or false", "bool_type": "true or false",
    "string_type": "text",
}  # fmt: skip


def describe(err: Mapping[str, Any]) -> str:
    """What a pydantic error says, in the words of the file."""
    t = err.get("type", "")
    ctx = err.get("ctx") or {}
    if t == "extra_forbidden":
        return "unknown key (typo?)"
    if t == "missing":
        return "required key is missing"
    if t == "literal_error":
        return f"must be one of {ctx.get('expected', '')}"
    if t in ("greater_than_equal", "less_than_equal", "greater_than", "less_than"):
        bounds = {
            "greater_than_equal": ">=",
            "less_than_equal": "<=",
            "greater_than": ">",
            "less_than": "<",
        }
        limit = next(iter(ctx.values()), "")
        return f"got {err.get('input')!r}, must be {bounds[t]} {limit}"
    if t == "string_pattern_mismatch":
        return f"got {err.get('input')!r}, must match {ctx.get('pattern')}"
    if t in _TYPE_WORDS:  # the value as written, and what the key takes
        return f"got {err.get('input')!r}, must be {_TYPE_WORDS[t]}"
    msg = str(err.get("msg", "invalid"))
    return msg.removeprefix("Value error, ")


def _models_in(annotation: Any) -> tuple[type[BaseModel] | None, bool]:
    """The pydantic model a field holds (directly, in a list, an Optional, or as dict values),
    and whether the next part of a key path is a dict key."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation, False
    origin = typing.get_origin(annotation)
    args = typing.get_args(annotation)
    if origin is Annotated:
        return _models_in(args[0])
    for arg in args:
        model, _ = _models_in(arg)
        if model is not None:
            return model, origin is dict
    return None, False


def nearest_key(loc: tuple[Any, ...]) -> str | None:
    """For an unknown key at ``loc``: the closest key its section allows, if one is close."""
    model: type[BaseModel] | None = Config
    skip = False
    for part in loc[:-1]:
        if isinstance(part, int) or skip:
            skip = False
            continue
        field = model.model_fields.get(str(part)) if model is not None else None
        if field is None:
            return None
        model, skip = _models_in(field.annotation)
    if model is None:
        return None
    near = difflib.get_close_matches(str(loc[-1]), list(model.model_fields), n=1, cutoff=0.6)
    return near[0] if near else None
