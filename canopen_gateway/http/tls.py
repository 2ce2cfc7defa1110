"""HTTPS on the health port (``health.tls: {cert, key}``): the server's TLS context, and what is
wrong with the files it is made of, in words (``canopen-gateway check`` and every start).

TLS 1.2 at least; ALPN offers ``http/1.1`` (the server speaks nothing else); no client
certificates (the console's operators carry its token). A key with a passphrase is refused
rather than asked for on a terminal the gateway does not have.

Imports: the standard library only.
"""

from __future__ import annotations

import ssl
from pathlib import Path

#: (the key under ``health.tls``, what is wrong), one per problem
Problem = tuple[str, str]


class TlsFilesError(Exception):
    """The certificate or the key cannot make a server context; ``problems`` say why."""

    def __init__(self, problems: list[Problem]) -> None:
        super().__init__("; ".join(f"{key}: {message}" for key, message in problems))
        self.problems = problems


def _refuse_passphrase() -> bytes:
    raise TlsFilesError([("key", "is encrypted with a passphrase; give the key without one")])


def server_context(cert: Path, key: Path) -> ssl.SSLContext:
    """The TLS context of the health server; ``TlsFilesError`` naming ``cert`` or ``key``."""
    problems: list[Problem] = []
    for name, path in (("cert", cert), ("key", key)):
        try:
            with path.open("rb"):
                pass
        except OSError as exc:
            problems.append((name, f"cannot read {path}: {exc.strerror or exc}"))
    if problems:
        raise TlsFilesError(problems)
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    ctx.minimum_version = ssl.TLSVersion.TLSv1_2
    ctx.set_alpn_protocols(["http/1.1"])
    try:
        ctx.load_cert_chain(cert, key, password=_refuse_passphrase)
    except ssl.SSLError as exc:
        raise TlsFilesError(
            [("cert", f"{cert} and {key} are not a PEM certificate and its private key ({exc.reason or exc})")]
        ) from None
    return ctx


def file_problems(cert: Path, key: Path) -> list[Problem]:
    """What ``server_context`` would refuse (empty: the files make a context)."""
    try:
        server_context(cert, key)
    except TlsFilesError as exc:
        return exc.problems
    return []
