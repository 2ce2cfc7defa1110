"""Who may use the web console (``web.access``), on a fake clock: the Host allow-list, the
operators' endpoints with and without a token, the throttle on wrong tokens (429 with a
growing ``Retry-After``) and the streams per client."""

from __future__ import annotations

import logging
from http import HTTPStatus

import pytest

from canopen_gateway.commands.audit import RefusalAudit
from canopen_gateway.http.server import Request
from canopen_gateway.web.access import (
    BLOCK_S,
    FAILURES_LIMIT,
    MAX_BLOCK_S,
    ClientSlots,
    HostCheck,
    LoginGuard,
    Operators,
)

TOKEN = "plant-floor-token-42"


class Clock:
    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


def req(client: str = "10.0.0.9", host: str | None = None, token: str | None = None,
        cookie: str | None = None, local: str = "10.0.0.1") -> Request:  # fmt: skip
    headers = {}
    if host is not None:
        headers["host"] = host
    if token is not None:
        headers["authorization"] = f"Bearer {token}"
    if cookie is not None:
        headers["cookie"] = cookie
    return Request("GET", "/api/journal", headers=headers, client=client, local=local)


@pytest.mark.parametrize(
    ("bind", "host", "ok"),
    [
        ("127.0.0.1", "127.0.0.1:8080", True),
        ("127.0.0.1", "localhost:8080", True),
        ("127.0.0.1", "LOCALHOST", True),
        ("127.0.0.1", "[::1]:8080", True),
        ("127.0.0.1", "evil.example", False),
        ("127.0.0.1", "evil.example:8080", False),
        ("0.0.0.0", "10.0.0.1:8080", True),  # the address the request arrived at
        ("0.0.0.0", "10.0.0.2:8080", False),
        ("192.168.1.5", "192.168.1.5", True),
    ],
)
def test_the_default_hosts_are_this_machine_and_its_addresses(bind: str, host: str, ok: bool) -> None:
    refused = HostCheck(None, bind).refusal(req(host=host))
    assert (refused is None) is ok
    if not ok:
        assert refused is not None and refused.status == HTTPStatus.MISDIRECTED_REQUEST


def test_allowed_hosts_replace_the_defaults_and_a_star_allows_any() -> None:
    check = HostCheck(["gateway.plant.local", "proxy:443"], "127.0.0.1")
    assert check.refusal(req(host="gateway.plant.local:8080")) is None
    assert check.refusal(req(host="proxy:443")) is None
    assert check.refusal(req(host="proxy:80")) is not None
    assert check.refusal(req(host="localhost")) is not None
    assert HostCheck(["*"], "127.0.0.1").refusal(req(host="anything")) is None


def test_without_a_token_the_operators_endpoints_serve_this_machine_only() -> None:
    ops = Operators(None)
    assert ops.check(req(client="127.0.0.1")) is None
    assert ops.check(req(client="::1")) is None
    refused = ops.check(req(client="10.0.0.9"))
    assert refused is not None and refused.status == HTTPStatus.FORBIDDEN
    assert b"web.token" in refused.body


def test_with_a_token_they_need_it_by_header_or_by_the_login_cookie() -> None:
    ops = Operators(TOKEN)
    assert ops.check(req(client="127.0.0.1")).status == HTTPStatus.UNAUTHORIZED  # type: ignore[union-attr]
    assert ops.check(req(token=TOKEN)) is None
    login = ops.login(Request("POST", "/api/login", headers={"authorization": f"Bearer {TOKEN}"}, client="10.0.0.9"))
    cookie = login.headers["Set-Cookie"].split(";")[0]
    assert TOKEN not in cookie and "HttpOnly" in login.headers["Set-Cookie"]
    assert ops.check(req(cookie=cookie)) is None
    for _ in range(2 * FAILURES_LIMIT):  # an open page whose cookie is of an older token
        stale = ops.check(req(cookie="canopen_gateway_session=" + "0" * 64))
        assert stale is not None and stale.status == HTTPStatus.UNAUTHORIZED
    assert ops.guard.wait_s("10.0.0.9") == 0  # not counted as guesses: the address is not blocked
    assert ops.check(req(cookie=cookie), cookie_ok=False).status == HTTPStatus.UNAUTHORIZED  # type: ignore[union-attr]
    assert ops.who(req(token=TOKEN)) == "web 10.0.0.9 token"
    assert ops.who(req()) == "web 10.0.0.9"


def test_ten_wrong_tokens_from_one_address_are_answered_429_with_a_growing_retry_after(
    caplog: pytest.LogCaptureFixture,
) -> None:
    clock = Clock()
    audited: list[dict] = []
    ops = Operators(TOKEN, RefusalAudit(lambda: audited.append, clock=clock, period_s=0.0), clock=clock)
    with caplog.at_level(logging.WARNING, "gateway.web"):
        codes = [ops.check(req(token=f"guess-{i:04d}-xxxx")).status for i in range(FAILURES_LIMIT)]  # type: ignore[union-attr]
    assert codes == [HTTPStatus.FORBIDDEN] * FAILURES_LIMIT
    blocked = ops.check(req(token=TOKEN))  # the right one too: guessing stops
    assert blocked is not None and blocked.status == HTTPStatus.TOO_MANY_REQUESTS
    assert blocked.headers["Retry-After"] == str(int(BLOCK_S))
    assert ops.check(req(client="10.0.0.10", token=TOKEN)) is None  # another address
    assert any("10.0.0.9" in r.getMessage() and "wrong tokens" in r.getMessage() for r in caplog.records)
    assert len(audited) == FAILURES_LIMIT and audited[0]["who"] == "web 10.0.0.9"
    assert audited[0]["op"] == "login" and audited[0]["outcome"] == "refused: wrong token"
    clock.now += BLOCK_S
    assert ops.check(req(token=TOKEN)) is None  # the block is over
    for i in range(FAILURES_LIMIT):
        ops.check(req(token=f"guess-again-{i:04d}"))
    assert ops.check(req(token=TOKEN)).headers["Retry-After"] == str(int(2 * BLOCK_S))  # type: ignore[union-attr]


def test_the_block_grows_to_a_ceiling_and_a_quiet_address_starts_again() -> None:
    clock = Clock()
    guard = LoginGuard(clock)
    blocks = []
    for _ in range(8):
        for _ in range(FAILURES_LIMIT):
            b = guard.failed("10.0.0.9")
        blocks.append(b)
        clock.now += guard.wait_s("10.0.0.9")
    assert blocks[:4] == [BLOCK_S, 2 * BLOCK_S, 4 * BLOCK_S, 8 * BLOCK_S]
    assert max(blocks) == MAX_BLOCK_S
    clock.now += MAX_BLOCK_S + 1
    for _ in range(FAILURES_LIMIT):
        b = guard.failed("10.0.0.9")
    assert b == BLOCK_S


def test_stream_slots_are_counted_per_client() -> None:
    slots = ClientSlots(2)
    assert slots.take("a") and slots.take("a") and not slots.take("a")
    assert slots.full("a") and slots.take("b")
    slots.give("a")
    assert slots.take("a")
