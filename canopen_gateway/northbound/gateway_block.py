"""The gateway's own registers (input registers of ``modbus.gateway_unit_id``, 247): the
bus state, counters, version, nodes, the output watchdog's trips, the hot-standby pair's role,
and per CAN network its bus state and pair role (``network_registers``).

Pure: the table and the codes the register map (``northbound.regmap``) and the Modbus reads
(``modbus.reads``) share.

Imports: nothing of the gateway.
"""

from __future__ import annotations

#: the gateway's role in a hot-standby pair (``master.redundancy``), as the register says it
PAIR_ROLE_CODES: dict[str | None, int] = {
    None: 0,  # no pair
    "active": 1,
    "standby": 2,
    "listening": 3,
    "negotiating": 3,
    "isolated": 4,
    "duplicate": 5,
}
PAIR_ROLE_DESCRIPTION = (
    "hot-standby pair: 0 no pair, 1 active, 2 standby, 3 listening / negotiating, "
    "4 isolated (its bus down or silent), 5 out (another device has its pair id)"
)
BUS_STATE_DESCRIPTION = "CAN bus: 0 down, 1 ok, 2 error passive / bus off"
#: a bus state as the registers say it
BUS_STATE_CODES = {"down": 0, "ok": 1, "error": 2}
GATEWAY_REGS = [
    (0, "bus_state", "uint16", BUS_STATE_DESCRIPTION + " (several networks: the worst of them)"),
    (1, "frames_in", "uint32", "CAN frames received"),
    (3, "frames_out", "uint32", "CAN frames sent"),
    (5, "decode_errors", "uint32", "frames that could not be decoded"),
    (7, "unknown_cob_id", "uint32", "frames with an unexpected COB-ID"),
    (9, "bus_errors", "uint32", "CAN bus errors"),
    (11, "uptime_s", "uint32", "seconds since start"),
    (13, "version_major", "uint16", "gateway version"),
    (14, "version_minor", "uint16", ""),
    (15, "version_patch", "uint16", ""),
    (16, "nodes_configured", "uint16", "nodes in the configuration"),
    (17, "nodes_alive", "uint16", "nodes alive"),
    (18, "nodes_operational", "uint16", "nodes operational"),
    (19, "watchdog_trips", "uint32", "output watchdog trips (safe outputs written)"),
    (21, "pair_role", "uint16", PAIR_ROLE_DESCRIPTION + " (several networks: the first's)"),
    (
        22,
        "pair_master_id",
        "uint16",
        "hot-standby pair: the pair id of the master heard active (this gateway's own when it is "
        "active; a third-party master's), 0 unknown",
    ),
]
#: the gateway block's registers per CAN network (the k-th network, configured order, 0-based):
#: its bus state at ``NETWORK_BUS_STATE + k``, its pair role at ``NETWORK_PAIR_ROLE + k``
NETWORKS_REGISTER = 23
NETWORK_BUS_STATE = 24
NETWORK_PAIR_ROLE = 32
#: the most networks a gateway has (the gateway block fits below ``flat_stride``'s least, 50)
MAX_NETWORKS = NETWORK_PAIR_ROLE - NETWORK_BUS_STATE

#: one register of the gateway block: (address, name, type, description, network or None)
GatewayRegister = tuple[int, str, str, str, str | None]


def gateway_registers(networks: list[str]) -> list[GatewayRegister]:
    """The gateway block of a gateway with ``networks`` (their names, configured order):
    ``GATEWAY_REGS``, the number of networks, and each network's bus state and pair role."""
    out: list[GatewayRegister] = [(*reg, None) for reg in GATEWAY_REGS]
    out.append((NETWORKS_REGISTER, "networks", "uint16",
                "CAN networks of the gateway; the registers of each follow (configured order)",
                None))  # fmt: skip
    for k, name in enumerate(networks[:MAX_NETWORKS]):
        where = f"network {k + 1} of {len(networks)} ({name})"
        out.append(
            (NETWORK_BUS_STATE + k, "bus_state", "uint16", f"{where}: {BUS_STATE_DESCRIPTION}", name)
        )
        out.append(
            (NETWORK_PAIR_ROLE + k, "pair_role", "uint16", f"{where}: {PAIR_ROLE_DESCRIPTION}", name)
        )
    return out


def worst_bus_state(states: list[str]) -> str:
    """The bus state register 0 says for several networks: down if one is down, else error if
    one is in error, else ok."""
    for state in ("down", "error"):
        if state in states:
            return state
    return "ok" if states else "down"
