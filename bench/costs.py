"""Benchmark 9, cost per frame: the line-rate rig (``bench.linerate``) run as scenarios, each
a bare python-can listener and the gateway back to back in the same run.

Scenarios (60 SGH10 nodes through a socketcand server on 127.0.0.1, default config
``publish: change`` unless said, a PLC reading 1,200 requests/s, a Zenoh subscriber on every
value, a Modbus poller for the latency): a 500 kbit/s bus (4,505 frames/s of 8-byte standard
frames without stuffing) and a 1 Mbit/s bus (9,009 frames/s), every frame carrying new values;
the same 1 Mbit/s bus with ``publish: pdo``; one frame per TCP write at 5,000 frames/s (as
SocketCAN delivers them: one frame per read), also with ``zenoh.batch_ms: 0`` (per burst; the
default is 1) and with Zenoh off (what publication costs per wake-up); then a ladder of rates to find the largest one the
gateway holds with 0 frames lost and p99 frame -> Modbus and frame -> Zenoh <= 1 ms.

The 500 kbit/s and 1 Mbit/s scenarios then run the bare pipeline (``bench.pipeline``: the
least code on the same libraries, under the same load) in the gateway's place: what the
libraries and this machine give, for CPU and latency alike.

Per scenario: gateway CPU (% of one core) and its ratio to the bare listener, p99 frame ->
Modbus and frame -> Zenoh (and frame -> Zenoh with the PLC alone, at a subscriber on node 1's
position only: not queued behind the other keys' samples, no poller), the reader thread's CPU per burst (one wake-up each:
``canopen_gateway_can_bursts_total``) and per frame, frames per burst, context switches per
burst (the reader's, and all threads').

Imports: bench.*.
"""

from __future__ import annotations

from typing import Any

from bench.linerate import scenario
from bench.report import Row, Section
from bench.stats import Summary

BUS_500K, BUS_1M = 4505, 9009
LADDER = (1000, 2000, 3000, 4505)  # above the 600 heartbeats/s of the 60 nodes


def _rows(sec: Section, label: str, runs: list[dict[str, Any]], zenoh: bool = True) -> None:
    s = Summary.of

    def col(key: str) -> Summary:
        return s([r[key] for r in runs])

    pipe = "pipe_cpu" in runs[0]  # the bare pipeline ran too (bench/pipeline.py)

    rows = [
        Row(f"{label}: frames/s", col("fps")),
        Row(f"{label}: gateway CPU, % of one core", s([r["cpu"] * 100 for r in runs]),
            "bare listener", s([r["bare_cpu"] * 100 for r in runs]), col("ratio"),
            "<= 2.5x bare", all(r["ratio"] <= 2.5 for r in runs), digits=1),
        Row(f"{label}: p99 frame -> Modbus (ms)", col("mb_p99"), target="<= 1 ms",
            met=all(r["mb_p99"] <= 1.0 for r in runs), digits=2),
        Row(f"{label}: p99 frame -> Zenoh (ms)", col("z_p99"), target="<= 1 ms",
            met=all(r["z_p99"] <= 1.0 for r in runs), digits=2),
        Row(f"{label}: p99 frame -> Zenoh, PLC only, a subscriber on node 1's position (ms)",
            col("zq_p99"), baseline_name="bare pipeline" if pipe else "",
            baseline=col("pipe_zq_p99") if pipe else None, digits=2),
        Row(f"{label}: frames lost", col("lost"), target="0", met=all(r["lost"] == 0 for r in runs)),
        Row(f"{label}: reader us per burst (wake-up)", col("reader_us_per_burst"), digits=1),
        Row(f"{label}: reader us per frame", col("reader_us_per_frame"), "bare listener",
            s([r["bare_us_per_frame"] for r in runs]), digits=1),
        Row(f"{label}: zenoh-publish thread us per frame", col("publish_us_per_frame"), digits=1),
        Row(f"{label}: frames per burst", col("frames_per_burst"), digits=2),
        Row(f"{label}: value samples/s at the subscriber", col("value_samples_per_s")),
        Row(f"{label}: context switches per burst, reader / all threads",
            col("reader_switches_per_burst"), "all threads", col("switches_per_burst"), digits=2),
    ]  # fmt: skip
    if pipe:  # the bare pipeline under the same load
        rows += [
            Row(f"{label}: bare pipeline CPU, % of one core", s([r["pipe_cpu"] * 100 for r in runs]),
                "bare listener", s([r["bare_cpu"] * 100 for r in runs]), col("pipe_ratio"),
                "<= 2.5x bare", all(r["pipe_ratio"] <= 2.5 for r in runs), digits=1),
            Row(f"{label}: gateway CPU against the bare pipeline, % of one core",
                s([r["cpu"] * 100 for r in runs]), "bare pipeline",
                s([r["pipe_cpu"] * 100 for r in runs]), col("gw_to_pipe"), digits=1),
            Row(f"{label}: bare pipeline p99 frame -> Modbus (ms)", col("pipe_mb_p99"),
                target="<= 1 ms", met=all(r["pipe_mb_p99"] <= 1.0 for r in runs), digits=2),
            Row(f"{label}: bare pipeline p99 frame -> Zenoh (ms)", col("pipe_z_p99"),
                target="<= 1 ms", met=all(r["pipe_z_p99"] <= 1.0 for r in runs), digits=2),
        ]  # fmt: skip
    sec.rows += [row for row in rows if zenoh or ("-> Zenoh" not in row.figure
                                                  and "zenoh-publish" not in row.figure)]


async def run(phase_s: float = 8.0, reps: int = 2) -> Section:
    sec = Section(
        key="costs",
        title="9. Cost per frame: the line-rate rig by scenario",
        method=(
            "The line-rate rig of section 8 (60 SGH10 through socketcand, a PLC at 1,200 "
            "requests/s, a Zenoh subscriber on every value, a Modbus poller) run as scenarios, "
            f"each a bare python-can listener then the gateway ({phase_s:g} s each, the same "
            "frames): a 500 kbit/s bus (4,505 frames/s: 8-byte standard frames without "
            "stuffing) and a 1 Mbit/s bus (9,009 frames/s), every frame carrying new values "
            f"(position and velocity), default config (`publish: change`), {reps} runs each; "
            "the 1 Mbit/s bus with `publish: pdo`; one frame per TCP write at 5,000 frames/s "
            "(one frame per read, as SocketCAN delivers them), also with `zenoh.batch_ms: 0` "
            "(per burst; the default window is 1 ms) "
            "and, once, with Zenoh off (what publication costs); then rates "
            f"{', '.join(f'{r:,}' for r in LADDER)} frames/s once each for the largest rate "
            "held with 0 lost and both p99 <= 1 ms. Reader CPU per burst and per frame (and the "
            "zenoh-publish thread's per frame: the values the reader marked) from "
            "/proc/PID/task and the gateway's `can_bursts_total` / `frames_in_total`."
        ),
    )
    plan: list[tuple[str, dict[str, Any], int]] = [
        ("500 kbit/s, every value", {"fps": BUS_500K, "every_value": True, "pipeline": "bare"},
         reps),
        ("1 Mbit/s, every value", {"fps": BUS_1M, "every_value": True, "pipeline": "bare"}, reps),
        ("1 Mbit/s, every value, publish: pdo",
         {"fps": BUS_1M, "every_value": True, "publish": "pdo"}, reps),
        ("one frame per read, 5,000 frames/s, every value",
         {"fps": 5000, "every_value": True, "per_frame": True}, reps),
        ("one frame per read, 5,000 frames/s, every value, zenoh.batch_ms 0",
         {"fps": 5000, "every_value": True, "per_frame": True, "batch_ms": 0.0}, reps),
        ("one frame per read, 5,000 frames/s, every value, Zenoh off",
         {"fps": 5000, "every_value": True, "per_frame": True, "zenoh": False}, 1),
    ]  # fmt: skip
    for label, kw, n in plan:
        runs = [await scenario(phase_s=phase_s, **kw) for _ in range(n)]
        _rows(sec, label, runs, kw.get("zenoh", True))
    held = 0
    ladder = []
    for fps in LADDER:
        try:
            r = await scenario(fps=fps, every_value=True, phase_s=phase_s)
        except Exception as exc:  # noqa: BLE001 - one failed rate must not lose the others
            ladder.append(f"{fps:,} frames/s: not measured ({exc})")
            continue
        ok = r["lost"] == 0 and r["mb_p99"] <= 1.0 and r["z_p99"] <= 1.0
        ladder.append(
            f"{fps:,} frames/s: CPU {r['cpu'] * 100:.1f}% ({r['ratio']:.2f}x bare), p99 Modbus "
            f"{r['mb_p99']:.2f} ms, Zenoh {r['z_p99']:.2f} ms, lost {r['lost']:.0f}"
            + (" - held" if ok else "")
        )
        if ok:
            held = fps
    sec.rows.append(Row("largest rate held (0 lost, both p99 <= 1 ms), frames/s",
                        Summary.of([held]), target=f">= {BUS_1M:,}", met=held >= BUS_1M))  # fmt: skip
    sec.notes.append(
        "Rate ladder, every value changing, default config: " + "; ".join(ladder) + "."
    )
    return sec
