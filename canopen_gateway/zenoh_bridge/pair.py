"""The Zenoh side of a hot-standby pair (``master.redundancy``): two gateways share one prefix
and a cloud subscriber sees them as one gateway.

* Only the gateway that masters the bus publishes (values, PDO records, raw PDOs, state and
  EMCY events, the nodes' liveliness tokens): ``ZenohBridge.publishing``. Both answer gets
  from their image; writes on the other one are answered ``not_active``.
* Liveliness: each gateway of a pair holds ``<prefix>/alive/_gateway`` (a gateway runs under
  the prefix) and its member token ``<prefix>/alive/_pair/<master.node_id>/<its pair node
  id>``; the one that masters the bus also holds ``<prefix>/alive/_active/<its pair node
  id>``, undeclared when it stands by.
* The duplicate-prefix refusal (``zenoh.refuse_duplicate_prefix``) lets a partner in: a
  gateway of a pair may start under a prefix whose ``_gateway`` token is held when a member
  token of the same logical master (another pair node id) is there too (``refusal``).
* Sequence numbers never go back at a take-over: while it does not publish, a gateway hears
  its own prefix, with the history of the other one's advanced publishers, and keeps the
  highest ``seq`` per published key (``HeardSeq``); when it
  takes over, each value key publishes from above what was heard (``SignalPub.seq_offset``)
  and each event key from max(own, heard) + 1.

Rule: what is decided here is pure (keys in, verdicts and numbers out) or a small class fed by
a zenoh callback; the bridge does the declarations (``bridge.py``, ``session.py``).

Imports: northbound.keys. Never zenoh, modbus/ nor bus/.
"""

from __future__ import annotations

import json
import threading
from collections.abc import Collection, Iterable

from canopen_gateway.northbound.keys import GATEWAY_TOKEN, alive_key

ACTIVE_TOKEN = "_active"  # <prefix>/alive/_active/<pair node id>: the one that publishes
MEMBER_TOKEN = "_pair"  # <prefix>/alive/_pair/<master node id>/<pair node id>


def active_key(prefix: str, pair_node_id: int) -> str:
    return f"{alive_key(prefix, ACTIVE_TOKEN)}/{pair_node_id}"


def member_key(prefix: str, master_node_id: int, pair_node_id: int) -> str:
    return f"{alive_key(prefix, MEMBER_TOKEN)}/{master_node_id}/{pair_node_id}"


def refusal(
    tokens: Iterable[str], prefix: str, member: tuple[int, int] | None
) -> str | None:
    """The token that keeps this gateway from starting under ``prefix`` (None: start).

    ``tokens``: the liveliness tokens present under ``<prefix>/alive/**``; ``member``: this
    gateway's (master node id, pair node id) when it is one of a pair. A gateway runs there
    when ``_gateway`` is held; a pair member may join it when a member token of the same
    logical master with another pair node id is there too; the same member twice, a stranger,
    or a gateway of another pair is refused.
    """
    present = set(tokens)
    gateway = alive_key(prefix, GATEWAY_TOKEN)
    if gateway not in present:
        return None
    if member is None:
        return gateway
    master_node_id, pair_node_id = member
    own = member_key(prefix, master_node_id, pair_node_id)
    if own in present:
        return own
    partners = alive_key(prefix, MEMBER_TOKEN) + f"/{master_node_id}/"
    if any(t.startswith(partners) for t in present):
        return None
    return gateway


class HeardSeq:
    """The highest ``seq`` heard per published key while this gateway does not publish.

    ``on_sample`` runs on a zenoh thread (a subscriber on ``<prefix>/**``): it parses the
    JSON payload of the keys it was given and keeps the maximum, under a lock; anything else
    (raw PDO bytes, a payload without ``seq``, a ``seq`` outside 0 to 2**63 - 1) is ignored.
    """

    def __init__(self, keys: Collection[str]):
        self.keys = frozenset(keys)
        self.lock = threading.Lock()
        self.highest: dict[str, int] = {}
        self.samples = 0  # samples of our keys heard

    def on_sample(self, key: str, payload: bytes) -> None:
        if key not in self.keys:
            return
        try:
            seq = json.loads(payload)["seq"]
        except (ValueError, KeyError, TypeError):
            return
        if not isinstance(seq, int) or isinstance(seq, bool) or not 0 <= seq < 1 << 63:
            return  # not a number this gateway could go on from (nor journal)
        with self.lock:
            self.samples += 1
            if seq > self.highest.get(key, 0):
                self.highest[key] = seq

    def get(self, key: str) -> int:
        with self.lock:
            return self.highest.get(key, 0)


def seq_offset(previous: int, heard: int, own: int) -> int:
    """What a value key adds to its image ``seq`` after a take-over: its next sample (own + 1
    or more) goes above the highest heard from the other gateway, and never below what it
    published itself before (``previous`` offset)."""
    return max(previous, heard - own)
