"""LSS master frames byte for byte against the SGH10 manual 4.6 (frames copied here as data),
and the request/answer matching machine with a fake clock."""

from __future__ import annotations

import math
from typing import Any

import pytest

from canopen_gateway.bus.lss.master import (
    COB_ID_MASTER_TO_SLAVE,
    COB_ID_SLAVE_TO_MASTER,
    ConfigAnswer,
    LssAnswered,
    LssBusy,
    LssIgnored,
    LssMaster,
    LssMode,
    LssStateError,
    LssTimedOut,
    activate_bit_timing,
    bit_timing_index,
    configure_bit_timing,
    configure_node_id,
    decode_answer,
    inquire,
    store_configuration,
    switch_state_global,
    switch_state_selective,
)

# SGH10 manual 4.6: LSS number of the SGH10
SGH10_VENDOR_ID = 0x00000195
SGH10_PRODUCT_CODE = 0xFFFFFFFF
SGH10_REVISION = 0xFFFFFFFF
SERIAL = 0x12345678


def hx(text: str) -> bytes:
    return bytes.fromhex(text)


def configured_master(timeout_s: float = 1.0) -> LssMaster:
    m = LssMaster(timeout_s)
    m.send(switch_state_global(True), 0.0)
    return m


class TestFramesAgainstManual:
    def test_cob_ids(self) -> None:
        # SGH10 manual 4.6: LSS (rx) master -> SGH10 7E5h, LSS (tx) SGH10 -> master 7E4h
        assert COB_ID_MASTER_TO_SLAVE == 0x7E5
        assert COB_ID_SLAVE_TO_MASTER == 0x7E4

    def test_switch_state_global(self) -> None:  # 4.6.1.1
        assert switch_state_global(True).frames == (hx("04 01 00 00 00 00 00 00"),)
        assert switch_state_global(False).frames == (hx("04 00 00 00 00 00 00 00"),)
        assert switch_state_global(True).answer_cs is None

    def test_switch_state_selective_sends_the_four_lss_address_parts(self) -> None:  # 4.6.1.2
        req = switch_state_selective(SGH10_VENDOR_ID, SGH10_PRODUCT_CODE, SGH10_REVISION, SERIAL)
        assert req.frames == (
            hx("40 95 01 00 00 00 00 00"),
            hx("41 FF FF FF FF 00 00 00"),
            hx("42 FF FF FF FF 00 00 00"),
            hx("43 78 56 34 12 00 00 00"),
        )
        assert req.answer_cs == 0x44

    def test_configure_node_id(self) -> None:  # 4.6.2.1
        assert configure_node_id(0x05).frames == (hx("11 05 00 00 00 00 00 00"),)
        assert configure_node_id(0x7F).frames == (hx("11 7F 00 00 00 00 00 00"),)
        for bad in (0, 128):
            with pytest.raises(ValueError, match="1..127"):
                configure_node_id(bad)

    def test_configure_bit_timing_with_ds301_table(self) -> None:  # 4.6.2.2
        assert configure_bit_timing(3).frames == (hx("13 00 03 00 00 00 00 00"),)
        with pytest.raises(ValueError, match="reserved"):
            configure_bit_timing(5)

    def test_bit_timing_table(self) -> None:  # 4.6.2.2 table index
        assert [bit_timing_index(k) for k in (1000, 800, 500, 250, 125, 50, 20, 10)] == [
            0, 1, 2, 3, 4, 6, 7, 8,
        ]  # fmt: skip
        with pytest.raises(ValueError, match="100 kbit/s is not"):
            bit_timing_index(100)

    def test_activate_bit_timing_delay_is_lsb_first(self) -> None:  # 4.6.2.3
        assert activate_bit_timing(0x01F4).frames == (hx("15 F4 01 00 00 00 00 00"),)
        assert activate_bit_timing(500).answer_cs is None

    def test_store_configuration(self) -> None:  # 4.6.2.4
        assert store_configuration().frames == (hx("17 00 00 00 00 00 00 00"),)

    @pytest.mark.parametrize(
        ("what", "cs"),
        [("vendor_id", 0x5A), ("product_code", 0x5B), ("revision", 0x5C), ("serial", 0x5D),
         ("node_id", 0x5E)],
    )  # fmt: skip
    def test_inquire_requests(self, what: str, cs: int) -> None:  # 4.6.3.1 - 4.6.3.5
        req = inquire(what)
        assert req.frames == (bytes([cs, 0, 0, 0, 0, 0, 0, 0]),)
        assert req.answer_cs == cs

    def test_every_frame_is_eight_bytes(self) -> None:
        reqs = [
            switch_state_global(True),
            switch_state_selective(1, 2, 3, 4),
            configure_node_id(1),
            configure_bit_timing(0),
            activate_bit_timing(0),
            store_configuration(),
            inquire("serial"),
        ]
        assert all(len(f) == 8 for r in reqs for f in r.frames)


class TestAnswers:
    def test_vendor_id_answer_is_little_endian_in_bytes_1_to_4(self) -> None:  # 4.6.3.1
        assert decode_answer(hx("5A 95 01 00 00 00 00 00")) == (0x5A, 0x195)

    def test_node_id_answer(self) -> None:  # 4.6.3.5
        assert decode_answer(hx("5E 01 00 00 00 00 00 00")) == (0x5E, 1)

    def test_configure_answers_with_error_texts(self) -> None:
        cs, ok = decode_answer(hx("11 00 00 00 00 00 00 00"))
        assert isinstance(ok, ConfigAnswer) and ok.ok and ok.text == "ok"
        _, bad = decode_answer(hx("11 01 00 00 00 00 00 00"))
        assert isinstance(bad, ConfigAnswer) and not bad.ok
        assert bad.text == "no valid node id (01h..7Fh)"
        _, rate = decode_answer(hx("13 01 00 00 00 00 00 00"))
        assert isinstance(rate, ConfigAnswer) and "baud rate" in rate.text
        _, store = decode_answer(hx("17 02 00 00 00 00 00 00"))
        assert isinstance(store, ConfigAnswer) and store.text == "error occurred during storing"
        _, impl = decode_answer(hx("17 FF 2A 00 00 00 00 00"))
        assert isinstance(impl, ConfigAnswer) and "spec error 0x2A" in impl.text

    def test_unknown_cs_is_rejected(self) -> None:
        with pytest.raises(ValueError, match="0x99"):
            decode_answer(hx("99 00 00 00 00 00 00 00"))


class TestLssMaster:
    def test_request_answered_within_timeout(self) -> None:
        m = configured_master()
        frames = m.send(inquire("vendor_id"), 1.0)
        assert frames == [hx("5A 00 00 00 00 00 00 00")]
        out = m.on_frame(hx("5A 95 01 00 00 00 00 00"), 1.2)
        assert out == [LssAnswered(inquire("vendor_id"), 0x195)]
        assert m.pending is None

    def test_timeout_exactly_after_deadline(self) -> None:
        m = configured_master(timeout_s=0.5)
        m.send(configure_node_id(5), 2.0)
        assert m.poll(2.5) == []
        out = m.poll(math.nextafter(2.5, math.inf))
        assert out == [LssTimedOut(configure_node_id(5), 0.5)]
        assert m.pending is None and m.timeouts == 1
        assert m.poll(3.0) == []

    def test_answer_after_timeout_is_ignored(self) -> None:
        m = configured_master(timeout_s=0.5)
        m.send(store_configuration(), 0.0)
        m.poll(1.0)
        out = m.on_frame(hx("17 00 00 00 00 00 00 00"), 1.1)
        assert len(out) == 1 and isinstance(out[0], LssIgnored)

    def test_answer_with_other_cs_does_not_complete_the_request(self) -> None:
        m = configured_master()
        m.send(inquire("serial"), 0.0)
        out = m.on_frame(hx("5A 95 01 00 00 00 00 00"), 0.1)
        assert isinstance(out[0], LssIgnored)
        assert m.pending is not None
        out = m.on_frame(hx("5D 78 56 34 12 00 00 00"), 0.2)
        assert out == [LssAnswered(inquire("serial"), SERIAL)]

    def test_one_request_at_a_time(self) -> None:
        m = configured_master()
        m.send(inquire("node_id"), 0.0)
        with pytest.raises(LssBusy, match="inquire node id"):
            m.send(inquire("serial"), 0.1)

    def test_requests_without_answer_leave_nothing_pending(self) -> None:
        m = configured_master()
        assert m.send(activate_bit_timing(100), 0.0) == [hx("15 64 00 00 00 00 00 00")]
        assert m.pending is None and m.next_deadline() is None

    def test_configuration_services_refused_in_waiting_state(self) -> None:
        m = LssMaster()
        assert m.mode is LssMode.WAITING  # SGH10 manual 4.6: slaves start in LSS waiting
        with pytest.raises(LssStateError, match="Table 10"):
            m.send(configure_node_id(5), 0.0)
        m.send(switch_state_global(True), 0.0)
        assert m.mode is LssMode.CONFIGURATION
        m.send(switch_state_global(False), 0.0)
        assert m.mode is LssMode.WAITING

    def test_selective_switch_confirmed_puts_master_in_configuration_mode(self) -> None:
        m = LssMaster()
        req = switch_state_selective(SGH10_VENDOR_ID, SGH10_PRODUCT_CODE, SGH10_REVISION, SERIAL)
        assert len(m.send(req, 0.0)) == 4
        assert m.on_frame(hx("44 00 00 00 00 00 00 00"), 0.05) == [LssAnswered(req, None)]
        assert m.mode is LssMode.CONFIGURATION

    def test_resumed_configuration_state_allows_the_configuration_services(self) -> None:
        m = LssMaster()
        m.resume(LssMode.CONFIGURATION)  # a previous session left the slave in configuration
        assert m.send(store_configuration(), 0.0) == [hx("17 00 00 00 00 00 00 00")]
        assert m.on_frame(hx("17 00 00 00 00 00 00 00"), 0.01)[0] == LssAnswered(
            store_configuration(), ConfigAnswer(0x17, 0, 0)
        )

    def test_unmatched_selective_switch_times_out_and_stays_waiting(self) -> None:
        m = LssMaster(timeout_s=0.2)
        m.send(switch_state_selective(1, 2, 3, 4), 0.0)
        assert isinstance(m.poll(0.3)[0], LssTimedOut)
        assert m.mode is LssMode.WAITING

    def test_frame_without_pending_request_is_ignored(self) -> None:
        m = LssMaster()
        out = m.on_frame(hx("44 00 00 00 00 00 00 00"), 0.0)
        assert out == [LssIgnored(hx("44 00 00 00 00 00 00 00"), "no LSS request pending")]

    def test_full_node_id_change_sequence(self) -> None:
        """Switch selective, configure node id, store, back to waiting (4.6.2.1)."""
        m = LssMaster()
        sent: list[bytes] = []
        sent += m.send(switch_state_selective(SGH10_VENDOR_ID, SGH10_PRODUCT_CODE,
                                              SGH10_REVISION, SERIAL), 0.0)  # fmt: skip
        m.on_frame(hx("44 00 00 00 00 00 00 00"), 0.01)
        sent += m.send(configure_node_id(0x0A), 0.02)
        (ans,) = m.on_frame(hx("11 00 00 00 00 00 00 00"), 0.03)
        assert isinstance(ans, LssAnswered) and isinstance(ans.value, ConfigAnswer)
        assert ans.value.ok
        sent += m.send(store_configuration(), 0.04)
        m.on_frame(hx("17 00 00 00 00 00 00 00"), 0.05)
        sent += m.send(switch_state_global(False), 0.06)
        assert [f[0] for f in sent] == [0x40, 0x41, 0x42, 0x43, 0x11, 0x17, 0x04]
        assert sent[4] == hx("11 0A 00 00 00 00 00 00")
        assert sent[-1] == hx("04 00 00 00 00 00 00 00")


class TestLssServiceOfTheMaster:
    """LSS while the gateway runs: the master's service sends on its connection, takes the
    7E4h frames from the reader's hand-off and times out on the bus clock (fake here)."""

    @staticmethod
    def _service(now: list[float], sent: list[tuple[int, bytes]]) -> Any:
        from canopen_gateway.bus.lss.service import LssService

        svc = LssService(
            lambda cob, data: sent.append((cob, data)),
            lambda fn, *args: fn(*args),  # the hand-off, run at once
            lambda: now[0],
            lambda msg: now[0],
            timeout_s=0.5,
        )
        svc.machine.resume(LssMode.CONFIGURATION)  # a slave in configuration already
        return svc

    async def test_an_answer_on_7e4h_resolves_the_request(self) -> None:
        import asyncio

        import can

        now, sent = [0.0], []
        svc = self._service(now, sent)
        task = asyncio.create_task(svc.request(inquire("node_id")))
        await asyncio.sleep(0)  # the request goes out
        assert sent == [(0x7E5, bytes([0x5E, 0, 0, 0, 0, 0, 0, 0]))]
        svc.reader_handler()(can.Message(arbitration_id=0x7E4, data=bytes([0x5E, 7, 0, 0, 0, 0, 0, 0])))
        assert await task == 7
        svc.stop()

    async def test_an_unanswered_request_fails_just_after_its_deadline(self) -> None:
        import asyncio

        from canopen_gateway.errors import LssFailed

        now, sent = [0.0], []
        svc = self._service(now, sent)
        task = asyncio.create_task(svc.request(inquire("node_id")))
        await asyncio.sleep(0)
        now[0] = 0.5
        svc._poll()
        await asyncio.sleep(0)
        assert not task.done(), "at the deadline itself it still waits"
        now[0] = math.nextafter(0.5, 1.0)
        svc._poll()
        with pytest.raises(LssFailed, match="no answer on 0x7E4 within 0.5 s"):
            await task
        svc.stop()

    async def test_a_request_the_bus_refuses_leaves_nothing_pending(self) -> None:
        import can

        now = [0.0]

        def refused(cob: int, data: bytes) -> None:
            raise can.CanOperationError("CAN bus is down")

        from canopen_gateway.bus.lss.service import LssService

        svc = LssService(refused, lambda fn, *args: fn(*args), lambda: now[0], lambda m: now[0])
        svc.machine.resume(LssMode.CONFIGURATION)
        with pytest.raises(can.CanError):
            await svc.request(inquire("node_id"))
        assert svc.machine.pending is None, "the next request is not refused as busy"



class FastScanSlaves:
    """Unconfigured LSS slaves answering Fast Scan (CiA 305) and configure node id / store as
    each frame is sent, through the service's reader hand-off (the next loop iteration): the
    bus of a Fast Scan without a clock."""

    def __init__(self, serials: list[int], refuse_node_id: bool = False) -> None:
        self.addresses = [(SGH10_VENDOR_ID, SGH10_PRODUCT_CODE, SGH10_REVISION, s) for s in serials]
        self.part = [0] * len(serials)
        self.configuring: int | None = None  # the slave in LSS configuration
        self.node_ids: dict[int, int] = {}
        self.refuse_node_id = refuse_node_id
        self.svc: Any = None

    def answer(self, data: bytes) -> None:
        import can

        self.svc.reader_handler()(can.Message(arbitration_id=0x7E4, data=data.ljust(8, b"\0")))

    def send(self, cob: int, data: bytes) -> None:
        import struct

        if data[0] == 0x51:  # Fast Scan: IDNumber, BitChecked, LSSSub, LSSNext
            id_number, bit, sub, nxt = struct.unpack_from("<IBBB", data, 1)
            answered = False
            for i, address in enumerate(self.addresses):
                if i in self.node_ids or self.configuring is not None:
                    continue
                if bit == 0x80:
                    self.part[i] = 0
                elif sub != self.part[i] or (address[sub] >> bit) != (id_number >> bit):
                    continue
                else:
                    self.part[i] = nxt
                    if bit == 0 and nxt < sub:
                        self.configuring = i
                answered = True
            if answered:
                self.answer(bytes([0x4F]))
        elif data[0] == 0x11 and self.configuring is not None:  # configure node id
            if self.refuse_node_id:
                return self.answer(bytes([0x11, 0x01, 0x00]))
            self.node_ids[self.configuring] = data[1]
            self.answer(bytes([0x11, 0x00, 0x00]))
        elif data[0] == 0x17 and self.configuring is not None:  # store configuration
            self.answer(bytes([0x17, 0x00, 0x00]))
        elif data[0] == 0x04 and data[1] == 0x00:  # switch state global: waiting
            self.configuring = None


def fast_scan_service(slaves: FastScanSlaves) -> Any:
    import asyncio

    from canopen_gateway.bus.lss.service import LssService

    def post(fn: Any, *args: Any) -> None:  # the reader's hand-off: on the loop, after the send
        asyncio.get_running_loop().call_soon(fn, *args)

    slaves.svc = LssService(slaves.send, post, lambda: 0.0, lambda m: 0.0)
    return slaves.svc


KNOWN = (SGH10_VENDOR_ID, SGH10_PRODUCT_CODE, SGH10_REVISION, None)


async def test_fast_scan_of_the_service_gives_node_ids_lowest_address_first_and_says_why_it_stopped() -> None:
    slaves = FastScanSlaves([0x2300, 0x0F01])
    result = await fast_scan_service(slaves).fast_scan(KNOWN, 0.0, first_node_id=5, count=3, store=True)
    assert [(f["address"][3], f["node_id"], f["stored"]) for f in result["found"]] == [(0x0F01, 5, True), (0x2300, 6, True)]
    assert slaves.node_ids == {1: 5, 0: 6}
    assert result["failed"].startswith("no unconfigured LSS slave answered")
    assert result["frames"] == 37 + 37 + 1  # reset, 3 parts confirmed, 32 bits and a confirm each
    assert slaves.configuring is None  # every slave back in waiting


async def test_fast_scan_of_the_service_finds_nobody_or_a_refused_node_id_in_words() -> None:
    from canopen_gateway.errors import LssFailed

    with pytest.raises(LssFailed, match="no unconfigured LSS slave answered"):
        await fast_scan_service(FastScanSlaves([])).fast_scan(KNOWN, 0.0)
    slaves = FastScanSlaves([0x0F01], refuse_node_id=True)
    with pytest.raises(LssFailed, match="configure node id: no valid node id"):
        await fast_scan_service(slaves).fast_scan(KNOWN, 0.0, first_node_id=5)
    assert slaves.configuring is None  # switched back to waiting all the same
    with pytest.raises(ValueError, match="count needs a first node id"):
        await fast_scan_service(FastScanSlaves([1])).fast_scan(KNOWN, 0.0, count=2)
