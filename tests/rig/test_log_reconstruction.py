"""rig/log_reconstruction.py: what is logged reads back as the result (depth map, segments, points)."""

from __future__ import annotations

import numpy as np

from reconstruction.pipeline import Reconstruction
from reconstruction.rigmodel import UNLABELLED
from rig.log_reconstruction import log_reconstruction
from rig.recording import Recording


def _result() -> Reconstruction:
    rng = np.random.default_rng(3)
    depth = np.full((6, 8), np.nan, np.float32)
    depth[2, 3], depth[4, 5] = 812.25, 1234.5
    n = 2
    return Reconstruction(
        points_proj=rng.normal(size=(n, 3)).astype(np.float32), q_cam=np.array([[3, 2], [5, 4]], np.float32),
        family=np.array([1, 2], np.int8), label=np.array([[4, UNLABELLED], [UNLABELLED, 7]], np.int32),
        residual=np.zeros(n, np.float32), depth_cam=depth, junctions_cam=np.array([[1.5, 2.5]], np.float32),
        junction_labels=np.array([[4, 7]], np.int32),
        segments=np.array([[[0, 0], [1, 1]], [[2, 3], [4, 5]], [[6.5, 1], [7, 2]]], np.float32),
        segment_labelled=np.array([True, False, True]), stats={"points": n, "ms": {"total": 1.0}},
    )


def test_depth_segments_and_points_read_back(rrd, tmp_path):
    res = _result()
    out = tmp_path / "r.rrd"
    with Recording(out) as rec:
        rec.set_frame(0)
        log_reconstruction(rec.stream, res)
    buf = rrd.column(out, "/world/camera/depth", "DepthImage:buffer")
    assert len(buf) == 1
    depth = np.frombuffer(bytes(np.asarray(buf[0][0], np.uint8)), np.float32).reshape(6, 8)
    expect = np.nan_to_num(res.depth_cam, nan=0.0)
    assert np.array_equal(depth, expect), "NaN (nothing measured) is logged as 0, every depth as it is"
    strips = rrd.column(out, "/world/camera/image/grid/segments", "LineStrips2D:strips")
    assert np.allclose(np.array(strips[0], np.float32), res.segments)
    pos = rrd.column(out, "/world/points", "Points3D:positions")
    assert np.allclose(np.array(pos[0], np.float32), res.points_proj)
