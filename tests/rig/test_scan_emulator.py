"""`rig scan` against the firmware emulator through a real pseudo-terminal, as a user would point it at a board.

The projector is the serial driver on /dev/pts/N; the camera is the simulated one, lit by whatever the serial
projector reports it is showing. With faults injected, every frame is captured and triggered exactly once, or
the scan stops with a clear error and keeps what it captured.
"""

from __future__ import annotations

import json
from collections import Counter

import pytest

from calibration.errors import DeviceError
from drivers.serial import Emulator, EmulatorFaults, serve_on_pty
from rig.acquire import ScanRequest, run_scan
from rig.config import config_from_dict


def _scan(tmp_path, faults: str, frames: int, seed: int = 1):
    em = Emulator(faults=EmulatorFaults.parse(faults), seed=seed)
    with serve_on_pty(em) as port:
        cfg = config_from_dict({"projector": {"port": port, "timeout_ms": 200.0, "retries": 4}})
        out, rec = tmp_path / "scan.rrd", tmp_path / "raw"
        try:
            summary = run_scan(cfg, ScanRequest(out=out, frames=frames, record=rec, reconstruct=False))
            error = None
        except DeviceError as e:
            summary, error = e.summary, e  # type: ignore[attr-defined]
    return em, summary, error, out, rec


def test_clean_link_scans_every_frame_once(tmp_path, rrd):
    em, summary, error, out, rec = _scan(tmp_path, "", frames=5)
    assert error is None and summary.frames_captured == 5
    assert len(em.fired) == 5 and len(set(em.fired)) == 5, "one trigger per frame"
    m = json.loads((rec / "manifest.json").read_text())
    assert m["complete"] and len(m["frames"]) == 5
    assert m["devices"]["projector"]["device"] == "rig-trigger-emulator"
    tx = [json.loads(line) for line in (rec / "serial.jsonl").read_text().splitlines()[1:]]
    assert any("HELLO" in t["data"] for t in tx if t["dir"] == "tx")
    assert rrd.rows(out, "/world/camera/image") == 5
    rrd.verify(out)


@pytest.mark.parametrize("faults", ["drop=0.05,corrupt=0.05", "duplicate=0.05,delay=0.05"])
def test_faults_at_a_few_percent_lose_nothing(tmp_path, rrd, faults):
    em, summary, error, out, rec = _scan(tmp_path, faults, frames=8)
    m = json.loads((rec / "manifest.json").read_text())
    # Either everything was captured, or the scan stopped with an error naming the fault; never a silent loss.
    if error is None:
        assert summary.frames_captured == 8 and m["complete"]
    else:
        assert "retr" in str(error) or "timeout" in str(error).lower() or "link" in str(error).lower()
        assert m["complete"] is False
    assert len(m["frames"]) == summary.frames_captured == rrd.rows(out, "/world/camera/image")
    # A lost acknowledgement is retried with the same sequence number and never fires twice.
    per_boot = Counter(em.fired)
    assert all(c == 1 for c in per_boot.values()), per_boot
    rrd.verify(out)


def test_recorded_scan_replays_without_hardware(tmp_path, rrd):
    """`camera = "replay:DIR"` + `port = "replay:DIR/serial.jsonl"` reproduce the scan byte for byte."""
    import cv2
    import numpy as np

    from rig.config import load_config

    _, summary, error, _, rec = _scan(tmp_path, "", frames=3)
    assert error is None
    (rec / "rig.toml").write_text(
        'calibration = "calibration.json"\n[projector]\nport = "replay:serial.jsonl"\ntimeout_ms = 200.0\nretries = 4\n'
        '[camera]\ndevice = "replay:."\n'
    )
    out = tmp_path / "replayed.rrd"
    again = run_scan(load_config(rec / "rig.toml"), ScanRequest(out=out, frames=3, reconstruct=False))
    assert again.frames_captured == 3 and rrd.rows(out, "/world/camera/image") == 3
    first = cv2.imread(str(rec / "frames" / "000000.png"), cv2.IMREAD_UNCHANGED)
    replayed = rrd.column(out, "/world/camera/image", "Image:buffer")[0]
    np.testing.assert_array_equal(np.asarray(replayed, np.uint8).ravel(), first.ravel())
