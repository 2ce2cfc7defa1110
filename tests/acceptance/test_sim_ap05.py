"""The simulated AP05 position indicator against its manual (004), byte for byte: SDO examples
5.4.1.3, the communication example 5.3.1.3, control/status words 5.3.2/5.3.3, guarding bit
5.5.5, external heartbeat 5.5.4, Auto-ID 5.6.2, alpha-numeric display 4.1.2, warnings/errors
4.6. Raw python-can frames, a fake clock."""

from __future__ import annotations

import can
import pytest

from canopen_gateway.profiles import load_profile
from canopen_gateway.sim.node import NmtState, SimNode
from canopen_gateway.sim.objects import PersistentStore
from tests.helpers import frame


def hexframes(msgs: list[can.Message]) -> list[tuple[int, str]]:
    return [(m.arbitration_id, m.data.hex(" ").upper()) for m in msgs]


def rx(node: SimNode, cob: int, hexdata: str, now: float = 1.0) -> list[tuple[int, str]]:
    return hexframes(node.handle(frame(cob, hexdata), now))


def ap05(node_id: int = 1, position: int = 250, **options: object) -> SimNode:
    node = SimNode(
        load_profile("ap05"), node_id, motion={"kind": "hold", "hold": position}, options=options
    )
    node.power_on(0.0)
    return node


def status_of(msgs: list[can.Message]) -> int:
    (msg,) = msgs
    return int.from_bytes(msg.data[6:8], "little")


@pytest.fixture
def node() -> SimNode:
    return ap05()


# -- 5.4.1.3 SDO examples --------------------------------------------------------------------
def test_5_4_1_3_read_calibration_value_510(node: SimNode) -> None:
    node.set(0x6003, 0, 510)
    assert rx(node, 0x601, "40 03 60 00 00 00 00 00") == [(0x581, "43 03 60 00 FE 01 00 00")]


def test_5_4_1_3_write_loop_length_4500(node: SimNode) -> None:
    assert rx(node, 0x601, "2B 14 5F 00 94 11 00 00") == [(0x581, "60 14 5F 00 00 00 00 00")]
    assert node.get(0x5F14, 0) == 4500


def test_set_points_and_control_word_are_read_only_by_sdo(node: SimNode) -> None:
    assert rx(node, 0x601, "23 16 5F 01 2C 01 00 00") == [(0x581, "80 16 5F 01 02 00 01 06")]
    assert rx(node, 0x601, "2B 0C 5F 00 00 02 00 00") == [(0x581, "80 0C 5F 00 02 00 01 06")]


def test_sdo_is_expedited_only(node: SimNode) -> None:
    assert rx(node, 0x601, "21 08 10 00 05 00 00 00") == [(0x581, "80 08 10 00 01 00 04 05")]
    assert rx(node, 0x601, "40 08 10 00 00 00 00 00") == [(0x581, "43 08 10 00 41 50 30 35")]


# -- 5.3.1.3 communication example -----------------------------------------------------------
def test_5_3_1_3_communication_example_two_position_indicators() -> None:
    n1 = SimNode(load_profile("ap05"), 0x01, motion={"kind": "hold", "hold": 250})
    n7d = SimNode(load_profile("ap05"), 0x7D, motion={"kind": "hold", "hold": 100})
    assert hexframes(n1.power_on(0.0)) == [(0x701, "00")]
    assert hexframes(n7d.power_on(0.0)) == [(0x77D, "00")]

    start = frame(0x000, "01 00")  # "All subscribers Operational"
    # TPDO: position bytes 0-3, dummy 5F1Dh bytes 4-5, status word bytes 6-7 (Table 25)
    assert hexframes(n1.handle(start, 1.0)) == [(0x181, "FA 00 00 00 00 00 00 00")]
    assert hexframes(n7d.handle(start, 1.0)) == [(0x1FD, "64 00 00 00 00 00 00 00")]

    rpdo2 = frame(0x301, "2C 01 00 00 00 00 00 02")  # set point2 = 300, STW 0200h
    assert n1.handle(rpdo2, 1.1) == []
    assert n7d.handle(rpdo2, 1.1) == []

    sync = frame(0x080)
    assert hexframes(n1.handle(sync, 1.2)) == [(0x281, "FA 00 00 00 00 00 01 04")]
    assert hexframes(n7d.handle(sync, 1.2)) == [(0x2FD, "64 00 00 00 00 00 00 00")]


# -- 5.3.3 status word -----------------------------------------------------------------------
def test_status_word_arrows_deviation_and_target_windows(node: SimNode) -> None:
    rx(node, 0x000, "01 01")
    sync = frame(0x080)
    rx(node, 0x301, "C8 00 00 00 00 00 00 02", now=1.1)  # target 200 < position 250
    status = status_of(node.handle(sync, 1.2))
    assert status & 0b11 == 0b10  # CCW arrow
    assert status >> 6 & 1  # deviation: actual > set point
    assert not status >> 5 & 1
    rx(node, 0x301, "FD 00 00 00 00 00 00 02", now=1.3)  # target 253: within window1 (5)
    status = status_of(node.handle(sync, 1.4))
    assert status & 0b11 == 0  # no arrow inside window1
    assert status >> 5 & 1 and status >> 4 & 1  # dynamic and static reached
    rx(node, 0x301, "E8 03 00 00 00 00 00 02", now=1.5)  # target 1000: window left
    status = status_of(node.handle(sync, 1.6))
    assert not status >> 5 & 1 and status >> 4 & 1  # static stays latched
    rx(node, 0x301, "E8 03 00 00 00 00 10 02", now=1.7)  # control bit 4 acknowledges
    status = status_of(node.handle(sync, 1.8))
    assert not status >> 4 & 1
    assert status & 0b11 == 0b01  # CW
    rx(node, 0x301, "E8 03 00 00 00 00 00 00", now=1.9)  # set point2 invalid
    assert status_of(node.handle(sync, 2.0)) == 0


def test_set_point1_validity_bit(node: SimNode) -> None:
    rx(node, 0x000, "01 01")
    rx(node, 0x201, "2C 01 00 00 00 00 04 00", now=1.1)  # control bit 2: set point1 valid
    assert status_of(node.handle(frame(0x080), 1.2)) & (1 << 2)


# -- 5.5.5 guarding bit ----------------------------------------------------------------------
def test_5_5_5_guarding_bit_is_echoed_in_the_next_tpdo(node: SimNode) -> None:
    rx(node, 0x000, "01 01")
    sync = frame(0x080)
    rx(node, 0x201, "00 00 00 00 00 00 00 01", now=1.1)  # control bit 8
    assert status_of(node.handle(sync, 1.2)) == 0x0100
    rx(node, 0x201, "00 00 00 00 00 00 00 00", now=1.3)
    assert status_of(node.handle(sync, 1.4)) == 0x0000


def test_frozen_guarding_echo_keeps_the_last_bit(node: SimNode) -> None:
    rx(node, 0x000, "01 01")
    sync = frame(0x080)
    rx(node, 0x201, "00 00 00 00 00 00 00 01", now=1.1)
    assert node.freeze_guarding_echo(True, now=1.15)
    rx(node, 0x201, "00 00 00 00 00 00 00 00", now=1.2)
    assert status_of(node.handle(sync, 1.3)) == 0x0100
    node.freeze_guarding_echo(False, now=1.35)
    rx(node, 0x201, "00 00 00 00 00 00 00 00", now=1.4)
    assert status_of(node.handle(sync, 1.5)) == 0x0000


# -- 5.5.4 external heartbeat ----------------------------------------------------------------
def test_5_5_4_no_rpdo_within_the_interval_drops_to_pre_operational(node: SimNode) -> None:
    rx(node, 0x601, "2B 09 5F 01 64 00 00 00", now=1.0)  # 5F09h:01 = 100 ms, source RPDO
    rx(node, 0x000, "01 01", now=1.0)
    rx(node, 0x201, "00 00 00 00 00 00 00 00", now=1.05)
    assert node.tick(1.15) == []  # exactly the interval: still operational
    assert node.nmt_state == NmtState.OPERATIONAL
    assert node.tick(1.1501) == []  # no boot-up, just the state
    assert node.nmt_state == NmtState.PRE_OPERATIONAL


def test_5_5_4_sync_as_external_heartbeat_source(node: SimNode) -> None:
    rx(node, 0x601, "2B 09 5F 01 64 00 00 00", now=1.0)
    rx(node, 0x601, "2F 09 5F 02 01 00 00 00", now=1.0)  # source SYNC
    rx(node, 0x000, "01 01", now=1.0)
    node.handle(frame(0x080), 1.09)
    node.tick(1.18)
    assert node.nmt_state == NmtState.OPERATIONAL
    rx(node, 0x201, "00 00 00 00 00 00 00 00", now=1.18)  # an RPDO does not count
    node.tick(1.2)
    assert node.nmt_state == NmtState.PRE_OPERATIONAL


# -- 5.6.2 Auto-ID ---------------------------------------------------------------------------
def test_5_6_2_auto_id_answers_on_5fdh_and_boots_with_the_new_id() -> None:
    store = PersistentStore()
    node = SimNode(load_profile("ap05"), 0x7D, store=store)
    assert hexframes(node.power_on(0.0)) == [(0x77D, "00")]
    assert rx(node, 0x67D, "2F 0A 5F 02 05 00 00 00") == [(0x5FD, "60 0A 5F 02 00 00 00 00")]
    assert hexframes(node.tick(1.001)) == [(0x705, "00")]
    assert node.node_id == 5
    assert rx(node, 0x605, "40 0A 5F 01 00 00 00 00") == [(0x585, "4F 0A 5F 01 05 00 00 00")]
    assert hexframes(node.power_cycle(2.0)) == [(0x705, "00")]  # stored in the EEPROM


def test_5_6_2_auto_id_with_an_illegal_id_aborts() -> None:
    node = SimNode(load_profile("ap05"), 0x7D)
    node.power_on(0.0)
    assert rx(node, 0x67D, "2F 0A 5F 02 80 00 00 00") == [(0x5FD, "80 0A 5F 02 30 00 09 06")]
    assert node.tick(1.001) == []
    assert node.node_id == 0x7D


def test_auto_id_waits_for_the_key_when_asked_to() -> None:
    node = SimNode(
        load_profile("ap05"), 0x7D, options={"features": {"auto_id": {"key_press": "manual"}}}
    )
    node.power_on(0.0)
    assert rx(node, 0x67D, "2F 0A 5F 02 09 00 00 00") == []
    auto_id = node.feature("auto_id")
    auto_id.press_key(2.0)  # type: ignore[union-attr]
    assert hexframes(node.drain()) == [(0x5FD, "60 0A 5F 02 00 00 00 00")]
    assert hexframes(node.tick(2.001)) == [(0x709, "00")]


# -- 4.1.2 alpha-numeric display -------------------------------------------------------------
def test_4_1_2_alphanumeric_rows_ascii_and_acknowledgement(node: SimNode) -> None:
    rx(node, 0x601, "2F 1B 5F 02 03 00 00 00")  # operating mode 3
    rx(node, 0x000, "01 01")
    display = node.feature("alphanumeric_display")
    assert display is not None
    assert display.rows == {1: "", 2: "---"}  # type: ignore[attr-defined]
    # RPDO1: "HELLO!" in bytes 0-5, control bits 2 (valid) and 7 (ASCII)
    rx(node, 0x201, "48 45 4C 4C 4F 21 84 00", now=1.1)
    assert display.rows[1] == "HELLO!"  # type: ignore[attr-defined]
    status = status_of(node.handle(frame(0x080), 1.2))
    assert status == (1 << 2) | (1 << 9)  # valid, ASCII, not acknowledged
    rx(node, 0x201, "48 45 4C 4C 4F 21 84 04", now=1.3)  # + control bit 10: acknowledge
    status = status_of(node.handle(frame(0x080), 1.4))
    assert status == (1 << 2) | (1 << 5) | (1 << 9)


# -- 4.6 warnings and errors -----------------------------------------------------------------
def test_4_6_battery_critical_warning(node: SimNode) -> None:
    rx(node, 0x000, "01 01")
    assert node.battery_low(True, now=1.0)
    assert hexframes(node.drain()) == [(0x081, "20 FF 01 00 00 00 00 00")]
    assert status_of(node.handle(frame(0x080), 1.1)) == 1 << 11
    assert node.get(0x6503, 0) == 1 << 12 and node.get(0x6505, 0) == 1 << 4
    node.battery_low(False, now=1.2)
    assert hexframes(node.drain()) == [(0x081, "00 00 00 00 00 00 00 00")]
    assert status_of(node.handle(frame(0x080), 1.3)) == 0


def test_4_6_battery_empty_and_speed_error(node: SimNode) -> None:
    assert node.inject_fault("battery_empty", True, now=1.0)
    assert hexframes(node.drain()) == [(0x081, "00 32 81 00 00 00 00 00")]
    assert node.sensor_error(True, now=1.1)
    assert hexframes(node.drain()) == [(0x081, "12 FF 81 00 00 00 00 00")]
    rx(node, 0x000, "01 01", now=1.2)
    status = status_of(node.handle(frame(0x080), 1.3))
    assert status == (1 << 7) | (1 << 11) | (1 << 12)
    assert rx(node, 0x601, "40 03 10 00 00 00 00 00", now=1.4) == [
        (0x581, "4F 03 10 00 02 00 00 00")
    ]


# -- 4.4 calibration -------------------------------------------------------------------------
def test_4_4_calibration_by_2002h_sets_the_position_to_the_preset(node: SimNode) -> None:
    rx(node, 0x601, "23 03 60 00 E8 03 00 00")  # 6003h = 1000
    assert rx(node, 0x601, "40 04 60 00 00 00 00 00") == [(0x581, "43 04 60 00 FA 00 00 00")]
    rx(node, 0x601, "2F 02 20 00 01 00 00 00")  # 2002h = 1: calibrate
    assert rx(node, 0x601, "40 04 60 00 00 00 00 00") == [(0x581, "43 04 60 00 E8 03 00 00")]
    assert rx(node, 0x601, "40 02 20 00 00 00 00 00") == [(0x581, "4F 02 20 00 02 00 00 00")]


def test_4_4_application_offset_2001h_is_added_to_the_position(node: SimNode) -> None:
    rx(node, 0x601, "2B 01 20 00 0A 00 00 00")  # 2001h = 10
    assert rx(node, 0x601, "40 04 60 00 00 00 00 00") == [(0x581, "43 04 60 00 04 01 00 00")]
    rx(node, 0x601, "23 03 60 00 64 00 00 00")  # 6003h = 100
    rx(node, 0x601, "2F 02 20 00 01 00 00 00")  # calibrate: 100 + 10
    assert rx(node, 0x601, "40 04 60 00 00 00 00 00") == [(0x581, "43 04 60 00 6E 00 00 00")]


def test_5_1_cob_ids_change_only_in_pre_operational(node: SimNode) -> None:
    rx(node, 0x000, "01 01")
    assert rx(node, 0x601, "23 00 14 01 01 02 00 80") == [(0x581, "80 00 14 01 22 00 00 08")]


def test_an_active_battery_warning_is_shown_again_after_reset_node(node: SimNode) -> None:
    node.battery_low(True, now=1.0)
    node.drain()
    rx(node, 0x000, "81 01", now=1.1)
    assert node.get(0x5F19, 0) & (1 << 11)
    assert node.get(0x6503, 0) & (1 << 12)
