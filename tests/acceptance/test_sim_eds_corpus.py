"""Every file of ``../shared/eds-corpus/`` (third-party EDS and DCF files) that ``check`` accepts
as a one-node config runs as a simulated device against the gateway: the simulator builds the
device from the same resolved node the gateway decodes (a DCF's ParameterValues and CompactSubObj
``[xxxxValue]`` sections included), so each enabled TPDO arrives with the mapping the gateway
decodes and every value it carries is good and equal to what the device holds.

One private virtual bus and one in-process gateway + simulator per file (no Modbus, no Zenoh);
the simulated inputs hold still (motion ``hold``), so each TPDO's first frame carries the values
compared. Waits on conditions, bounded. The corpus is read from next to the clone (never copied
into the repository); the tests skip when it is absent."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from canopen_gateway.checks import check_config
from canopen_gateway.config import ConfigError
from canopen_gateway.image import Quality
from canopen_gateway.profiles import ProfileError
from tests.helpers import gateway_of, make_config, resolved, wait_until

CORPUS = Path(__file__).resolve().parents[2] / ".." / "shared" / "eds-corpus"
FILES = sorted(p for p in CORPUS.glob("*") if p.suffix.lower() in (".eds", ".dcf")) if CORPUS.is_dir() else []
pytestmark = pytest.mark.skipif(not FILES, reason=f"no EDS corpus at {CORPUS}")

NODE_ID = 5


def checked_config(eds: Path) -> Any:
    """The one-node config of ``eds`` with the device simulated, or None when ``check`` refuses it."""
    try:
        cfg = make_config(
            [{"name": "dev", "node_id": NODE_ID, "eds": str(eds)}],
            modbus={"enabled": False},
            zenoh={"enabled": False},
            simulate={"nodes": "all", "motion": {"dev": {"kind": "hold", "hold": 1234}}},
        )
        check_config(cfg, resolved(cfg))
    except (ConfigError, ProfileError):
        return None
    return cfg


@pytest.mark.parametrize("eds", FILES, ids=lambda p: p.name[:60])
async def test_each_enabled_tpdo_of_a_simulated_corpus_device_arrives_as_the_gateway_decodes_it(
    eds: Path,
) -> None:
    cfg = checked_config(eds)
    if cfg is None:
        pytest.skip(f"check refuses {eds.name}")
    if 0x1000 not in resolved(cfg)["dev"].lp.od:
        # CiA 301 makes 1000h mandatory: the gateway finds a running node by reading it, so a
        # device without it is found only by its boot-up, sent here before the gateway listens
        pytest.skip(f"{eds.name} has no 1000h (device type)")
    gw = gateway_of(cfg)
    await gw.start()
    try:
        node = gw.nodes["dev"]
        sim = gw.sim.nodes["dev"]
        rt = gw.image.nodes["dev"]
        await wait_until(lambda: rt.operational(), 10, f"{eds.name} operational")
        codecs = [c for c in node.tpdos if c.names]

        def expected() -> dict[str, Any]:
            """Each TPDO's values as the gateway decodes the frame the device would send now."""
            out: dict[str, Any] = {}
            for c in codecs:
                data = gw.sim.runner.call(lambda now, n=c.number: sim.tpdo_data(n, now))
                assert len(data) == c.length, f"TPDO{c.number}: {len(data)} bytes, decoder {c.length}"
                out.update(zip(c.names, c.decode(data), strict=True))
            return out

        want = expected()

        def arrived() -> bool:
            return all(
                rt.quality(rt.signals[name]) == Quality.GOOD and rt.signals[name].value == value
                for name, value in want.items()
            )

        await wait_until(arrived, 10, f"{eds.name}: every TPDO value good and as the device holds it")
        assert (rt.rx.pdo_too_short, rt.rx.pdo_too_long) == (0, 0)  # every frame its mapping's length
    finally:
        await gw.stop()
