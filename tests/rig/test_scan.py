"""`rig scan` end to end on the built-in simulated rig: a valid recording, raw frames kept, clean stops."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from calibration.errors import DeviceError
from rig.acquire import ScanRequest, run_scan
from rig.cli import main
from rig.config import config_from_dict



def test_default_scan_makes_a_valid_recording(rrd, tmp_path, capsys):
    out = tmp_path / "scan.rrd"
    assert main(["scan", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert f"recording: {out.resolve()}" in printed and f"rerun {out}" in printed
    ents = rrd.entities(out)
    for e in ("/world/projector", "/world/camera", "/world/camera/image", "/world/projector/pattern"):
        assert e in ents
    rrd.verify(out)


def test_record_dir_keeps_raw_frames(rrd, tmp_path):
    out, rec = tmp_path / "scan.rrd", tmp_path / "raw"
    assert main(["scan", "--out", str(out), "--frames", "3", "--record", str(rec)]) == 0
    m = json.loads((rec / "manifest.json").read_text())
    assert m["complete"] is True and len(m["frames"]) == 3
    assert m["devices"]["camera"] and m["devices"]["projector"]
    img = cv2.imread(str(rec / m["frames"][0]["file"]), cv2.IMREAD_UNCHANGED)
    assert img is not None and img.ndim == 2 and img.max() > 100, "the grid is visible in the raw frame"
    assert (rec / "calibration.json").exists() and (rec / "patterns/000.png").exists()
    stamps = [f["timestamp_s"] for f in m["frames"]]
    assert stamps == sorted(stamps)


def test_ctrl_c_keeps_what_was_captured(rrd, tmp_path):
    out, rec = tmp_path / "scan.rrd", tmp_path / "raw"

    def interrupt(n: int, info: dict) -> None:
        if n == 1:
            raise KeyboardInterrupt

    summary = run_scan(config_from_dict({}), ScanRequest(out=out, frames=10, record=rec), on_frame=interrupt)
    # scan 1's result arrives while later scans are being captured (the reconstruction runs beside the capture):
    # every scan captured by then is kept and, before the recording closes, reconstructed
    n = summary.frames_captured
    assert summary.interrupted and 2 <= n < 10
    assert summary.scans_done == n
    assert rrd.rows(out, "/world/camera/image") == n
    assert rrd.rows(out, "/world/points") == n
    # each scan's results sit on its own frame (Rerun's time is per thread: the worker sets it)
    assert sorted(rrd.column(out, "/world/points", "frame")) == list(range(n))
    assert sorted(rrd.column(out, "/world/camera/depth", "frame")) == list(range(n))
    rrd.verify(out)
    m = json.loads((rec / "manifest.json").read_text())
    assert m["complete"] is False and len(m["frames"]) == n


def test_ctrl_c_without_overlap_stops_after_the_scan(rrd, tmp_path):
    out = tmp_path / "scan.rrd"

    def interrupt(n: int, info: dict) -> None:
        if n == 1:
            raise KeyboardInterrupt

    summary = run_scan(config_from_dict({}), ScanRequest(out=out, frames=10, overlap=False), on_frame=interrupt)
    assert summary.interrupted and summary.frames_captured == 2 and summary.scans_done == 2
    assert rrd.rows(out, "/world/points") == 2
    rrd.verify(out)


def test_bad_config_is_one_line_and_exit_2(rrd, tmp_path, capsys):
    cfg = tmp_path / "rig.toml"
    cfg.write_text("[camera]\nexposure_ms = 0\n")
    assert main(["scan", "--config", str(cfg), "--out", str(tmp_path / "s.rrd")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("rig: error: ") and "camera.exposure_ms" in err[-1]
    assert not (tmp_path / "s.rrd").exists()


def test_pattern_that_does_not_fit_names_the_fix(rrd, tmp_path, capsys):
    cfg = tmp_path / "rig.toml"
    cfg.write_text("[pattern]\npitch_px = 60.0\n")
    assert main(["scan", "--config", str(cfg), "--out", str(tmp_path / "s.rrd")]) == 2
    assert "reduce pitch_px" in capsys.readouterr().err


def test_replay_runs_out_mid_scan_and_keeps_frames(rrd, tmp_path, capsys):
    raw = tmp_path / "raw"
    assert main(["scan", "--out", str(tmp_path / "first.rrd"), "--frames", "2", "--record", str(raw)]) == 0
    cfg = tmp_path / "rig.toml"
    cfg.write_text(f'calibration = "raw/calibration.json"\n[camera]\ndevice = "replay:raw"\n')
    out = tmp_path / "replayed.rrd"
    code = main(["scan", "--config", str(cfg), "--out", str(out), "--frames", "5"])
    err = capsys.readouterr().err
    assert code == DeviceError.exit_code, err
    assert "2 frame(s) captured before the fault are kept" in err
    assert rrd.rows(out, "/world/camera/image") == 2
    rrd.verify(out)


def test_graycode_mode_scans_the_whole_sequence_and_measures_depth(rrd, tmp_path):
    from drivers.sim import SimWorld, preset

    out, rec, depth = tmp_path / "gc.rrd", tmp_path / "raw", tmp_path / "depth.npy"
    summary = run_scan(config_from_dict({}), ScanRequest(out=out, record=rec, depth=depth, pattern="graycode"))
    m = json.loads((rec / "manifest.json").read_text())
    n = len(m["frames"])
    assert n == summary.frames_captured == 42  # 2·(10 + 10) + 2 for a 1024×1024 projector
    assert [f["pattern"] for f in m["frames"]] == list(range(n))
    assert rrd.rows(out, "/world/camera/image") == n
    measured = np.load(depth)
    truth = SimWorld(preset("tabletop")).truth.depth_cam
    both = np.isfinite(measured) & np.isfinite(truth)
    assert both.sum() > 0.5 * np.isfinite(truth).sum()
    rel = np.abs(measured[both] - truth[both]) / truth[both]
    assert np.median(rel) < 5e-4
    rrd.verify(out)


def test_sigterm_stops_a_running_scan_cleanly(rrd, tmp_path):
    """A real process, stopped by a signal mid-scan: exit 130, every captured frame on disk and in the recording."""
    import signal
    import subprocess
    import sys
    import time

    out, rec = tmp_path / "scan.rrd", tmp_path / "raw"
    rig = Path(sys.executable).with_name("rig")
    proc = subprocess.Popen([str(rig), "scan", "--frames", "500", "--no-reconstruct", "--out", str(out), "--record", str(rec)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            lines = (rec / "frames.jsonl").read_text().splitlines() if (rec / "frames.jsonl").exists() else []
            if len(lines) >= 3 or proc.poll() is not None:
                break
            time.sleep(0.2)
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 130, err
    m = json.loads((rec / "manifest.json").read_text())
    assert m["complete"] is False and 3 <= len(m["frames"]) < 500
    # The raw frame is written before it is logged: the signal may fall between the two.
    assert len(m["frames"]) - 1 <= rrd.rows(out, "/world/camera/image") <= len(m["frames"])
    rrd.verify(out)
