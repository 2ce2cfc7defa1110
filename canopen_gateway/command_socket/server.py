"""The command socket: the command line's local way into a running gateway whose bus lives
in its process (``can.interface: virtual``), where ``canopen-gateway sdo`` and ``nmt`` cannot
open the bus themselves. A Unix socket only the gateway's user can open: its directory is
made mode 0700 and must be this user's alone, the socket is mode 0600, and a client whose
kernel-given credentials (``SO_PEERCRED``) are another user's (but root) is refused. No
network, no token, nothing opened to the cloud: Zenoh writes stay off (``zenoh.writes``).

Each connection sends lines of the language of ``command_socket.protocol`` and gets its
answers in order; each request takes a turn on the event loop (``runtime.turns``: the PLC
first) and goes through the command service, the one way south, audited as asked by
``command line (pid N)``.

At start a socket file left by a gateway that died is removed; one another running gateway
answers on is left alone (a warning; this gateway runs without it): the socket never stops
a start. At stop the file is removed when it is still this gateway's.

Imports: asyncio, json, logging, os, socket, stat, pathlib, commands (the service, audit),
config, errors, command_socket.protocol, runtime.ratelimit, runtime.turns.
"""

from __future__ import annotations

import asyncio
import json
import logging
import os
import socket
import stat
from pathlib import Path
from typing import Any

from canopen_gateway.command_socket.protocol import (
    MAX_LINE_BYTES,
    answer_error,
    in_process_bus,
    line,
    peer_credentials,
    socket_paths,
    trusted,
    value_from_json,
    value_to_json,
)
from canopen_gateway.commands import CommandService
from canopen_gateway.commands.audit import acting_as
from canopen_gateway.config import Config
from canopen_gateway.errors import GatewayError
from canopen_gateway.runtime.ratelimit import RateLimitedLog
from canopen_gateway.runtime.turns import ACCEPT_BACKLOG, LoopTurns

log = logging.getLogger("gateway.command_socket")

class CommandSocket:
    """``await start()`` / ``await stop()``; ``path`` is where it listens (None: it does not)."""

    def __init__(self, cfg: Config, commands: CommandService, turns: LoopTurns) -> None:
        self.cfg = cfg
        self.commands = commands
        self.turns = turns
        paths = socket_paths(cfg) if in_process_bus(cfg) else []  # a bus of any network
        self.path: Path | None = paths[0] if paths else None
        self.server: asyncio.base_events.Server | None = None
        self.tasks: set[asyncio.Task[Any]] = set()
        self._inode: int | None = None
        self.warn = RateLimitedLog(log)
        self.requests = 0
        #: what ``hello`` tells beside the gateway's name (the application's: ``health_port``,
        #: the web port it listens on, which ``canopen-gateway fault`` posts to)
        self.facts: dict[str, Any] = {}

    async def start(self) -> None:
        path = self.path
        if path is None:
            return
        why = self._prepare(path)
        if why is not None:
            log.warning("no command socket for the command line: %s", why)
            self.path = None
            return
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        old = os.umask(0o177)  # the socket is born mode 0600: no instant with more
        try:
            sock.bind(str(path))
        except OSError as exc:
            sock.close()
            log.warning("no command socket for the command line: %s: %s", path, exc.strerror)
            self.path = None
            return
        finally:
            os.umask(old)
        os.chmod(path, 0o600)
        self._inode = os.stat(path).st_ino
        self.server = await asyncio.start_unix_server(
            self._client, sock=sock, limit=MAX_LINE_BYTES, backlog=ACCEPT_BACKLOG
        )
        log.info("command socket for the command line (this user only): %s", path)

    def _prepare(self, path: Path) -> str | None:
        """Make the default directory (0700, ours alone) and remove a socket file left by a
        gateway that died; the reason when the socket cannot be opened."""
        if not self.cfg.command_socket.path:
            try:
                path.parent.mkdir(mode=0o700, exist_ok=True)
                st = path.parent.lstat()
            except OSError as exc:
                return f"{path.parent}: {exc.strerror}"
            if not stat.S_ISDIR(st.st_mode) or st.st_uid != os.getuid() or st.st_mode & 0o077:
                return f"{path.parent} is not this user's alone (mode 0700): not used"
        try:
            st = path.lstat()
        except FileNotFoundError:
            return None
        except OSError as exc:
            return f"{path}: {exc.strerror}"
        if not stat.S_ISSOCK(st.st_mode):
            return f"{path} exists and is not a socket: not removed"
        probe = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        try:
            probe.connect(str(path))
            return f"{path} is in use: another gateway runs {self.cfg.source}"
        except OSError:
            path.unlink(missing_ok=True)  # left by a gateway that died
            return None
        finally:
            probe.close()

    async def stop(self) -> None:
        if self.server is not None:
            self.server.close()
        tasks = list(self.tasks)
        for t in tasks:
            t.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        if self.server is not None:
            await self.server.wait_closed()
            self.server = None
        path = self.path
        if path is not None and self._inode is not None:
            try:
                if path.lstat().st_ino == self._inode:
                    path.unlink()
            except OSError:
                pass
            self._inode = None

    # ------------------------------------------------------------------ one client
    async def _client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        assert task is not None
        self.tasks.add(task)
        try:
            pid, uid = peer_credentials(writer.get_extra_info("socket"))
            if not trusted(uid):  # the mode says so already; the kernel says who
                self.warn.warning(("uid", uid), "command socket: a process of user %d refused", uid)
                return
            who = "command line" + (f" (pid {pid})" if pid else "")
            while True:
                try:
                    raw = await reader.readline()
                except (asyncio.LimitOverrunError, ValueError):
                    writer.write(line(answer_error("bad_request", f"a line of more than {MAX_LINE_BYTES} bytes")))  # fmt: skip
                    break
                if not raw:
                    break
                if await self.turns.turn():
                    answer = await self.answer(raw, who)
                else:
                    answer = answer_error("busy", "the gateway is busy: ask again in a second")
                writer.write(line(answer))
                await writer.drain()
        except (ConnectionError, OSError):
            pass  # the command line went away: its request completed, its answer is dropped
        finally:
            self.tasks.discard(task)
            writer.close()

    async def answer(self, raw: bytes, who: str) -> dict[str, Any]:
        """The answer to one request line (see ``command_socket.protocol``)."""
        try:
            req = json.loads(raw)
            op = req["op"]
        except (ValueError, TypeError, KeyError):
            return answer_error("bad_request", 'a line is one JSON object with an "op"')
        if op == "hello":
            config = str(Path(self.cfg.source).resolve())
            return {"ok": True, "gateway": self.cfg.gateway.name, "config": config, "pid": os.getpid(), **self.facts}  # fmt: skip
        self.requests += 1
        try:
            with acting_as(who):  # the audit of a write names the command line
                if op == "sdo_read":
                    value = await self.commands.sdo_read(req["node"], req["object"], req.get("type"))
                    return {"ok": True, "value": value_to_json(value)}
                if op == "sdo_write":
                    value = value_from_json(req["value"])
                    await self.commands.sdo_write(req["node"], req["object"], value, req.get("type"))  # fmt: skip
                    return {"ok": True}
                if op == "nmt":
                    await self.commands.nmt(req["node"], req["command"])
                    return {"ok": True}
            return answer_error("bad_request", f"unknown op {op!r}: hello, sdo_read, sdo_write, nmt")
        except GatewayError as exc:
            return answer_error(exc.kind, str(exc))
        except (KeyError, TypeError, ValueError) as exc:
            return answer_error("bad_request", f"{type(exc).__name__}: {exc}")
        except Exception as exc:  # nothing a client sends may crash the gateway
            self.warn.warning(("internal", type(exc).__name__), "command socket request failed: %r", exc)  # fmt: skip
            return answer_error("error", f"{type(exc).__name__}: {exc}")
