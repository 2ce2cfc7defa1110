"""The simulated node's parts own their state and see their node through a narrow Protocol: each
runs here on a small fake host, not on a ``SimNode`` (SGH10 manual 000/003 section numbers)."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import canopen_gateway.sim.nmt as nmt
from canopen_gateway.canopen.cia301 import NmtCommand
from canopen_gateway.canopen.states import NmtState
from canopen_gateway.sim.device_faults import DeviceFaults
from canopen_gateway.sim.error_control import ErrorControl
from canopen_gateway.sim.hints import SimHints
from canopen_gateway.sim.objects import PersistentStore


class FakeValues:
    """The few object values a part reads and writes."""

    def __init__(self, values: dict[tuple[int, int], int]):
        self.values = dict(values)

    def get(self, index: int, sub: int = 0, default: Any = None) -> Any:
        return self.values.get((index, sub), default)

    def set(self, index: int, sub: int, value: Any) -> None:
        self.values[(index, sub)] = value

    def has(self, index: int, sub: int = 0) -> bool:
        return (index, sub) in self.values


class FakeHost:
    def __init__(self, values: dict[tuple[int, int], int], hints: SimHints | None = None):
        self.values: Any = FakeValues(values)  # as ObjectValues for the parts
        self.hints = hints or SimHints()
        self.node_id = 5
        self.nmt_state = NmtState.PRE_OPERATIONAL
        self.features: list[Any] = []
        self.emcy: Any = SimpleNamespace(active={})  # no active error
        self.sent: list[tuple[int, bytes]] = []
        self.emcys: list[tuple[str, int]] = []

    def send(self, cob_id: int, data: bytes = b"", *, rtr: bool = False, dlc: int = 0) -> None:
        self.sent.append((cob_id, bytes(data)))

    def raise_emcy(self, code: int, register: int = 0, mfr: bytes = b"", now: float | None = None) -> None:
        self.emcys.append(("raise", code))

    def clear_emcy(self, code: int, now: float | None = None) -> None:
        self.emcys.append(("clear", code))


def test_nmt_says_what_a_command_asks_and_which_node_id_a_reset_adopts() -> None:
    assert nmt.command(NmtCommand.START, 0, 5) == NmtState.OPERATIONAL  # 0: every node (4.2.1)
    assert nmt.command(NmtCommand.STOP, 5, 5) == NmtState.STOPPED
    assert nmt.command(NmtCommand.START, 6, 5) is None  # another node's
    assert nmt.command(NmtCommand.RESET_NODE, 5, 5) == "node"
    assert nmt.command(NmtCommand.RESET_COMMUNICATION, 0, 5) == "communication"
    assert nmt.command(0x7F, 5, 5) is None  # not an NMT command
    # power-on: the stored id (LSS / Auto-ID) or the configured one; a pending one is dropped
    assert nmt.node_id_after_reset("power", configured=5, current=9, pending=8, stored=7) == 7
    assert nmt.node_id_after_reset("power", configured=5, current=9, pending=8, stored=None) == 5
    # reset node / communication: the pending id, else the current one
    assert nmt.node_id_after_reset("communication", configured=5, current=9, pending=8, stored=7) == 8
    assert nmt.node_id_after_reset("node", configured=5, current=9, pending=None, stored=7) == 9


def test_a_reset_communication_reloads_1000h_1fffh_and_keeps_1001h_1003h() -> None:
    calls: list[tuple[int, int]] = []

    class Values(FakeValues):
        def keys(self) -> list[tuple[int, int]]:
            return list(self.values)

        def load_defaults(self, node_id: int, store: Any, which: int) -> None:
            calls.append((node_id, which))
            self.values = {k: 0 for k in self.values}

    values = Values({(0x1001, 0): 0x81, (0x1003, 1): 0x5010, (0x1017, 0): 100})
    nmt.reload_objects(values, PersistentStore(), 5, "communication")  # type: ignore[arg-type]
    assert calls == [(5, 2)]  # 1010h/1011h sub 2: 1000h-1FFFh (4.7.2.11/12)
    assert values.values == {(0x1001, 0): 0x81, (0x1003, 1): 0x5010, (0x1017, 0): 0}


def test_error_control_runs_on_a_host_that_is_not_a_node_and_owns_its_stop() -> None:
    host = FakeHost({(0x1017, 0): 100})
    ec = ErrorControl(host, emcy_codes=())
    ec.schedule_heartbeat(0.0)
    ec.tick(0.1)
    assert host.sent == [(0x705, bytes([NmtState.PRE_OPERATIONAL]))]  # 4.5.3
    ec.stop()
    ec.tick(0.2)
    assert len(host.sent) == 1 and ec.off
    ec.resume(0.25)  # the next heartbeat now
    ec.tick(0.25)
    assert len(host.sent) == 2 and not ec.off


def test_a_hint_fault_raises_its_emcy_and_sets_its_alarm_bit_then_shows_again_after_a_reset() -> None:
    hints = SimHints(faults={"sensor_error": {"emcy": 0x5010}})
    host = FakeHost({(0x6503, 0): 0}, hints)
    faults = DeviceFaults(host)
    assert faults.inject("sensor_error", True, 1.0)
    assert host.emcys == [("raise", 0x5010)] and host.values.get(0x6503, 0) == 1  # 4.7.2.38 bit 0
    host.values.set(0x6503, 0, 0)  # a reset reloaded 6503h
    faults.show_again()
    assert host.values.get(0x6503, 0) == 1
    assert not faults.inject("battery_low", True, 1.0)  # no feature, no hint: not simulated
    faults.clear()
    assert faults.active == {}
