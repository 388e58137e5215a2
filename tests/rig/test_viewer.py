"""A scan recording opened in the real Rerun viewer (headless, Mesa's software Vulkan), and `rig view` itself.

The viewer test writes a small recording with rig.recording (rig geometry, pattern, three frames, depth, points,
grid overlay, statistics), opens it in `rerun --headless`, drives it with rerun.experimental.ViewerClient, and
checks that it loads, that the default blueprint's views report no errors, and that the screenshots show what was
logged (the points' colour in the 3-D view, the overlay's colour in the camera view). Recipe and pitfalls:
/work/shared/notes/rerun-0.41.md and docs/decisions/0080-viewer-test.md.
"""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from calibration.models import Intrinsics, ProCam, look_at

LAVAPIPE_ICD = Path("/usr/share/vulkan/icd.d/lvp_icd.x86_64.json")
CONNECT_TIMEOUT_S = 30.0
LOAD_TIMEOUT_S = 30.0

POINTS_RGB = (255, 0, 255)  # magenta: nothing else in the viewer's dark theme has it
OVERLAY_RGB = (0, 255, 255)  # cyan grid overlay over the camera image


# --- the recording -----------------------------------------------------------------------------------------------
def _procam() -> ProCam:
    cam = Intrinsics(320, 240, [[300, 0, 159.5], [0, 300, 119.5], [0, 0, 1]])
    proj = Intrinsics(400, 300, [[350, 0, 199.5], [0, 350, 149.5], [0, 0, 1]])
    eye = np.array([200.0, 0.0, 0.0])
    return ProCam(cam, proj, look_at(eye, np.array([0.0, 0.0, 800.0])), eye)


def _write_scan(path: Path, *, frames: int = 3) -> ProCam:
    """A small scan: a plane at z = 800 mm seen by the camera, with its points, depth, overlay and statistics."""
    import rerun as rr

    from reconstruction.patterns import GridPattern
    from rig.recording import open_recording

    pc = _procam()
    pattern = GridPattern(pitch_px=20.0, lines=11, centre_px=(199.5, 149.5)).render(400, 300)
    cam = pc.camera
    q_cam = cam.pixel_grid()
    rays_proj = cam.rays(q_cam) @ pc.R_proj_cam.T
    with open_recording(path, procam=pc, pattern_image=pattern, report={"rms_px": 0.31}) as rec:
        for n in range(frames):
            z_plane = 800.0 + 10.0 * n
            lam = (z_plane - pc.t_proj_cam[2]) / rays_proj[:, 2]
            p_proj = pc.t_proj_cam + lam[:, None] * rays_proj
            depth = pc.proj_to_cam(p_proj)[:, 2].reshape(cam.height, cam.width).astype(np.float32)
            # The camera sees the pattern as stripes: enough texture that a blank view would be noticed.
            q_proj = pc.projector.project(p_proj)
            image = np.where(((q_proj[:, 0] // 20 + q_proj[:, 1] // 20) % 2) == 0, 200, 40)
            rec.log_frame(n, image.reshape(cam.height, cam.width).astype(np.uint8), timestamp_s=100.0 + n)
            rec.stream.log("world/camera/depth", rr.DepthImage(depth, meter=1000.0))
            rec.stream.log("world/points", rr.Points3D(p_proj[::7].astype(np.float32), colors=POINTS_RGB, radii=3.0))
            strips = [np.array([[20.0, 20.0 + 40 * k], [300.0, 30.0 + 40 * k]]) for k in range(5)]
            rec.stream.log("world/camera/image/grid", rr.LineStrips2D(strips, colors=OVERLAY_RGB, radii=2.0))
            rec.stream.log("stats/points", rr.Scalars(float(len(p_proj) // 7 + 100 * n)))
    return pc


# --- the viewer process ------------------------------------------------------------------------------------------
def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _rerun_exe() -> str:
    exe = Path(sys.executable).parent / "rerun"
    assert exe.is_file(), f"the rerun executable is missing beside {sys.executable} (rerun-sdk not installed?)"
    return str(exe)


def _tail(log: Path, n: int = 15) -> str:
    try:
        return "\n".join(log.read_text(errors="replace").splitlines()[-n:])
    except OSError:
        return "(no viewer log)"


@contextlib.contextmanager
def _headless_viewer(workdir: Path):
    """A `rerun --headless` viewer on a free local port, yielding a connected ViewerClient; always killed after."""
    from rerun.experimental import ViewerClient

    home, tmp, xdg = workdir / "home", workdir / "tmp", workdir / "xdg"
    for d in (home, tmp, xdg):
        d.mkdir(mode=0o700, exist_ok=True)
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    # Its own HOME/TMPDIR: the viewer writes analytics settings and temporary folders there, not in the user's.
    env.update(
        WGPU_BACKEND="vulkan", VK_ICD_FILENAMES=str(LAVAPIPE_ICD), HOME=str(home), TMPDIR=str(tmp),
        XDG_RUNTIME_DIR=str(xdg),
    )
    log = workdir / "viewer.log"
    port = _free_port()
    cmd = [_rerun_exe(), "--headless", "--bind", "127.0.0.1", "--port", str(port), "--hide-welcome-screen",
           "--window-size", "1280x800"]
    with open(log, "wb") as log_f:
        # A new session: the `rerun` script runs the viewer binary as a child, so the whole group is killed.
        proc = subprocess.Popen(cmd, env=env, stdout=log_f, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                cwd=workdir, start_new_session=True)
    try:
        deadline = time.monotonic() + CONNECT_TIMEOUT_S
        while True:
            if proc.poll() is not None:
                pytest.fail(f"the viewer exited with code {proc.returncode} before accepting a connection:\n{_tail(log)}")
            try:
                client = ViewerClient.connect(f"rerun+http://127.0.0.1:{port}/proxy")
                client.get_state()
                break
            except ConnectionError:
                if time.monotonic() > deadline:
                    pytest.fail(f"no connection to the headless viewer within {CONNECT_TIMEOUT_S} s:\n{_tail(log)}")
                time.sleep(0.3)
        yield client, log
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout=10)


def _wait_loaded(client, log: Path):
    deadline = time.monotonic() + LOAD_TIMEOUT_S
    while True:
        state = client.get_state()
        frame_tl = [t for r in state.recordings for t in r.timelines if t.name == "frame"]
        if not state.loading and state.views and frame_tl and frame_tl[0].end is not None:
            return state
        if time.monotonic() > deadline:
            pytest.fail(f"the viewer did not finish loading within {LOAD_TIMEOUT_S} s: {state.loading}\n{_tail(log)}")
        time.sleep(0.2)


def _png_rgb(data: bytes) -> np.ndarray:
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    assert img is not None, "the viewer returned something that is not a PNG"
    return img[..., ::-1]


def _best_screenshot(client, view_ids: list[str], score, *, enough: float, timeout_s: float = 20.0) -> float:
    """Screenshot the views until one scores `enough` or `timeout_s` passes; returns the best score seen."""
    deadline = time.monotonic() + timeout_s
    best = -np.inf
    while True:
        for view_id in view_ids:
            best = max(best, score(_png_rgb(client.take_screenshot(view_id))))
        if best >= enough or time.monotonic() > deadline:
            return best
        time.sleep(0.5)


def _pixels_near(img_rgb: np.ndarray, rgb, tol: int = 40) -> int:
    return int(np.all(np.abs(img_rgb.astype(int) - np.array(rgb)) <= tol, axis=-1).sum())


@pytest.mark.viewer
@pytest.mark.timeout(150)
def test_scan_opens_in_the_real_viewer(tmp_path):
    if not LAVAPIPE_ICD.is_file():
        pytest.skip(f"no software Vulkan driver ({LAVAPIPE_ICD} absent): apt-get install mesa-vulkan-drivers libvulkan1 "
                    "(.ci/run does)")
    scan = tmp_path / "scan.rrd"
    _write_scan(scan, frames=3)
    with _headless_viewer(tmp_path) as (client, log):
        client.open(str(scan))
        state = _wait_loaded(client, log)

        (recording,) = state.recordings
        frame_tl = {t.name: t for t in recording.timelines}["frame"]
        assert (frame_tl.start, frame_tl.end) == (0, 2)
        assert "capture_time" in {t.name for t in recording.timelines}

        # The default blueprint travelled inside the file: 3-D, camera and depth images, statistics, report.
        classes = [v.view_class for v in state.views]
        assert {"3D", "2D", "TimeSeries", "TextDocument"} <= set(classes), classes
        assert classes.count("2D") >= 2, classes

        client.set_time("frame", sequence=2, play_state="paused")
        # Chunks load lazily: poll each view's screenshot until it shows what was logged (or time runs out).
        view_3d = [v.view_id for v in state.views if v.view_class == "3D"]
        points = _best_screenshot(client, view_3d, lambda im: _pixels_near(im, POINTS_RGB), enough=200)
        assert points >= 200, f"the 3-D view does not show the logged (magenta) points ({points} pixels)"
        cam_views = [v.view_id for v in state.views if v.view_class == "2D" and v.origin == "/world/camera"]
        overlay = _best_screenshot(client, cam_views, lambda im: _pixels_near(im, OVERLAY_RGB), enough=200)
        assert overlay >= 200, f"no camera view shows the (cyan) grid overlay ({overlay} pixels)"

        shot = tmp_path / "shot.png"
        client.save_screenshot(str(shot))
        assert shot.is_file(), "the viewer wrote no screenshot"
        whole = cv2.imread(str(shot), cv2.IMREAD_COLOR)[..., ::-1]
        assert whole.shape[:2] == (800, 1280)
        assert whole.std() > 10, f"the screenshot is blank (pixel std {whole.std():.1f})"

        # Views are checked after they were painted: their reports say what failed to visualise.
        state = client.get_state()
        errors = [(v.name, r.summary) for v in state.views for r in v.reports if r.severity == "error"]
        assert not errors, f"views report errors: {errors}"
        logged = [e.message for e in client.get_logs() if e.level == "ERROR"]
        assert not logged, f"the viewer logged errors: {logged}"


# --- `rig view` --------------------------------------------------------------------------------------------------
def _run_view(args, monkeypatch, *, display: str | None):
    from rig.cli import main

    if display is None:
        monkeypatch.delenv("DISPLAY", raising=False)
    else:
        monkeypatch.setenv("DISPLAY", display)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr(sys, "platform", "linux")
    return main(["view", *args])


def test_rig_view_headless_says_how(tmp_path, monkeypatch, capsys):
    scan = tmp_path / "my scan.rrd"
    scan.write_bytes(b"")
    assert _run_view([str(scan)], monkeypatch, display=None) == 0
    out = capsys.readouterr().out.strip().splitlines()
    assert len(out) == 1, out
    assert f"rerun '{scan}'" in out[0]
    assert f"--headless --window-size 1280x800 --screenshot-to '{tmp_path / 'my scan.png'}' '{scan}'" in out[0]


def test_rig_view_with_a_display_runs_the_viewer_beside_python(tmp_path, monkeypatch):
    scan = tmp_path / "scan.rrd"
    scan.write_bytes(b"")
    calls = []
    monkeypatch.setattr(subprocess, "call", lambda argv: calls.append(argv) or 0)
    assert _run_view([str(scan)], monkeypatch, display=":0") == 0
    assert calls == [[str(Path(sys.executable).parent / "rerun"), str(scan)]]


def test_rig_view_refuses_missing_and_non_rrd_files(tmp_path, monkeypatch, capsys):
    assert _run_view([str(tmp_path / "absent.rrd")], monkeypatch, display=None) == 2
    err = capsys.readouterr().err
    assert "absent.rrd: no such recording" in err and "rig scan --out" in err
    (tmp_path / "killed.rrd.partial").write_bytes(b"")
    assert _run_view([str(tmp_path / "killed.rrd")], monkeypatch, display=None) == 2
    assert "killed before it closed its recording" in capsys.readouterr().err
    (tmp_path / "points.ply").write_bytes(b"ply\n")
    assert _run_view([str(tmp_path / "points.ply")], monkeypatch, display=":0") == 2
    assert "not a Rerun recording (expected a .rrd file" in capsys.readouterr().err
