"""The docs as a new user copies them: zenoh-cli commands print text (and keys where they
subscribe), the README lists every command, the systemd unit installs what it points at, the
container test stands on its own, and the web API's set example is accepted as written."""

from __future__ import annotations

import asyncio
import json
import re
import urllib.error
import urllib.request
from pathlib import Path

from canopen_gateway.cli import build_parser
from tests.helpers import gateway_of

ROOT = Path(__file__).resolve().parents[2]
DOCS = [
    ROOT / "README.md",
    *sorted((ROOT / "docs").glob("*.md")),
    *sorted((ROOT / "deploy").rglob("*.yml")),
]


def zenoh_cli_commands() -> list[tuple[Path, str]]:
    """Every zenoh-cli `get`/`subscribe` command of the docs, continuation lines joined."""
    out = []
    for path in DOCS:
        text = path.read_text(encoding="utf-8").replace("\\\n", " ")
        for line in text.splitlines():
            if re.search(r"zenoh --mode \S+ --connect \S+.*\b(get|subscribe)\b", line) or re.search(
                r"(^|\s)\$Z\s+(get|subscribe)\b", line
            ):
                out.append((path, line))
    return out


def test_every_zenoh_cli_command_decodes_text_and_subscriptions_print_keys() -> None:
    commands = zenoh_cli_commands()
    assert len(commands) >= 10
    for path, line in commands:
        assert "--decoder text" in line, f"{path.name}: {line.strip()}"
        if re.search(r"\bsubscribe\b", line) and "-k 'canopen/demo/*/emcy'" not in line:
            assert "--line '{key} {value}'" in line, f"{path.name}: {line.strip()}"


def test_the_readme_lists_every_command() -> None:
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    block = readme.split("## Command line", 1)[1].split("```", 2)[1]
    sub = next(a for a in build_parser()._actions if a.dest == "command")
    for name in sub.choices:  # type: ignore[union-attr]
        assert f"canopen-gateway {name} " in block, name


def test_the_systemd_unit_installs_what_it_points_at() -> None:
    unit = (ROOT / "deploy/systemd/canopen-gateway.service").read_text(encoding="utf-8")
    assert "pip install canopen-gateway" not in unit  # not on PyPI: the wheel is built here
    assert "pip wheel --no-deps -w dist ." in unit
    doc = re.search(r"^Documentation=file://(\S+)$", unit, re.M)
    assert doc is not None
    assert f"install -D -m 0644 docs/deploy.md {doc.group(1)}" in unit
    deploy = (ROOT / "docs/deploy.md").read_text(encoding="utf-8")
    assert f"install -D -m 0644 docs/deploy.md {doc.group(1)}" in deploy
    assert "/opt/canopen-gateway/bin/pip wheel --no-deps -w dist ." in deploy


def test_the_container_test_cites_nothing_outside_the_repository() -> None:
    script = (ROOT / "deploy/container-test.sh").read_text(encoding="utf-8")
    assert "NOTES.md" not in script


def test_the_web_api_set_example_is_accepted_as_written() -> None:
    from tests.helpers import free_port, make_config, node_operational, wait_until

    web = (ROOT / "docs/web.md").read_text(encoding="utf-8")
    row = next(line for line in web.splitlines() if line.startswith("| `POST /api/commission/set`"))
    body = json.loads(re.search(r"`(\{.*?\})`", row).group(1))  # type: ignore[union-attr]
    token = "docs-example-token-1"

    async def run() -> tuple[int, dict]:
        cfg = make_config(
            [{"name": body["node"], "node_id": 1, "profile": "sgh10"}],
            health={"port": free_port()},
            web={"writes": True, "token": token},
        )
        gw = gateway_of(cfg)
        await gw.start()
        try:
            await wait_until(lambda: node_operational(gw, body["node"]), what="operational")

            def post() -> tuple[int, dict]:
                req = urllib.request.Request(
                    f"http://127.0.0.1:{gw.health.port}/api/commission/set",
                    data=json.dumps(body).encode(),
                    method="POST",
                    headers={"Authorization": f"Bearer {token}"},
                )
                try:
                    with urllib.request.urlopen(req, timeout=10) as r:
                        return r.status, json.loads(r.read())
                except urllib.error.HTTPError as e:
                    return e.code, json.loads(e.read())

            return await asyncio.to_thread(post)
        finally:
            await gw.stop()

    code, doc = asyncio.run(run())
    assert code == 200, doc
    assert doc["raw"] == 125  # 12.5 mm with the signal's scale 0.1, as the row says
