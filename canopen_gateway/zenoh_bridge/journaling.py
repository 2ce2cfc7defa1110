"""What the Zenoh bridge hands the journal (``canopen_gateway.journal``) besides its events
(``events.py``), decided here:

* ``ValueHistory``: the journal's writer asks it, once per ``journal.values_ms`` window, for
  the value of every signal whose value or quality changed since the last window, read from
  the process image (whatever the Zenoh session does: the journal is fed from the bus side):
  every signal published on its value key and every signal of a ``publish: pdo`` record (its
  history is kept per signal, on ``<node>/value/<signal>``). The payload is the one published
  when the last sample published is of this frame, else the same JSON built from the image;
  its ``seq`` is the one the key shows (the image's plus the key's offset); its stamp is the
  journal's clock at the window. A gateway that stands by in a pair journals what it hears
  instead (``heard_entry``), not its own image (with a pair per network, of the nodes of the
  networks it stands by on);
* ``restore_seqs``: at start, every value key's ``seq`` goes on above the highest the journal
  ever handed out on it (``SignalPub.seq_offset``, ``PdoPub.seq_offset``);
* ``heard_entry``: a sample a pair's standby hears of the other member, as a journal entry
  (state and EMCY events it has not journaled yet, values), or None.

Imports: journal, image, northbound.keys, northbound.scaling, profiles.schema,
zenoh_bridge.plan, zenoh_bridge.payloads. Never zenoh, modbus/ nor bus/.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Collection, Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

from canopen_gateway.image import ProcessImage
from canopen_gateway.journal import Entry, HybridClock, ntp64_of_ns
from canopen_gateway.northbound.keys import value_key
from canopen_gateway.northbound.scaling import Scaling
from canopen_gateway.profiles.schema import Signal
from canopen_gateway.zenoh_bridge.payloads import value_json
from canopen_gateway.zenoh_bridge.plan import PdoPub, SignalPub


@dataclass(eq=False)
class ValueKey:
    """One signal whose values are journaled on its value key."""

    node: str
    sig: Signal
    scaling: Scaling
    key: str
    #: the publication its ``seq`` offset (and last published sample) comes from
    pub: SignalPub | PdoPub
    #: (image seq, quality) last journaled: only the writer reads and writes it
    journaled: tuple[int, Any] = field(default=(0, None))


def value_keys_of(
    prefix: str,
    by_node: Mapping[str, Iterable[SignalPub]],
    pdo_pubs: Mapping[tuple[str, tuple[str, ...]], PdoPub],
) -> list[ValueKey]:
    """Every journaled value key: the published signals', and each ``publish: pdo`` signal's."""
    out = [ValueKey(node, sp.sig, sp.scaling, sp.key, sp) for node, sps in by_node.items() for sp in sps]
    for (node, _names), pp in pdo_pubs.items():
        out += [ValueKey(node, sig, sc, value_key(prefix, node, sig.name), pp) for sig, _i, sc in pp.entries]
    return out


class ValueHistory:
    """The writer's source of value samples (see the module docstring)."""

    def __init__(
        self,
        image: ProcessImage,
        keys: list[ValueKey],
        publishes: Callable[[str], bool],
        hlc: Callable[[], HybridClock],
    ) -> None:
        self.image = image
        self.keys = keys
        #: whether this gateway publishes a node (else it journals what it hears of it)
        self.publishes = publishes
        self.hlc = hlc

    def window(self) -> list[Entry]:
        """The journal writer's window (its thread): each changed value once."""
        now = time.monotonic()
        hlc = self.hlc()
        out = []
        for vk in self.keys:
            if not self.publishes(vk.node):
                continue
            node = self.image.nodes[vk.node]
            sv = node.signals[vk.sig.name]
            if not sv.seq:
                continue
            quality = node.quality(sv, now)
            if vk.journaled == (sv.seq, quality):
                continue
            vk.journaled = (sv.seq, quality)
            seq = sv.seq + vk.pub.seq_offset
            last = vk.pub.last_pub if isinstance(vk.pub, SignalPub) else None
            if last is not None and last[0] == seq:
                payload: bytes | str = last[1]
            else:
                payload = value_json(vk.sig, sv._replace(seq=seq), quality, vk.scaling)
            out.append(Entry(ntp64_of_ns(hlc.stamp()), "value", vk.key, vk.node, seq, payload))
        return out


def restore_seqs(last: Mapping[str, int], keys: Iterable[ValueKey]) -> None:
    """Each value key's publication goes on above the highest ``seq`` journaled for it (a
    ``publish: pdo`` record above the highest of its signals)."""
    for vk in keys:
        if vk.key in last:
            with vk.pub.lock:
                vk.pub.seq_offset = max(vk.pub.seq_offset, last[vk.key])


def heard_entry(
    prefix: str,
    keys: Collection[str],
    key: str,
    payload: bytes,
    timestamp: Any,
    before: int,
) -> Entry | None:
    """The journal entry of a sample heard (``before``: the highest seq of its key known
    before it), or None: not a key we publish, not JSON with a seq, an event already had."""
    if key not in keys or timestamp is None:
        return None
    node, _, what = key[len(prefix) + 1 :].partition("/")
    kind = "value" if what.startswith("value/") else what
    if kind not in ("state", "emcy", "value"):
        return None
    try:
        seq = json.loads(payload).get("seq")
    except (ValueError, AttributeError):
        return None
    if not isinstance(seq, int) or (kind != "value" and seq <= before):
        return None  # an event journaled already (a late joiner's history repeats the cache)
    return Entry(timestamp, kind, key, node, seq, payload)
