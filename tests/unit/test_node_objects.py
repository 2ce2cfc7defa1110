"""The node's parts own their state: the sub-steps of ``Node`` (what a lifecycle change and a
finished transfer mean) return values the node applies, the device features see the node only
through ``NodeContext``, and nothing in ``bus/node`` or ``bus/error_control`` reaches into
another object's private attributes."""

from __future__ import annotations

import ast
import logging
from pathlib import Path
from types import SimpleNamespace

from canopen_gateway.bus.events import Note
from canopen_gateway.bus.node.features.verify_mapping import VerifyMapping
from canopen_gateway.bus.node.lifecycle import Configured, LifecycleState, NodeLifecycle, StepFailed
from canopen_gateway.bus.node.lifecycle_report import Report, lifecycle_reports
from canopen_gateway.bus.node.sdo_done import SDO_DONE, SdoOutcome
from canopen_gateway.bus.sdo.channel import SdoChannel, SdoJob
from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.device.boot_steps import ConfigStep
from canopen_gateway.image import NodeHealth
from canopen_gateway.pdo.verify import MappingRead

GATEWAY = Path(__file__).resolve().parents[2] / "canopen_gateway"
#: NamedTuple's public API is spelled with an underscore
NAMEDTUPLE_API = {"_replace", "_asdict", "_fields", "_make", "_field_defaults"}


def _private_reaches(paths: list[Path]) -> list[str]:
    """``x._y`` where x is not self / cls (the attribute of another object)."""
    found = []
    for path in paths:
        for node in ast.walk(ast.parse(path.read_text())):
            if (
                isinstance(node, ast.Attribute)
                and node.attr.startswith("_")
                and not node.attr.startswith("__")
                and node.attr not in NAMEDTUPLE_API
                and not (isinstance(node.value, ast.Name) and node.value.id in ("self", "cls"))
            ):
                found.append(f"{path.relative_to(GATEWAY)}:{node.lineno} .{node.attr}")
    return found


def test_bus_node_and_error_control_reach_into_no_private_attribute_of_another_object() -> None:
    paths = sorted((GATEWAY / "bus" / "node").rglob("*.py"))
    paths += sorted((GATEWAY / "bus" / "error_control").rglob("*.py"))
    assert _private_reaches(paths) == []


def test_features_do_not_know_the_node_class() -> None:
    """A feature is typed against ``NodeContext`` (name, health, SDO channel, image), never the
    whole ``Node``."""
    importers = []
    for path in sorted((GATEWAY / "bus" / "node" / "features").glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and any(a.name == "Node" for a in node.names):
                importers.append(f"{path.name}: from {node.module} import Node")
    assert importers == []


def test_a_feature_works_on_a_context_with_only_name_health_sdo_and_image() -> None:
    health = NodeHealth()
    ctx = SimpleNamespace(name="io", health=health, sdo=SdoChannel(5, 0.5, 1), image=None)
    reads = [
        MappingRead("tpdo", 1, ObjRef(0x1800, 0x01), "uint32", 0x185, "cob_id"),
        MappingRead("tpdo", 1, ObjRef(0x1A00, 0x00), "uint8", 1, "count"),
        MappingRead("tpdo", 1, ObjRef(0x1A00, 0x01), "uint32", 0x60000108, "entry"),
    ]
    feature = VerifyMapping(reads, frozenset({"a"}))
    feature.on_bootup(ctx, 1.0)
    assert health.invalid_signals == frozenset({"a"}), "not trusted until read back"
    feature.on_configured(ctx, 2.0)
    jobs = list(ctx.sdo.jobs)
    assert [j.obj for j in jobs] == [r.object for r in reads], "queued in the context's channel"
    for job in jobs:
        answer = SimpleNamespace(result=job.arg.expected.to_bytes(4, "little"), abort_code=None)
        out = feature.sdo_done(ctx, job, answer, 2.5)
    assert health.invalid_signals == frozenset()
    assert isinstance(out[0], Note) and "PDO mapping verified" in out[0].text


def test_lifecycle_changes_become_reports_the_node_applies() -> None:
    step = ConfigStep(ObjRef(0x1017, 0x00), 1000, "uint16", "heartbeat")
    changes = [
        StepFailed(0, step, 0x06020000, 2, 1.5, "0x1017:00 (heartbeat): SDO abort"),
        Configured(0.25),
    ]
    failed, configured = lifecycle_reports(changes, "io", 5, None, now=10.0)
    assert failed == Report(
        Note(
            logging.WARNING,
            "node io: boot step 0 failed: 0x1017:00 (heartbeat): SDO abort; retry 2 in 1.5 s",
        ),
        last_error="0x1017:00 (heartbeat): SDO abort",
        last_sdo_abort=0x06020000,
        wait_until_s=11.5,
    )
    assert configured == Report(
        Note(logging.INFO, "node io (id 5) configured in 250 ms and started"),
        last_error="",
        configured=True,
    )


def _probe(device_type: int) -> tuple[SimpleNamespace, SdoOutcome]:
    """A probe of node 5 (1000h read) answered with ``device_type``; its context and outcome."""
    lifecycle = NodeLifecycle([], expected_device_type=0x00020192)
    ctx = SimpleNamespace(name="io", node_id=5, lifecycle=lifecycle, resumes=False)
    job = SdoJob(1, ObjRef(0x1000, 0x00), None, "probe")
    transfer = SimpleNamespace(
        result=device_type.to_bytes(4, "little"),
        abort_code=None,
        timed_out=False,
        aborted_by_server=False,
    )
    return ctx, SDO_DONE["probe"](ctx, job, transfer, 3.0)


def test_a_probe_that_finds_the_node_says_so_and_writes_nothing_of_the_node() -> None:
    ctx, outcome = _probe(0x00020192)
    assert isinstance(outcome, SdoOutcome)
    assert outcome.probe_ended and outcome.found and not outcome.user
    assert outcome.outputs == [Note(logging.INFO, "node io (id 5) found running")]
    assert ctx.lifecycle.state is LifecycleState.BOOTING
    assert set(vars(ctx)) == {"name", "node_id", "lifecycle", "resumes"}, "the node applies the outcome"


def test_a_probe_of_a_wrong_device_ends_the_probe_and_finds_nothing() -> None:
    ctx, outcome = _probe(0x00030191)
    assert outcome.probe_ended and not outcome.found
    assert ctx.lifecycle.state is LifecycleState.WAITING
    assert [type(c).__name__ for c in outcome.changes] == ["WrongDevice"]
