"""Points through the crossings' gaps of lines labelled on both sides (decision 0086,
reconstruction.crossing_fill), against simulator truth."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from calibration.models import Intrinsics, ProCam, look_at
from reconstruction.crossing_fill import CrossingFillOptions, fill_crossings
from reconstruction.extraction import ExtractOptions, extract_grid, sigma_for
from reconstruction.labelling import LabelOptions, TraceOptions, label_epipolar, label_samples
from reconstruction.patterns import GridPattern
from reconstruction.pipeline import ReconstructOptions, reconstruct
from reconstruction.rigmodel import UNLABELLED, rig_model
from tests.reconstruction._scenes import PINHOLE_DEPTH_RANGE, PINHOLE_PATTERN, collinear_plate


def _read(img: np.ndarray, q: np.ndarray) -> np.ndarray:
    m = q.astype(np.float32).reshape(-1, 1, 2)
    return cv2.remap(img.astype(np.float32), m[..., 0], m[..., 1], cv2.INTER_LINEAR, borderValue=np.nan).reshape(len(q), -1)


def _line_offset_px(pattern: GridPattern, truth, q: np.ndarray, fam: np.ndarray, index: np.ndarray) -> np.ndarray:
    """Projector px between the projector point each camera pixel q sees (truth) and the centre of line
    (fam, index) (uniform spacing)."""
    qp = _read(truth.q_proj, q)
    n = np.where(fam == 1, pattern.n1, pattern.n2)
    s = (qp[:, 1] - pattern.centre_px[1]) - n * (qp[:, 0] - pattern.centre_px[0])
    return np.abs(s - index * pattern.pitch_px) / np.hypot(1.0, n)


def _stages(procam, pattern, image, depth_range, **trace):
    model = rig_model(procam, pattern, depth_range)
    obs = extract_grid(image, model)
    lab = label_epipolar(obs, model, model.cam_normalised(obs.q_junction),
                         options=LabelOptions(depth_min_mm=depth_range[0], depth_max_mm=depth_range[1]))
    sigma = float(obs.stats.get("sigma_px", sigma_for(model, ExtractOptions())))
    sl = label_samples(obs, lab.labels, sigma_px=sigma, seed_radius_px=float(obs.stats["junction_radius_px"]),
                       options=dataclasses.replace(TraceOptions(), **trace), model=model, depth_range_mm=depth_range,
                       image=image, line_width_px=model.line_width_cam_px)
    return model, obs, lab.labels, sigma, sl


def _fill(model, obs, labels, sigma, sl, depth_range, **opts):
    return fill_crossings(sl.q, obs.family, sl.index, sl.junction, q_samples=obs.q, family_samples=obs.family,
                          q_junction=obs.q_junction, junction_dir=obs.junction_dir, junction_labels=labels, model=model,
                          sigma_px=sigma, cell_px=float(max(1, int(obs.stats.get("scale", 1)))), depth_range_mm=depth_range,
                          options=CrossingFillOptions(**opts))



def test_points_added_in_crossing_gaps_lie_on_their_true_line(small_scene):
    """The small rig's plane and sphere (full resolution, σ ≈ 1.1 px): every added point lies on the centre
    of the line whose index it carries, as closely as the extracted samples do."""
    sc = small_scene
    model, obs, labels, sigma, sl = _stages(sc.procam, sc.pattern, sc.image, sc.depth_range_mm)
    cp = _fill(model, obs, labels, sigma, sl, sc.depth_range_mm)
    assert len(cp.q) >= 1000, cp.stats
    assert cp.stats["crossing_gaps_filled"] >= 500
    d = _line_offset_px(sc.pattern, sc.truth, cp.q, cp.family, cp.index)
    assert np.isfinite(d).all()
    # measured: median 0.018, p90 0.068, max 0.86 projector px (the extracted samples: median 0.018, p90 0.065)
    assert np.percentile(d, 90) <= 0.1, np.percentile(d, [50, 90, 100])
    assert d.max() <= 1.0, d.max()
    # each added point lies in a gap: no labelled sample of its line within half a sampling step
    ok = np.isfinite(sl.index)
    for f in (1, 2):
        m = cp.family == f
        dmin = np.min(np.hypot(*(cp.q[m][:, None, :] - sl.q[ok & (obs.family == f)][None, :, :]).transpose(2, 0, 1))
                      + 1e9 * (cp.index[m][:, None] != sl.index[ok & (obs.family == f)][None, :]), axis=1)
        assert dmin.min() >= 0.5, dmin.min()


@pytest.fixture(scope="module")
def wide_lines():
    """The small rig's plane and sphere (conftest.small_procam's devices) shown a grid of 8 px wide lines, pitch
    48: σ ≈ 2.9 px, so extraction works at half resolution (as on the paper rigs)."""
    from drivers.sim import Plane, RenderOptions, Scene, Sphere, render

    cam = Intrinsics(640, 480, np.array([[900.0, 0, 319.5], [0, 900.0, 239.5], [0, 0, 1]]), np.array([-0.05, 0.02, 0, 0, 0]))
    prj = Intrinsics(800, 600, np.array([[1000.0, 0, 399.5], [0, 1000.0, 299.5], [0, 0, 1]]), np.array([0.03, 0, 0, 0, 0]))
    t = np.array([180.0, 60.0, 40.0])
    procam = ProCam(cam, prj, look_at(t, np.array([0, 0, 800.0])), t)
    pattern = GridPattern(pitch_px=48.0, lines=13, centre_px=(399.5, 299.5), line_width_px=8.0)
    scene = Scene(objects=[Plane(np.array([0, 0, 900.0]), np.array([0.1, -0.2, -1.0])), Sphere(np.array([30.0, 20.0, 760.0]), 90.0)])
    image, truth = render(procam, scene, pattern.render(800, 600), options=RenderOptions(noise_grey=2.0, supersample=2),
                          rng=np.random.default_rng(0))
    return procam, pattern, image, truth, (500.0, 1200.0)


def test_wide_lines_at_half_resolution_fill_the_crossings_cores(wide_lines):
    """Every added point lies inside its line (within a quarter of the line's width of its centre; the
    neighbouring line is 48 px away), most of them within a fraction of a pixel, and coverage rises."""
    from benchmarks.bench_reconstruction import coverage

    procam, pattern, image, truth, depth_range = wide_lines
    model, obs, labels, sigma, sl = _stages(procam, pattern, image, depth_range)
    assert obs.stats.get("scale") == 2 and sigma > 2.6
    cp = _fill(model, obs, labels, sigma, sl, depth_range)
    assert len(cp.q) >= 300, cp.stats
    d = _line_offset_px(pattern, truth, cp.q, cp.family, cp.index)
    # measured: median 0.03, p90 0.27, max 1.2 projector px (the extracted samples: median 0.03, p90 0.14, p99 0.68)
    assert np.percentile(d, 90) <= 0.4, np.percentile(d, [50, 90, 100])
    assert d.max() <= 0.25 * pattern.line_width_px, d.max()
    res = {on: reconstruct(image, procam, pattern, options=ReconstructOptions(depth_min_mm=depth_range[0], depth_max_mm=depth_range[1],
                                                                              crossing=CrossingFillOptions(enabled=on)))
           for on in (False, True)}
    assert res[True].stats["samples_crossing_filled"] == len(cp.q)
    assert res[True].n_points >= res[False].n_points + 0.9 * len(cp.q)
    # measured 70.9 % -> 72.2 %
    assert coverage(truth, pattern, res[True].q_cam) >= coverage(truth, pattern, res[False].q_cam) + 0.008


def test_the_paper_labeller_gets_no_crossing_points(small_scene):
    """--labeller paper stays the paper's method: no points are added, the output is that of the fill turned off."""
    sc = small_scene
    out = {}
    for on in (False, True):
        o = ReconstructOptions(labeller="paper", depth_min_mm=sc.depth_range_mm[0], depth_max_mm=sc.depth_range_mm[1],
                               crossing=CrossingFillOptions(enabled=on))
        out[on] = reconstruct(sc.image, sc.procam, sc.pattern, options=o)
    assert out[True].stats["samples_crossing_filled"] == 0
    assert out[True].n_points == out[False].n_points > 1000
    assert np.array_equal(out[True].points_proj, out[False].points_proj)
    # the default labeller on the same image does add points
    d = reconstruct(sc.image, sc.procam, sc.pattern, options=ReconstructOptions(depth_min_mm=sc.depth_range_mm[0],
                                                                                 depth_max_mm=sc.depth_range_mm[1]))
    assert d.stats["samples_crossing_filled"] >= 1000

# --- a depth edge: a plate in front of a plane whose line j = 6 continues the plane's line j = 0 in the image --
# (the construction of test_recon_trace_depth_edges.py, decision 0084: the one case where a line on two
# surfaces looks like one straight line in the image, so the tangent tests cannot see the edge)

DEPTH_RANGE, PATTERN = PINHOLE_DEPTH_RANGE, PINHOLE_PATTERN


@pytest.fixture(scope="module")
def plate_with_a_gap_at_the_edge():
    """The collinear plate, labelled with the trace leak that decision 0084's check removes (far_end_check off:
    the plane's line 0 carries the plate's index 6 past the silhouette), and the samples within 2.5 px of the
    edge point taken out (a gap at the silhouette, as the cut-profile test leaves one): a gap of line 6 whose
    sides are collinear and carry one index, with no crossing in it."""
    procam, image, truth, edge = collinear_plate()
    model, obs, labels, sigma, _sl = _stages(procam, PATTERN, image, DEPTH_RANGE)
    object_id = _read(truth.object_id, obs.q_junction)[:, 0]
    gone = (np.hypot(*(obs.q_junction - edge).T) < 2.0 * model.junction_step_cam_px) & (np.rint(object_id) == 0)
    labels[gone] = UNLABELLED  # as in test_recon_trace_depth_edges.py: the plane's junctions next to the edge unlabelled
    sl = label_samples(obs, labels, sigma_px=sigma, seed_radius_px=float(obs.stats["junction_radius_px"]),
                       options=dataclasses.replace(TraceOptions(), far_end_check=False), model=model, depth_range_mm=DEPTH_RANGE,
                       image=image, line_width_px=model.line_width_cam_px)
    index = sl.index.copy()
    cut = (obs.family == 2) & (index == 6) & (np.hypot(*(sl.q - edge).T) < 2.5)
    index[cut] = np.nan
    sl = dataclasses.replace(sl, index=index)
    return truth, model, obs, labels, sigma, sl, edge, int(cut.sum())


def test_a_gap_at_a_depth_edge_gets_no_points(plate_with_a_gap_at_the_edge):
    truth, model, obs, labels, sigma, sl, edge, n_cut = plate_with_a_gap_at_the_edge
    assert n_cut >= 4
    # on both sides of the gap the labels say 6, on the plate (object 1) and on the plane (object 0)
    near = (obs.family == 2) & (sl.index == 6) & (np.hypot(*(sl.q - edge).T) < 8.0)
    side = np.rint(_read(truth.object_id, sl.q[near])[:, 0])
    assert (side == 1).sum() >= 3 and (side == 0).sum() >= 3
    # the tangent tests alone do not see the edge (the lines are collinear by construction): without the
    # crossing requirement the gap is filled, with points that are far off the surface
    loose = _fill(model, obs, labels, sigma, sl, DEPTH_RANGE, require_crossing=False)
    in_gap = np.hypot(*(loose.q - edge).T) < 2.5
    assert in_gap.sum() >= 2, loose.stats
    from benchmarks._common import relative_errors

    p = model.intersect_light_sheets(model.cam_normalised(loose.q[in_gap]), loose.family[in_gap], loose.index[in_gap].astype(np.intp))
    err = relative_errors(p, loose.q[in_gap], truth)
    assert err.max() > 0.1, err  # measured: 24 % and 26 % off on the plane's side of the edge
    # with it (the default) the gap stays empty: no labelled junction of line 6 within the crossing's reach,
    # and no line of the other family runs through it
    cp = _fill(model, obs, labels, sigma, sl, DEPTH_RANGE)
    assert int((np.hypot(*(cp.q - edge).T) < 2.5).sum()) == 0
    # while the crossings around the edge on both surfaces are filled, on their true lines
    around = np.hypot(*(cp.q - edge).T) < 60.0
    assert around.sum() >= 50
    d = _line_offset_px(PATTERN, truth, cp.q[around], cp.family[around], cp.index[around])
    assert np.nanmax(d) <= 1.0, np.nanmax(d)
