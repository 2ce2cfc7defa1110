"""The command socket (canopen_gateway.command_socket) against a stand-in command service: where it
lives and who may open it (mode 0600 in a directory of mode 0700 that must be this user's
alone), what it does with a file left by a gateway that died, with one another gateway still
answers on, with a file that is not a socket; its answers (values, bytes, the command
service's errors in its words, bad lines); and the command line's client of it
(``tools.beside.find_local_gateway``) end to end."""

from __future__ import annotations

import asyncio
import json
import logging
import socket
import stat
from pathlib import Path
from typing import Any

import pytest

from canopen_gateway.command_socket import CommandSocket, socket_paths
from canopen_gateway.config import parse_config
from canopen_gateway.errors import NodeNotOperational
from canopen_gateway.runtime.turns import LoopTurns


class Commands:
    """What the socket calls of the command service, recorded."""

    def __init__(self) -> None:
        self.calls: list[tuple[Any, ...]] = []

    async def sdo_read(self, node: str, obj: str, type_: str | None = None) -> Any:
        self.calls.append(("sdo_read", node, obj, type_))
        return b"\x0a\x0b" if type_ == "bytes" else 405

    async def sdo_write(self, node: str, obj: str, value: Any, type_: str | None = None) -> None:
        self.calls.append(("sdo_write", node, obj, value, type_))

    async def nmt(self, node: str, command: str) -> None:
        if node == "display":
            raise NodeNotOperational("display", "not alive (lost or never booted)")
        self.calls.append(("nmt", node, command))


def config(tmp_path: Path, **section: Any) -> Any:
    raw = {"gateway": {"name": "line"}, "can": {"interface": "virtual"}, "command_socket": section}
    return parse_config(raw, str(tmp_path / "line.yaml"), environ={})


async def test_the_socket_is_mode_0600_and_removed_at_stop(tmp_path: Path) -> None:
    cs = CommandSocket(config(tmp_path, path="cmd.sock"), Commands(), LoopTurns())  # type: ignore[arg-type]
    await cs.start()
    assert cs.path == tmp_path / "cmd.sock"
    assert stat.S_IMODE(cs.path.lstat().st_mode) == 0o600
    await cs.stop()
    assert not (tmp_path / "cmd.sock").exists()


async def test_a_file_left_by_a_dead_gateway_is_replaced_and_a_live_one_is_left_alone(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    path = tmp_path / "cmd.sock"
    dead = socket.socket(socket.AF_UNIX)
    dead.bind(str(path))
    dead.close()  # the file stays, nobody listens: a gateway killed
    cfg = config(tmp_path, path="cmd.sock")
    first = CommandSocket(cfg, Commands(), LoopTurns())  # type: ignore[arg-type]
    await first.start()
    assert first.server is not None
    second = CommandSocket(cfg, Commands(), LoopTurns())  # type: ignore[arg-type]
    with caplog.at_level(logging.WARNING, logger="gateway.command_socket"):
        await second.start()  # never stops a start
    assert second.path is None and path.exists()
    assert caplog.messages == [f"no command socket for the command line: {path} is in use: another gateway runs {tmp_path / 'line.yaml'}"]  # fmt: skip
    await second.stop()
    assert path.exists()  # not its file
    await first.stop()
    path.write_text("not a socket")
    with caplog.at_level(logging.WARNING, logger="gateway.command_socket"):
        await first.start()
    assert first.path is None and path.read_text() == "not a socket"
    assert caplog.messages[-1].endswith("exists and is not a socket: not removed")


async def test_the_default_directory_must_be_this_users_alone(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path))
    cfg = config(tmp_path)
    path = socket_paths(cfg)[0]
    assert path.parent == tmp_path / "canopen-gateway" and path.name.startswith("line-")
    cs = CommandSocket(cfg, Commands(), LoopTurns())  # type: ignore[arg-type]
    await cs.start()
    assert stat.S_IMODE(path.parent.lstat().st_mode) == 0o700 and cs.path == path
    await cs.stop()
    path.parent.chmod(0o755)  # another user could list and reach it
    with caplog.at_level(logging.WARNING, logger="gateway.command_socket"):
        await cs.start()
    assert cs.path is None
    assert caplog.messages == [f"no command socket for the command line: {path.parent} is not this user's alone (mode 0700): not used"]  # fmt: skip


def test_off_or_without_a_file_there_is_no_socket(tmp_path: Path) -> None:
    assert socket_paths(config(tmp_path, enabled=False)) == []
    assert socket_paths(parse_config({"can": {"interface": "virtual"}}, environ={})) == []
    # a bus other processes share: the command line opens it itself
    shared = parse_config({"can": {"interface": "remote", "channel": "ws://x/"}}, str(tmp_path / "c.yaml"), environ={})  # fmt: skip
    assert CommandSocket(shared, Commands(), LoopTurns()).path is None  # type: ignore[arg-type]


def test_with_several_networks_a_bus_of_any_network_in_process_opens_the_socket(tmp_path: Path) -> None:
    def networks(*interfaces: str) -> Any:
        nets = [{"name": f"n{k}", "can": {"interface": i, "channel": f"ws://x/{k}" if i == "remote" else f"c{k}"}}
                for k, i in enumerate(interfaces)]  # fmt: skip
        return parse_config({"gateway": {"name": "line"}, "networks": nets}, str(tmp_path / "line.yaml"), environ={})

    mixed = networks("remote", "virtual")  # the second network's bus lives in the gateway
    assert CommandSocket(mixed, Commands(), LoopTurns()).path is not None  # type: ignore[arg-type]
    assert CommandSocket(networks("remote", "remote"), Commands(), LoopTurns()).path is None  # type: ignore[arg-type]
    # a command given --network asks of its network's bus; the socket is the gateway's one
    from canopen_gateway.tools.beside import in_process_bus

    first, second = (mixed.network_view(n) for n in ("n0", "n1"))
    assert (in_process_bus(first), in_process_bus(second)) == (False, True)
    assert socket_paths(second) == socket_paths(mixed)


async def test_answers_carry_values_bytes_and_the_command_services_words(tmp_path: Path) -> None:
    commands = Commands()
    cs = CommandSocket(config(tmp_path), commands, LoopTurns())  # type: ignore[arg-type]

    async def ask(line: Any) -> dict[str, Any]:
        raw = line if isinstance(line, bytes) else json.dumps(line).encode()
        return await cs.answer(raw, "command line (pid 7)")

    assert await ask({"op": "sdo_read", "node": "wire", "object": "0x1018:01"}) == {"ok": True, "value": 405}
    assert await ask({"op": "sdo_read", "node": "wire", "object": "0x1018:01", "type": "bytes"}) == {"ok": True, "value": {"hex": "0a 0b"}}  # fmt: skip
    assert await ask({"op": "sdo_write", "node": "wire", "object": "0x6000:00", "value": "4"}) == {"ok": True}  # fmt: skip
    assert await ask({"op": "nmt", "node": "wire", "command": "stop"}) == {"ok": True}
    assert await ask({"op": "nmt", "node": "display", "command": "stop"}) == {
        "ok": False, "error": "node_not_operational",
        "message": "node display is not operational: not alive (lost or never booted)",
    }  # fmt: skip
    assert (await ask(b"nmt stop"))["error"] == "bad_request"
    assert (await ask({"op": "reboot"}))["message"] == "unknown op 'reboot': hello, sdo_read, sdo_write, nmt"
    assert (await ask({"op": "nmt"}))["error"] == "bad_request"
    assert commands.calls[2] == ("sdo_write", "wire", "0x6000:00", "4", None)


async def test_the_command_lines_client_finds_the_gateway_of_its_config(tmp_path: Path) -> None:
    from canopen_gateway.tools.beside import RemoteError, find_local_gateway

    cfg = config(tmp_path, path="cmd.sock")
    cs = CommandSocket(cfg, Commands(), LoopTurns())  # type: ignore[arg-type]
    await cs.start()
    try:
        gw = await asyncio.to_thread(find_local_gateway, cfg)
        assert gw is not None and gw.endpoint == f"its command socket {tmp_path / 'cmd.sock'}"
        try:
            assert await asyncio.to_thread(gw.sdo_read, "wire", "0x1018:01", "bytes") == b"\x0a\x0b"
            with pytest.raises(RemoteError, match="node display is not operational"):
                await asyncio.to_thread(gw.nmt, "display", "stop")
        finally:
            gw.close()
        other = config(tmp_path, path="cmd.sock").model_copy(update={"gateway": cfg.gateway.model_copy(update={"name": "other"})})  # fmt: skip
        assert await asyncio.to_thread(find_local_gateway, other) is None  # another gateway's socket
    finally:
        await cs.stop()
