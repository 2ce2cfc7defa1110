"""The web console: the bus and every node at a glance, commissioning from a browser.

Served by the health HTTP server (``health.host`` / ``health.port``; off when the port is 0,
or with ``web.enabled: false``). Modules:

* ``console``: HTTP routes, static files, the token check of the commissioning API;
* ``views``: the documents shown (overview, nodes table, node page), read from the process image
  and the command service;
* ``live``: server-sent events, the one hand-off from the CAN reader thread, per-client
  coalescing and bounds;
* ``commissioning``: SDO, NMT, set points, LSS inquiry (``web.writes: true`` only);
* ``pages``: each page put together at load time, the shell ``static/shell.html`` around the
  page's own part;
* ``static/``: HTML, CSS and plain JavaScript, shipped as package data (no CDN, no build step).

Imports: nothing of this package is imported by bus/, modbus/ or zenoh_bridge/.
"""
