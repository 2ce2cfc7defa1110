"""Fixtures shared by the tests: a gateway with a connected Modbus client, and CAN frames.

``modbus_gateway`` gives ``tests.helpers.modbus_gateway`` (an async context manager: a started
gateway of a config and a connected pymodbus client, both stopped on exit); ``can_frame`` gives
``tests.helpers.frame`` (a standard CAN frame from bytes or hex text). Modules that build their
own variants call the same helpers, so there is one of each. Every test session keeps what
commands store between runs (``$XDG_STATE_HOME``) in its own temporary directory.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from typing import Any

import pytest

from tests.helpers import frame
from tests.helpers import modbus_gateway as _modbus_gateway


@pytest.fixture(scope="session", autouse=True)
def _state_of_the_session(tmp_path_factory: pytest.TempPathFactory) -> Iterator[None]:
    """What commands keep between runs (``lss``'s slaves left in configuration state, under
    ``$XDG_STATE_HOME``) goes to the session's temporary directory, the processes the tests
    start included, never to the user's own ``~/.local/state``."""
    before = os.environ.get("XDG_STATE_HOME")
    os.environ["XDG_STATE_HOME"] = str(tmp_path_factory.mktemp("state"))
    yield
    if before is None:
        os.environ.pop("XDG_STATE_HOME", None)
    else:
        os.environ["XDG_STATE_HOME"] = before


@pytest.fixture
def modbus_gateway() -> Callable[..., Any]:
    return _modbus_gateway


@pytest.fixture
def can_frame() -> Callable[..., Any]:
    return frame
