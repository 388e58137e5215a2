"""Decision 0094: the compiled paths of the surface labels, `RigModel.sheet_depth` and the label stage's
epipolar lines reproduce the NumPy code they replaced bit for bit."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import reconstruction.labelling as labelling
from calibration.models import Intrinsics, ProCam
from reconstruction import _label_kernels as _k
from reconstruction.extraction import ExtractOptions, extract_grid, sigma_for
from reconstruction.geometry import camera_rays_proj, depth_cam, epipolar_lines
from reconstruction.labelling import LabelOptions, TraceOptions, label_epipolar, label_samples
from reconstruction.rigmodel import UNLABELLED, rig_model
from reconstruction.surface_labels import label_from_surface

_ALONE = dict(continue_lines=False, piece_seeds=False, piece_junctions=False, cross_rounds=0, cross_rounds_after=0)


def _pinhole(procam: ProCam) -> ProCam:
    """The same rig with a camera without distortion (no camera table: the pinhole path)."""
    cam = procam.camera
    return dataclasses.replace(procam, camera=Intrinsics(cam.width, cam.height, cam.K.copy(), np.zeros(5)))


def _surface_call(scene, model):
    """label_from_surface's arguments in the label stage of the small scene, with the junction labels of a
    slanted band taken away (the case `test_recon_surface_labels` measures: several hundred samples to label)."""
    obs = extract_grid(scene.image, model)
    lo = LabelOptions(depth_min_mm=scene.depth_range_mm[0], depth_max_mm=scene.depth_range_mm[1])
    labels = label_epipolar(obs, model, model.cam_normalised(obs.q_junction), options=lo).labels.copy()
    qj = obs.q_junction
    labels[np.abs(qj[:, 0] + 0.4 * qj[:, 1] - 400.0) < 1.5 * model.junction_step_cam_px] = UNLABELLED
    sigma = float(obs.stats.get("sigma_px", sigma_for(model, ExtractOptions())))
    calls = []

    def capture(*args, **kwargs):
        calls.append(([a.copy() if isinstance(a, np.ndarray) else a for a in args], kwargs))
        return {"samples": 0}

    real = labelling.label_from_surface
    labelling.label_from_surface = capture
    try:
        label_samples(obs, labels, sigma_px=sigma, seed_radius_px=float(obs.stats["junction_radius_px"]),
                      options=dataclasses.replace(TraceOptions(), **_ALONE), model=model, depth_range_mm=scene.depth_range_mm,
                      image=scene.image, line_width_px=model.line_width_cam_px)
    finally:
        labelling.label_from_surface = real
    return calls[0]


@pytest.mark.parametrize("camera", ["table", "pinhole"])
def test_surface_labels_compiled_equals_numpy_path(small_scene, camera):
    """The compiled round (camera table, or the pinhole inverse) and the NumPy path label the same samples with
    the same index and junction, and count the same."""
    s = small_scene
    procam = s.procam if camera == "table" else _pinhole(s.procam)
    model = rig_model(procam, s.pattern, s.depth_range_mm)
    assert (model.cam_xy_table is None) == (camera == "pinhole")
    args, kwargs = _surface_call(s, model)
    q, fam, sid, piece, ts, index, seed_jid = args
    out = {}
    for compiled in (True, False):
        idx = index.copy()
        sj = seed_jid.copy()
        stats = label_from_surface(q, fam, sid, piece, ts, idx, sj, **kwargs, compiled=compiled)
        out[compiled] = (idx, sj, stats)
    (i1, j1, s1), (i0, j0, s0) = out[True], out[False]
    assert s1 == s0
    assert s1["pieces"] >= 5, s1  # something was labelled (the table rig: ~30 pieces, 600 samples)
    assert np.array_equal(i1, i0, equal_nan=True)
    assert np.array_equal(j1, j0)
    assert np.sum(np.isfinite(i1)) > np.sum(np.isfinite(index))


def test_sheet_depth_equals_sheet_check(small_scene):
    """`RigModel.sheet_depth` gives `sheet_check`'s depths to the bit: through the camera table, through the
    NumPy path (no table), and with given normalised points."""
    s = small_scene
    rng = np.random.default_rng(3)
    n = 500
    q = np.column_stack([rng.uniform(0, 639, n), rng.uniform(0, 479, n)])
    fam = rng.integers(1, 3, n)
    for procam in (s.procam, _pinhole(s.procam)):
        model = rig_model(procam, s.pattern, s.depth_range_mm)
        idx = rng.integers(model.index_min, model.index_max + 1, n)
        z_ref = model.sheet_check(q, fam, idx)[1]
        assert np.sum(np.isfinite(z_ref)) > 0.5 * n  # (random sheets: some rays miss theirs)
        assert np.array_equal(model.sheet_depth(q, fam, idx), z_ref, equal_nan=True)
        assert np.array_equal(model.sheet_depth(q, fam, idx, xy_cam=model.cam_normalised(q)), z_ref, equal_nan=True)
    # and the NumPy path is depth_cam of the light-sheet points
    model = rig_model(_pinhole(s.procam), s.pattern, s.depth_range_mm)
    p = model.intersect_light_sheets(model.cam_normalised(q), fam, idx)
    assert np.array_equal(model.sheet_depth(q, fam, idx), depth_cam(model.procam, p), equal_nan=True)


def test_epipolar_from_rays_equals_epipolar_lines(small_scene):
    """The compiled cross product and scaling of the epipolar lines equal `geometry.epipolar_lines` (to the bit
    on the development machine; within 1e-12 relative here, since another CPU or numba build may contract a
    multiply-add the other way), and each line passes through the projection of a point on its camera ray (|l·x| ~ 0)."""
    procam = small_scene.procam
    rng = np.random.default_rng(4)
    xy = rng.uniform(-0.5, 0.5, (2000, 2))
    t = np.ascontiguousarray(procam.t_proj_cam, np.float64)
    got = _k.epipolar_from_rays(camera_rays_proj(procam, xy), t)
    np.testing.assert_allclose(got, epipolar_lines(procam, xy), rtol=1e-12, atol=1e-15)
    # a point 800 mm along each camera ray, in the projector's normalised plane, lies on its line
    p = t + 800.0 * camera_rays_proj(procam, xy)
    x = p[:, :2] / p[:, 2:]
    assert np.abs(got[:, 0] * x[:, 0] + got[:, 1] * x[:, 1] + got[:, 2]).max() < 1e-12
    assert np.allclose(np.hypot(got[:, 0], got[:, 1]), 1.0)
