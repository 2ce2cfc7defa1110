"""The Modbus view of the process image and the command service: one request PDU in, one
response PDU out (``execute``), dispatched to the role that serves it.

Reads are ``modbus.reads`` (computed from the process image at the moment of the request,
never torn), writes ``modbus.writes`` (through the command service, with write protection,
the refusal of a pair's standby and the write timeout), Read Device Identification (function
43/14) ``modbus.device_identity`` (the identity objects read from each device once per
boot). ``ImageDatastore`` holds the three and the request counters the server keeps.

Imports: commands, config, image, modbus.device_identity, modbus.identity, modbus.protocol,
modbus.reads, modbus.writes, northbound.regmap, runtime.ratelimit.
"""

from __future__ import annotations

import logging
import struct

from canopen_gateway.commands import CommandService
from canopen_gateway.config import Config
from canopen_gateway.image import ProcessImage
from canopen_gateway.modbus.device_identity import DeviceIdentity
from canopen_gateway.modbus.identity import parse_request as parse_identification
from canopen_gateway.modbus.identity import respond as identification_response
from canopen_gateway.modbus.protocol import (
    COIL_ON,
    ENCAPSULATED_INTERFACE,
    MASK_WRITE_REGISTER,
    READ_COILS,
    READ_DISCRETE_INPUTS,
    READ_HOLDING,
    READ_INPUT,
    READ_TABLE,
    WRITE_COIL,
    WRITE_COILS,
    WRITE_REGISTER,
    WRITE_REGISTERS,
    ExceptionCode,
    ModbusError,
    check_request,
    pack_bits,
    unpack_bits,
)
from canopen_gateway.modbus.reads import ImageReads
from canopen_gateway.modbus.writes import ImageWrites
from canopen_gateway.northbound.regmap import RegisterMap
from canopen_gateway.runtime.ratelimit import RateLimitedLog

log = logging.getLogger("gateway.modbus")


class ImageDatastore:
    """The three roles that serve a request, by the register map (``reads``: from the image;
    ``writes``: through the command service; ``identity``: Read Device Identification), and the
    request counters the server keeps. ``execute`` calls the roles directly."""

    def __init__(
        self, regmap: RegisterMap, image: ProcessImage, commands: CommandService, cfg: Config
    ):
        self.regmap = regmap
        self.image = image
        self.commands = commands
        self.requests = 0
        self.by_function: dict[int, int] = {}  # requests by function code
        self.exceptions: dict[int, int] = {}
        self.warn = RateLimitedLog(log)
        self.reads = ImageReads(regmap, image, commands)
        self.writes = ImageWrites(self.reads, cfg, self.warn)
        self.identity = DeviceIdentity(regmap, image, commands, cfg.gateway.name, self.warn)

    def count_exception(self, code: ExceptionCode) -> None:
        self.exceptions[int(code)] = self.exceptions.get(int(code), 0) + 1


# ---------------------------------------------------------------------- one request
def _check(store: ImageDatastore, unit: int, fc: int, body: bytes) -> None:
    """The checks every request passes first: raise the Modbus exception ``check_request``
    gives a malformed or unsupported request, or 0Ah for a unit id that is not configured."""
    code = check_request(fc, body)
    if code is not None:
        raise ModbusError(code, f"function code {fc}: malformed or unsupported request")
    if unit not in store.regmap.units:
        raise ModbusError(
            ExceptionCode.GATEWAY_PATH_UNAVAILABLE, f"unit id {unit} is not configured"
        )


def execute_now(store: ImageDatastore, unit: int, pdu: bytes) -> bytes | None:
    """A register read served from the image at once (no await, no task), or None when the
    request needs ``execute`` (writes, bits, identification, outputs read through the command
    service). Raises as ``execute`` does."""
    fc = pdu[0]
    if fc not in (READ_HOLDING, READ_INPUT):
        return None
    body = pdu[1:]
    _check(store, unit, fc, body)
    address, qty = struct.unpack(">HH", body)
    values = store.reads.read_now(unit, READ_TABLE[fc], address, qty)
    if values is None:
        return None
    data = struct.pack(f">{len(values)}H", *values)
    return bytes((fc, len(data))) + data


async def execute(store: ImageDatastore, unit: int, pdu: bytes, peer: str | None) -> bytes:
    """Serve one request PDU; returns the response PDU (raises ModbusError / GatewayError)."""
    fc, body = pdu[0], pdu[1:]
    _check(store, unit, fc, body)
    if fc == ENCAPSULATED_INTERFACE:
        code, object_id = parse_identification(body)
        return identification_response(await store.identity.identification(unit), code, object_id)
    if fc in READ_TABLE:
        address, qty = struct.unpack(">HH", body)
        values = await store.reads.read(unit, READ_TABLE[fc], address, qty)
        if fc in (READ_COILS, READ_DISCRETE_INPUTS):
            data = pack_bits(values)
        else:
            data = struct.pack(f">{len(values)}H", *values)
        return bytes((fc, len(data))) + data
    if fc == WRITE_COIL:
        address, value = struct.unpack(">HH", body)
        await store.writes.write_coils(unit, address, [value == COIL_ON], peer)
        return pdu  # the normal response is an echo of the request (6.5)
    if fc == WRITE_REGISTER:
        address, value = struct.unpack(">HH", body)
        await store.writes.write_registers(unit, address, [value], peer)
        return pdu  # echo (6.6)
    if fc == WRITE_COILS:
        address, qty, byte_count = struct.unpack_from(">HHB", body)
        await store.writes.write_coils(unit, address, unpack_bits(body[5:], qty), peer)
        return bytes((fc,)) + body[:4]
    if fc == WRITE_REGISTERS:
        address, qty, byte_count = struct.unpack_from(">HHB", body)
        await store.writes.write_registers(
            unit, address, list(struct.unpack_from(f">{qty}H", body, 5)), peer
        )
        return bytes((fc,)) + body[:4]
    if fc == MASK_WRITE_REGISTER:
        address, and_mask, or_mask = struct.unpack(">HHH", body)
        await store.writes.mask_write(unit, address, and_mask, or_mask, peer)
        return pdu  # echo (6.16)
    # READ_WRITE_REGISTERS: the write is performed before the read (6.17)
    r_addr, r_qty, w_addr, w_qty, _ = struct.unpack_from(">HHHHB", body)
    await store.writes.write_registers(
        unit, w_addr, list(struct.unpack_from(f">{w_qty}H", body, 9)), peer
    )
    values = await store.reads.read(unit, "hr", r_addr, r_qty)
    data = struct.pack(f">{len(values)}H", *values)
    return bytes((fc, len(data))) + data
