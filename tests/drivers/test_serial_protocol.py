"""Byte-for-byte protocol tests of SerialProjector against a strict scripted transport.

The frames are the ones printed in docs/protocol.md § 10 (checked below), so the page and the driver agree.
"""

from __future__ import annotations

import re

import numpy as np
import pytest

from calibration.errors import ConfigError, DeviceError, DeviceTimeout, ProtocolError
from drivers.base import Projector
from drivers.serial import SerialProjector
from drivers.serial import protocol as P
from tests.conftest import ROOT
from tests.drivers.strict_transport import FakeClock, StrictTransport, expected_protocol

HELLO = (
    b"\n1 HELLO 1.0*4EC0\n",
    b"1 OK device=rig-trigger-emulator fw=1.0.0 proto=1.0 caps=show,seq,evt,wdt max_order=256 max_line=128*101B\n",
)
PATTERNS = [np.full((3, 4), 10 * k, np.uint8) for k in range(4)]


def f(body: str) -> bytes:
    return P.encode(body)


def test_crc_is_crc16_ccitt_false_with_the_documented_check_value():
    assert P.crc16(b"123456789") == 0x29B1
    assert P.encode("2 PING") == b"2 PING*428F\n"


def test_every_frame_printed_in_the_protocol_page_has_a_valid_crc():
    text = (ROOT / "docs" / "protocol.md").read_text(encoding="utf-8")
    frames = re.findall(r"^\s+[<>] (\S.*?\*[0-9A-F]{4})\b", text, flags=re.M)
    assert len(frames) >= 30
    for frame in frames:
        assert P.check_frame(frame.encode()) is not None, frame


def test_hello_reports_the_board_and_handshakes_byte_for_byte():
    with expected_protocol([HELLO]) as (proj, _t):
        info = proj.hello()
    assert info == {
        "device": "rig-trigger-emulator",
        "firmware": "1.0.0",
        "protocol": "1.0",
        "capabilities": ["show", "seq", "evt", "wdt"],
        "max_order": 256,
        "max_line": 128,
    }


def test_hello_refuses_another_major_version_naming_both():
    reply = f("1 OK device=x fw=9 proto=2.1 caps=show")
    with expected_protocol([(HELLO[0], reply)]) as (proj, _t):
        with pytest.raises(ProtocolError, match=r"protocol 2\.1.*speaks 1\.0"):
            proj.hello()


def test_a_newer_minor_version_is_accepted():
    reply = f("1 OK device=x fw=9 proto=1.7 caps=show,future")
    with expected_protocol([(HELLO[0], reply)]) as (proj, _t):
        assert proj.hello()["protocol"] == "1.7"


def test_ping_set_get_load_show_stop_byte_for_byte():
    script = [
        HELLO,
        (b"2 PING*428F\n", b"2 OK t_us=16743*BE06\n"),
        (b"3 SET pulse_us 103*1143\n", b"3 OK pulse_us=104*DFCA\n"),
        (b"4 GET delay_us*03B1\n", b"4 OK delay_us=0*D057\n"),
        (b"5 LOAD 4 0 0,1,2,3*3804\n", b"5 OK n=4 len=4*F44C\n"),
        (b"6 SHOW 2*4535\n", b"6 OK i=2 t_us=18392 n=1*773C\n"),
        (b"7 STOP*CA87\n", f("7 OK state=idle")),
    ]
    with expected_protocol(script) as (proj, _t):
        rtt_s, t_us = proj.ping()
        assert t_us == 16743 and rtt_s >= 0
        assert proj.set("pulse_us", 103) == 104  # the applied value, not the asked one
        assert proj.get("delay_us") == 0
        proj.load(PATTERNS)
        assert proj.showing is None
        shown = proj.show(2)
        assert (shown.index, shown.device_time_us) == (2, 18392)
        np.testing.assert_array_equal(proj.showing, PATTERNS[2])
        proj.close()
        proj.close()  # idempotent: nothing more on the wire
        assert proj.showing is None


def test_satisfies_the_projector_protocol():
    proj = SerialProjector(StrictTransport([]), clock=FakeClock())
    assert isinstance(proj, Projector)


def test_a_lost_acknowledgement_is_resent_with_the_same_sequence_number():
    """The reply to SHOW is lost: the host resends the identical frame (the board answers from its cache)."""
    script = [
        HELLO,
        (b"2 LOAD 4 0 0,1,2,3*C8D1\n", f("2 OK n=4 len=4")),
        (b"3 SHOW 2*0D8B\n", b""),  # silence: the acknowledgement was lost
        (b"\n3 SHOW 2*0D8B\n", f("3 OK i=2 t_us=500 n=1")),
    ]
    with expected_protocol(script, timeout_s=0.25) as (proj, t):
        proj.load(PATTERNS)
        t0 = t.clock()
        assert proj.show(2).device_time_us == 500
        assert t.clock() - t0 == pytest.approx(0.25)  # exactly one deadline passed
    assert (proj.stats.retries, proj.stats.recovered, proj.stats.failed) == (1, 1, 0)


@pytest.mark.parametrize(
    "first_answer",
    [
        b"3 OK i=2 t_us=500 n=1*0000\n",  # bad CRC
        b"3 OK i=2 t_u",  # truncated, then the line ends with the next reply
        b"- ERR CRC bad frame check*8BE4\n",  # the board saw our frame damaged
        b"- ERR OVERFLOW line longer than 128 bytes*" + b"%04X\n" % P.crc16(b"- ERR OVERFLOW line longer than 128 bytes"),
        f("3 ERR BUSY trigger in progress"),
    ],
    ids=["bad-crc", "truncated", "err-crc", "err-overflow", "busy"],
)
def test_garbled_replies_and_retryable_errors_make_the_host_resend(first_answer):
    script = [
        HELLO,
        (b"2 LOAD 4 0 0,1,2,3*C8D1\n", f("2 OK n=4 len=4")),
        (b"3 SHOW 2*0D8B\n", first_answer),
        (b"\n3 SHOW 2*0D8B\n", f("3 OK i=2 t_us=500 n=1")),
    ]
    with expected_protocol(script) as (proj, _t):
        proj.load(PATTERNS)
        assert proj.show(2).index == 2
    assert proj.stats.retries == 1 and proj.stats.recovered == 1


def test_late_replies_to_earlier_requests_are_ignored():
    script = [
        HELLO,
        (b"2 PING*428F\n", f("1 OK device=stale fw=0 proto=1.0") + f("2 OK t_us=77")),
    ]
    with expected_protocol(script) as (proj, _t):
        assert proj.ping()[1] == 77
    assert proj.stats.stale == 1 and proj.stats.retries == 0


def test_errors_that_are_not_transient_raise_without_resending():
    script = [
        HELLO,
        (b"2 LOAD 4 0 0,1,2,3*C8D1\n", f("2 OK n=4 len=4")),
        (b"3 SHOW 3*1DAA\n", f("3 ERR STATE running: STOP first")),
        # a STATE refusal: has the board forgotten the patterns (an unseen reboot)? No: report it
        (f("4 STATUS"), f("4 OK state=running i=-1 n=4 len=4 k=1 triggers=1 missed=0 last=3 t_us=10")),
    ]
    with expected_protocol(script) as (proj, _t):
        proj.load(PATTERNS)
        with pytest.raises(ProtocolError, match="refused SHOW: ERR STATE running: STOP first"):
            proj.show(3)
    assert proj.stats.refused == 1 and proj.stats.retries == 0


def test_internal_errors_are_device_errors():
    script = [HELLO, (b"2 STATUS*B508\n", f("2 ERR INTERNAL projector not responding"))]
    with expected_protocol(script) as (proj, _t):
        with pytest.raises(DeviceError, match="INTERNAL projector not responding") as e:
            proj.status()
        assert not isinstance(e.value, ProtocolError)


def test_after_the_retries_the_host_reconnects_handshakes_reads_status_and_resends():
    script = [
        HELLO,
        (b"2 LOAD 4 0 0,1,2,3*C8D1\n", f("2 OK n=4 len=4")),
        (b"3 SHOW 2*0D8B\n", b""),
        (b"\n3 SHOW 2*0D8B\n", b""),
        (b"\n3 SHOW 2*0D8B\n", b""),
        (b"\n" + f("4 HELLO 1.0"), f("4 OK device=rig-trigger-emulator fw=1.0.0 proto=1.0 caps=show")),
        (f("5 STATUS"), f("5 OK state=showing i=2 n=4 len=4 k=0 triggers=1 missed=0 last=3 t_us=900")),
        (b"\n3 SHOW 2*0D8B\n", f("3 OK i=2 t_us=800 n=1")),  # answered from the board's cache
    ]
    with expected_protocol(script, retries=2) as (proj, _t):
        proj.load(PATTERNS)
        assert proj.show(2).device_time_us == 800
    s = proj.stats
    assert (s.retries, s.reconnects, s.recovered, s.failed) == (3, 1, 1, 0)


def test_a_board_that_never_answers_fails_with_a_clear_error():
    script = [(HELLO[0], b""), (b"\n1 HELLO 1.0*4EC0\n", b"")]
    with expected_protocol(script, retries=1) as (proj, _t):
        with pytest.raises(DeviceTimeout, match=r"HELLO failed after 1 resends.*no reply.*firmware flashed"):
            proj.hello()


def test_the_context_manager_stops_the_board_on_an_exception():
    script = [
        HELLO,
        (b"2 LOAD 4 0 0,1,2,3*C8D1\n", f("2 OK n=4 len=4")),
        (b"3 SHOW 1*3DE8\n", f("3 OK i=1 t_us=10 n=1")),
        (f("4 STOP"), f("4 OK state=idle")),
    ]
    clock = FakeClock()
    t = StrictTransport(script, clock=clock)
    with pytest.raises(KeyboardInterrupt):
        with SerialProjector(t, clock=clock) as proj:
            proj.load(PATTERNS)
            proj.show(1)
            raise KeyboardInterrupt
    t.verify()
    assert not t.is_open


def _chunks(order: list[int], *, n: int) -> list[list[int]]:
    """The chunking rule: as many entries as fit the 128-byte line with the longest (5-digit) SEQ."""
    out, at = [], 0
    while at < len(order):
        room = P.MAX_LINE - len(f"65535 LOAD {n} {at} ") - 5
        chunk = [order[at]]
        while at + len(chunk) < len(order) and len(",".join(map(str, chunk + [order[at + len(chunk)]]))) <= room:
            chunk.append(order[at + len(chunk)])
        out.append(chunk)
        at += len(chunk)
    return out


def test_a_long_order_is_loaded_in_chunks_that_fit_a_line():
    identity = list(range(100))
    order = [(7 * k) % 100 for k in range(120)]
    script, seq = [HELLO], 2
    for entries in (identity, order):
        at = 0
        for chunk in _chunks(entries, n=100):
            body = f"{seq} LOAD 100 {at} " + ",".join(map(str, chunk))
            at += len(chunk)
            assert len(f(body)) - 1 <= P.MAX_LINE
            script.append((f(body), f(f"{seq} OK n=100 len={at}")))
            seq += 1
    script.append((f(f"{seq} ARM"), f(f"{seq} OK len=120 period_us=33332")))
    assert len(script) == 1 + len(_chunks(identity, n=100)) + 4 + 1
    with expected_protocol(script) as (proj, _t):
        proj.load([np.zeros((2, 2), np.uint8)] * 100)
        assert proj.arm(order) == 120


def test_sequence_events_and_done():
    script = [
        HELLO,
        (f("2 LOAD 4 0 0,1,2,3"), f("2 OK n=4 len=4")),
        (f("3 LOAD 4 0 3,1,2"), f("3 OK n=4 len=3")),
        (f("4 ARM"), f("4 OK len=3 period_us=50000")),
        (
            f("5 START"),
            f("5 OK t_us=90000 len=3")
            + f("! EVT k=0 i=3 t_us=90000")
            + b"! EVT k=1 i=1 t_us=140000*0000\n"  # damaged on the line
            + f("! EVT k=2 i=2 t_us=190000")
            + f("! DONE fired=3 missed=0 t_us=190100"),
        ),
    ]
    seen = []
    with expected_protocol(script) as (proj, _t):
        proj.load(PATTERNS)
        done = proj.run_sequence([3, 1, 2], on_event=seen.append)
        np.testing.assert_array_equal(proj.showing, PATTERNS[2])
    assert [(e.k, e.index, e.device_time_us) for e in seen] == [(0, 3, 90000), (2, 2, 190000)]
    assert (done.fired, done.missed, done.lost_events, done.device_time_us) == (3, 0, 1, 190100)


def test_a_lost_done_is_reconstructed_from_status():
    script = [
        HELLO,
        (f("2 LOAD 4 0 0,1,2,3"), f("2 OK n=4 len=4")),
        (f("3 ARM"), f("3 OK len=4 period_us=1000")),
        (f("4 START"), f("4 OK t_us=100 len=4") + f("! EVT k=0 i=0 t_us=100") + f("! EVT k=1 i=1 t_us=1100")),
        (f("5 STATUS"), f("5 OK state=showing i=3 n=4 len=4 k=0 triggers=3 missed=1 last=4 t_us=9000")),
    ]
    with expected_protocol(script) as (proj, _t):
        proj.load(PATTERNS)
        proj.arm()
        proj.start()
        events = list(proj.events())
    assert [e.k for e in events] == [0, 1]
    assert proj.done == type(proj.done)(fired=3, missed=1, lost_events=1, device_time_us=None)


def test_a_watchdog_message_darkens_showing():
    script = [
        HELLO,
        (f("2 LOAD 4 0 0,1,2,3"), f("2 OK n=4 len=4")),
        (f("3 SHOW 1"), f("3 OK i=1 t_us=10 n=1") + f("! SAFE reason=watchdog t_us=5000010")),
    ]
    with expected_protocol(script) as (proj, _t):
        proj.load(PATTERNS)
        proj.show(1)
        assert proj.showing is None


def test_reset_waits_for_the_boot_banner_and_restores_order_and_timing():
    script = [
        HELLO,
        (f("2 SET period_us 20000"), f("2 OK period_us=20000")),
        (f("3 LOAD 4 0 0,1,2,3"), f("3 OK n=4 len=4")),
        (f("4 RESET"), f("4 OK") + f("! BOOT device=rig-trigger-emulator fw=1.0.0 proto=1.0 reason=reset")),
        (f("5 SET period_us 20000"), f("5 OK period_us=20000")),
        (f("6 LOAD 4 0 0,1,2,3"), f("6 OK n=4 len=4")),
    ]
    with expected_protocol(script) as (proj, _t):
        proj.set("period_us", 20000)
        proj.load(PATTERNS)
        banner = proj.reset()
    assert banner["reason"] == "reset" and proj.stats.reboots == 1


def test_bad_arguments_are_refused_before_anything_is_sent():
    with expected_protocol([HELLO]) as (proj, _t):
        with pytest.raises(ConfigError, match="no timing parameter"):
            proj.get("brightness")
        with pytest.raises(ConfigError, match="outside the protocol's range"):
            proj.set("pulse_us", 0)
        with pytest.raises(ConfigError, match="before load"):
            proj.show(0)


class _SilentAfterHello(StrictTransport):
    """Answers the handshake, then nothing ever again (the board was unplugged)."""

    def write(self, data: bytes) -> int:
        if self._i < len(self.script):
            return super().write(data)
        self.writes.append(bytes(data))
        return len(data)


def test_close_on_a_board_that_went_silent_does_not_raise_and_says_why():
    clock = FakeClock()
    t = _SilentAfterHello([HELLO], clock=clock)
    proj = SerialProjector(t, clock=clock, timeout_s=0.05, retries=1)
    proj.hello()
    proj.close()  # must not raise: it runs on exit paths
    assert isinstance(proj.close_error, DeviceError)
    assert "could not stop it before closing" in str(proj.close_error)
    assert t.writes[1] == b"2 STOP*%04X\n" % P.crc16(b"2 STOP") and not t.is_open
    proj.close()  # idempotent


def test_a_reboot_whose_banner_was_lost_is_found_by_status_restored_and_the_show_reissued():
    script = [
        HELLO,
        (f("2 LOAD 4 0 0,1,2,3"), f("2 OK n=4 len=4")),
        (f("3 SHOW 3"), f("3 ERR STATE no patterns loaded: LOAD first")),
        (f("4 STATUS"), f("4 OK state=idle i=-1 n=0 len=0 k=0 triggers=0 missed=0 last=-1 t_us=5000")),
        (f("5 LOAD 4 0 0,1,2,3"), f("5 OK n=4 len=4")),
        (f("6 SHOW 3"), f("6 OK i=3 t_us=6000 n=1")),  # a new number: the refusal of 3 is in the cache
    ]
    with expected_protocol(script) as (proj, _t):
        proj.load(PATTERNS)
        assert proj.show(3).device_time_us == 6000
    assert proj.stats.reboots == 1 and proj.stats.failed == 0
