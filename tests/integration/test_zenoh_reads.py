"""SDO uploads over Zenoh read what the operators chose to publish (``zenoh.reads: catalog``,
the default: the objects of the node's catalogue), any object only with ``zenoh.reads: all``;
a refused upload is answered ``forbidden`` and counted, and nothing goes on the bus."""

from __future__ import annotations

import asyncio

import pytest
import zenoh

from tests.helpers import gateway_of, make_config, wait_until
from tests.zenoh_client import ZClient

WIRE = [{"name": "wire", "node_id": 1, "profile": "sgh10"}]


@pytest.mark.parametrize("reads", ["catalog", "all"])
async def test_an_sdo_upload_of_an_object_outside_the_catalogue_needs_reads_all(reads: str) -> None:
    cfg = make_config(WIRE, zenoh={"reads": reads})
    gw = gateway_of(cfg)
    await gw.start()
    z = ZClient(cfg.zenoh.listen)
    try:
        await wait_until(lambda: gw.image.nodes["wire"].usable(), 8, "wire usable")
        listed = await z.get_one("canopen/test/wire/sdo/6000/00")  # operating parameters
        assert listed.ok, listed.body
        cob_id = await z.get_one("canopen/test/wire/sdo/1800/01")  # TPDO1 COB-ID: not listed
        if reads == "all":
            assert cob_id.ok and cob_id.body["value"] == 0x181, cob_id.body
        else:
            assert not cob_id.ok and cob_id.body["error"] == "forbidden"
            assert "zenoh.reads" in cob_id.body["message"]
            assert gw.zenoh.refused == {"sdo_read": 1}
    finally:
        z.close()
        await gw.stop()


async def test_a_refused_write_is_audited_with_the_querier_id_kept_as_a_hint() -> None:
    cfg = make_config(WIRE)  # zenoh.writes off
    gw = gateway_of(cfg)
    await gw.start()
    audit: list[dict] = []
    gw.commands.audit = audit.append
    z = ZClient(cfg.zenoh.listen)
    try:
        zid = z.session.zid()
        querier = z.session.declare_querier("canopen/test/wire/nmt")  # its id: what the get says

        def get() -> list:
            return list(z.session.get("canopen/test/wire/nmt", payload="stop", timeout=5,
                                      source_info=zenoh.SourceInfo(querier.id, 7)))  # fmt: skip

        (reply,) = await asyncio.to_thread(get)
        assert reply.err is not None and b"forbidden" in reply.err.payload.to_bytes()
        (record,) = audit
        assert record["who"] == "zenoh" and record["op"] == "nmt"
        assert record["outcome"].startswith("refused: Zenoh writes are off")
        assert record["hint"] == f"zenoh session {zid} (said by the client, not verified)"
    finally:
        z.close()
        await gw.stop()
