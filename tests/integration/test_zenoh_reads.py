"""SDO uploads over Zenoh read what the operators chose to publish (``zenoh.reads: catalog``,
the default: the objects of the node's catalogue), any object only with ``zenoh.reads: all``;
a refused upload is answered ``forbidden`` and counted, and nothing goes on the bus."""

from __future__ import annotations

import pytest

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
