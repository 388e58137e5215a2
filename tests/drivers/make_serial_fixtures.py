"""Record the serial transcripts under fixtures/serial/ (never edit them by hand; re-run this instead).

    .venv/bin/python -m tests.drivers.make_serial_fixtures

Each session runs SerialProjector against the firmware emulator through a real pseudo-terminal with a
TranscriptWriter attached. tests/drivers/test_serial_replay.py replays the transcripts with the same
session functions through ReplayTransport.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Callable

import numpy as np

from drivers.serial import Emulator, EmulatorFaults, SerialProjector, TranscriptWriter, open_transport, serve_on_pty

FIXTURES = Path(__file__).resolve().parents[2] / "fixtures" / "serial"
PATTERNS = [np.full((4, 6), 40 * k, np.uint8) for k in range(5)]


def session_basic(proj: SerialProjector) -> dict:
    """Handshake, timing, load, a few shows, status, stop."""
    out: dict = {"hello": proj.hello()}
    out["pulse_us"] = proj.set("pulse_us", 250)
    out["delay_us"] = proj.set("delay_us", 1000)
    out["exposure_us"] = proj.get("exposure_us")
    proj.load(PATTERNS)
    out["shown"] = [(s.index, s.device_time_us) for s in (proj.show(i) for i in (0, 2, 4, 1, 3))]
    out["status"] = proj.status()
    proj.stop()
    out["after_stop"] = proj.status()["state"]
    return out


def session_sequence(proj: SerialProjector) -> dict:
    """Sequence mode: load an order, arm, start, follow the events to DONE."""
    proj.hello()
    proj.set("period_us", 10_000)
    proj.load(PATTERNS)
    events = []
    done = proj.run_sequence([4, 3, 2, 1, 0, 2], on_event=events.append)
    return {
        "events": [(e.k, e.index, e.device_time_us) for e in events],
        "done": (done.fired, done.missed, done.lost_events, done.device_time_us),
        "status": proj.status(),
    }


def session_faults(proj: SerialProjector) -> dict:
    """Thirty shows over a line that drops and corrupts bytes (the emulator's faults, seeded)."""
    proj.hello()
    proj.load(PATTERNS)
    shown = [proj.show(k % 5).index for k in range(30)]
    return {"shown": shown, "status": proj.status(), "stats": proj.stats.as_dict()}


SESSIONS: dict[str, tuple[Callable[[SerialProjector], dict], dict, EmulatorFaults, int]] = {
    # name: (session, driver options, emulator faults, seed)
    "basic": (session_basic, {}, EmulatorFaults(), 0),
    "sequence": (session_sequence, {}, EmulatorFaults(), 0),
    "faults": (session_faults, {"timeout_s": 0.1}, EmulatorFaults(drop=0.08, corrupt=0.08), 5),
}


def record(name: str, *, out_dir: Path = FIXTURES) -> Path:
    session, options, faults, seed = SESSIONS[name]
    path = out_dir / f"{name}.jsonl"
    em = Emulator(faults=faults, seed=seed)
    meta = {
        "made_by": "python -m tests.drivers.make_serial_fixtures",
        "session": name,
        "emulator": {"device": em.device, "firmware": em.firmware, "seed": seed, "faults": {
            k: getattr(faults, k) for k in faults.KINDS if getattr(faults, k)
        }},
        "driver_options": options,
    }
    with serve_on_pty(em) as port, TranscriptWriter(path, meta=meta) as transcript:
        with SerialProjector(open_transport(port), transcript=transcript, **options) as proj:
            session(proj)
    return path


def main(argv: list[str]) -> int:
    FIXTURES.mkdir(parents=True, exist_ok=True)
    for name in argv or list(SESSIONS):
        print(f"recorded {record(name)}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
