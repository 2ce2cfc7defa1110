"""Client addresses against a list of networks (``modbus.allowed_networks``,
``ascii.allowed_networks``): one rule for every adapter that filters by address.

An IPv4 client seen on an IPv6 socket (``::ffff:10.0.0.5``) is matched as its IPv4 address; a
scope (``fe80::1%eth0``) is ignored; an address that cannot be read matches nothing.

Imports: the standard library only.
"""

from __future__ import annotations

import ipaddress
from collections.abc import Iterable

IpNetwork = ipaddress.IPv4Network | ipaddress.IPv6Network


def client_ip(peer: str) -> ipaddress.IPv4Address | ipaddress.IPv6Address | None:
    """The address of a client as text (``peername[0]``), None when it is not an IP address."""
    try:
        ip = ipaddress.ip_address(peer.split("%", 1)[0])
    except ValueError:
        return None
    if isinstance(ip, ipaddress.IPv6Address) and ip.ipv4_mapped is not None:
        return ip.ipv4_mapped
    return ip


class Networks:
    """A list of networks (``["127.0.0.0/8", "192.168.10.0/24"]``) and who is in it."""

    def __init__(self, networks: Iterable[str]) -> None:
        self.networks: list[IpNetwork] = [ipaddress.ip_network(n, strict=False) for n in networks]

    def __contains__(self, peer: object) -> bool:
        if not isinstance(peer, str):
            return False
        ip = client_ip(peer)
        return ip is not None and any(ip in net for net in self.networks)

    def __str__(self) -> str:
        return ", ".join(str(n) for n in self.networks) or "none"
