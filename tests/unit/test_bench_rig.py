"""The benchmarks build their gateways as the command line does: a bench config's nodes are
resolved and handed to ``Gateway`` (a change of the gateway's constructor breaks ``make bench``
here, not at the next benchmark run)."""

from __future__ import annotations

import importlib

from bench.rig import bench_config, bench_node, gateway_of


def test_every_benchmark_module_imports() -> None:
    main = importlib.import_module("bench.__main__")
    assert set(main.BENCHES) >= {"hotpath", "ingest", "linerate", "costs", "scale", "pair"}


def test_a_bench_gateway_is_built_from_its_resolved_nodes() -> None:
    gw = gateway_of(bench_config([bench_node("n1", 1)], "rig"), simulate=False)
    assert list(gw.nodes) == ["n1"]
    assert gw.nodes["n1"].tpdos  # the node's codecs, resolved once
    assert gw.master is not None and gw.modbus is not None
