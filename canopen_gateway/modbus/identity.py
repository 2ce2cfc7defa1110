"""Read Device Identification: function 43 (0x2B), MEI type 14 (0x0E), Modbus Application
Protocol V1.1b3, section 6.21. Pure: the objects of a unit and the encoding of one answer.

Objects (6.21, table "Object Id"):

    id    name                    category   node unit                        gateway unit
    0x00  VendorName              basic      EDS VendorName (*)               canopen-gateway
    0x01  ProductCode             basic      1018h:02 (else EDS ProductNumber) canopen-gateway
    0x02  MajorMinorRevision      basic      1018h:03 as major.minor (else EDS RevisionNumber)
                                                                              our version
    0x04  ProductName             regular    EDS ProductName (else profile title)
    0x05  ModelName               regular    1008h (else profile title / EDS ProductName)
    0x06  UserApplicationName     regular    "<node> (CANopen node <id>)"     gateway.name
    0x80  hardware version        extended   1009h
    0x81  software version        extended   100Ah
    0x82  serial number           extended   1018h:04

(*) when the vendor id read from 1018h:01 is not the EDS VendorNumber, the EDS name is not this
device's: ``CANopen vendor 0x<id>``. Values in CANopen objects are those read from the device
since its last boot (the caller reads them); an object the device does not answer is taken from
the EDS / profile, or left out (the extended ones). VendorUrl (0x03) is not served.

Access (6.21): ReadDevId code 1 basic, 2 regular (basic + regular objects), 3 extended (all)
are streams starting at the requested object id (an id that is not in the stream restarts at
0x00), split over several answers when they exceed one PDU (More Follows 0xFF, Next Object
Id); code 4 is individual access to one object. Conformity level 0x83: extended
identification, stream and individual access. Errors: a ReadDevId code other than 1..4 ->
exception 0x03; individual access to an absent object -> 0x02; a MEI type other than 0x0E ->
0x01; a request not 3 bytes long -> 0x03.

Imports: modbus.protocol (exception codes), profiles (EDS device information). No I/O.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from canopen_gateway.modbus.protocol import ENCAPSULATED_INTERFACE, ExceptionCode, ModbusError
from canopen_gateway.profiles import LoadedProfile

MEI_READ_DEVICE_ID = 0x0E  # MEI type 14
BASIC, REGULAR, EXTENDED, INDIVIDUAL = 1, 2, 3, 4
CONFORMITY_EXTENDED_INDIVIDUAL = 0x83
MORE_FOLLOWS = 0xFF

VENDOR_NAME, PRODUCT_CODE, MAJOR_MINOR_REVISION = 0x00, 0x01, 0x02
PRODUCT_NAME, MODEL_NAME, USER_APPLICATION_NAME = 0x04, 0x05, 0x06
HARDWARE_VERSION, SOFTWARE_VERSION, SERIAL_NUMBER = 0x80, 0x81, 0x82

#: the CANopen objects read from a device for its identification (key -> object)
IDENTITY_OBJECTS = {
    "vendor_id": "0x1018:01",
    "product_code": "0x1018:02",
    "revision": "0x1018:03",
    "serial": "0x1018:04",
    "device_name": "0x1008:00",
    "hardware_version": "0x1009:00",
    "software_version": "0x100A:00",
}

_MAX_PDU = 253  # Application Protocol 4.1
_HEADER = 7  # function, MEI type, code, conformity, more follows, next object id, count
_MAX_VALUE = _MAX_PDU - _HEADER - 2  # one object always fits in one answer


def parse_request(body: bytes) -> tuple[int, int]:
    """(ReadDevId code, object id) of a request body (after the function code)."""
    if len(body) != 3:
        raise ModbusError(ExceptionCode.ILLEGAL_DATA_VALUE, "function 43/14 needs 3 bytes")
    mei, code, object_id = body
    if mei != MEI_READ_DEVICE_ID:
        raise ModbusError(ExceptionCode.ILLEGAL_FUNCTION, f"MEI type {mei} is not supported")
    if code not in (BASIC, REGULAR, EXTENDED, INDIVIDUAL):
        raise ModbusError(
            ExceptionCode.ILLEGAL_DATA_VALUE, f"ReadDevId code {code} is not 1, 2, 3 or 4"
        )
    return code, object_id


def _in_stream(code: int, object_id: int) -> bool:
    if code == BASIC:
        return object_id <= MAJOR_MINOR_REVISION
    if code == REGULAR:
        return object_id < 0x80
    return True


def respond(objects: Mapping[int, bytes], code: int, object_id: int) -> bytes:
    """The response PDU for a parsed request (6.21)."""
    if code == INDIVIDUAL:
        if object_id not in objects:
            raise ModbusError(
                ExceptionCode.ILLEGAL_DATA_ADDRESS, f"object id 0x{object_id:02X} is not served"
            )
        chosen = [object_id]
    else:
        stream = sorted(i for i in objects if _in_stream(code, i))
        if object_id not in stream:
            object_id = stream[0]  # 6.21: an unknown object id restarts at the beginning
        chosen = stream[stream.index(object_id) :]
    body = bytearray()
    count = 0
    more, next_id = 0x00, 0x00
    for i in chosen:
        value = objects[i][:_MAX_VALUE]
        if count and _HEADER + len(body) + 2 + len(value) > _MAX_PDU:
            more, next_id = MORE_FOLLOWS, i
            break
        body += bytes((i, len(value))) + value
        count += 1
    head = bytes(
        (ENCAPSULATED_INTERFACE, MEI_READ_DEVICE_ID, code, CONFORMITY_EXTENDED_INDIVIDUAL,
         more, next_id, count)
    )  # fmt: skip
    return head + bytes(body)


def _text(value: Any) -> bytes:
    if isinstance(value, (bytes, bytearray)):
        value = bytes(value).rstrip(b"\0").decode("ascii", "replace")
    return str(value).strip().encode("ascii", "replace")


def gateway_objects(version: str, name: str) -> dict[int, bytes]:
    """The gateway unit's identification: our name and version."""
    return {
        VENDOR_NAME: b"canopen-gateway",
        PRODUCT_CODE: b"canopen-gateway",
        MAJOR_MINOR_REVISION: _text(version),
        PRODUCT_NAME: b"canopen-gateway",
        MODEL_NAME: b"CANopen to Modbus TCP and Zenoh gateway",
        USER_APPLICATION_NAME: _text(name),
    }


def node_objects(
    lp: LoadedProfile, node: str, node_id: int, read: Mapping[str, Any]
) -> dict[int, bytes]:
    """A node unit's identification from its EDS / profile and the values ``read`` from the
    device since its last boot (keys of ``IDENTITY_OBJECTS``; absent = not read)."""
    info = lp.od.device_information
    eds_vendor = info.vendor_number
    vendor_id = read.get("vendor_id", eds_vendor)
    if info.vendor_name and (vendor_id is None or vendor_id == eds_vendor):
        vendor = _text(info.vendor_name)
    elif vendor_id is not None:
        vendor = f"CANopen vendor 0x{int(vendor_id):08X}".encode()
    else:
        vendor = b"unknown"
    product_code = read.get("product_code", info.product_number)
    revision = read.get("revision", info.revision_number)
    title = lp.profile.title or info.product_name or lp.family
    out = {
        VENDOR_NAME: vendor,
        PRODUCT_CODE: f"0x{int(product_code):08X}".encode()
        if product_code is not None
        else _text(info.order_code or "unknown"),
        MAJOR_MINOR_REVISION: f"{int(revision) >> 16}.{int(revision) & 0xFFFF}".encode()
        if revision is not None
        else b"unknown",
        PRODUCT_NAME: _text(info.product_name or title),
        MODEL_NAME: _text(read.get("device_name") or title),
        USER_APPLICATION_NAME: f"{node} (CANopen node {node_id})".encode(),
    }
    for key, oid in (
        ("hardware_version", HARDWARE_VERSION),
        ("software_version", SOFTWARE_VERSION),
    ):
        if read.get(key):
            out[oid] = _text(read[key])
    if read.get("serial") is not None:
        out[SERIAL_NUMBER] = f"0x{int(read['serial']):08X}".encode()
    return out
