"""Modbus/TCP Security (MB-TCP-Security-v21, 2018): the TLS context of the secure listener and
the authorisation of a client from its certificate.

* TLS 1.2 at least; our certificate and key from ``modbus.tls.cert`` / ``key``; client
  certificates verified against ``modbus.tls.ca`` (required unless ``require_client_cert:
  false``). An expired certificate or one signed by another CA fails the handshake: the
  client is never served.
* ``modbus.tls.crl``: the CA's certificate revocation list(s) (PEM); with it, a client whose
  certificate is revoked fails the handshake (OpenSSL's CRL check of the client's certificate).
* The identity the audit records: the role and the certificate's subject
  (``certificate_subject``, RFC 4514: ``CN=plc-line1,O=Plant``).
* The role: the certificate extension with OID 1.3.6.1.4.1.50316.802.1, an ASN.1 UTF8String
  (R-21 of the standard). ``modbus.tls.roles`` maps a role to ``read`` (reads and device
  identification) or ``write`` (everything, subject to ``read_only`` and
  ``allowed_networks`` as on plain TCP); a certificate without the extension (or no
  certificate) gets ``default_role``; a role not in ``roles``, or no role at all, gets
  ``none``: every request is answered with exception 0x01.

Imports: config, cryptography (to read the extension). No sockets: the server passes the
certificate it received.
"""

from __future__ import annotations

import ssl
from pathlib import Path
from typing import Literal

from cryptography import x509
from cryptography.x509.oid import ObjectIdentifier

from canopen_gateway.config import Config, ConfigError, ModbusTls

#: MB-TCP-Security-v21, R-21: the role extension of a client certificate
ROLE_OID = ObjectIdentifier("1.3.6.1.4.1.50316.802.1")
_UTF8STRING = 0x0C  # ASN.1 universal tag 12

Access = Literal["read", "write", "none"]


def tls_context(cfg: Config) -> ssl.SSLContext:
    """The server context of ``modbus.tls``; ConfigError naming the key when a file fails."""
    tls = cfg.modbus.tls
    assert tls is not None

    def path(name: str, value: str) -> str:
        p = Path(value)
        p = p if p.is_absolute() else cfg.base_dir / p
        if not p.is_file():
            raise ConfigError([f"{cfg.source}: modbus.tls.{name}: file {p} does not exist"])
        return str(p)

    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    ctx.minimum_version = ssl.TLSVersion.TLSv1_2  # MB-TCP-Security R-01: TLS 1.2 or later
    try:
        ctx.load_cert_chain(path("cert", tls.cert), path("key", tls.key))
    except ssl.SSLError as exc:
        raise ConfigError(
            [f"{cfg.source}: modbus.tls.cert/key: not a matching PEM certificate and key ({exc})"]
        ) from None
    for name, value, what in (("ca", tls.ca, "PEM CA certificates"),
                              ("crl", tls.crl, "a PEM certificate revocation list")):  # fmt: skip
        if not value:
            continue
        try:
            ctx.load_verify_locations(cafile=path(name, value))
        except ssl.SSLError as exc:
            raise ConfigError([f"{cfg.source}: modbus.tls.{name}: not {what} ({exc})"]) from None
    if tls.crl:
        ctx.verify_flags |= ssl.VERIFY_CRL_CHECK_LEAF
    ctx.verify_mode = ssl.CERT_REQUIRED if tls.require_client_cert else ssl.CERT_OPTIONAL
    return ctx


def _utf8string(der: bytes) -> str:
    """The text of a DER-encoded UTF8String (ValueError when it is not one)."""
    if len(der) < 2 or der[0] != _UTF8STRING:
        raise ValueError("not a UTF8String")
    n, i = der[1], 2
    if n & 0x80:  # long form: the next (n & 0x7F) bytes are the length
        k = n & 0x7F
        if not 1 <= k <= 4 or len(der) < 2 + k:
            raise ValueError("bad length")
        n, i = int.from_bytes(der[2 : 2 + k], "big"), 2 + k
    if len(der) != i + n:
        raise ValueError("length does not match")
    return der[i:].decode("utf-8")


def certificate_role(der: bytes | None) -> str | None:
    """The role named in a DER certificate (None: no certificate, or no role extension).
    ValueError when the extension is there but is not a UTF8String."""
    if not der:
        return None
    cert = x509.load_der_x509_certificate(der)
    try:
        ext = cert.extensions.get_extension_for_oid(ROLE_OID)
    except x509.ExtensionNotFound:
        return None
    value = ext.value
    raw = value.value if isinstance(value, x509.UnrecognizedExtension) else b""
    return _utf8string(raw)


def certificate_subject(der: bytes | None) -> str | None:
    """The subject of a DER certificate as RFC 4514 text (None: no certificate, or one that
    cannot be read)."""
    if not der:
        return None
    try:
        return x509.load_der_x509_certificate(der).subject.rfc4514_string()
    except ValueError:
        return None


def access_of(tls: ModbusTls, der: bytes | None) -> tuple[str | None, Access]:
    """(role, what the client may do) for the certificate a client presented."""
    try:
        role = certificate_role(der)
    except ValueError:
        return "<unreadable role>", "none"
    if role is None:
        role = tls.default_role
    if role is None:
        return None, "none"
    return role, tls.roles.get(role, "none")
