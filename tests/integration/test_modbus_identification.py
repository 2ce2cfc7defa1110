"""Read Device Identification (function 43 / MEI 14, Modbus Application Protocol V1.1b3 6.21)
asked by pymodbus's client: for a device known from its EDS alone played by python canopen's
LocalNode (its 1018h/1008h/1009h/100Ah answered from its own dictionary), for our simulated
SGH10 and for the gateway unit 247; basic, regular, extended and individual access, and the
exception codes of the standard, also over raw frames."""

from __future__ import annotations

import struct

from pymodbus.client import AsyncModbusTcpClient

from canopen_gateway import __version__
from canopen_gateway.modbus.identity import respond
from tests.integration.test_eds_devices import IO, gateway_with
from tests.integration.test_modbus_frames import ask, running

DEVICE_OD = {
    (0x1018, 1): 0x00000ABC,  # the EDS VendorNumber
    (0x1018, 2): 0x00000401,  # the EDS ProductNumber (the identity check at boot compares both)
    (0x1018, 3): 0x00020011,  # revision 2.17
    (0x1018, 4): 0xCAFE0001,
}


def request(code: int, object_id: int = 0, mei: int = 0x0E) -> bytes:
    return bytes((0x2B, mei, code, object_id))


async def test_io_module_identifies_itself_with_its_eds_and_what_it_answered() -> None:
    async with gateway_with(IO, 5, "io", device_od=DEVICE_OD) as (gw, node, _bus, _log):
        node.set_data(0x1008, 0, b"IO-8/16 rev B")
        client = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus.port, timeout=3)
        await client.connect()
        try:
            basic = await client.read_device_information(read_code=1, device_id=5)
            assert not basic.isError(), basic
            assert basic.conformity == 0x83
            assert basic.information == {
                0x00: b"Example Automation GmbH",  # EDS VendorName, vendor id 0xABC as read
                0x01: b"0x00000401",  # 1018h:02 as read
                0x02: b"2.17",  # 1018h:03 as read
            }
            regular = await client.read_device_information(read_code=2, device_id=5)
            assert regular.information[0x04] == b"IO-8/16"  # EDS ProductName
            assert regular.information[0x05] == b"IO-8/16 rev B"  # 1008h as read
            assert regular.information[0x06] == b"io (CANopen node 5)"
            assert set(regular.information) == {0, 1, 2, 4, 5, 6}
            extended = await client.read_device_information(read_code=3, device_id=5)
            assert extended.information[0x82] == b"0xCAFE0001"  # 1018h:04
            one = await client.read_device_information(read_code=4, object_id=5, device_id=5)
            assert one.information == {0x05: b"IO-8/16 rev B"}
            # VendorUrl (0x03) is not served: individual access to it is exception 0x02
            assert await ask(gw, request(4, 0x03), unit=5) == bytes((0xAB, 0x02))
        finally:
            client.close()


async def test_another_vendor_id_than_the_eds_is_not_given_the_eds_vendor_name() -> None:
    od = {**DEVICE_OD, (0x1018, 1): 0x00000123}
    # another vendor than the EDS says: served only with the identity check off
    async with gateway_with(IO, 5, "io", {"identity_check": False}, device_od=od) as (gw, _node, _bus, _log):
        client = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus.port, timeout=3)
        await client.connect()
        try:
            one = await client.read_device_information(read_code=4, object_id=0, device_id=5)
            assert one.information == {0x00: b"CANopen vendor 0x00000123"}
        finally:
            client.close()


async def test_simulated_sgh10_and_the_gateway_unit_identify_themselves() -> None:
    async with running() as gw:
        client = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus.port, timeout=3)
        await client.connect()
        try:
            wire = await client.read_device_information(read_code=2, device_id=1)
            assert not wire.isError(), wire
            assert wire.information[0x00] == b"SIKO GmbH"
            assert wire.information[0x06] == b"wire (CANopen node 1)"
            me = await client.read_device_information(read_code=2, device_id=247)
            assert me.information[0x00] == b"canopen-gateway"
            assert me.information[0x02] == __version__.encode()
            assert me.information[0x06] == b"test"  # gateway.name
        finally:
            client.close()


async def test_exception_codes_of_read_device_identification() -> None:
    async with running() as gw:
        for code in (0, 5, 0xFF):  # ReadDevId code not 1..4
            assert await ask(gw, request(code), unit=1) == bytes((0xAB, 0x03)), code
        assert await ask(gw, request(4, 0x90), unit=247) == bytes((0xAB, 0x02))
        assert await ask(gw, request(1, mei=0x0D), unit=1) == bytes((0xAB, 0x01))  # CANopen ref.
        assert await ask(gw, bytes((0x2B, 0x0E, 0x01)), unit=1) == bytes((0xAB, 0x03))  # short
        assert await ask(gw, request(1), unit=99) == bytes((0xAB, 0x0A)), "unit not configured"
        # a stream from an object id that is not in it restarts at object 0 (6.21)
        got = await ask(gw, request(1, 0x55), unit=247)
        assert got[:7] == bytes((0x2B, 0x0E, 0x01, 0x83, 0x00, 0x00, 3))
        assert got[7:9] == bytes((0x00, len(b"canopen-gateway")))


def test_a_stream_longer_than_one_pdu_is_split_with_more_follows() -> None:
    objects = {0: b"A" * 100, 1: b"B" * 100, 2: b"C" * 100, 4: b"D" * 10}
    first = respond(objects, 2, 0)
    head = first[:7]
    assert head == bytes((0x2B, 0x0E, 2, 0x83, 0xFF, 0x02, 2)), "objects 0 and 1, next is 2"
    assert len(first) <= 253
    rest = respond(objects, 2, 2)
    assert rest[:7] == bytes((0x2B, 0x0E, 2, 0x83, 0x00, 0x00, 2))
    assert rest[7:] == bytes((2, 100)) + b"C" * 100 + bytes((4, 10)) + b"D" * 10
    huge = respond({0: b"x" * 400}, 1, 0)
    assert len(huge) == 253 and struct.unpack_from(">BB", huge, 7) == (0, 244), "cut to fit"
