"""What a hot-standby pair must keep through a take-over, as functions any pair test can call
on what it recorded (the frames each member sent, the members' output images): each returns
the list of violations, empty when the rule holds, so that a generated test can assert on it
and print what broke.

* ``outputs_known_alike(active, standby)``: every RPDO the standby knows carries what the
  active member's image carries, field for field (the guarding bit aside: each gateway toggles
  it when the device echoed the last one).
* ``rpdos_resume_as_sent(before, after, ignore)``: every RPDO the new active member sends
  after a take-over, up to its first write, is the frame the old one last sent on that COB-ID
  (the bits of ``ignore`` aside: the guarding bit), and it sends none the old one never sent.
* ``left_open_aborted_first(frames, node_id, sender)``: the new active member's first frame to
  a node's SDO server (600h + node id) is an abort, when the old one left a transfer open.
* ``safe_in_time(last_write_s, safe_s, now_s, watchdog_s, takeover_s)``: with the output
  watchdog on, the safe outputs went out no sooner than ``watchdog_s`` after the PLC's last
  write and no later than ``watchdog_s`` + one take-over after it (times on one clock).

Imports: canopen_gateway.bus.node.outputs (the image's type), canopen_gateway.canopen.cia301, the standard
library.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from typing import Any

from canopen_gateway.bus.node.outputs import OutputImage
from canopen_gateway.canopen.cia301 import COB_SDO_RX

#: (COB-ID, data) of one frame
Frame = tuple[int, bytes]


def outputs_known_alike(active: OutputImage, standby: OutputImage) -> list[str]:
    """Every RPDO the standby knows (heard or sent) equals the active member's, the guarding
    bit aside (its content as a write sets it)."""
    out = []
    for codec in active.rpdos:
        n = codec.number
        if n in standby.unknown:
            continue
        mine, theirs = standby.content(n), active.content(n)
        if mine != theirs:
            out.append(f"RPDO{n}: the standby has {mine}, the active member {theirs}")
    return out


def _masked(data: bytes, mask: bytes | None) -> bytes:
    if mask is None:
        return data
    return bytes(b & ~m for b, m in zip(data, mask.ljust(len(data), b"\0"), strict=False))


def rpdos_resume_as_sent(
    before: Sequence[Frame], after: Sequence[Frame], ignore: Mapping[int, bytes]
) -> list[str]:
    """``before``: the RPDO frames the old active member sent (in order); ``after``: those the
    new one sent after the take-over up to its first write; ``ignore``: per COB-ID a byte mask
    of the bits the gateway owns (the guarding bit)."""
    last: dict[int, bytes] = {}
    for cob, data in before:
        last[cob] = data
    out = []
    for cob, data in after:
        if cob not in last:
            out.append(f"0x{cob:03X} {data.hex()}: an RPDO the old active member never sent")
        elif _masked(data, ignore.get(cob)) != _masked(last[cob], ignore.get(cob)):
            out.append(f"0x{cob:03X} {data.hex()}: the old active member last sent {last[cob].hex()}")
    return out


def left_open_aborted_first(frames: Iterable[tuple[str, Frame]], node_id: int, sender: str) -> list[str]:
    """``frames``: (sender, frame) in bus order from the take-over on; the first SDO request of
    ``sender`` to ``node_id`` must be an abort (command 80h)."""
    for who, (cob, data) in frames:
        if who == sender and cob == COB_SDO_RX + node_id:
            return [] if data[:1] == b"\x80" else [f"first SDO request to node {node_id} is {data.hex()}, not an abort"]
    return [f"no SDO request of {sender} to node {node_id}: the transfer left open was not aborted"]


def safe_in_time(
    last_write_s: float, safe_s: float | None, now_s: float, watchdog_s: float, takeover_s: float
) -> list[str]:
    """``safe_s``: when the first frame with the safe values went out after the PLC's last
    write at ``last_write_s`` (None: none yet, at ``now_s``)."""
    due = last_write_s + watchdog_s + takeover_s
    if safe_s is None:
        return [f"no safe outputs {now_s - last_write_s:.3f} s after the last write"] if now_s > due else []
    if safe_s < last_write_s + watchdog_s:
        return [f"safe outputs {safe_s - last_write_s:.3f} s after the last write: sooner than the watchdog"]
    if safe_s > due:
        return [f"safe outputs {safe_s - last_write_s:.3f} s after the last write: later than watchdog + take-over"]
    return []


def as_frames(sent: Iterable[Any]) -> list[Frame]:
    """``Send`` outputs of a node as (COB-ID, data) frames."""
    return [(s.cob_id, bytes(s.data)) for s in sent]
