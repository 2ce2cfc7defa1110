"""The command socket: the command line's local way into a running gateway whose CAN bus lives
in its process (``can.interface: virtual``): ``canopen-gateway sdo`` and ``nmt`` reach its
devices through it, with no Zenoh writes opened. ``protocol`` (pure: where the socket is, its
language of JSON lines) is read by the gateway and the command line; ``server`` is the
gateway's side, a northbound adapter like the others.

Imports: command_socket.protocol, command_socket.server.
"""

from canopen_gateway.command_socket.protocol import socket_paths
from canopen_gateway.command_socket.server import CommandSocket

__all__ = ["CommandSocket", "socket_paths"]
