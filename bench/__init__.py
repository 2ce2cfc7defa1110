"""Benchmarks of the gateway: throughput, latency, scale and start-up, each as a ratio against a
bare baseline measured in the same run (``python -m bench``; results in bench/RESULTS.md).

Nothing here is a test: figures are measured and reported, never asserted.

Imports: gateway, python-can, pymodbus, zenoh. Never a test module.
"""
