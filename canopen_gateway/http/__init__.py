"""HTTP for probes, scrapes and the web console: server.py (the HTTP/1.1 server on the event
loop, ``/healthz``, ``/livez``, ``/metrics``, the shape of the health document), connection.py
(one connection, framed by h11), messages.py (the request and its answers) and metrics.py
(the Prometheus families read from the process image). Knows nothing of CAN, Modbus or Zenoh.

Imports: nothing of the gateway (each module names its own).
"""
