"""The simulated SGH10 against the worked examples and frame tables of its manual (000, 2020
edition 003), byte for byte. Frames are raw python-can messages; the clock is a number."""

from __future__ import annotations

import pytest

from canopen_gateway.profiles import load_profile
from canopen_gateway.sim.node import NmtState, SimNode
from canopen_gateway.sim.objects import PersistentStore
from tests.helpers import frame


def rx(node: SimNode, cob: int, hexdata: str, now: float = 1.0) -> list[tuple[int, str]]:
    return [
        (m.arbitration_id, m.data.hex(" ").upper()) for m in node.handle(frame(cob, hexdata), now)
    ]


@pytest.fixture
def sgh10() -> SimNode:
    node = SimNode(load_profile("sgh10"), 1, motion={"kind": "hold", "hold": 1234})
    assert [(m.arbitration_id, bytes(m.data)) for m in node.power_on(0.0)] == [(0x701, b"\x00")]
    return node


# -- 4.4.1.4 SDO examples --------------------------------------------------------------------
def test_4_4_1_4_expedited_read_of_calibration_value_510(sgh10: SimNode) -> None:
    sgh10.set(0x6010, 1, 510)  # "The current value is 510d = 01FEh"
    assert rx(sgh10, 0x601, "40 10 60 01 00 00 00 00") == [(0x581, "43 10 60 01 FE 01 00 00")]


def test_4_4_1_4_expedited_write_of_6200h_4500(sgh10: SimNode) -> None:
    assert rx(sgh10, 0x601, "2B 00 62 00 94 11 00 00") == [(0x581, "60 00 62 00 00 00 00 00")]
    assert sgh10.get(0x6200, 0) == 4500
    assert sgh10.get(0x1800, 5) == 4500  # 4.7.2.31: linked with 1800h:05


def test_4_4_1_4_segmented_read_of_1008h_sgh10(sgh10: SimNode) -> None:
    assert rx(sgh10, 0x601, "40 08 10 00 00 00 00 00") == [(0x581, "41 08 10 00 05 00 00 00")]
    assert rx(sgh10, 0x601, "60 08 10 00 00 00 00 00") == [(0x581, "03 53 47 48 31 30 00 00")]


def test_4_4_1_3_abort_frames(sgh10: SimNode) -> None:
    assert rx(sgh10, 0x601, "40 34 12 00 00 00 00 00") == [(0x581, "80 34 12 00 00 00 02 06")]
    assert rx(sgh10, 0x601, "40 18 10 07 00 00 00 00") == [(0x581, "80 18 10 07 11 00 09 06")]
    assert rx(sgh10, 0x601, "23 18 10 01 00 00 00 00") == [(0x581, "80 18 10 01 02 00 01 06")]
    # 5F0Ah:01 node id range 01h..7Fh (4.7.2.22)
    assert rx(sgh10, 0x601, "2F 0A 5F 01 00 00 00 00") == [(0x581, "80 0A 5F 01 30 00 09 06")]


# -- 4.2 NMT, 4.5 node monitoring ------------------------------------------------------------
def test_4_2_1_2_nmt_commands_and_4_2_2_boot_up(sgh10: SimNode) -> None:
    rx(sgh10, 0x000, "01 01")
    assert sgh10.nmt_state == NmtState.OPERATIONAL
    rx(sgh10, 0x000, "02 00")
    assert sgh10.nmt_state == NmtState.STOPPED
    assert rx(sgh10, 0x000, "81 01") == [(0x701, "00")]
    assert sgh10.nmt_state == NmtState.PRE_OPERATIONAL


def test_4_5_2_guarding_answers_toggle_and_state(sgh10: SimNode) -> None:
    rtr = frame(0x701, rtr=True, dlc=1)
    assert [m.data[0] for m in sgh10.handle(rtr, 1.0)] == [0x7F]
    assert [m.data[0] for m in sgh10.handle(rtr, 1.1)] == [0x80 | 0x7F]


def test_4_5_3_heartbeat_carries_the_nmt_state(sgh10: SimNode) -> None:
    rx(sgh10, 0x601, "2B 17 10 00 0A 00 00 00", now=1.0)  # 10 ms
    rx(sgh10, 0x000, "01 00", now=1.0)
    assert [(m.arbitration_id, bytes(m.data)) for m in sgh10.tick(1.01)] == [(0x701, b"\x05")]


# -- 4.3.1.1 TPDOs --------------------------------------------------------------------------
def test_4_3_1_1_tpdo1_position_and_velocity_layout(sgh10: SimNode) -> None:
    rx(sgh10, 0x000, "01 01")
    out = sgh10.handle(frame(0x181, rtr=True, dlc=6), 1.1)
    assert [(m.arbitration_id, m.data.hex(" ").upper()) for m in out] == [
        (0x181, "D2 04 00 00 00 00")  # 6020h:01 = 1234, 6030h:01 = 0 (held still)
    ]


# -- 4.5.1 EMCY, work areas 4.7.2.32-34 ------------------------------------------------------
def test_work_area_1_violation_sends_ff15h_once_and_0000h_when_left() -> None:
    node = SimNode(load_profile("sgh10"), 1, motion={"kind": "hold", "hold": 500})
    node.power_on(0.0)
    rx(node, 0x601, "23 01 64 01 00 00 00 00", now=0.1)  # low 0
    rx(node, 0x601, "23 02 64 01 64 00 00 00", now=0.1)  # high 100: position 500 is above
    out = node.tick(0.2)
    assert [(m.arbitration_id, m.data.hex(" ").upper()) for m in out] == [
        (0x081, "15 FF 01 00 00 00 00 00")
    ]
    assert node.get(0x6400, 1) == 0b011  # outside, above high limit
    assert node.get(0x6503, 0) & (1 << 12)
    assert node.tick(0.3) == []  # once per error event
    rx(node, 0x601, "23 02 64 01 E8 03 00 00", now=0.4)  # high 1000: inside again
    out = node.tick(0.5)
    assert [(m.arbitration_id, m.data.hex(" ").upper()) for m in out] == [
        (0x081, "00 00 00 00 00 00 00 00")
    ]
    assert node.get(0x6400, 1) == 0


def test_sensor_error_sends_ff05h_with_register_bit_7(sgh10: SimNode) -> None:
    assert sgh10.sensor_error(True, now=1.0)
    assert [m.data.hex(" ").upper() for m in sgh10.drain()] == ["05 FF 81 00 00 00 00 00"]
    assert sgh10.get(0x6503, 0) & 1  # 4.7.2.38: bit 0 position value invalid
    sgh10.sensor_error(False, now=1.1)
    assert [m.data.hex(" ").upper() for m in sgh10.drain()] == ["00 00 00 00 00 00 00 00"]


# -- 4.6 LSS ---------------------------------------------------------------------------------
def test_4_6_1_1_switch_state_global_has_no_answer(sgh10: SimNode) -> None:
    assert rx(sgh10, 0x7E5, "04 01 00 00 00 00 00 00") == []
    assert rx(sgh10, 0x7E5, "5E 00 00 00 00 00 00 00") == [(0x7E4, "5E 01 00 00 00 00 00 00")]
    assert rx(sgh10, 0x7E5, "04 00 00 00 00 00 00 00") == []
    assert rx(sgh10, 0x7E5, "5E 00 00 00 00 00 00 00") == []  # waiting: no inquiry


def test_4_6_1_2_switch_state_selective_answers_44h(sgh10: SimNode) -> None:
    serial = sgh10.get(0x1018, 4)
    assert rx(sgh10, 0x7E5, "40 95 01 00 00 00 00 00") == []  # vendor 195h
    assert rx(sgh10, 0x7E5, "41 FF FF FF FF 00 00 00") == []  # product FFFFFFFFh
    assert rx(sgh10, 0x7E5, "42 FF FF FF FF 00 00 00") == []  # revision FFFFFFFFh
    assert rx(sgh10, 0x7E5, f"43 {serial.to_bytes(4, 'little').hex()} 00 00 00") == [
        (0x7E4, "44 00 00 00 00 00 00 00")
    ]


def test_selective_switch_with_a_wrong_vendor_stays_waiting(sgh10: SimNode) -> None:
    serial = sgh10.get(0x1018, 4)
    rx(sgh10, 0x7E5, "40 96 01 00 00 00 00 00")
    rx(sgh10, 0x7E5, "41 FF FF FF FF 00 00 00")
    rx(sgh10, 0x7E5, "42 FF FF FF FF 00 00 00")
    assert rx(sgh10, 0x7E5, f"43 {serial.to_bytes(4, 'little').hex()} 00 00 00") == []


def test_4_6_2_1_configure_node_id_then_waiting_and_reset_communication(sgh10: SimNode) -> None:
    rx(sgh10, 0x7E5, "04 01 00 00 00 00 00 00")
    assert rx(sgh10, 0x7E5, "11 05 00 00 00 00 00 00") == [(0x7E4, "11 00 00 00 00 00 00 00")]
    assert rx(sgh10, 0x7E5, "11 80 00 00 00 00 00 00") == [(0x7E4, "11 01 00 00 00 00 00 00")]
    rx(sgh10, 0x7E5, "04 00 00 00 00 00 00 00")
    assert rx(sgh10, 0x000, "82 01") == [(0x705, "00")]
    assert rx(sgh10, 0x605, "40 00 10 00 00 00 00 00") == [(0x585, "43 00 10 00 96 01 0A 00")]


def test_4_6_2_2_configure_bit_timing_accepts_table_0_indices_0_to_7_but_5(sgh10: SimNode) -> None:
    rx(sgh10, 0x7E5, "04 01 00 00 00 00 00 00")
    assert rx(sgh10, 0x7E5, "13 00 03 00 00 00 00 00") == [(0x7E4, "13 00 00 00 00 00 00 00")]
    assert rx(sgh10, 0x7E5, "13 00 05 00 00 00 00 00") == [(0x7E4, "13 01 00 00 00 00 00 00")]
    assert rx(sgh10, 0x7E5, "13 00 08 00 00 00 00 00") == [(0x7E4, "13 01 00 00 00 00 00 00")]
    assert rx(sgh10, 0x7E5, "13 80 00 00 00 00 00 00") == [(0x7E4, "13 01 00 00 00 00 00 00")]


def test_4_6_2_3_activate_bit_timing_is_silent_for_two_delays_then_boots(sgh10: SimNode) -> None:
    rx(sgh10, 0x601, "2B 17 10 00 0A 00 00 00", now=1.0)  # heartbeat 10 ms
    rx(sgh10, 0x7E5, "04 01 00 00 00 00 00 00", now=1.0)
    rx(sgh10, 0x7E5, "13 00 03 00 00 00 00 00", now=1.0)
    assert rx(sgh10, 0x7E5, "15 64 00 00 00 00 00 00", now=1.0) == []  # delay 100 ms
    assert sgh10.tick(1.1) == []
    assert rx(sgh10, 0x601, "40 00 10 00 00 00 00 00", now=1.15) == []
    assert sgh10.tick(1.1999) == []
    out = sgh10.tick(1.2)
    assert [(m.arbitration_id, bytes(m.data)) for m in out][0] == (0x701, b"\x00")
    lss = sgh10.feature("lss_slave")
    assert lss is not None and lss.bitrate_kbps == 250  # type: ignore[attr-defined]


def test_4_6_2_4_store_configuration_keeps_node_id_over_power_cycle() -> None:
    store = PersistentStore()
    node = SimNode(load_profile("sgh10"), 1, store=store)
    node.power_on(0.0)
    rx(node, 0x7E5, "04 01 00 00 00 00 00 00")
    rx(node, 0x7E5, "11 07 00 00 00 00 00 00")
    assert rx(node, 0x7E5, "17 00 00 00 00 00 00 00") == [(0x7E4, "17 00 00 00 00 00 00 00")]
    assert [(m.arbitration_id, bytes(m.data)) for m in node.power_cycle(2.0)] == [(0x707, b"\x00")]
    assert node.node_id == 7


def test_4_6_3_inquire_identity_and_node_id(sgh10: SimNode) -> None:
    rx(sgh10, 0x7E5, "04 01 00 00 00 00 00 00")
    serial = sgh10.get(0x1018, 4).to_bytes(4, "little").hex(" ").upper()
    assert rx(sgh10, 0x7E5, "5A 00 00 00 00 00 00 00") == [(0x7E4, "5A 95 01 00 00 00 00 00")]
    assert rx(sgh10, 0x7E5, "5B 00 00 00 00 00 00 00") == [(0x7E4, "5B FF FF FF FF 00 00 00")]
    assert rx(sgh10, 0x7E5, "5C 00 00 00 00 00 00 00") == [(0x7E4, "5C FF FF FF FF 00 00 00")]
    assert rx(sgh10, 0x7E5, "5D 00 00 00 00 00 00 00") == [(0x7E4, f"5D {serial} 00 00 00")]
    assert rx(sgh10, 0x7E5, "5E 00 00 00 00 00 00 00") == [(0x7E4, "5E 01 00 00 00 00 00 00")]


# -- 3.2 calibration, 4.7.2.28 6010h, 4.7.2.44 6509h -----------------------------------------
def test_3_2_calibration_value_becomes_the_position_and_6509h_the_offset(sgh10: SimNode) -> None:
    # position 1234 (held); 6010h:01 = 510 -> position 510, 6509h = 1234 - 510 = 724
    assert rx(sgh10, 0x601, "23 10 60 01 FE 01 00 00") == [(0x581, "60 10 60 01 00 00 00 00")]
    assert rx(sgh10, 0x601, "40 20 60 01 00 00 00 00") == [(0x581, "43 20 60 01 FE 01 00 00")]
    assert rx(sgh10, 0x601, "40 09 65 00 00 00 00 00") == [(0x581, "43 09 65 00 D4 02 00 00")]
    assert rx(sgh10, 0x601, "40 10 60 01 00 00 00 00") == [(0x581, "43 10 60 01 FE 01 00 00")]


def test_calibration_survives_a_power_cycle_only_when_saved() -> None:
    store = PersistentStore()
    node = SimNode(load_profile("sgh10"), 1, store=store, motion={"kind": "hold", "hold": 1234})
    node.power_on(0.0)
    rx(node, 0x601, "23 10 60 01 00 00 00 00")  # calibrate to 0
    node.power_cycle(2.0)
    assert node.sdo_read_local("0x6020:01") == 1234
    rx(node, 0x601, "23 10 60 01 00 00 00 00", now=2.1)
    rx(node, 0x601, "23 10 10 01 73 61 76 65", now=2.2)  # 1010h:01 "save"
    node.power_cycle(3.0)
    assert node.sdo_read_local("0x6020:01") == 0
    assert node.sdo_read_local("0x6509:00") == 1234


def test_4_1_cob_ids_change_only_in_pre_operational(sgh10: SimNode) -> None:
    rx(sgh10, 0x000, "01 01")
    assert rx(sgh10, 0x601, "23 00 18 01 81 01 00 80") == [(0x581, "80 00 18 01 22 00 00 08")]
    assert rx(sgh10, 0x601, "23 14 10 00 81 00 00 80") == [(0x581, "80 14 10 00 22 00 00 08")]
    rx(sgh10, 0x000, "80 01")
    assert rx(sgh10, 0x601, "23 00 18 01 81 01 00 80") == [(0x581, "60 00 18 01 00 00 00 00")]


def test_4_7_2_23_6000h_bit_3_counts_descending(sgh10: SimNode) -> None:
    assert sgh10.sdo_read_local("0x6020:01") == 1234
    rx(sgh10, 0x601, "2B 00 60 00 0C 00 00 00")  # bit 3 + scaling bit 2
    assert sgh10.sdo_read_local("0x6020:01") == -1234
