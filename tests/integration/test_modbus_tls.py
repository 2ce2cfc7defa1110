"""Modbus/TCP Security (MB-TCP-Security-v21) against pymodbus's TLS client, with certificates
made here with the ``cryptography`` package: a CA, the gateway's certificate, client
certificates carrying the role extension 1.3.6.1.4.1.50316.802.1 (UTF8String). An operator
writes (the RPDO reaches the simulated AP05), a viewer reads but its write is answered 0x01
(logged once per period, audited), a certificate of another CA, an expired one and one the CA
revoked (``modbus.tls.crl``) are refused at the handshake and never served, the audit names
the role and the certificate's subject, and plain Modbus TCP can be turned off."""

from __future__ import annotations

import asyncio
import datetime as dt
import logging
import shutil
import socket
import ssl
import subprocess
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

import pytest
from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import NameOID
from pymodbus.client import AsyncModbusTlsClient
from pymodbus.exceptions import ModbusException

from canopen_gateway.app import Gateway
from canopen_gateway.config import ConfigError
from canopen_gateway.modbus.security import ROLE_OID, access_of, certificate_role
from tests.helpers import gateway_of, make_config, wait_until

DISPLAY = {"name": "display", "node_id": 125, "profile": "ap05"}
SET_POINT1 = 100  # AP05 holding registers 100-101 (docs/modbus.md)
NOW = dt.datetime.now(dt.UTC)


def utf8string(text: str) -> bytes:
    data = text.encode()
    assert len(data) < 128
    return bytes((0x0C, len(data))) + data


class Pki:
    """A CA and the certificates it signs, written as PEM files into ``tmp``."""

    def __init__(self, tmp: Path, name: str = "Plant CA") -> None:
        self.tmp = tmp
        self.key = ec.generate_private_key(ec.SECP256R1())
        subject = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, name)])
        self.cert = (
            x509.CertificateBuilder()
            .subject_name(subject)
            .issuer_name(subject)
            .public_key(self.key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(NOW - dt.timedelta(days=1))
            .not_valid_after(NOW + dt.timedelta(days=30))
            .add_extension(x509.BasicConstraints(ca=True, path_length=None), critical=True)
            .add_extension(
                x509.KeyUsage(True, False, False, False, False, True, True, False, False), critical=True
            )
            .add_extension(x509.SubjectKeyIdentifier.from_public_key(self.key.public_key()), critical=False)
            .sign(self.key, hashes.SHA256())
        )  # fmt: skip
        self.ca_file = self._write(f"{name}.ca.pem", self.cert.public_bytes(serialization.Encoding.PEM))

    def _write(self, name: str, data: bytes) -> str:
        p = self.tmp / name.replace(" ", "_")
        p.write_bytes(data)
        return str(p)

    def issue(
        self, name: str, *, role: str | None = None, server: bool = False, expired: bool = False
    ) -> tuple[str, str]:
        """(certificate file, key file) for ``name`` signed by this CA."""
        key = ec.generate_private_key(ec.SECP256R1())
        start, end = (NOW - dt.timedelta(days=10), NOW - dt.timedelta(days=1)) if expired else (
            NOW - dt.timedelta(days=1), NOW + dt.timedelta(days=30))  # fmt: skip
        b = (
            x509.CertificateBuilder()
            .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, name)]))
            .issuer_name(self.cert.subject)
            .public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(start)
            .not_valid_after(end)
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(
                x509.AuthorityKeyIdentifier.from_issuer_public_key(self.key.public_key()), critical=False
            )
        )  # fmt: skip
        if server:
            b = b.add_extension(
                x509.SubjectAlternativeName([x509.IPAddress(__import__("ipaddress").ip_address("127.0.0.1"))]),
                critical=False,
            ).add_extension(x509.ExtendedKeyUsage([x509.oid.ExtendedKeyUsageOID.SERVER_AUTH]), critical=False)  # fmt: skip
        else:
            b = b.add_extension(
                x509.ExtendedKeyUsage([x509.oid.ExtendedKeyUsageOID.CLIENT_AUTH]), critical=False
            )
        if role is not None:
            b = b.add_extension(x509.UnrecognizedExtension(ROLE_OID, utf8string(role)), critical=False)
        cert = b.sign(self.key, hashes.SHA256())
        key_pem = key.private_bytes(
            serialization.Encoding.PEM,
            serialization.PrivateFormat.PKCS8,
            serialization.NoEncryption(),
        )
        return (
            self._write(f"{name}.pem", cert.public_bytes(serialization.Encoding.PEM)),
            self._write(f"{name}.key", key_pem),
        )


@pytest.fixture(scope="module")
def pki(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    tmp = tmp_path_factory.mktemp("pki")
    ca = Pki(tmp)
    other = Pki(tmp, "Other CA")
    return {
        "ca": ca,
        "server": ca.issue("gateway", server=True),
        "operator": ca.issue("plc1", role="Operator"),
        "viewer": ca.issue("scada1", role="Viewer"),
        "norole": ca.issue("norole"),
        "expired": ca.issue("old-plc", role="Operator", expired=True),
        "foreign": other.issue("intruder", role="Operator"),
        "revoked": ca.issue("stolen-plc", role="Operator"),
    }


def tls_section(pki: dict[str, Any], **extra: Any) -> dict[str, Any]:
    cert, key = pki["server"]
    return {"port": 0, "cert": cert, "key": key, "ca": pki["ca"].ca_file, **extra}


@asynccontextmanager
async def secure_gateway(pki: dict[str, Any], **modbus: Any) -> AsyncIterator[Gateway]:
    tls = modbus.pop("tls", tls_section(pki))
    cfg = make_config([DISPLAY], zenoh={"enabled": False}, modbus={"tls": tls, **modbus})
    gw = gateway_of(cfg)
    await gw.start()
    try:
        await wait_until(gw.image.nodes["display"].operational, 5, "display operational")
        yield gw
    finally:
        await gw.stop()


def client_for(gw: Gateway, pki: dict[str, Any], who: str) -> AsyncModbusTlsClient:
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
    ctx.minimum_version = ssl.TLSVersion.TLSv1_2
    ctx.load_verify_locations(pki["ca"].ca_file)
    cert, key = pki[who]
    ctx.load_cert_chain(cert, key)
    return AsyncModbusTlsClient("127.0.0.1", port=gw.modbus.tls_port, sslctx=ctx, timeout=2, retries=0)


def sim_set_point(gw: Gateway) -> int:
    sim = gw.sim.nodes["display"]
    return gw.sim.runner.call(lambda now: sim.get(0x5F16, 3))


async def test_operator_writes_and_viewer_reads_but_may_not_write(
    pki: dict[str, Any], caplog: pytest.LogCaptureFixture
) -> None:
    async with secure_gateway(pki) as gw:
        audit: list[dict[str, Any]] = []
        gw.commands.audit = audit.append
        operator = client_for(gw, pki, "operator")
        viewer = client_for(gw, pki, "viewer")
        assert await operator.connect() and await viewer.connect()
        try:
            rr = await operator.write_registers(SET_POINT1, [0, 4321], device_id=125)
            assert not rr.isError(), rr
            assert audit[0]["who"] == "modbus 127.0.0.1 tls role Operator subject CN=plc1"
            await wait_until(lambda: sim_set_point(gw) == 4321, 3, "operator's set point on the device")
            seen = await viewer.read_holding_registers(SET_POINT1, count=2, device_id=125)
            assert seen.registers == [0, 4321]
            ident = await viewer.read_device_information(read_code=1, device_id=125)
            assert ident.information[0] == b"SIKO GmbH", "identification is a read"
            with caplog.at_level(logging.WARNING, logger="gateway.modbus"):
                for value in (1, 2, 3):
                    rr = await viewer.write_registers(SET_POINT1, [0, value], device_id=125)
                    assert rr.isError() and rr.exception_code == 0x01
            refused = [r for r in caplog.records if "refused" in r.getMessage()]
            assert len(refused) == 1, "logged once per period"
            assert "role Viewer has read" in refused[0].getMessage()
            assert sim_set_point(gw) == 4321, "the viewer's writes never reached the device"
            (refusal,) = [r for r in audit if r["outcome"].startswith("refused")]  # once per period
            assert refusal["who"] == "modbus 127.0.0.1 tls role Viewer subject CN=scada1"
            assert "role Viewer has read" in refusal["outcome"]
        finally:
            operator.close()
            viewer.close()


async def test_plain_tcp_stays_beside_tls_or_is_turned_off(pki: dict[str, Any]) -> None:
    async with secure_gateway(pki) as gw:
        assert gw.modbus.port and gw.modbus.tls_port and gw.modbus.port != gw.modbus.tls_port
        _, w = await asyncio.open_connection("127.0.0.1", gw.modbus.port)
        w.close()
    async with secure_gateway(pki, plain=False) as gw:
        assert f"Modbus/TLS 127.0.0.1:{gw.modbus.tls_port}" in gw.summary()
        assert "Modbus TCP" not in gw.summary()
        with pytest.raises(OSError):
            await asyncio.open_connection("127.0.0.1", gw.cfg.modbus.port)
        operator = client_for(gw, pki, "operator")
        assert await operator.connect()
        try:
            rr = await operator.read_holding_registers(SET_POINT1, count=2, device_id=125)
            assert not rr.isError(), rr
        finally:
            operator.close()


async def refused(gw: Gateway, client: AsyncModbusTlsClient) -> None:
    """The handshake fails (at connect, or, with TLS 1.3, when the server checks the client's
    certificate right after): no request is ever served."""
    served = gw.modbus.store.requests
    answer = None
    try:
        if await client.connect():
            answer = await client.read_holding_registers(SET_POINT1, count=2, device_id=125)
    except (ModbusException, OSError):
        answer = None  # the connection broke at or right after the handshake: refused
    finally:
        client.close()
    assert answer is None or answer.isError(), f"a refused client got an answer: {answer}"
    assert gw.modbus.store.requests == served
    assert not [c for c in gw.modbus.connections if c.tls], "no TLS connection was accepted"


async def test_certificate_of_another_ca_is_refused_at_the_handshake(pki: dict[str, Any]) -> None:
    async with secure_gateway(pki) as gw:
        await refused(gw, client_for(gw, pki, "foreign"))


def crl_revoking(pki: dict[str, Any], who: str) -> str:
    """A PEM revocation list of the plant CA that revokes ``who``'s certificate."""
    ca = pki["ca"]
    cert = x509.load_pem_x509_certificate(Path(pki[who][0]).read_bytes())
    revoked = (
        x509.RevokedCertificateBuilder().serial_number(cert.serial_number)
        .revocation_date(NOW - dt.timedelta(hours=1)).build()
    )  # fmt: skip
    crl = (
        x509.CertificateRevocationListBuilder().issuer_name(ca.cert.subject)
        .last_update(NOW - dt.timedelta(days=1)).next_update(NOW + dt.timedelta(days=30))
        .add_revoked_certificate(revoked).sign(ca.key, hashes.SHA256())
    )  # fmt: skip
    return ca._write("plant.crl.pem", crl.public_bytes(serialization.Encoding.PEM))


async def test_a_revoked_certificate_is_refused_at_the_handshake(pki: dict[str, Any]) -> None:
    async with secure_gateway(pki, tls=tls_section(pki, crl=crl_revoking(pki, "revoked"))) as gw:
        await refused(gw, client_for(gw, pki, "revoked"))
        operator = client_for(gw, pki, "operator")
        assert await operator.connect()
        try:
            assert not (await operator.read_holding_registers(SET_POINT1, count=2, device_id=125)).isError()
        finally:
            operator.close()


async def test_expired_certificate_is_refused_at_the_handshake(pki: dict[str, Any]) -> None:
    async with secure_gateway(pki) as gw:
        await refused(gw, client_for(gw, pki, "expired"))


async def test_no_role_gets_the_default_role_or_nothing(pki: dict[str, Any]) -> None:
    async with secure_gateway(pki) as gw:
        c = client_for(gw, pki, "norole")
        assert await c.connect()
        try:
            rr = await c.read_holding_registers(SET_POINT1, count=2, device_id=125)
            assert rr.isError() and rr.exception_code == 0x01, "no role, no default: refused"
        finally:
            c.close()
    async with secure_gateway(pki, tls=tls_section(pki, default_role="Viewer")) as gw:
        c = client_for(gw, pki, "norole")
        assert await c.connect()
        try:
            rr = await c.read_holding_registers(SET_POINT1, count=2, device_id=125)
            assert not rr.isError(), rr
            rr = await c.write_registers(SET_POINT1, [0, 1], device_id=125)
            assert rr.isError() and rr.exception_code == 0x01
        finally:
            c.close()


def test_role_extension_is_read_from_the_certificate(pki: dict[str, Any]) -> None:
    der = x509.load_pem_x509_certificate(Path(pki["viewer"][0]).read_bytes()).public_bytes(
        serialization.Encoding.DER
    )
    assert certificate_role(der) == "Viewer"
    tls = make_config([], modbus={"tls": tls_section(pki)}).modbus.tls
    assert access_of(tls, der) == ("Viewer", "read")
    assert access_of(tls, None) == (None, "none")


def test_a_missing_certificate_file_is_a_config_error_naming_the_key(pki: dict[str, Any]) -> None:
    cfg = make_config([DISPLAY], modbus={"tls": tls_section(pki, cert="/nonexistent/gw.pem")})
    with pytest.raises(ConfigError) as err:
        gateway_of(cfg)
    assert "modbus.tls.cert: file /nonexistent/gw.pem does not exist" in str(err.value)


@pytest.mark.skipif(shutil.which("openssl") is None, reason="openssl command not installed")
def test_role_made_by_openssl_is_read(tmp_path: Path) -> None:
    """The role extension as OpenSSL's config syntax writes it (an independent encoder)."""
    (tmp_path / "ext.cnf").write_text(
        "[req]\ndistinguished_name = dn\n[dn]\n[v3]\n"
        "1.3.6.1.4.1.50316.802.1 = ASN1:UTF8String:Operator\n"
    )
    subprocess.run(
        ["openssl", "req", "-x509", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:P-256",
         "-nodes", "-keyout", str(tmp_path / "k.pem"), "-out", str(tmp_path / "c.pem"),
         "-subj", "/CN=plc", "-days", "2", "-extensions", "v3",
         "-config", str(tmp_path / "ext.cnf")],
        check=True, capture_output=True,
    )  # fmt: skip
    cert = x509.load_pem_x509_certificate((tmp_path / "c.pem").read_bytes())
    assert certificate_role(cert.public_bytes(serialization.Encoding.DER)) == "Operator"


async def test_a_busy_tls_port_is_named_by_its_own_key_with_the_plain_port(
    pki: dict[str, Any],
) -> None:
    """Both Modbus ports taken: one start names both, the TLS one by ``modbus.tls.port``."""
    from canopen_gateway.runtime.startup import StartupError

    holders = []
    for _ in range(2):
        h = socket.socket()
        h.bind(("127.0.0.1", 0))
        h.listen()
        holders.append(h)
    plain, secure = (h.getsockname()[1] for h in holders)
    cfg = make_config(
        [DISPLAY], zenoh={"enabled": False}, modbus={"port": plain, "tls": tls_section(pki, port=secure)}
    )
    gw = gateway_of(cfg)
    try:
        with pytest.raises(StartupError) as err:
            await gw.start()
    finally:
        for h in holders:
            h.close()
    assert [(e.key, e.value) for e in (err.value, *err.value.also)] == [
        ("modbus.port", f"{plain} on 127.0.0.1"),
        ("modbus.tls.port", f"{secure} on 127.0.0.1"),
    ]
