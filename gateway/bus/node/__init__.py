"""The per-node owner and its parts: ``node.Node`` (the one writer of a node's state), what the
master builds for one node (``parts.build_node``), its lifecycle (``lifecycle``), boot
configuration (``boot_steps``), settings (``settings``), output image (``outputs``), what it
returns to the driver (``events``) and the device features it drives (``features/``).

Imports: bus.sdo, bus.error_control, bus.emcy, pdo, image, states, objref. Never python-can,
asyncio or a northbound module.
"""
