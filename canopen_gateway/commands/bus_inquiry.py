"""The bus tools of the command service, on the gateway's own connection to the bus: LSS
inquire and Fast Scan (CiA 305) and the scan of which node ids are on the bus and what they are.

Imports: bus.lss.master (its errors), bus.lss.service (the Fast Scan's known parts), bus.master (the master), bus.scan (the scan beside the
master), device.values (value codecs), errors, canopen.objref, python-can (its error type).
"""

from __future__ import annotations

import asyncio
from typing import Any

import can

from canopen_gateway.bus.lss.master import LssBusy, LssStateError
from canopen_gateway.bus.lss.service import Known
from canopen_gateway.bus.master import Master
from canopen_gateway.bus.scan import Found, scan_beside
from canopen_gateway.bus.scan import report as scan_report
from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.device.values import decode_value
from canopen_gateway.errors import BusDown, GatewayError, LssConflict


async def lss_inquire(
    master: Master, address: tuple[int, int, int, int] | None = None
) -> dict[str, Any]:
    """LSS inquire (CiA 305; SGH10 manual 4.6.3) of the one slave at ``address`` (switch
    state selective), else of every slave (switch state global), on the gateway's own
    connection to the bus: vendor_id, product_code, revision, serial, node_id."""
    master.require_bus()
    try:
        return await master.lss.inquire_all(address)
    except (LssBusy, LssStateError) as exc:
        raise LssConflict(str(exc)) from None
    except can.CanError as exc:
        raise BusDown(str(exc)) from None


async def lss_fast_scan(master: Master, known: Known, wait_s: float, first_node_id: int | None = None,
                        count: int = 1, store: bool = False) -> dict[str, Any]:  # fmt: skip
    """CiA 305 Fast Scan on the gateway's own connection to the bus (``LssService.fast_scan``):
    the unconfigured slaves' LSS addresses, lowest first, each given the next node id."""
    master.require_bus()
    try:
        return await master.lss.fast_scan(known, wait_s, first_node_id, count, store)
    except (LssBusy, LssStateError) as exc:
        raise LssConflict(str(exc)) from None
    except can.CanError as exc:
        raise BusDown(str(exc)) from None


async def scan_bus(
    master: Master, *, listen_s: float = 1.0, sdo_timeout_s: float = 0.1
) -> dict[str, Any]:
    """Which node ids are on the bus and what they are (``canopen-gateway scan --active``),
    on the gateway's own connection: the ids that talk within ``listen_s``; device type,
    name and identity (1000h, 1008h, 1018h:01..04) of every id that answers. The scan's own
    SDO client probes the ids no node of the config has; a configured node is read by the
    master's SDO client, in turn with its other transfers. Returns ``{"nodes": [...],
    "report": [lines as printed by the scan command]}``."""
    master.require_bus()
    ids = {p.node_id: name for name, p in master.nodes.items()}
    try:
        found, identities = await asyncio.gather(
            asyncio.to_thread(
                scan_beside,
                master.driver,
                configured=set(ids),
                listen_s=listen_s,
                sdo_timeout_s=sdo_timeout_s,
            ),
            asyncio.gather(*(_identify(master, name, node_id) for node_id, name in ids.items())),
        )
    except can.CanError as exc:  # the bus went down under the scan
        raise BusDown(str(exc)) from None
    for f in identities:
        if f is None:
            continue
        heard = found.get(f.node_id)
        if heard is not None:  # what it sent in the listening window
            f.state, f.cob_ids = heard.state, heard.cob_ids
        found[f.node_id] = f
    return {
        "nodes": [found[i].doc() for i in sorted(found)],
        "report": scan_report(found, master.cfg, active=True, beside=True),
    }


async def _identify(master: Master, name: str, node_id: int) -> Found | None:
    """Device type, name and identity of a configured node by the master's SDO client;
    None if it does not answer 1000h."""

    async def upload(index: int, sub: int) -> bytes | None:
        try:
            return await master.sdo(name, ObjRef(index, sub), None, check_state=False)
        except GatewayError:  # an abort, no answer, the bus down
            return None

    async def read(index: int, sub: int, type_: str) -> Any:
        raw = await upload(index, sub)
        return decode_value(raw, type_) if raw else None

    device_type = await read(0x1000, 0, "uint32")
    if device_type is None:
        return None
    f = Found(node_id, device_type=device_type, name=await read(0x1008, 0, "string"))
    f.vendor, f.product, f.revision, f.serial = [
        await read(0x1018, sub, "uint32") for sub in (1, 2, 3, 4)
    ]
    return f
