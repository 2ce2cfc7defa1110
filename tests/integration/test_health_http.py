"""The health endpoint over real HTTP on 127.0.0.1, with urllib as the client."""

from __future__ import annotations

import asyncio
import json
import urllib.error
import urllib.request

import pytest
from prometheus_client.parser import text_string_to_metric_families

from canopen_gateway.http.metrics import Metrics, NodeSample
from canopen_gateway.http.server import HealthServer, build_status

TIMEOUT_S = 5.0


async def http_get(url: str, method: str = "GET") -> tuple[int, dict[str, str], bytes]:
    """A real HTTP client (urllib) in a worker thread; 4xx/5xx are answers, not errors."""

    def fetch() -> tuple[int, dict[str, str], bytes]:
        request = urllib.request.Request(url, method=method)
        try:
            with urllib.request.urlopen(request, timeout=TIMEOUT_S) as response:
                return response.status, dict(response.headers), response.read()
        except urllib.error.HTTPError as error:
            return error.code, dict(error.headers), error.read()

    return await asyncio.wait_for(asyncio.to_thread(fetch), TIMEOUT_S + 1)


class Gateway:
    """The few facts a real gateway would feed the health server."""

    def __init__(self) -> None:
        self.bus_open = True
        self.modbus_up = True
        self.zenoh_up = True

    def status(self) -> dict:
        return build_status(
            bus_open=self.bus_open,
            modbus_up=self.modbus_up,
            zenoh_up=self.zenoh_up,
            nodes={"encoder1": {"nmt_state": "OPERATIONAL", "alive": True}},
        )


@pytest.fixture
async def served():
    gateway = Gateway()
    metrics = Metrics()
    metrics.set_node_source(lambda: [NodeSample("encoder1", "OPERATIONAL", True, 0.02)])
    server = HealthServer("127.0.0.1", 0, gateway.status, registry=metrics.registry)
    await server.start()
    try:
        yield gateway, metrics, server
    finally:
        await server.stop()


async def test_port_zero_binds_an_ephemeral_port_and_reports_it(served):
    _, _, server = served
    assert server.port > 0
    assert server.url == f"http://127.0.0.1:{server.port}"


async def test_healthz_answers_200_with_the_status_document_when_ready(served):
    _, _, server = served
    code, headers, body = await http_get(server.url + "/healthz")
    assert code == 200
    assert headers["Content-Type"] == "application/json"
    doc = json.loads(body)
    assert doc["status"] == "ready"
    assert doc["bus_open"] is True and doc["modbus_up"] is True and doc["zenoh_up"] is True
    assert doc["nodes"]["encoder1"] == {"nmt_state": "OPERATIONAL", "alive": True}


async def test_healthz_answers_503_when_the_bus_is_closed(served):
    gateway, _, server = served
    gateway.bus_open = False
    code, _, body = await http_get(server.url + "/healthz")
    assert code == 503
    doc = json.loads(body)
    assert doc["status"] == "not-ready"
    assert "CAN bus is not open" in doc["reasons"]


async def test_healthz_reflects_recovery_on_the_next_request(served):
    gateway, _, server = served
    gateway.zenoh_up = False
    assert (await http_get(server.url + "/healthz"))[0] == 503
    gateway.zenoh_up = True
    assert (await http_get(server.url + "/healthz"))[0] == 200


async def test_livez_answers_200_even_when_not_ready(served):
    gateway, _, server = served
    gateway.bus_open = False
    code, _, body = await http_get(server.url + "/livez")
    assert code == 200
    assert json.loads(body) == {"status": "alive"}


async def test_metrics_serves_prometheus_text_from_the_gateway_registry(served):
    _, metrics, server = served
    metrics.counters.frames_in = 42
    metrics.sdo_request("encoder1", "write")
    code, headers, body = await http_get(server.url + "/metrics")
    assert code == 200
    assert headers["Content-Type"].startswith("text/plain; version=")
    values = {
        (s.name, tuple(sorted(s.labels.items()))): s.value
        for family in text_string_to_metric_families(body.decode())
        for s in family.samples
    }
    assert values[("canopen_gateway_frames_in_total", ())] == 42
    assert (
        values[("canopen_gateway_sdo_requests_total", (("node", "encoder1"), ("op", "write")))] == 1
    )
    assert values[("canopen_gateway_node_data_age_seconds", (("node", "encoder1"),))] == 0.02


async def test_query_strings_are_ignored(served):
    _, _, server = served
    assert (await http_get(server.url + "/healthz?verbose=1"))[0] == 200


async def test_unknown_paths_answer_404(served):
    _, _, server = served
    assert (await http_get(server.url + "/"))[0] == 404
    assert (await http_get(server.url + "/healthz/extra"))[0] == 404


async def test_head_answers_headers_without_a_body(served):
    _, _, server = served
    code, headers, body = await http_get(server.url + "/healthz", method="HEAD")
    assert code == 200
    assert int(headers["Content-Length"]) > 0
    assert body == b""


async def test_other_methods_answer_405(served):
    _, _, server = served
    code, headers, _ = await http_get(server.url + "/healthz", method="POST")
    assert code == 405
    assert headers["Allow"] == "GET, HEAD"


async def test_metrics_path_is_404_without_a_registry():
    server = HealthServer("127.0.0.1", 0, lambda: {"status": "ready"})
    await server.start()
    try:
        assert (await http_get(server.url + "/metrics"))[0] == 404
        assert (await http_get(server.url + "/healthz"))[0] == 200
    finally:
        await server.stop()


async def test_async_status_functions_are_awaited():
    async def status() -> dict:
        await asyncio.sleep(0)
        return {"status": "not-ready", "reasons": ["starting"]}

    server = HealthServer("127.0.0.1", 0, status)
    await server.start()
    try:
        code, _, body = await http_get(server.url + "/healthz")
        assert code == 503
        assert json.loads(body)["reasons"] == ["starting"]
    finally:
        await server.stop()


async def test_a_failing_status_function_answers_500_with_the_error():
    def status() -> dict:
        raise RuntimeError("image not built")

    server = HealthServer("127.0.0.1", 0, status)
    await server.start()
    try:
        code, _, body = await http_get(server.url + "/healthz")
        assert code == 500
        doc = json.loads(body)
        assert doc["status"] == "not-ready"
        assert "image not built" in doc["reasons"][0]
    finally:
        await server.stop()


async def test_garbage_request_line_answers_400():
    server = HealthServer("127.0.0.1", 0, lambda: {"status": "ready"})
    await server.start()
    try:
        reader, writer = await asyncio.open_connection("127.0.0.1", server.port)
        writer.write(b"HELLO\r\n\r\n")
        await writer.drain()
        answer = await asyncio.wait_for(reader.read(), TIMEOUT_S)
        writer.close()
        assert answer.startswith(b"HTTP/1.1 400 Bad Request\r\n")
    finally:
        await server.stop()


async def test_a_client_that_never_finishes_its_request_is_answered_408():
    server = HealthServer("127.0.0.1", 0, lambda: {"status": "ready"}, read_timeout_s=0.1)
    await server.start()
    try:
        reader, writer = await asyncio.open_connection("127.0.0.1", server.port)
        writer.write(b"GET /healthz HTTP/1.1\r\n")
        await writer.drain()
        answer = await asyncio.wait_for(reader.read(), TIMEOUT_S)
        writer.close()
        assert answer.startswith(b"HTTP/1.1 408 Request Timeout\r\n")
    finally:
        await server.stop()


async def test_stop_closes_idle_connections_and_frees_the_port():
    server = HealthServer("127.0.0.1", 0, lambda: {"status": "ready"}, read_timeout_s=30)
    await server.start()
    port = server.port
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    writer.write(b"GET /healthz HTTP/1.1\r\n")  # incomplete: the server keeps waiting
    await writer.drain()
    await asyncio.wait_for(server.stop(), TIMEOUT_S)
    assert await asyncio.wait_for(reader.read(), TIMEOUT_S) == b""
    writer.close()
    with pytest.raises(OSError):
        await asyncio.open_connection("127.0.0.1", port)
