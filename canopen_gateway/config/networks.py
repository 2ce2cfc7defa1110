"""What one file can say about its CAN networks (``networks:``) before its sections validate,
read on the data as written: the ``networks:`` form given together with a top-level ``can:``,
``master:`` or ``nodes:`` (the single-network form), two networks of one name, two networks on
one bus; and every node entry of either form with its key path and its network, for the checks
across nodes (``config.load``: a node id twice on one network, a node name twice in the
gateway, two nodes on one Modbus unit).

Imports: config.model (the names of a network's sections). Nothing of bus/, checks.
"""

from __future__ import annotations

from typing import Any

from canopen_gateway.config.model import DEFAULT_NETWORK, NETWORK_KEYS

Problem = tuple[str, str]

#: what tells two buses apart in a ``can:`` section (python-can's keys)
BUS_KEYS = ("interface", "channel", "host", "port")


def network_problems(raw: dict[str, Any]) -> list[Problem]:
    """The ``networks:`` form's own problems (see the module docstring), one line each."""
    nets = raw.get("networks")
    if nets is None:
        return []
    out: list[Problem] = [
        (key, f"the single-network form's {key}: cannot be given with networks: (each network "
              f"has its own can:, master: and nodes:); move it into networks[] or remove networks:")
        for key in NETWORK_KEYS if key in raw
    ]  # fmt: skip
    if not isinstance(nets, list):
        return out  # the schema says what a list needs
    if not nets:
        out.append(("networks", "empty: give at least one network, or the single-network form"))
    names: dict[str, int] = {}
    buses: dict[tuple[Any, ...], int] = {}
    for k, net in enumerate(nets):
        if not isinstance(net, dict):
            continue
        name = net.get("name")
        if isinstance(name, str):
            if name in names:
                out.append((f"networks[{k}].name",
                            f"duplicate network name {name!r} (also networks[{names[name]}])"))  # fmt: skip
            else:
                names[name] = k
        can = net.get("can")
        if isinstance(can, dict):
            bus = tuple(str(can.get(key)) for key in BUS_KEYS)
            if bus in buses:
                said = ", ".join(f"{key} {can[key]}" for key in BUS_KEYS if can.get(key) is not None)
                out.append((f"networks[{k}].can",
                            f"the same bus as networks[{buses[bus]}] ({said}): each network "
                            "is a bus of its own (another channel)"))  # fmt: skip
            else:
                buses[bus] = k
    return out


def node_entries(raw: dict[str, Any]) -> list[tuple[str, Any, str]]:
    """Every node entry as written, with its key path (``nodes[1]``, ``networks[0].nodes[1]``)
    and the name of its network (``default`` in the single form)."""
    nets = raw.get("networks")
    if nets is None:
        nodes = raw.get("nodes") or []
        if not isinstance(nodes, list):
            return []
        return [(f"nodes[{i}]", n, DEFAULT_NETWORK) for i, n in enumerate(nodes)]
    out: list[tuple[str, Any, str]] = []
    for k, net in enumerate(nets if isinstance(nets, list) else []):
        if not isinstance(net, dict) or not isinstance(net.get("nodes"), list):
            continue
        name = str(net.get("name", f"networks[{k}]"))
        out += [(f"networks[{k}].nodes[{i}]", n, name) for i, n in enumerate(net["nodes"])]
    return out
