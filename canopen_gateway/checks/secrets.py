"""Checks of the secrets a configuration names by file (``canopen-gateway check`` and every
start): the web console's token (``web.token_file``: readable, at least
``WEB_TOKEN_MIN_LENGTH`` characters), the Zenoh password (``zenoh.auth.password_file``:
not the placeholder of the examples) and the health port's TLS certificate and key
(``health.tls.cert`` / ``key``: readable, a PEM certificate and its key, ``http.tls``). A secret given in the file itself or by an environment
variable is checked by the config's own model.

A missing ``zenoh.auth.password_file`` is reported when the gateway starts (its Zenoh step
names the key); a missing ``web.token_file`` here, since the console cannot run without it.

Imports: config, http.tls (what makes the TLS context). Reads the files it checks, nothing else.
"""

from __future__ import annotations

from canopen_gateway.config import WEB_TOKEN_MIN_LENGTH, Config, placeholder_problem, read_secret
from canopen_gateway.http.tls import file_problems

Problem = tuple[str, str]


def secret_problems(cfg: Config) -> list[Problem]:
    out: list[Problem] = []
    if cfg.web.token_file is not None:
        path = cfg.path_of(cfg.web.token_file)
        try:
            token = read_secret(path)
        except OSError as exc:
            out.append(("web.token_file", f"cannot read {path}: {exc.strerror or exc}"))
        else:
            if len(token) < WEB_TOKEN_MIN_LENGTH:
                out.append(("web.token_file", f"{path} holds fewer than {WEB_TOKEN_MIN_LENGTH} "
                                              "characters: a token is at least that long"))  # fmt: skip
            elif token.isdigit():  # the one rule of web.token (config.model.WEB_TOKEN_DIGITS)
                out.append(("web.token_file", f"{path} holds digits only: mix in letters"))
    auth = cfg.zenoh.auth if cfg.zenoh.enabled else None
    if auth is not None and auth.password_file is not None:
        path = cfg.path_of(auth.password_file)
        try:
            why = placeholder_problem(read_secret(path)) if path.is_file() else None
        except OSError:
            why = None  # the start names an unreadable file, with the key
        if why:
            out.append(("zenoh.auth.password_file", f"{path}: {why}"))
    tls = cfg.health.tls
    if tls is not None:
        out += [(f"health.tls.{key}", why) for key, why in file_problems(cfg.path_of(tls.cert), cfg.path_of(tls.key))]
    return out
