"""Whether this gateway's frames can go out: the CAN controller's state as the driver learns it
(``bus/driver.py`` state ``error``, with its reason).

Three sources, each a cause of its own; the state is ``error`` while any cause holds:

=========  =========================================================  ==========================
cause      set by                                                     cleared by
=========  =========================================================  ==========================
frames     an error frame: bus off, error passive (linux/can/error.h  an "error active" /
           layout, which python-can's backends follow)                "restarted" error frame, or
                                                                      frames received with no
                                                                      error frame for
                                                                      ``error_hold_s``
state      python-can's ``bus.state`` (``BusState.ERROR``: bus off,   ``BusState.ACTIVE``
           ``PASSIVE``: error passive), read every ``POLL_S``
sending    a frame refused by the interface: its transmit queue full  a frame sent
           after the retries (ENOBUFS), or any other refusal
=========  =========================================================  ==========================

The one home of what the controller says: ``controller_report`` reads an error frame by the
SocketCAN layout (linux/can/error.h, which python-can's other backends follow too: the error
class bits in the CAN-ID, the controller's status in data byte 1), pure; ``ControllerState``
keeps the causes; the bus driver (``bus.driver``) keeps the bus state and logs it, naming its
network.

Threads: the reader thread owns the object; the sender thread only writes ``sending`` (one
assignment) and the reader takes it at its next look (``look``).

Imports: python-can and the standard library.
"""

from __future__ import annotations

import errno
from collections.abc import Callable

import can

# linux/can/error.h: error classes (CAN-ID bits of an error frame) and controller status bits
CAN_ERR_CRTL = 0x00000004  # controller problems, details in data[1]
CAN_ERR_BUSOFF = 0x00000040  # bus off
CAN_ERR_RESTARTED = 0x00000100  # controller restarted
CAN_ERR_CRTL_RX_PASSIVE = 0x10  # reached error passive status on receive
CAN_ERR_CRTL_TX_PASSIVE = 0x20  # reached error passive status on transmit
CAN_ERR_CRTL_ACTIVE = 0x40  # recovered to error active state

#: the report of a controller error active again (restarted, or recovered)
ERROR_ACTIVE = "error active"

#: python-can's bus state is read this often (a vendor driver call)
POLL_S = 0.25
_BUS_STATE = {can.BusState.ERROR: "bus off", can.BusState.PASSIVE: "error passive"}


def controller_report(msg: can.Message) -> str | None:
    """``bus off``, ``error passive (transmit)`` / ``(receive)``, ``ERROR_ACTIVE``, or None
    for an error frame that says none of these."""
    cls = msg.arbitration_id
    data = bytes(msg.data).ljust(8, b"\0")
    ctrl = data[1] if cls & CAN_ERR_CRTL else 0
    if cls & CAN_ERR_BUSOFF:
        return "bus off"
    if ctrl & (CAN_ERR_CRTL_RX_PASSIVE | CAN_ERR_CRTL_TX_PASSIVE):
        return f"error passive ({'transmit' if ctrl & CAN_ERR_CRTL_TX_PASSIVE else 'receive'})"
    if cls & CAN_ERR_RESTARTED or ctrl & CAN_ERR_CRTL_ACTIVE:
        return ERROR_ACTIVE
    return None

def send_errno(exc: BaseException) -> int | None:
    """The errno of a refused send: python-can's backends raise ``CanError`` with it as
    ``error_code`` (socketcan), others the ``OSError`` itself (python-can-remote)."""
    if isinstance(exc, can.CanError) and exc.error_code is not None:
        return exc.error_code
    code = getattr(exc, "errno", None)
    if code is None and exc.__cause__ is not None:
        code = getattr(exc.__cause__, "errno", None)
    return code if isinstance(code, int) else None


def tx_queue_full(exc: Exception) -> bool:
    """The interface refused a frame because its transmit queue is full (ENOBUFS: python-can's
    socketcan backend raises ``CanOperationError`` with that ``error_code``)."""
    return send_errno(exc) == errno.ENOBUFS


class ControllerState:
    """The causes of the ``error`` state (see the module docstring)."""

    def __init__(self, mono: Callable[[], float], error_hold_s: float = 5.0):
        self.mono = mono
        self.error_hold_s = error_hold_s
        self.causes: dict[str, str] = {}  # cause -> what it says
        #: written by the sender thread: why its last frame was refused (None: it went out)
        self.sending: str | None = None
        self.last_error_frame_s: float | None = None
        self._polled_s = float("-inf")

    @property
    def error(self) -> str | None:
        """Why the frames cannot go out (None: nothing says so)."""
        return next(iter(self.causes.values()), None)

    def reset(self) -> None:
        """The bus was (re)opened: nothing of the old controller holds."""
        self.causes.clear()
        self.sending = None
        self.last_error_frame_s = None

    def on_error_frame(self, msg: can.Message) -> bool:
        """An error frame; False when it says nothing of the controller's state."""
        self.last_error_frame_s = self.mono()
        said = controller_report(msg)
        if said is None:
            return False
        if said == ERROR_ACTIVE:
            self.causes.pop("frames", None)
        else:
            self.causes["frames"] = said
        return True

    def on_frame(self) -> None:
        """A frame received: error frames that stopped for the hold time end their cause."""
        if "frames" in self.causes:
            last = self.last_error_frame_s
            if last is None or self.mono() - last >= self.error_hold_s:
                del self.causes["frames"]

    def look(self, bus: can.BusABC | None) -> None:
        """Between bursts: the sender's last refusal, and python-can's bus state now and then."""
        refused = self.sending
        if refused is None:
            self.causes.pop("sending", None)
        else:
            self.causes["sending"] = refused
        now = self.mono()
        if bus is None or now - self._polled_s < POLL_S:
            return
        self._polled_s = now
        try:
            state = bus.state
        except Exception:  # noqa: BLE001 - a backend without it, or a dying one
            return
        what = _BUS_STATE.get(state)
        if what is None:
            self.causes.pop("state", None)
        else:
            self.causes["state"] = what
