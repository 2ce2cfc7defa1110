"""The web console's answers to the typed errors of the command service (HTTP status and the
error kind), pure."""

from __future__ import annotations

from http import HTTPStatus

from canopen_gateway.errors import BusDown, NotActive
from canopen_gateway.web.commissioning import error_doc


def test_a_command_on_the_standby_of_a_pair_is_answered_503_not_active() -> None:
    status, doc = error_doc(NotActive())
    assert status == HTTPStatus.SERVICE_UNAVAILABLE and doc["error"] == "not_active"
    assert "pair" in doc["message"]


def test_a_bus_down_is_answered_503_bus_down() -> None:
    status, doc = error_doc(BusDown())
    assert status == HTTPStatus.SERVICE_UNAVAILABLE and doc["error"] == "bus_down"
