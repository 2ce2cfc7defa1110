"""docs/redundancy.md, "A pair on one machine, without Docker or SocketCAN", run as written: the
code blocks of that section, in order, each run as the process it describes (the shared bus,
B's file made with ``sed``, ``check -c A -c B``, the simulated devices, gateway A, gateway B,
their ``/healthz``), with free ports in place of the doc's. Then A is killed (SIGKILL) and B's
``/healthz`` says it is active, as step 6 says.

A block's ``NAME=value`` words before the command are its environment; ``python`` and
``canopen-gateway`` are this interpreter and its entry point; ``curl -s URL`` is a GET of URL.
"""

from __future__ import annotations

import json
import os
import re
import shlex
import signal
import subprocess
import sys
import urllib.error
import urllib.request
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path
from typing import Any

import pytest

from tests.helpers import free_port, stop_process, wait_ready, wait_until_sync

pytest.importorskip("can_remote")

ROOT = Path(__file__).resolve().parents[2]
SECTION = "## A pair on one machine, without Docker or SocketCAN"
#: the ports the doc names, each replaced by a free one
DOC_PORTS = (54701, 5020, 5021, 8080, 8081, 7447, 7448)


def recipe_blocks() -> list[tuple[str, str]]:
    """``(language, text)`` of each fenced block of the section, in order, dedented."""
    doc = (ROOT / "docs" / "redundancy.md").read_text(encoding="utf-8")
    start = doc.index(SECTION)
    end = doc.find("\n## ", start + len(SECTION))
    section = doc[start : end if end >= 0 else None]
    blocks = re.findall(r"^( *)```(\w+)\n(.*?)^\1```", section, flags=re.S | re.M)
    return [(lang, "\n".join(line[len(indent) :] for line in body.splitlines())) for indent, lang, body in blocks]


def command(line: str, ports: dict[int, int]) -> tuple[dict[str, str], list[str]]:
    """A shell line of the doc as (environment, argv), with the free ports."""
    for doc_port, port in ports.items():
        line = line.replace(str(doc_port), str(port))
    words = shlex.split(line, comments=True)
    env = dict(os.environ)
    while words and re.match(r"^[A-Z_][A-Z0-9_]*=", words[0]):
        key, _, value = words.pop(0).partition("=")
        env[key] = value
    bindir = Path(sys.executable).parent
    if words[0] == "python":
        words[0] = sys.executable
    elif words[0] == "canopen-gateway":
        words[0] = str(bindir / "canopen-gateway")
    return env, words


@contextmanager
def process(argv: list[str], env: dict[str, str], cwd: Path, **kw: Any) -> Iterator[subprocess.Popen[str]]:
    proc = subprocess.Popen(argv, cwd=cwd, env=env, text=True, **kw)
    try:
        yield proc
    finally:
        stop_process(proc)


def healthz(url: str) -> dict[str, Any]:
    try:
        with urllib.request.urlopen(url, timeout=5) as r:
            return dict(json.load(r))
    except urllib.error.HTTPError as exc:  # 503 while not ready: the body says why
        return dict(json.loads(exc.read()))
    except (urllib.error.URLError, ConnectionError, json.JSONDecodeError):
        return {}


def test_the_recipe_of_a_pair_on_one_machine_runs_as_written_and_b_takes_over(tmp_path: Path) -> None:
    blocks = recipe_blocks()
    assert [lang for lang, _ in blocks] == ["sh", "yaml", "sh", "sh", "sh", "sh", "sh"]
    (_, bus), (_, config), (_, make_b), (_, simulate), (_, run_a), (_, run_b), (_, curls) = blocks
    ports = {p: free_port() for p in DOC_PORTS}
    text = config
    for doc_port, port in ports.items():
        text = text.replace(str(doc_port), str(port))
    (tmp_path / "pair-a.yaml").write_text(text)

    with ExitStack() as stack:
        env, argv = command(bus, ports)
        stack.enter_context(process(argv, env, tmp_path, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        sed_line, check_line = make_b.splitlines()
        done = subprocess.run(sed_line, shell=True, cwd=tmp_path, capture_output=True, text=True)
        assert done.returncode == 0, done.stderr
        assert "redundancy: {node_id: 102, priority: 1, peer_node_id: 101}" in (tmp_path / "pair-b.yaml").read_text()
        env, argv = command(check_line, ports)
        checked = subprocess.run(argv, env=env, cwd=tmp_path, capture_output=True, text=True)
        assert checked.returncode == 0, checked.stderr
        assert "pair-a.yaml, pair-b.yaml: a pair" in checked.stdout
        # the recipe as written is clean: no warning line (each EDS file: "0 warnings")
        assert not [line for line in checked.stdout.splitlines() if line.lstrip().startswith("warning:")], checked.stdout

        env, argv = command(simulate, ports)
        sim = stack.enter_context(process(argv, env, tmp_path, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL))
        assert sim.stdout is not None and "simulating" in sim.stdout.readline()

        logs = {}
        gws = {}
        for tag, block in (("a", run_a), ("b", run_b)):
            env, argv = command(block, ports)
            logs[tag] = tmp_path / f"{tag}.log"
            err = stack.enter_context(logs[tag].open("w"))
            gws[tag] = stack.enter_context(process(argv, env, tmp_path, stdout=subprocess.PIPE, stderr=err))
            wait_ready(gws[tag])
            if tag == "a":
                wait_until_sync(lambda: "pair: negotiating -> active" in logs["a"].read_text(), 15, "A active")

        url_a, url_b = (command(line, ports)[1][-1] for line in curls.splitlines())
        wait_until_sync(lambda: healthz(url_a).get("role") == "active", 15, "A's /healthz: active")
        wait_until_sync(lambda: healthz(url_b).get("role") == "standby", 15, "B's /healthz: standby")
        wait_until_sync(lambda: (healthz(url_b).get("peer") or {}).get("role") == "active", 15, "B hears A")

        os.kill(gws["a"].pid, signal.SIGKILL)  # step 6
        gws["a"].wait()
        wait_until_sync(lambda: "pair: negotiating -> active" in logs["b"].read_text(), 10, "B takes over")
        wait_until_sync(lambda: healthz(url_b).get("role") == "active", 10, "B's /healthz: active")
        assert set(healthz(url_b).get("nodes") or {}) == {"wire", "display"}
