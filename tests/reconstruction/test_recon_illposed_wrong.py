"""Decision 0131: line-sample points on light sheets that run nearly along the epipolar lines are left out when their
predicted depth error is larger than asked for.

- `predicted_error` against the geometry: the sheet moved δ across its line, cut with the same camera ray, moves the
  point by what the prediction says (slopes from across to nearly along the epipolar line; a sideways and a
  converged camera).
- The unseen ill-posed scene where it was found (seed 126 of `benchmarks.unseen`: converged 1280 rig, pitch 14 at
  20°/119°): every junction is labelled right, yet 2.8 % of the points are more than 1 % off: samples of the family
  whose lines run within 5° of the epipolar lines. With the step, under 0.5 %; the junctions stay.
- A well-posed scene (the small test rig): nothing is left out, the outputs are those without the step.
- Part 2: decision 0089's piece seeds are off by default; on unseen seed 134 the points they add are nearly all
  wrong.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from calibration.models import Intrinsics, ProCam, look_at
from reconstruction.sheet_precision import SheetPrecisionOptions, frame_noise_px, imprecise_samples, predicted_error


def _procam(t) -> ProCam:
    cam = Intrinsics(1280, 1024, np.array([[1500.0, 0, 639.5], [0, 1500.0, 511.5], [0, 0, 1]]), np.zeros(5))
    prj = Intrinsics(1024, 768, np.array([[1400.0, 0, 511.5], [0, 1400.0, 383.5], [0, 0, 1]]), np.zeros(5))
    t = np.asarray(t, np.float64)
    return ProCam(cam, prj, look_at(t, np.array([0, 0, 900.0])), t)


def _moved_sheet_error(procam: ProCam, p: np.ndarray, slope: float, delta_px: float) -> float:
    """|p' − p| / |p|: p' the camera ray through p cut with the sheet of the projector line through p's projector
    pixel, moved delta_px across the line (a plane through the projector centre)."""
    K = procam.projector.K
    q = K @ (p / p[2])
    d_line = np.array([1.0, slope]) / np.hypot(1.0, slope)
    n_img = np.array([-d_line[1], d_line[0]])
    a = np.array([q[0] + delta_px * n_img[0], q[1] + delta_px * n_img[1], 1.0])
    b = a + np.array([d_line[0], d_line[1], 0.0]) * 50.0
    Ki = np.linalg.inv(K)
    normal = np.cross(Ki @ a, Ki @ b)  # the sheet: a plane through the projector centre
    t = procam.t_proj_cam
    d = p - t
    lam = -(normal @ t) / (normal @ d)
    p2 = t + lam * d
    return float(np.linalg.norm(p2 - p) / np.linalg.norm(p))


@pytest.mark.parametrize("t", [(200.0, 0.0, 0.0), (250.0, 40.0, 60.0)])
def test_predicted_error_is_the_geometry_of_a_moved_sheet(t):
    procam = _procam(t)
    K, tt = procam.projector.K, procam.t_proj_cam
    rng = np.random.default_rng(3)
    p = np.column_stack([rng.uniform(-150, 150, 12), rng.uniform(-120, 120, 12), rng.uniform(700, 1100, 12)])
    q = (K @ (p / p[:, 2:3]).T).T
    e = K @ tt
    du, dv = e[0] - q[:, 0] * e[2], e[1] - q[:, 1] * e[2]
    epi = np.arctan2(dv, du)
    delta = 0.002  # small: the prediction is the first-order term (at 0.3°, 0.05 px moves the point 3 % and bends it)
    for k in range(len(p)):
        # across, oblique, and within 3°, 1° and 0.3° of the epipolar line
        for off_deg in (90.0, 30.0, 3.0, 1.0, 0.3):
            slope = np.tan(epi[k] + np.radians(off_deg))
            want = _moved_sheet_error(procam, p[k], slope, delta)
            got = predicted_error(K, tt, np.array([slope]), p[k : k + 1], delta)[0]
            assert got == pytest.approx(want, rel=0.03), (k, off_deg)
        # the error grows as 1 / sin θ: 0.3° is about 190 times 90°
        r = predicted_error(K, tt, np.tan(epi[k] + np.radians([90.0, 0.3])), p[[k, k]], delta)
        assert r[1] / r[0] == pytest.approx(1 / np.sin(np.radians(0.3)), rel=0.05)


def test_only_samples_past_the_limit_are_flagged_and_junctions_never():
    procam = _procam((200.0, 0.0, 0.0))
    K, t = procam.projector.K, procam.t_proj_cam
    p = np.array([[0.0, 0.0, 900.0]] * 4)
    # epipolar lines horizontal (camera displaced along x): slope 0 runs along them, slope 1 at 45°
    fam = np.array([0, 1, 2, 1])
    n1, n2 = np.tan(np.radians(0.2)), 1.0
    err = predicted_error(K, t, np.array([n1, n2, n1]), p[1:], 0.1)
    lim = 100 * float(np.sqrt(err[0] * err[1]))  # between the two
    flagged = imprecise_samples(K, t, n1, n2, p, fam, 0.1, SheetPrecisionOptions(max_error_pct=lim))
    assert flagged.tolist() == [False, True, False, True]
    assert not imprecise_samples(K, t, n1, n2, p, fam, 0.1, SheetPrecisionOptions(enabled=False)).any()
    # a noisier frame (or a rougher calibration's floor) flags the 45° samples too once δ·G / sin 45° passes the limit
    noisier = 0.1 * (lim / 100) / err[1]
    assert imprecise_samples(K, t, n1, n2, p, fam, 0.99 * noisier, SheetPrecisionOptions(max_error_pct=lim)).tolist() == [False, True, False, True]
    assert imprecise_samples(K, t, n1, n2, p, fam, 1.01 * noisier, SheetPrecisionOptions(max_error_pct=lim)).tolist() == [False, True, True, True]
    assert frame_noise_px(np.full(30, 0.01), 0.1) == 0.1
    assert frame_noise_px(np.r_[np.full(30, 0.3), np.nan], 0.1) == pytest.approx(1.4826 * 0.3)
    assert frame_noise_px(np.full(5, 0.3), 0.1) == 0.1  # too few junctions: the floor


@pytest.fixture(scope="module")
def ill_posed_scene():
    from benchmarks._common import render_scene
    from benchmarks.unseen import draw_scene
    from drivers.sim.presets import depth_range

    _rig, procam, scene, pattern, noise = draw_scene(126)
    image, truth = render_scene(procam, scene, pattern, noise_grey=noise, seed=126)
    return procam, pattern, image, truth, depth_range(procam, scene)


def test_the_ill_posed_unseen_scene_loses_its_wrong_points_not_its_junctions(ill_posed_scene):
    from benchmarks._common import relative_errors
    from reconstruction.pipeline import ReconstructOptions, reconstruct

    procam, pattern, image, truth, dr = ill_posed_scene
    o = ReconstructOptions(depth_min_mm=dr[0], depth_max_mm=dr[1])
    off = reconstruct(image, procam, pattern, options=dataclasses.replace(o, sheet_precision=SheetPrecisionOptions(enabled=False)))
    on = reconstruct(image, procam, pattern, options=o)
    assert any("ill-posed" in w for w in on.warnings)
    e_off = relative_errors(off.points_proj, off.q_cam, truth)
    e_on = relative_errors(on.points_proj, on.q_cam, truth)
    assert np.mean(e_off > 0.01) > 0.01  # the failure: right labels, imprecise points
    assert np.mean(e_on > 0.01) < 0.005
    assert np.percentile(e_on, 99) < 0.005
    # the junctions are all kept; what is left out are samples, counted
    assert (on.family == 0).sum() == (off.family == 0).sum()
    assert on.stats["samples_imprecise"] == off.n_points - on.n_points > 0
    # they are the family whose lines run along the epipolar lines: the other family keeps its points
    fam_along = np.bincount(off.family, minlength=3)[1:] - np.bincount(on.family, minlength=3)[1:]
    assert fam_along.min() == 0
    # the depth map holds no dropped point
    z_map = np.isfinite(on.depth_cam).sum()
    assert z_map <= np.isfinite(off.depth_cam).sum()


def test_a_well_posed_scene_is_unchanged(small_scene):
    from reconstruction.pipeline import ReconstructOptions, reconstruct

    s = small_scene
    o = ReconstructOptions(depth_min_mm=s.depth_range_mm[0], depth_max_mm=s.depth_range_mm[1])
    # decision 0151's own offsets off: they leave out a few samples here (test_recon_own_offset)
    on = reconstruct(s.image, s.procam, s.pattern, options=dataclasses.replace(o, sheet_precision=SheetPrecisionOptions(own_offset=False)))
    off = reconstruct(s.image, s.procam, s.pattern, options=dataclasses.replace(o, sheet_precision=SheetPrecisionOptions(enabled=False)))
    assert on.stats["samples_imprecise"] == 0
    assert np.array_equal(on.points_proj, off.points_proj) and np.array_equal(on.q_cam, off.q_cam)
    assert np.array_equal(on.depth_cam, off.depth_cam, equal_nan=True)


def test_the_compiled_flags_are_the_numpy_prediction():
    rng = np.random.default_rng(0)
    n = 4000
    p = np.column_stack([rng.uniform(-100, 100, n), rng.uniform(-100, 100, n), rng.uniform(800, 1000, n)]).astype(np.float32)
    fam = rng.integers(0, 3, n).astype(np.int8)
    procam = _procam((200.0, 10.0, 30.0))
    K, t = procam.projector.K, procam.t_proj_cam
    n1, n2 = 0.03, -2.0
    sel = fam > 0
    err = predicted_error(K, t, np.where(fam[sel] == 1, n1, n2), p[sel].astype(np.float64), 0.1)
    e = np.sort(err)
    lim = 50 * float(e[len(e) // 2] + e[len(e) // 2 + 1])  # between two predictions: no rounding at the limit
    got = imprecise_samples(K, t, n1, n2, p, fam, 0.1, SheetPrecisionOptions(max_error_pct=lim))
    want = np.zeros(n, bool)
    want[sel] = ~(err <= lim / 100)
    assert 0 < want.sum() < sel.sum()
    assert np.array_equal(got, want)


def test_piece_seeds_are_off_and_on_unseen_seed_134_their_points_were_mostly_wrong():
    """Decision 0131, part 2: decision 0089's one-sided piece seeds are off by default. On unseen seed 134 (tabletop,
    pitch 16 at 36°/124°, not warned) the points they add are nearly all a line off, and without them the scene
    meets the issue's > 1 % target."""
    from benchmarks._common import relative_errors, render_scene
    from benchmarks.unseen import draw_scene
    from drivers.sim.presets import depth_range
    from reconstruction.labelling import TraceOptions
    from reconstruction.pipeline import ReconstructOptions, reconstruct

    assert TraceOptions().piece_seeds is False
    _rig, procam, scene, pattern, noise = draw_scene(134)
    image, truth = render_scene(procam, scene, pattern, noise_grey=noise, seed=134)
    dr = depth_range(procam, scene)
    o = ReconstructOptions(depth_min_mm=dr[0], depth_max_mm=dr[1])
    default = reconstruct(image, procam, pattern, options=o)
    # the step's own points, measured without decision 0141's guard (which takes most of them back on this scene:
    # they contradict an ambiguous junction component's best offset)
    o = dataclasses.replace(o, trace=dataclasses.replace(o.trace, ambiguity_guard=False))
    off = reconstruct(image, procam, pattern, options=o)
    on = reconstruct(image, procam, pattern, options=dataclasses.replace(o, trace=dataclasses.replace(o.trace, piece_seeds=True)))
    e_off = relative_errors(off.points_proj, off.q_cam, truth)
    e_on = relative_errors(on.points_proj, on.q_cam, truth)
    added = on.n_points - off.n_points
    added_wrong = int((e_on > 0.01).sum() - (e_off > 0.01).sum())
    assert added > 10 and added_wrong >= 0.8 * added
    assert np.mean(e_off > 0.01) < 0.005
    assert np.mean(relative_errors(default.points_proj, default.q_cam, truth) > 0.01) < 0.005
