"""A machine's transition rows become the (state, event) -> next state dict its code reads."""

from __future__ import annotations

import pytest

from canopen_gateway.bus.transitions import transition_table


def test_each_state_of_a_row_on_each_of_its_events_goes_to_the_rows_next_state() -> None:
    table = transition_table((("a", "b"), (1, 2), "c"), (("c",), (1,), "a"))
    assert table == {("a", 1): "c", ("a", 2): "c", ("b", 1): "c", ("b", 2): "c", ("c", 1): "a"}


def test_a_state_and_event_written_in_two_rows_is_refused() -> None:
    with pytest.raises(ValueError, match=r"\(b, 2\) is in two rows"):
        transition_table((("a", "b"), (1, 2), "c"), (("b",), (2,), "a"))
