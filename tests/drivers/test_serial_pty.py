"""The driver against the emulator through a real pseudo-terminal (os.openpty), with and without faults."""

from __future__ import annotations

import collections
import time

import numpy as np
import pytest

from calibration.errors import DeviceError
from drivers.serial import Emulator, EmulatorFaults, SerialProjector, open_transport, serve_on_pty

PATTERNS = [np.full((2, 3), k, np.uint8) for k in range(4)]


def shows_executed(em: Emulator) -> collections.Counter:
    """How many times the board fired the trigger for each SHOW request (by its sequence number)."""
    return collections.Counter(seq for _boot, seq in em.fired)


def test_a_session_over_a_pseudo_terminal():
    em = Emulator(seed=0)
    with serve_on_pty(em) as path:
        assert path.startswith("/dev/pts/")
        with SerialProjector(open_transport(path)) as proj:
            assert proj.describe()["device"] == "rig-trigger-emulator"
            assert proj.describe()["port"] == path
            rtt_s, t_us = proj.ping()
            assert 0 < rtt_s < 0.25 and t_us > 0
            assert proj.set("period_us", 20_000) == 20_000
            proj.load(PATTERNS)
            for i in (0, 3, 1):
                shown = proj.show(i)
                assert shown.index == i and em.shown == i
                np.testing.assert_array_equal(proj.showing, PATTERNS[i])
            seen = []
            done = proj.run_sequence([2, 0, 1, 3, 3], on_event=seen.append)
            assert [e.index for e in seen] == [2, 0, 1, 3, 3]
            dt_us = np.diff([e.device_time_us for e in seen])
            assert np.all(dt_us == 20_000)  # slots on the board's clock, exactly one period apart
            assert (done.fired, done.missed, done.lost_events) == (5, 0, 0)
            st = proj.status()
            assert st["triggers"] == 8 and st["state"] == "showing" and st["i"] == 3
        assert em.state == "idle" and em.executed[-1].endswith("STOP")  # closed → stopped


def test_the_port_is_opened_exclusively_and_errors_name_the_fix(tmp_path):
    with serve_on_pty(Emulator()) as path:
        first = open_transport(path)
        try:
            with pytest.raises(DeviceError, match=r"busy: another program has it open"):
                open_transport(path)
        finally:
            first.close()
    with pytest.raises(DeviceError, match=r"does not exist.*rig devices"):
        open_transport(str(tmp_path / "ttyACM9"))


def test_the_watchdog_darkens_the_projector_when_the_host_goes_silent():
    em = Emulator()
    with serve_on_pty(em) as path:
        with SerialProjector(open_transport(path)) as proj:
            assert proj.set("watchdog_us", 100_000) == 100_000
            proj.load(PATTERNS)
            proj.show(2)
            assert proj.showing is not None
            time.sleep(0.3)
            assert proj.showing is None and em.state == "idle"
            proj.show(1)  # a new request wakes it up
            assert proj.showing_index == 1


def test_stop_on_an_exception_inside_the_context():
    em = Emulator()
    with serve_on_pty(em) as path:
        with pytest.raises(RuntimeError):
            with SerialProjector(open_transport(path)) as proj:
                proj.load(PATTERNS)
                proj.show(3)
                raise RuntimeError("scan loop failed")
        assert em.state == "idle" and em.shown == -1


FAULT_RUNS = {
    # kind: (rate, durations)
    "drop": (0.1, {}),
    "corrupt": (0.1, {}),
    "duplicate": (0.1, {}),
    "delay": (0.1, {"delay_s": 0.12}),
    "stall": (0.1, {"stall_s": 0.25}),
    "reset": (0.1, {}),
    "disconnect": (0.1, {"disconnect_s": 0.1}),
}


@pytest.mark.parametrize("kind", list(FAULT_RUNS))
def test_every_show_is_acknowledged_and_executed_exactly_once_under_faults(kind, tmp_path):
    rate, durations = FAULT_RUNS[kind]
    em = Emulator(faults=EmulatorFaults(**{kind: rate}, **durations), seed=11)
    n_shows = 40
    with serve_on_pty(em, link=tmp_path / "ttyEMU") as path:
        proj = SerialProjector(open_transport(path), timeout_s=0.08, reopen=lambda: open_transport(path))
        with proj:
            proj.load(PATTERNS)
            for k in range(n_shows):
                assert proj.show(k % 4).index == k % 4
            st = proj.status()
    executed = shows_executed(em)
    assert len(executed) == n_shows  # every show reached the board …
    assert max(executed.values()) == 1  # … and none fired twice, whatever was lost
    assert em.fault_counts[kind] > 0  # the fault really happened …
    assert proj.stats.retries > 0 and proj.stats.recovered > 0  # … and the driver recovered
    assert proj.stats.failed == 0
    if kind == "disconnect":
        assert proj.stats.reconnects > 0
    if kind == "reset":
        assert proj.stats.reboots > 0 and st["n"] == 4  # the order was restored after each reboot
    else:
        assert st["triggers"] == n_shows


def test_a_board_that_stays_away_fails_with_an_error_naming_the_problem(tmp_path):
    em = Emulator(faults=EmulatorFaults(disconnect=1.0, disconnect_s=30.0))
    with serve_on_pty(em, link=tmp_path / "ttyEMU") as path:
        proj = SerialProjector(open_transport(path), timeout_s=0.05, retries=1, reopen=lambda: open_transport(path))
        t0 = time.monotonic()
        with pytest.raises(DeviceError, match=r"HELLO failed|reconnecting failed too|does not exist"):
            proj.hello()
            proj.load(PATTERNS)
        assert time.monotonic() - t0 < 10
        proj._closed = True  # the board is gone; nothing to stop


def test_connect_opens_the_port_and_reconnects_after_a_disconnect(tmp_path):
    from drivers.serial import TranscriptWriter, connect

    em = Emulator(faults=EmulatorFaults(disconnect=0.2, disconnect_s=0.05), seed=2)
    with serve_on_pty(em, link=tmp_path / "ttyEMU") as path:
        with TranscriptWriter(tmp_path / "serial.jsonl") as tw, connect(path, timeout_s=0.1, transcript=tw) as proj:
            proj.load(PATTERNS)
            for k in range(15):
                proj.show(k % 4)
    assert proj.stats.reconnects > 0 and max(shows_executed(em).values()) == 1
    assert len(shows_executed(em)) == 15
    assert (tmp_path / "serial.jsonl").read_text().count('"dir":"tx"') >= 17
