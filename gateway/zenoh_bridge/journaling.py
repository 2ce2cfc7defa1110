"""What the Zenoh bridge hands the journal (``gateway.journal``), decided here and pure of I/O:

* ``restore_seqs``: at start, every key's ``seq`` goes on above the highest the journal holds
  (events: the bridge's next ``seq`` per key; values: ``SignalPub.seq_offset``);
* ``published_values``: the journal's writer asks, once per ``journal.values_ms`` window, for
  the latest sample each value key published since the last window. Publishing costs one tuple
  assignment (``SignalPub.last_pub``, under the signal's lock, by whichever thread publishes);
  the writer reads it (one attribute read: a whole tuple) and marks what it took in
  ``SignalPub.journaled``, which only it writes;
* ``heard_entry``: a sample a pair's standby hears of the other member, as a journal entry
  (state and EMCY events it has not journaled yet, values), or None.

Imports: journal, zenoh_bridge.plan (the publications). Never zenoh, modbus/ nor bus/.
"""

from __future__ import annotations

import json
from collections.abc import Collection, Iterable, Mapping
from typing import Any

from gateway.journal import Entry
from gateway.zenoh_bridge.plan import SignalPub


def restore_seqs(
    last: Mapping[str, int],
    event_seq: dict[str, int],
    event_keys: Iterable[str],
    pubs: Iterable[SignalPub],
) -> None:
    for key in event_keys:
        if key in last:
            event_seq[key] = max(event_seq.get(key, 0), last[key])
    for sp in pubs:
        if sp.key in last:
            with sp.lock:
                sp.seq_offset = max(sp.seq_offset, last[sp.key])


def published_values(pubs: Mapping[tuple[str, str], SignalPub]) -> list[Entry]:
    """The journal writer's window (its thread): each value key's latest sample, once."""
    out = []
    for (node, _name), sp in list(pubs.items()):
        lp = sp.last_pub
        if lp is not None and lp is not sp.journaled:
            sp.journaled = lp
            stamp, seq, payload = lp
            out.append(Entry(stamp, "value", sp.key, node, seq, payload))
    return out


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
