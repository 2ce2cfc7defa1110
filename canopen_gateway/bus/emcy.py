"""The per-node EMCY error history: current errors, a bounded history and counters.

The frames are decoded by ``canopen.emcy`` (pure CiA 301 facts); this module keeps what a node
has said over time.

Imports: canopen_gateway.canopen.emcy (the decoded frame) and the standard library. Must not import
python-can, canopen, logging or any other gateway module.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

from canopen_gateway.canopen.emcy import Emcy

# --------------------------------------------------------------------------- history


@dataclass(frozen=True)
class ErrorRaised:
    """Change: an error code not current before is now current."""

    emcy: Emcy


@dataclass(frozen=True)
class ErrorsCleared:
    """Change: an EMCY 0000h cleared the current errors.

    ``register`` is the error register sent with 0000h: when not 0, the device still has an
    error it did not name again (SGH10 manual 4.5.1: "the persisting error status is indicated
    in the error register").
    """

    codes: tuple[int, ...]
    register: int


class EmcyHistory:
    """Per node: the current errors, a bounded history and counters.

    ====================  ===================================================  =============
    frame                 effect                                               output
    ====================  ===================================================  =============
    code != 0000h, new    added to ``current``, appended to ``history``        ErrorRaised
    code != 0000h, known  replaces the entry in ``current``, appended          (none)
    code == 0000h         ``current`` emptied, appended to ``history``         ErrorsCleared
    ====================  ===================================================  =============

    The devices send one EMCY per error event and one 0000h when a cause is removed; which
    cause is not said, so 0000h clears every current error and ``register`` keeps the error
    register it carried (non-zero: something persists).
    """

    def __init__(self, max_history: int = 64):
        if max_history < 1:
            raise ValueError("max_history must be >= 1")
        self.current: dict[int, Emcy] = {}
        self.history: deque[Emcy] = deque(maxlen=max_history)
        self.count = 0
        self.last: Emcy | None = None
        self.register = 0

    def add(self, emcy: Emcy) -> list[ErrorRaised | ErrorsCleared]:
        self.count += 1
        self.last = emcy
        self.register = emcy.register
        self.history.append(emcy)
        if emcy.is_reset:
            codes = tuple(sorted(self.current))
            self.current.clear()
            return [ErrorsCleared(codes, emcy.register)]
        is_new = emcy.code not in self.current
        self.current[emcy.code] = emcy
        return [ErrorRaised(emcy)] if is_new else []

    def clear(self) -> None:
        """Forget current errors (e.g. the node rebooted); history and count stay."""
        self.current.clear()
        self.register = 0
