"""Recordings: the layout of docs/recording.md, read back with Rerun's own reader; atomic; valid after errors."""

from __future__ import annotations

import numpy as np
import pytest

from calibration.models import Intrinsics, ProCam, look_at
from rig.recording import open_recording


def _procam() -> ProCam:
    cam = Intrinsics(64, 48, [[60, 0, 31.5], [0, 60, 23.5], [0, 0, 1]])
    proj = Intrinsics(80, 60, [[70, 0, 39.5], [0, 70, 50.0], [0, 0, 1]])
    return ProCam(cam, proj, look_at(np.array([200.0, 0, 0]), np.array([0, 0, 800.0])), [200.0, 0, 0])


def test_layout_and_round_trip(tmp_path, rrd):
    out = tmp_path / "scan.rrd"
    pc = _procam()
    frames = [np.full((48, 64), 10 * i, np.uint8) for i in range(3)]
    with open_recording(out, procam=pc, pattern_image=np.zeros((60, 80), np.uint8)) as rec:
        assert not out.exists(), "nothing under the final name while writing"
        for i, f in enumerate(frames):
            rec.log_frame(i, f, timestamp_s=100.0 + i)
    assert out.exists() and not (tmp_path / "scan.rrd.partial").exists()
    ents = rrd.entities(out)
    for e in ("/world", "/world/projector", "/world/camera", "/world/camera/image", "/world/projector/pattern", "/report"):
        assert e in ents, e
    image_rows = " ".join(ents["/world/camera/image"])
    assert rrd.rows(out, "/world/camera/image") == 3 and "frame" in image_rows and "capture_time" in image_rows
    # The camera pose reads back (column-major mat3x3, see the Rerun notes).
    t = rrd.column(out, "/world/camera", "Transform3D:translation")[0]
    np.testing.assert_allclose(np.array(t).ravel(), pc.t_proj_cam)
    R = np.array(rrd.column(out, "/world/camera", "Transform3D:mat3x3")[0]).reshape(3, 3).T
    np.testing.assert_allclose(R, pc.R_proj_cam, atol=1e-6)
    K = np.array(rrd.column(out, "/world/camera", "Pinhole:image_from_camera")[0]).reshape(3, 3).T
    np.testing.assert_allclose(K, pc.camera.K)
    rrd.verify(out)


def test_closed_and_renamed_after_an_error(tmp_path, rrd):
    out = tmp_path / "scan.rrd"
    with pytest.raises(RuntimeError):
        with open_recording(out, procam=_procam()) as rec:
            rec.log_frame(0, np.zeros((48, 64), np.uint8), timestamp_s=1.0)
            raise RuntimeError("device fell over")
    assert rrd.rows(out, "/world/camera/image") == 1
    rrd.verify(out)


def test_sixteen_bit_frames_keep_their_depth(tmp_path, rrd):
    out = tmp_path / "scan.rrd"
    with open_recording(out, procam=_procam()) as rec:
        rec.log_frame(0, np.full((48, 64), 40000, np.uint16))
    import rerun as rr

    fmt = rrd.column(out, "/world/camera/image", "Image:format")[0][0]
    assert rr.ChannelDatatype(fmt["channel_datatype"]).to_np_dtype() == np.uint16
    assert (fmt["width"], fmt["height"]) == (64, 48)
