"""Fixtures shared by the tests: a gateway with a connected Modbus client, and CAN frames.

``modbus_gateway`` gives ``tests.helpers.modbus_gateway`` (an async context manager: a started
gateway of a config and a connected pymodbus client, both stopped on exit); ``can_frame`` gives
``tests.helpers.frame`` (a standard CAN frame from bytes or hex text). Modules that build their
own variants call the same helpers, so there is one of each.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import pytest

from tests.helpers import frame
from tests.helpers import modbus_gateway as _modbus_gateway


@pytest.fixture
def modbus_gateway() -> Callable[..., Any]:
    return _modbus_gateway


@pytest.fixture
def can_frame() -> Callable[..., Any]:
    return frame
