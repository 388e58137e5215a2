"""Recorded serial sessions (fixtures/serial/*.jsonl, made by tests/drivers/make_serial_fixtures.py) replayed
through ReplayTransport: the driver must send exactly the recorded bytes and read the recorded replies."""

from __future__ import annotations

import json

import pytest

from calibration.errors import ConfigError, ProtocolError
from drivers.serial import ReplayTransport, SerialProjector, TranscriptWriter, open_transport, read_transcript
from drivers.serial import protocol as P
from tests.drivers.make_serial_fixtures import FIXTURES, SESSIONS


def rx_bodies(path) -> list[str]:
    _meta, records = read_transcript(path)
    out = []
    for direction, data, _t in records:
        body = P.check_frame(data.rstrip(b"\n")) if direction == "rx" else None
        if body is not None:
            out.append(body)
    return out


@pytest.mark.parametrize("name", list(SESSIONS))
def test_a_recorded_session_replays_byte_for_byte(name):
    session, options, _faults, _seed = SESSIONS[name]
    path = FIXTURES / f"{name}.jsonl"
    transport = open_transport(f"replay:{path}")
    assert isinstance(transport, ReplayTransport)
    with SerialProjector(transport, **options) as proj:
        result = session(proj)
    assert transport.remaining == 0  # every recorded frame was sent and read, STOP on close included
    replies = rx_bodies(path)
    if name == "basic":
        for index, t_us in result["shown"]:
            assert any(b.endswith(f"OK i={index} t_us={t_us} n={b.split('n=')[-1]}") for b in replies)
        assert (result["pulse_us"], result["delay_us"], result["exposure_us"]) == (248, 1000, 16667)  # rounded to the 4 µs timer
        assert result["status"]["triggers"] == 5 and result["after_stop"] == "idle"
    elif name == "sequence":
        assert [i for _k, i, _t in result["events"]] == [4, 3, 2, 1, 0, 2]
        times = [t for _k, _i, t in result["events"]]
        assert all(b - a == 10_000 for a, b in zip(times, times[1:]))
        assert result["done"][:3] == (6, 0, 0)
    else:
        assert result["shown"] == [k % 5 for k in range(30)]
        assert result["stats"]["retries"] > 0 and result["stats"]["failed"] == 0
        assert result["status"]["triggers"] == 30  # no double trigger in the recording either


def test_replay_detects_a_host_that_diverges_from_the_recording():
    transport = ReplayTransport(FIXTURES / "basic.jsonl")
    proj = SerialProjector(transport)
    proj.hello()
    with pytest.raises(ProtocolError, match=r"replay diverged at record \d+: recorded b'2 SET pulse_us 250"):
        proj.set("pulse_us", 300)


def test_transcripts_are_json_lines_with_a_header(tmp_path):
    path = tmp_path / "t.jsonl"
    clock = iter([1.0, 2.0, 3.0]).__next__
    with TranscriptWriter(path, meta={"port": "/dev/ttyACM0"}, clock=clock) as tw:
        tw.tx(b"1 PING*XXXX\n")
        tw.rx(b"\xff\x00garbage\n")
    lines = [json.loads(x) for x in path.read_text().splitlines()]
    assert lines[0]["format"] == "rig-serial-transcript" and lines[0]["port"] == "/dev/ttyACM0"
    assert lines[1] == {"t": 1.0, "dir": "tx", "data": "1 PING*XXXX\n"}
    meta, records = read_transcript(path)
    assert records[1] == ("rx", b"\xff\x00garbage\n", 2.0)  # any byte round-trips


def test_a_file_that_is_not_a_transcript_is_refused(tmp_path):
    bad = tmp_path / "x.jsonl"
    bad.write_text('{"t": 1, "dir": "tx", "data": "x"}\n')
    with pytest.raises(ConfigError, match="not a rig serial transcript"):
        ReplayTransport(bad)
