"""The command line's logging: python-can's socketcand client warns at every TCP read that ends
inside a frame's text (about a hundred times a second on a busy bus, nothing lost); that one
line is dropped, its other warnings are kept."""

from __future__ import annotations

import logging

import pytest

from canopen_gateway.cli.serve import SOCKETCAND_PARTIAL_READ, setup_logging


def test_the_partial_read_warning_is_dropped_and_other_socketcand_warnings_are_kept(
    caplog: pytest.LogCaptureFixture,
) -> None:
    setup_logging("info")
    setup_logging("info")  # twice: one filter
    log = logging.getLogger("can.interfaces.socketcand.socketcand")
    assert len(log.filters) == 1
    with caplog.at_level(logging.WARNING):
        log.warning(SOCKETCAND_PARTIAL_READ)
        log.warning("Incomplete message exceeds 200 chars => Discarding")
        log.warning("Could not parse ascii message: < frame 123 >")
    assert [r.getMessage() for r in caplog.records] == [
        "Incomplete message exceeds 200 chars => Discarding",
        "Could not parse ascii message: < frame 123 >",
    ]


def test_the_filter_matches_the_text_python_can_logs() -> None:
    import inspect

    from can.interfaces.socketcand import socketcand

    assert f'log.warning("{SOCKETCAND_PARTIAL_READ}")' in inspect.getsource(socketcand)
