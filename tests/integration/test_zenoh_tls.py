"""Zenoh over TLS with the ``zenoh.tls`` config keys: the gateway listens on tls/localhost with its
certificate; a client that trusts the CA gets values, one that does not is refused.
Certificates are made for the test with the openssl command (skipped without it)."""

from __future__ import annotations

import json
import pathlib
import queue
import shutil
import subprocess

import pytest
import zenoh

from tests.helpers import free_port, gateway_of, make_config, wait_until

pytestmark = pytest.mark.skipif(shutil.which("openssl") is None, reason="needs openssl")

P = "canopen/test"


def make_certificates(d: pathlib.Path) -> dict[str, str]:
    """A throw-away CA and a server certificate for localhost / 127.0.0.1."""

    def run(*args: str) -> None:
        subprocess.run(["openssl", *args], cwd=d, check=True, capture_output=True, timeout=30)

    run("req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", "ca.key", "-out", "ca.pem",
        "-days", "2", "-subj", "/CN=test-ca")  # fmt: skip
    run("req", "-newkey", "rsa:2048", "-nodes", "-keyout", "server.key", "-out", "server.csr",
        "-subj", "/CN=localhost")  # fmt: skip
    (d / "ext.cnf").write_text(
        "subjectAltName=DNS:localhost,IP:127.0.0.1\nbasicConstraints=CA:FALSE\n"
        "keyUsage=digitalSignature,keyEncipherment\nextendedKeyUsage=serverAuth,clientAuth\n"
    )
    run("x509", "-req", "-in", "server.csr", "-CA", "ca.pem", "-CAkey", "ca.key",
        "-CAcreateserial", "-out", "server.pem", "-days", "2", "-extfile", "ext.cnf")  # fmt: skip
    return {
        k: str(d / f) for k, f in (("ca", "ca.pem"), ("cert", "server.pem"), ("key", "server.key"))
    }


def client_config(endpoint: str, ca: str | None) -> zenoh.Config:
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    if ca is not None:
        conf.insert_json5("transport/link/tls/root_ca_certificate", json.dumps(ca))
    return conf


async def test_values_over_tls_for_a_client_that_trusts_the_ca_and_refusal_otherwise(
    tmp_path: pathlib.Path,
) -> None:
    certs = make_certificates(tmp_path)
    endpoint = f"tls/localhost:{free_port()}"
    cfg = make_config(
        [{"name": "wire", "node_id": 1, "profile": "sgh10"}],
        simulate={"nodes": "all", "motion": {"wire": {"kind": "ramp", "speed": 2000}}},
        zenoh={
            "listen": [endpoint],
            "tls": {"listen_certificate": certs["cert"], "listen_private_key": certs["key"]},
        },
    )
    gw = gateway_of(cfg)
    await gw.start()
    session = zenoh.open(client_config(endpoint, certs["ca"]))
    samples: queue.Queue[dict] = queue.Queue()
    sub = session.declare_subscriber(
        f"{P}/wire/value/position", lambda s: samples.put(json.loads(s.payload.to_bytes()))
    )
    try:
        await wait_until(lambda: gw.image.nodes["wire"].operational(), 8, "wire operational")
        await wait_until(lambda: not samples.empty(), 5, "a position over TLS")
        assert samples.get_nowait()["unit"] == "mm"
        with pytest.raises(zenoh.ZError):
            zenoh.open(client_config(endpoint, None))  # the gateway's CA is not trusted
    finally:
        sub.undeclare()
        session.close()
        await gw.stop()
