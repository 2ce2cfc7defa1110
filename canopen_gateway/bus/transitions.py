"""How the bus's state machines write their state changes: rows "from any of these states, on
any of these events, to this state", as the tables in the machines' docstrings read, turned into
the ``(state, event) -> next state`` dict the code reads (as h11's ``_state.py``). Used by the
node lifecycle (``bus/node/lifecycle.py``) and the pair's role machine (``bus/pair/flying_master.py``).

Imports: the standard library.
"""

from __future__ import annotations

from typing import TypeVar

S = TypeVar("S")
E = TypeVar("E")


def transition_table(*rows: tuple[tuple[S, ...], tuple[E, ...], S]) -> dict[tuple[S, E], S]:
    """The ``(state, event) -> next state`` dict of ``rows`` (``(states, events, next)``: each of
    ``states`` on each of ``events`` goes to ``next``). A pair written in two rows is a mistake
    of the table: ValueError."""
    table: dict[tuple[S, E], S] = {}
    for states, events, next_state in rows:
        for state in states:
            for event in events:
                if (state, event) in table:
                    raise ValueError(f"({state}, {event}) is in two rows of the table")
                table[state, event] = next_state
    return table
