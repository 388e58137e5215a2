"""The firmware emulator as a state machine on a fake clock: bytes in, bytes out (no pseudo-terminal)."""

from __future__ import annotations

import pytest

from calibration.errors import ConfigError
from drivers.serial import Emulator, EmulatorFaults
from drivers.serial import protocol as P
from tests.drivers.strict_transport import FakeClock


def boot(**kw) -> tuple[Emulator, FakeClock]:
    clock = FakeClock(0.0)
    em = Emulator(clock=clock, **kw)
    banner = em.transmit()
    assert banner.startswith(b"! BOOT device=rig-trigger-emulator") and banner.endswith(b"reason=power*%04X\n" % P.crc16(banner[:-6]))
    return em, clock


def ask(em: Emulator, clock: FakeClock, body: str, *, wait_s: float = 0.0) -> list[str]:
    em.receive(P.encode(body))
    em.poll()  # handled now …
    clock.advance(wait_s)  # … replies due by now + wait_s are returned
    out = em.transmit()
    lines = [ln for ln in out.split(b"\n") if ln]
    bodies = [P.check_frame(ln) for ln in lines]
    assert None not in bodies, out
    return bodies


def test_show_executes_once_and_a_repeat_is_answered_from_the_cache():
    em, clock = boot()
    assert ask(em, clock, "1 LOAD 3 0 0,1,2") == ["1 OK n=3 len=3"]
    first = ask(em, clock, "2 SHOW 1", wait_s=0.001)
    assert first == ["2 OK i=1 t_us=0 n=1"]
    clock.advance(0.5)
    assert ask(em, clock, "2 SHOW 1") == first  # the same bytes, not a new trigger
    assert em.triggers == 1 and em.cache_hits == 1
    assert ask(em, clock, "3 SHOW 1", wait_s=0.001)[0].startswith("3 OK i=1 t_us=501000 n=2")
    assert em.triggers == 2


def test_queries_do_not_disturb_the_cache_so_an_action_can_be_resent_after_a_handshake():
    em, clock = boot()
    ask(em, clock, "1 LOAD 3 0 0,1,2")
    ask(em, clock, "2 SHOW 2", wait_s=0.001)
    ask(em, clock, "3 HELLO 1.0")
    status = ask(em, clock, "4 STATUS")[0]
    assert " last=2 " in status and " triggers=1 " in status
    assert ask(em, clock, "2 SHOW 2") == ["2 OK i=2 t_us=0 n=1"]
    assert em.triggers == 1


def test_same_sequence_number_with_another_body_is_executed():
    em, clock = boot()
    ask(em, clock, "1 LOAD 3 0 0,1,2")
    ask(em, clock, "2 SHOW 2", wait_s=0.001)
    assert ask(em, clock, "2 SHOW 0", wait_s=0.001) == ["2 OK i=0 t_us=1000 n=2"]


def test_busy_during_the_trigger_is_not_cached():
    em, clock = boot()
    ask(em, clock, "1 LOAD 3 0 0,1,2")
    assert ask(em, clock, "2 SET delay_us 20000") == ["2 OK delay_us=20000"]
    em.receive(P.encode("3 SHOW 1"))
    assert em.transmit() == b""  # the reply follows the pulse
    assert ask(em, clock, "4 SHOW 2") == []  # queued behind the pending reply
    clock.advance(0.0202)
    bodies = [P.check_frame(x) for x in em.transmit().split(b"\n") if x]
    assert bodies == ["3 OK i=1 t_us=20000 n=1", "4 ERR BUSY trigger in progress"]
    assert ask(em, clock, "4 SHOW 2", wait_s=0.03) == ["4 OK i=2 t_us=40200 n=2"]


def test_set_echoes_the_applied_value_and_refuses_out_of_range():
    em, clock = boot()
    assert ask(em, clock, "1 SET pulse_us 103") == ["1 OK pulse_us=104"]
    assert ask(em, clock, "2 SET exposure_us 16667") == ["2 OK exposure_us=16700"]
    assert ask(em, clock, "3 SET period_us 999") == ["3 ERR RANGE period_us 999 outside 1000..10000000"]
    assert ask(em, clock, "4 GET period_us") == ["4 OK period_us=33333"]
    assert ask(em, clock, "5 SET brightness 3") == ["5 ERR RANGE no parameter brightness"]
    assert ask(em, clock, "6 SET watchdog_us 0") == ["6 OK watchdog_us=0"]


def test_sequence_fires_every_slot_on_time_and_reports_done():
    em, clock = boot()
    ask(em, clock, "1 LOAD 4 0 3,1,2")
    ask(em, clock, "2 SET period_us 50000")
    assert ask(em, clock, "3 ARM") == ["3 OK len=3 period_us=50000"]
    assert ask(em, clock, "4 SHOW 1") == ["4 ERR STATE armed: STOP first"]
    assert ask(em, clock, "5 START") == ["5 OK t_us=0 len=3"]
    clock.advance(0.2)
    got = [P.check_frame(x) for x in em.transmit().split(b"\n") if x]
    assert got == [
        "! EVT k=0 i=3 t_us=0",
        "! EVT k=1 i=1 t_us=50000",
        "! EVT k=2 i=2 t_us=100000",
        "! DONE fired=3 missed=0 t_us=200000",
    ]
    assert em.state == "showing" and em.shown == 2 and em.triggers == 3


def test_a_stall_during_a_sequence_counts_missed_slots():
    em, clock = boot(faults=EmulatorFaults(stall=1.0, stall_s=0.12))
    em.faults = EmulatorFaults()  # no faults while setting up …
    ask(em, clock, "1 LOAD 4 0 0,1,2,3")
    ask(em, clock, "2 SET period_us 50000")
    ask(em, clock, "3 ARM")
    ask(em, clock, "4 START")
    em.faults = EmulatorFaults(stall=1.0, stall_s=0.12)  # … then the next request freezes the board
    clock.advance(0.01)
    em.receive(P.encode("5 PING"))
    em.transmit()
    em.faults = EmulatorFaults()
    clock.advance(0.5)
    out = [P.check_frame(x) for x in em.transmit().split(b"\n") if x]
    evts = [b for b in out if b.startswith("! EVT")]
    assert [b.split()[2] for b in evts] == ["k=0", "k=3"]  # slots 1 and 2 fell in the stall
    assert out[-1].startswith("! DONE fired=2 missed=2")


def test_watchdog_darkens_a_silent_host_but_not_a_running_sequence():
    em, clock = boot()
    ask(em, clock, "1 SET watchdog_us 100000")
    ask(em, clock, "2 LOAD 2 0 0,1")
    ask(em, clock, "3 SHOW 1", wait_s=0.001)
    clock.advance(0.05)
    assert em.transmit() == b""
    clock.advance(0.06)
    assert [P.check_frame(x) for x in em.transmit().split(b"\n") if x] == ["! SAFE reason=watchdog t_us=111000"]
    assert em.state == "idle" and em.shown == -1
    ask(em, clock, "4 SET period_us 200000")
    ask(em, clock, "7 LOAD 2 0 0,1,0,1")
    ask(em, clock, "5 ARM")
    ask(em, clock, "6 START")
    clock.advance(0.3)  # longer than the watchdog, but running
    out = em.transmit()
    assert out.count(b"! EVT") == 2 and b"SAFE" not in out and em.state == "running"


def test_garbage_is_answered_and_the_next_frame_is_understood():
    em, clock = boot()
    em.receive(b"\x00\xffnoise" + P.encode("1 PING")[:5] + b"\n" + b"x" * 300 + b"\n" + P.encode("2 PING"))
    out = [P.check_frame(x) for x in em.transmit().split(b"\n") if x]
    assert out == ["- ERR CRC bad frame check", "- ERR OVERFLOW line longer than 128 bytes", "2 OK t_us=0"]


def test_syntax_errors_echo_the_sequence_number_when_it_is_readable():
    em, clock = boot()
    assert ask(em, clock, "7 FIRE 1") == ["7 ERR SYNTAX unknown verb 'FIRE'"]
    assert ask(em, clock, "x1 PING") == ["- ERR SYNTAX bad sequence number 'x1'"]
    assert ask(em, clock, "8 SHOW") == ["8 ERR SYNTAX SHOW index"]


def test_reset_replies_then_boots_with_a_banner_and_forgets_everything():
    em, clock = boot()
    ask(em, clock, "1 LOAD 2 0 0,1")
    assert ask(em, clock, "2 RESET") == ["2 OK"]
    assert ask(em, clock, "3 PING") == []  # rebooting: deaf
    clock.advance(0.05)
    out = [P.check_frame(x) for x in em.transmit().split(b"\n") if x]
    assert out == ["! BOOT device=rig-trigger-emulator fw=1.0.0 proto=1.0 reason=reset"]
    assert em.n_patterns == 0 and em.boots == 2
    assert ask(em, clock, "2 RESET") == ["2 OK"]  # the cache went with the reboot: executed again


def test_fault_specification_parses_and_validates():
    f = EmulatorFaults.parse("drop=0.05, corrupt=0.1,stall_s=0.3")
    assert (f.drop, f.corrupt, f.stall_s, f.delay) == (0.05, 0.1, 0.3, 0.0)
    assert EmulatorFaults.parse("") == EmulatorFaults()
    with pytest.raises(ConfigError, match="outside 0…1"):
        EmulatorFaults.parse("drop=2")
    with pytest.raises(ConfigError, match="expected name=value"):
        EmulatorFaults.parse("jitter=0.1")
    with pytest.raises(ConfigError, match="not a number"):
        EmulatorFaults.parse("drop=lots")


def test_byte_faults_hit_about_the_requested_share_of_frames():
    em, clock = boot(faults=EmulatorFaults(corrupt=0.2), seed=7)
    bad = 0
    for k in range(1, 401):
        em.receive(P.encode(f"{k} PING"))
        out = em.transmit()
        if not out or any(P.check_frame(x) is None for x in out.split(b"\n") if x) or out.startswith(b"- ERR"):
            bad += 1
    # each exchange has two frames that may be corrupted: P(bad) = 1 - 0.8**2 = 0.36
    assert 0.28 < bad / 400 < 0.44
