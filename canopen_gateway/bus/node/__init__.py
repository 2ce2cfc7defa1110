"""The per-node owner and its parts: ``node.Node`` (the one writer of a node's state), what the
master builds for one node from its resolution (``parts.build_node``), its lifecycle
(``lifecycle``), output image (``outputs``), what it returns to the driver (``events``) and the
device features it drives (``features/``). Its boot steps and settings are resolved with the
device (``canopen_gateway.device``).

Imports: bus.sdo, bus.error_control, bus.emcy, device, pdo, image, states, objref. Never python-can,
asyncio or a northbound module.
"""
