"""HTTPS on the health port (``health: {tls: {cert, key}}``) with real TLS clients (python's
ssl and http.client; curl when installed) and a certificate made here: /healthz, /livez,
/metrics and the web console over TLS, kept-alive; plain HTTP to the port gets no HTTP answer
and the server goes on; the image's HEALTHCHECK speaks HTTPS to it; ``check`` refuses a missing, unreadable or mismatched certificate or
key in one line naming the file and the key, the files relative to the config."""

from __future__ import annotations

import asyncio
import datetime
import http.client
import ipaddress
import json
import logging
import os
import shutil
import ssl
import subprocess
import sys
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

import pytest
import yaml
from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import NameOID

from canopen_gateway.app import Gateway
from canopen_gateway.cli import main
from canopen_gateway.config import ConfigError, parse_config
from canopen_gateway.http.server import HealthServer
from canopen_gateway.http.tls import server_context
from canopen_gateway.sim.faults_client import run_fault
from tests.helpers import free_port, gateway_of, make_config

TIMEOUT_S = 5.0
TOKEN = "plant-floor-token-42"


def self_signed(directory: Path, name: str = "server") -> tuple[Path, Path]:
    """A certificate for 127.0.0.1 and localhost and its key, as PEM files."""
    key = ec.generate_private_key(ec.SECP256R1())
    subject = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "canopen-gateway test")])
    now = datetime.datetime.now(datetime.UTC)
    cert = (
        x509.CertificateBuilder()
        .subject_name(subject)
        .issuer_name(subject)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=5))
        .not_valid_after(now + datetime.timedelta(days=1))
        .add_extension(x509.SubjectAlternativeName([x509.IPAddress(ipaddress.ip_address("127.0.0.1")),
                                                    x509.DNSName("localhost")]), critical=False)  # fmt: skip
        .sign(key, hashes.SHA256())
    )
    cert_path, key_path = directory / f"{name}.pem", directory / f"{name}.key"
    cert_path.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    key_path.write_bytes(key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                                           serialization.NoEncryption()))  # fmt: skip
    return cert_path, key_path


@pytest.fixture(scope="module")
def pem(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    return self_signed(tmp_path_factory.mktemp("pki"))


@asynccontextmanager
async def https_gateway(pem: tuple[Path, Path]) -> AsyncIterator[Gateway]:
    cfg = make_config(
        [{"name": "wire", "node_id": 1, "profile": "sgh10"}],
        health={"port": free_port(), "tls": {"cert": str(pem[0]), "key": str(pem[1])}}, web={"token": TOKEN},
        modbus={"enabled": False}, zenoh={"enabled": False},
    )  # fmt: skip
    gw = gateway_of(cfg)
    await gw.start()
    try:
        yield gw
    finally:
        await gw.stop()


def https_gets(port: int, cafile: Path, paths: list[str]) -> list[tuple[int, str, bytes, int]]:
    """GET each path on one HTTPS connection: status, content type, body, local port."""
    ctx = ssl.create_default_context(cafile=str(cafile))
    conn = http.client.HTTPSConnection("127.0.0.1", port, timeout=TIMEOUT_S, context=ctx)
    out = []
    for path in paths:
        conn.request("GET", path)
        r = conn.getresponse()
        assert conn.sock is not None
        out.append((r.status, r.getheader("Content-Type") or "", r.read(), conn.sock.getsockname()[1]))
    conn.close()
    return out


async def test_probes_metrics_and_the_console_are_served_over_tls(pem: tuple[Path, Path]) -> None:
    async with https_gateway(pem) as gw:
        assert gw.health is not None and gw.health.url.startswith("https://")
        answers = await asyncio.to_thread(https_gets, gw.health.port, pem[0],
                                          ["/healthz", "/livez", "/metrics", "/", "/api/overview"])  # fmt: skip
        (healthz, livez, metrics, page, overview) = answers
        assert healthz[0] == 200 and json.loads(healthz[2])["status"] == "ready"
        assert livez[0] == 200
        assert metrics[0] == 200 and b"canopen_gateway_build_info" in metrics[2]
        assert page[0] == 200 and page[1].startswith("text/html")
        assert overview[0] == 200 and json.loads(overview[2])["nodes"][0]["name"] == "wire"
        assert len({a[3] for a in answers}) == 1  # one connection, kept alive
        assert await asyncio.to_thread(run_fault, gw.cfg, "wire", "emcy", None) == 0  # `fault` over HTTPS
        assert gw.web is not None and gw.web.fault_routes.faults.state("wire")["emcy"] is not None
        if shutil.which("curl"):  # another TLS stack, when installed
            r = await asyncio.to_thread(subprocess.run, ["curl", "-sS", "--cacert", str(pem[0]),
                                        f"https://127.0.0.1:{gw.health.port}/livez"],
                                        capture_output=True, text=True, timeout=TIMEOUT_S)  # fmt: skip
            assert r.returncode == 0 and json.loads(r.stdout) == {"status": "alive"}, r.stderr


async def test_plain_http_to_the_tls_port_gets_no_http_answer_and_the_server_goes_on(
    pem: tuple[Path, Path], caplog: pytest.LogCaptureFixture
) -> None:
    async with https_gateway(pem) as gw:
        assert gw.health is not None
        with caplog.at_level(logging.WARNING):
            reader, writer = await asyncio.open_connection("127.0.0.1", gw.health.port)
            writer.write(b"GET /healthz HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
            await writer.drain()
            try:
                got = await asyncio.wait_for(reader.read(), TIMEOUT_S)
            except ConnectionResetError:
                got = b""
            writer.close()
        assert b"HTTP/" not in got  # at most a TLS alert, never a page
        assert not [r for r in caplog.records if r.levelno >= logging.ERROR]
        (healthz,) = await asyncio.to_thread(https_gets, gw.health.port, pem[0], ["/healthz"])
        assert healthz[0] == 200


def write_config(directory: Path, tls: dict[str, Any]) -> Path:
    doc = {
        "gateway": {"name": "tls"},
        "can": {"interface": "virtual", "channel": "tls-check"},
        "nodes": [{"name": "wire", "node_id": 1, "profile": "sgh10"}],
        "health": {"port": 8080, "tls": tls},
    }
    path = directory / "config.yaml"
    path.write_text(yaml.safe_dump(doc), encoding="utf-8")
    return path


def test_check_takes_cert_and_key_relative_to_the_config(tmp_path: Path) -> None:
    self_signed(tmp_path, "console")
    assert main(["check", "-c", str(write_config(tmp_path, {"cert": "console.pem", "key": "console.key"}))]) == 0


def test_check_refuses_a_missing_unreadable_or_mismatched_cert_or_key_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cert, key = self_signed(tmp_path, "console")
    _, other_key = self_signed(tmp_path, "other")
    (tmp_path / "dir.pem").mkdir()
    cases = [
        ({"cert": "missing.pem", "key": "console.key"},
         f"health.tls.cert: cannot read {tmp_path / 'missing.pem'}: No such file or directory"),
        ({"cert": "console.pem", "key": "dir.pem"}, f"health.tls.key: cannot read {tmp_path / 'dir.pem'}: Is a directory"),
        ({"cert": "console.pem", "key": str(other_key)}, f"health.tls.cert: {cert} and {other_key} are not a PEM "
                                                         "certificate and its private key"),
        ({"cert": "console.key", "key": "console.key"}, "are not a PEM certificate and its private key"),
    ]  # fmt: skip
    for tls, words in cases:
        path = write_config(tmp_path, tls)
        assert main(["check", "-c", str(path)]) == 2, tls
        err = [line for line in capsys.readouterr().err.splitlines() if "health.tls" in line]
        assert len(err) == 1 and err[0].startswith(f"{path}: health.tls.") and words in err[0], err


def test_config_errors_name_the_key_of_health_tls() -> None:
    base = {"gateway": {"name": "tls"}, "can": {"interface": "virtual", "channel": "x"}, "nodes": []}
    for tls, key in (({"cert": "a.pem"}, "health.tls.key"), ({"cert": "a.pem", "key": "b", "ca": "c"}, "health.tls.ca"),
                     ({"cert": "", "key": "b"}, "health.tls.cert")):  # fmt: skip
        with pytest.raises(ConfigError) as err:
            parse_config({**base, "health": {"port": 8080, "tls": tls}}, "plant.yaml", environ={})
        assert f"plant.yaml: {key}" in str(err.value), str(err.value)


def image_healthcheck() -> list[str]:
    """The container image's HEALTHCHECK command (Dockerfile), as Docker runs it."""
    text = (Path(__file__).resolve().parents[2] / "Dockerfile").read_text(encoding="utf-8")
    line = next(ln for ln in text.splitlines() if ln.strip().startswith("CMD [\"python3\""))
    return list(json.loads(line.strip().removeprefix("CMD ")))


async def test_the_images_healthcheck_speaks_https_to_a_tls_port_and_fails_when_not_ready(
    pem: tuple[Path, Path],
) -> None:
    state = {"status": "ready"}
    for tls in (server_context(*pem), None):
        server = HealthServer("127.0.0.1", 0, lambda: state, tls=tls)
        await server.start()
        try:
            for status, ok in (("ready", True), ("not-ready", False)):
                state["status"] = status
                env = {**os.environ, "CANOPEN_GATEWAY__HEALTH__PORT": str(server.port)}
                r = await asyncio.to_thread(subprocess.run, ["python3" if shutil.which("python3") else sys.executable,
                                            *image_healthcheck()[1:]], env=env, capture_output=True, timeout=TIMEOUT_S)  # fmt: skip
                assert (r.returncode == 0) is ok, (tls, status, r.stderr)
        finally:
            await server.stop()
