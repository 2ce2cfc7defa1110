"""``canopen-gateway lss ...``: commissioning by LSS (CiA 305, SGH10 manual 4.6) and the AP05
Auto-ID (AP05 manual 5.6.2), on an own connection to the configured bus.

Actions and their arguments (``key=value`` options anywhere after the action):

=================  ========================================================================
switch-global      ``[configuration|waiting]`` (04h; no answer)
switch-selective   ``VENDOR PRODUCT REVISION SERIAL`` (40h..43h, answer 44h)
inquire            ``[vendor_id|product_code|revision|serial|node_id|all]`` (5Ah..5Eh)
set-node-id        ``NODE_ID [store] [activate]`` (11h; 17h; NMT 82h to the old id)
set-bitrate        ``KBPS [store] [activate] [delay=MS]`` (13h; 17h; 15h)
store              (17h)
auto-id            ``NODE_ID [node=ID] [profile=NAME] [timeout=S]`` (SDO to 5F0Ah:02)
fast-scan          ``[NODE_ID] [count=N] [store] [vendor=V] [product=P] [revision=R]
                   [wait=S]``: CiA 305 Fast Scan (51h, answer 4Fh) finds the unconfigured
                   slave with the lowest LSS address, serial number unknown; with NODE_ID it
                   is given that id (11h, ``store`` 17h) and switched to waiting, then the
                   next slave gets the next id, ``count`` times; parts given are not scanned;
                   ``wait`` per step (default 0.05 s)
=================  ========================================================================

Every configuration action first puts the slave in the LSS configuration state: with
``address=VENDOR:PRODUCT:REVISION:SERIAL`` by switch state global to waiting, then switch state
selective (a slave already in configuration ignores the selective switch, manual 4.6 Table 10);
without an address it continues with the slave a previous ``keep`` or ``switch-selective``
left in configuration, else switches all slaves by switch state global (then only one LSS slave
may be on the bus). At the end it switches all slaves back to waiting (``keep`` leaves them in
configuration). What a command leaves the slaves in is kept per bus in
``$XDG_STATE_HOME/canopen-gateway/lss-state.json`` (default ``~/.local/state``) for the next
command. An answer from several slaves to a service meant for one is reported. A bit rate the
profile of the config's LSS slaves does not support is refused before anything is sent. Other
options: ``timeout=S`` (answer timeout, default 1 s), ``profile=NAME`` (the LSS slave's profile
for the bit rate check).

The LSS frames and their matching come from ``canopen_gateway.bus.lss.master``; this module only does the
I/O, parses the arguments and prints. When the config simulates nodes (``simulate:``), they
run in this process on the same bus, so the commands can be tried without hardware.

Imports: python-can, canopen_gateway.bus.lss.master, canopen_gateway.bus.lss.fastscan, canopen_gateway.tools.lss_session, canopen_gateway.tools.bus_open, canopen_gateway.device.resolved,
canopen_gateway.bus.sdo.client, canopen_gateway.config, canopen_gateway.profiles, canopen_gateway.canopen.objref,
canopen_gateway.canopen.cia301, canopen_gateway.tools.beside (whether the bus is in-process); canopen_gateway.sim only
when the config simulates nodes on an in-process bus. Nothing northbound.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any, TextIO

import can

from canopen_gateway.bus.lss import master as lss
from canopen_gateway.bus.lss.fastscan import FastScan
from canopen_gateway.bus.sdo.client import SdoTransfer
from canopen_gateway.canopen.cia301 import (
    COB_NMT,
    COB_NMT_EC,
    COB_SDO_RX,
    COB_SDO_TX,
    NmtCommand,
    abort_text,
)
from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.config import Config
from canopen_gateway.device.resolved import ResolvedNode
from canopen_gateway.profiles import LoadedProfile, ProfileError, load_profile
from canopen_gateway.tools.bus_open import open_bus
from canopen_gateway.tools.lss_session import (
    LeftState,
    LssFailed,
    LssSession,
    LssStateFile,
    format_address,
)

EXIT_OK = 0
EXIT_FAILED = 1
EXIT_USAGE = 2

INQUIRE_ORDER = lss.INQUIRE_ORDER
DEFAULT_SWITCH_DELAY_MS = 100  # activate bit timing: silent d1, then d2 (SGH10 manual 4.6.2.3)


class UsageError(Exception):
    """The arguments of an action are wrong; the message says what is expected."""


# --------------------------------------------------------------------------- arguments


@dataclass
class LssArgs:
    """The action's positional words and ``key=value`` options, parsed."""

    action: str
    words: list[str] = field(default_factory=list)
    options: dict[str, str] = field(default_factory=dict)

    @classmethod
    def parse(cls, action: str, tokens: list[str]) -> LssArgs:
        out = cls(action)
        for t in tokens:
            if "=" in t:
                key, value = t.split("=", 1)
                out.options[key.strip().lower()] = value.strip()
            else:
                out.words.append(t.strip())
        return out

    def flag(self, name: str) -> bool:
        if name in self.words:
            self.words.remove(name)
            return True
        return False

    def at_most(self, n: int) -> None:
        if len(self.words) > n:
            extra = " ".join(self.words[n:])
            raise UsageError(f"unexpected argument(s): {extra}")

    def number(self, key: str, default: float) -> float:
        raw = self.options.get(key)
        if raw is None:
            return default
        try:
            return float(raw)
        except ValueError:
            raise UsageError(f"{key}={raw!r}: expected a number") from None

    def address(self) -> tuple[int, int, int, int] | None:
        raw = self.options.get("address")
        if raw is None:
            return None
        return parse_address(raw.split(":"))


def parse_int(text: str, what: str) -> int:
    try:
        return int(text.replace("_", ""), 0)
    except ValueError:
        raise UsageError(f"{what}: {text!r} is not a number (decimal or 0x...)") from None


def parse_address(parts: list[str]) -> tuple[int, int, int, int]:
    """LSS address = 1018h:01..04 vendor id, product code, revision number, serial number."""
    if len(parts) != 4:
        raise UsageError(
            "an LSS address is VENDOR PRODUCT REVISION SERIAL (1018h:01..04), e.g. "
            "address=0x195:0xFFFFFFFF:0xFFFFFFFF:12345"
        )
    names = ("vendor id", "product code", "revision number", "serial number")
    values = tuple(parse_int(p, n) for p, n in zip(parts, names, strict=True))
    for v, n in zip(values, names, strict=True):
        if not 0 <= v <= 0xFFFFFFFF:
            raise UsageError(f"{n} 0x{v:X} does not fit UNSIGNED32")
    return values  # type: ignore[return-value]


# --------------------------------------------------------------------------- actions


def _hex(v: int) -> str:
    return f"0x{v:08X} ({v})"


def do_switch_global(s: LssSession, a: LssArgs, out: TextIO) -> None:
    a.at_most(1)
    mode = a.words[0] if a.words else "configuration"
    if mode not in ("configuration", "waiting"):
        raise UsageError(f"switch-global {mode!r}: expected configuration or waiting")
    s.request(lss.switch_state_global(mode == "configuration"))
    print(f"LSS switch state global: all slaves to {mode} (no answer expected)", file=out)


def do_switch_selective(s: LssSession, a: LssArgs, out: TextIO) -> None:
    address = parse_address(a.words) if a.words else a.address()
    if address is None:
        raise UsageError("switch-selective needs VENDOR PRODUCT REVISION SERIAL")
    s.select(address)
    print(f"LSS slave {format_address(address)} in configuration", file=out)


def do_inquire(s: LssSession, a: LssArgs, out: TextIO) -> None:
    keep = a.flag("keep")
    a.at_most(1)
    what = a.words[0] if a.words else "all"
    items = INQUIRE_ORDER if what == "all" else (what.replace("-", "_"),)
    for item in items:
        if item not in INQUIRE_ORDER:
            raise UsageError(f"inquire {what!r}: one of {', '.join(INQUIRE_ORDER)} or all")
    several = 0
    with s.configuration_state(a.address(), keep=keep):
        for item in items:
            s.request(lss.inquire(item))
            values = [v for v in s.answers if isinstance(v, int)]
            shown = [str(v) if item == "node_id" else _hex(v) for v in values]
            if len(values) > 1:
                several = max(several, len(values))
                print(f"{item:<13} {len(values)} slaves answered: {', '.join(shown)}", file=out)
            else:
                print(f"{item:<13} {shown[0]}", file=out)
    if several:
        raise LssFailed(
            f"{several} LSS slaves answered: more than one is in the LSS configuration state "
            "(switch state global reaches every slave); address one with "
            "address=VENDOR:PRODUCT:REVISION:SERIAL"
        )


def do_set_node_id(s: LssSession, a: LssArgs, out: TextIO) -> None:
    store, activate, keep = a.flag("store"), a.flag("activate"), a.flag("keep")
    if len(a.words) != 1:
        raise UsageError("set-node-id needs the new NODE_ID (1..127)")
    node_id = parse_int(a.words[0], "node id")
    if not 1 <= node_id <= 127:
        raise UsageError(f"node id {node_id} out of range 1..127 (SGH10 manual 4.6.2.1)")
    if activate and keep:
        raise UsageError("activate switches the slave back to waiting; drop keep")
    old: int | None = None
    with s.configuration_state(a.address(), keep=keep):
        if activate:
            value = s.request(lss.inquire("node_id"))
            old = value if isinstance(value, int) else None
        s.configure(lss.configure_node_id(node_id))
        print(f"node id {node_id} configured", file=out)
        if store:
            s.configure(lss.store_configuration())
            print("stored (kept over power-off)", file=out)
    if not activate:
        print("the new node id applies at the next NMT reset communication or power-on", file=out)
        return
    assert old is not None
    # SGH10 manual 4.6.2.1: back in LSS waiting, the next reset communication adopts the id
    s.send_frame(COB_NMT, bytes([NmtCommand.RESET_COMMUNICATION, old]))
    if s.wait_frame(COB_NMT_EC + node_id, max(2.0, s.master.timeout_s)) is None:
        raise LssFailed(f"NMT reset communication sent to node {old}: no boot-up from {node_id}")
    print(f"node {old} reset: boot-up received from node {node_id}", file=out)


def bitrate_argument(a: LssArgs) -> tuple[int, int]:
    """(kbit/s, DS-301 table index) of ``set-bitrate KBPS`` (flags already taken)."""
    words = [w for w in a.words if w not in ("store", "activate", "keep")]
    if len(words) != 1:
        raise UsageError("set-bitrate needs the bit rate in kbit/s, e.g. set-bitrate 250")
    kbps = parse_int(words[0], "bit rate")
    try:
        return kbps, lss.bit_timing_index(kbps)
    except ValueError as exc:
        raise UsageError(str(exc)) from None


def check_bitrate_supported(cfg: Config, nodes: dict[str, ResolvedNode], a: LssArgs) -> None:
    """Refuse a bit rate an LSS slave's profile does not list (``bit_timing_indices``), e.g.
    10 kbit/s on the SGH10 (manual 4.6.2.2: "supports only ... table index 0 until 7"). The
    profiles are ``profile=NAME``, else those of the config's nodes with feature lss_slave."""
    kbps, index = bitrate_argument(a)
    name = a.options.get("profile")
    lps: dict[str, tuple[LoadedProfile, list[str]]] = {}
    if name is not None:
        try:
            lps = {name: (load_profile(name, cfg.base_dir), [])}
        except ProfileError as exc:
            raise UsageError(str(exc)) from None
    else:
        for rn in nodes.values():
            lp = rn.lp
            if "lss_slave" in lp.profile.features:
                lps.setdefault(rn.cfg.profile or rn.lp.family, (lp, []))[1].append(rn.name)
    for profile, (lp, names) in lps.items():
        feature = lp.profile.features.get("lss_slave") or {}
        indices = feature.get("bit_timing_indices")
        if indices is None or index in indices:
            continue
        rates = ", ".join(str(lss.BIT_TIMING_KBPS[i]) for i in indices if i in lss.BIT_TIMING_KBPS)
        who = f" (nodes {', '.join(names)})" if names else ""
        raise UsageError(
            f"{kbps} kbit/s (table index {index}) is not supported by profile {profile}{who}; "
            f"it supports {rates} kbit/s; nothing was sent"
        )


def do_set_bitrate(s: LssSession, a: LssArgs, out: TextIO) -> None:
    store, activate, keep = a.flag("store"), a.flag("activate"), a.flag("keep")
    kbps, index = bitrate_argument(a)
    delay_ms = int(a.number("delay", DEFAULT_SWITCH_DELAY_MS))
    with s.configuration_state(a.address(), keep=keep):
        s.configure(lss.configure_bit_timing(index))
        print(f"bit rate {kbps} kbit/s configured (table index {index})", file=out)
        if store:
            s.configure(lss.store_configuration())
            print("stored (kept over power-off)", file=out)
        if activate:
            s.request(lss.activate_bit_timing(delay_ms))
            s.left = LeftState()  # the slaves switch, boot and start in LSS waiting (4.6.2.3)
            print(
                f"activate bit timing sent: the slaves switch after {delay_ms} ms and report "
                f"after another {delay_ms} ms; reopen the bus at {kbps} kbit/s",
                file=out,
            )


def do_store(s: LssSession, a: LssArgs, out: TextIO) -> None:
    keep = a.flag("keep")
    a.at_most(0)
    with s.configuration_state(a.address(), keep=keep):
        s.configure(lss.store_configuration())
    print("LSS configuration stored", file=out)


def _auto_id_feature(cfg: Config, nodes: dict[str, ResolvedNode], a: LssArgs) -> dict[str, Any]:
    name = a.options.get("profile")
    if name is not None:
        try:
            lp = load_profile(name, cfg.base_dir)
        except ProfileError as exc:
            raise UsageError(str(exc)) from None
        feature = lp.profile.features.get("auto_id")
        if feature is None:
            raise UsageError(f"profile {name} has no feature auto_id")
        return feature
    for rn in nodes.values():
        feature = rn.lp.profile.features.get("auto_id")
        if feature is not None:
            return feature
    raise UsageError(
        "no node of the config has a profile with feature auto_id; give profile=<name>"
    )


def do_auto_id(
    s: LssSession, a: LssArgs, out: TextIO, cfg: Config, nodes: dict[str, ResolvedNode]
) -> None:
    """AP05 manual 5.6.2: SDO write of the new id to 5F0Ah:02 of the devices with the factory
    id; the one whose key is pressed answers (on 580h + old id), stores the id and boots with
    it; then look whether another device still answers with the old id."""
    if len(a.words) != 1:
        raise UsageError("auto-id needs the new NODE_ID (1..127)")
    new_id = parse_int(a.words[0], "node id")
    if not 1 <= new_id <= 127:
        raise UsageError(f"node id {new_id} out of range 1..127 (AP05 manual 5.7.2.32)")
    feature = _auto_id_feature(cfg, nodes, a)
    obj = ObjRef.parse(feature.get("object", "0x5F0A:02"))
    old_id = parse_int(str(a.options.get("node", feature.get("factory_node_id", 125))), "node")
    if not 1 <= old_id <= 127:
        raise UsageError(f"node={old_id}: out of range 1..127")
    reply_cob = int(feature.get("reply_cob_id", COB_SDO_TX + old_id))
    if "node" in a.options:
        reply_cob = COB_SDO_TX + old_id
    timeout_s = a.number("timeout", 60.0)
    # AP05 manual table 32: 67Dh 2Fh 0Ah 5Fh 02h <new id> x x x (an expedited download of 1 byte)
    write = SdoTransfer(obj.index, obj.sub, bytes([new_id]), timeout_s=timeout_s, retries=0)
    for frame in write.start(s.clock()):
        s.send_frame(COB_SDO_RX + old_id, frame)
    print(
        f"Auto-ID: {obj} = {new_id} sent to node {old_id}; press the key on the device that "
        f"shall take node id {new_id} (waiting {timeout_s:g} s)",
        file=out,
        flush=True,
    )
    answer = s.wait_frame(reply_cob, timeout_s)
    if answer is None:
        raise LssFailed(f"Auto-ID: no answer on 0x{reply_cob:03X} within {timeout_s:g} s")
    data = bytes(answer.data).ljust(8, b"\0")
    write.on_response(data, s.clock())  # an abort frame it would send is not sent: none was asked
    if write.done and write.aborted_by_server and write.abort_code is not None:
        code = write.abort_code
        raise LssFailed(f"Auto-ID refused: SDO abort 0x{code:08X} ({abort_text(code)})")
    if not write.done or write.abort_code is not None:
        raise LssFailed(f"Auto-ID: unexpected answer {data.hex(' ')}")
    print(f"Auto-ID: a device took node id {new_id}", file=out, flush=True)
    if s.wait_frame(COB_NMT_EC + new_id, 5.0) is None:
        print(f"warning: no boot-up from node {new_id} within 5 s", file=out)
    else:
        print(f"boot-up received from node {new_id}", file=out)
    # Is there another device left with the old id? Read 1000h (DS-301 upload request).
    for frame in SdoTransfer(0x1000, 0x00).start(s.clock()):
        s.send_frame(COB_SDO_RX + old_id, frame)
    if s.wait_frame(COB_SDO_TX + old_id, 0.5) is not None:
        print(f"another device still answers as node {old_id}: run auto-id for it", file=out)
    else:
        print(f"no device answers as node {old_id} any more", file=out)


def do_fast_scan(s: LssSession, a: LssArgs, out: TextIO) -> None:
    """CiA 305 Fast Scan: the LSS address of the unconfigured slave with the lowest one; with
    NODE_ID, it is given that node id (and ``store``d), then the next one ``count`` times."""
    store = a.flag("store")
    a.at_most(1)
    first = parse_int(a.words[0], "node id") if a.words else None
    count = int(a.number("count", 1))
    wait_s = a.number("wait", FAST_SCAN_WAIT_S)
    if first is None and count != 1:
        raise UsageError("count needs a first NODE_ID (each device found is given the next id)")
    if first is not None and not (1 <= first and first + count - 1 <= 127 and count >= 1):
        raise UsageError(f"node ids {first}..{first + count - 1} are not within 1..127")
    known = tuple(parse_int(a.options[k], k) if k in a.options else None
                  for k in ("vendor", "product", "revision")) + (None,)  # fmt: skip
    for k in range(count):
        scan = s.fast_scan(FastScan(known), wait_s)  # type: ignore[arg-type]
        if scan.found is None:
            if k == 0:
                raise LssFailed(f"LSS fast scan: {scan.failed}")
            print(f"fast scan: {scan.failed}; {k} of {count} given node ids", file=out)
            break
        print(f"found {format_address(scan.found)} ({scan.frames} frames)", file=out)
        if first is not None:
            s.configure(lss.configure_node_id(first + k))
            text = f"  node id {first + k} configured"
            if store:
                s.configure(lss.store_configuration())
                text += ", stored"
            print(text, file=out)
        s.request(lss.switch_state_global(False))  # waiting; one with a node id stays silent
    if first is not None:
        print("the node ids apply at the next NMT reset communication or power-on", file=out)


#: Fast Scan: how long each step waits for 4Fh answers (a few ms on a real bus)
FAST_SCAN_WAIT_S = 0.05

ACTIONS: dict[str, Callable[[LssSession, LssArgs, TextIO], None]] = {
    "switch-global": do_switch_global,
    "switch-selective": do_switch_selective,
    "inquire": do_inquire,
    "set-node-id": do_set_node_id,
    "set-bitrate": do_set_bitrate,
    "store": do_store,
    "fast-scan": do_fast_scan,
}


# --------------------------------------------------------------------------- entry point


@contextmanager
def _simulation(cfg: Config, nodes: dict[str, ResolvedNode]) -> Iterator[None]:
    """The config's simulated nodes on their own connection to the bus (commissioning drills),
    when the bus is in-process: on a shared bus (remote, socketcand, SocketCAN) the devices are
    the ones there (a ``canopen-gateway simulate`` of the config, or real ones), never doubled."""
    from canopen_gateway.tools.beside import in_process_bus

    wanted = cfg.simulated_nodes()
    if not wanted or not in_process_bus(cfg):
        yield
        return
    from canopen_gateway.sim.runner import SimRunner, build_sim_nodes

    specs = []
    for n in wanted:
        opts: dict[str, Any] = dict(cfg.simulate.options.get(n.name) or {})
        if n.name in cfg.simulate.motion:
            opts["motion"] = cfg.simulate.motion[n.name]
        specs.append((nodes[n.name].lp, n.node_id, opts))
    bus = open_bus(cfg)
    runner = SimRunner(bus, build_sim_nodes(specs)).start()
    try:
        yield
    finally:
        runner.stop()
        bus.shutdown()


def run_lss(
    cfg: Config, nodes: dict[str, ResolvedNode], args: argparse.Namespace, out: TextIO | None = None
) -> int:
    """Run ``args.action`` with ``args.args``; 0 done, 1 failed, 2 wrong arguments."""
    out = out or sys.stdout
    try:
        a = LssArgs.parse(args.action, list(args.args or []))
        timeout_s = a.number("timeout", 1.0) if args.action != "auto-id" else 1.0
        if timeout_s <= 0:
            raise UsageError("timeout must be > 0")
        if args.action != "auto-id" and args.action not in ACTIONS:
            raise UsageError(f"unknown LSS action {args.action!r}")
        if args.action == "set-bitrate":
            check_bitrate_supported(cfg, nodes, a)
        state = LssStateFile.for_bus(cfg.can.bus_kwargs())
        with _simulation(cfg, nodes):
            bus = open_bus(cfg)
            session = LssSession(bus, timeout_s, left=state.load())
            try:
                if args.action == "auto-id":
                    do_auto_id(session, a, out, cfg, nodes)
                else:
                    ACTIONS[args.action](session, a, out)
            finally:
                bus.shutdown()
                state.save(session.left)
                for line in session.warnings:
                    print(line, file=sys.stderr)
    except UsageError as exc:
        print(f"error: lss {args.action}: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except (LssFailed, lss.LssStateError, lss.LssBusy) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_FAILED
    except can.CanError as exc:
        print(f"error: CAN bus: {exc}", file=sys.stderr)
        return EXIT_FAILED
    return EXIT_OK
