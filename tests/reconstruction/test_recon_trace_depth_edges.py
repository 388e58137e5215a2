"""Labelled traces must not run across a depth edge onto a collinear line of another surface (decision 0084,
reconstruction.trace_ends), against simulator truth.

The scene is constructed so that it happens: a plate in front of a plane, placed so that its line j = 6 is
collinear in the image with the plane's line j = 0 (the plate carries light sheet 6 on the 3D line where sheet 6
meets the camera plane through the plane's line 0). Both rigs' devices are distortion-free pinholes, so the
construction is exact.
"""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from reconstruction.extraction import ExtractOptions, extract_grid, sigma_for
from reconstruction.labelling import LabelOptions, TraceOptions, label_epipolar, label_samples
from reconstruction.rigmodel import UNLABELLED, rig_model
from tests.reconstruction._scenes import PINHOLE_DEPTH_RANGE, PINHOLE_PATTERN, pinhole_procam, render_pinhole
from tests.reconstruction._scenes import collinear_plate as collinear_plate_scene
from tests.reconstruction._truth import true_index

DEPTH_RANGE, PATTERN = PINHOLE_DEPTH_RANGE, PINHOLE_PATTERN


def _labels(procam, image):
    model = rig_model(procam, PATTERN, DEPTH_RANGE)
    obs = extract_grid(image, model)
    lab = label_epipolar(obs, model, model.cam_normalised(obs.q_junction),
                         options=LabelOptions(depth_min_mm=DEPTH_RANGE[0], depth_max_mm=DEPTH_RANGE[1]))
    return model, obs, lab.labels.copy()


def _samples(model, obs, labels, image, **trace):
    return label_samples(obs, labels, sigma_px=float(obs.stats.get("sigma_px", sigma_for(model, ExtractOptions()))),
                         seed_radius_px=float(obs.stats["junction_radius_px"]), options=dataclasses.replace(TraceOptions(), **trace),
                         model=model, depth_range_mm=DEPTH_RANGE, image=image, line_width_px=model.line_width_cam_px)


@pytest.fixture(scope="module")
def collinear_plate():
    """Plane (depth ~940 mm) and a 100 × 100 × 20 mm plate ~240 mm in front of it whose line j = 6 continues the
    plane's line j = 0 in the image; albedos set so that both lines are equally bright (the renderer has no
    distance fall-off: radiance = albedo·cos θ_p·P), so the brightness cut (decision 0053) does not see the edge.
    The plane's junctions within two junction steps of the edge where the plate's line leaves it lose their
    labels (as on the paper rigs, where junctions are sparse): the trace from the plate's junctions then runs
    across the silhouette to the plane's next crossing."""
    procam, image, truth, edge = collinear_plate_scene()
    model, obs, labels = _labels(procam, image)
    object_id = cv2.remap(truth.object_id.astype(np.float32), obs.q_junction[:, 0].astype(np.float32).reshape(-1, 1),
                          obs.q_junction[:, 1].astype(np.float32).reshape(-1, 1), cv2.INTER_NEAREST).ravel()
    gone = (np.hypot(*(obs.q_junction - edge).T) < 2.0 * model.junction_step_cam_px) & (object_id == 0)
    labels[gone] = UNLABELLED
    return image, truth, model, obs, labels, edge, int(gone.sum())


def test_a_trace_does_not_carry_its_index_across_a_silhouette_onto_a_collinear_line(collinear_plate):
    image, truth, model, obs, labels, edge, n_gone = collinear_plate
    assert n_gone >= 1
    near = np.hypot(*(obs.q - edge).T) < 60.0
    off = _samples(model, obs, labels, image, far_end_check=False)
    on = _samples(model, obs, labels, image)

    def wrong(sl):
        t = true_index(truth, PATTERN, sl.q, obs.family)
        return np.isfinite(sl.index) & np.isfinite(t) & (np.abs(t - sl.index) > 0.5)

    # the leak: without the check, plane samples on line 0 next to the silhouette carry the plate's index 6
    leaked = wrong(off) & near
    assert leaked.sum() >= 8, int(leaked.sum())
    t_off = true_index(truth, PATTERN, off.q, obs.family)
    assert np.all(off.index[leaked] == 6)
    assert (np.abs(t_off[leaked]) < 0.3).sum() >= 8  # on the plane's line 0 (the truth mixes the two at the edge pixel)
    # with it: no wrong label next to the edge, and the plate's line keeps its label up to the edge
    assert int((wrong(on) & near).sum()) == 0
    assert on.stats["samples_far_end_cut"] >= leaked.sum()
    right_off = np.isfinite(off.index) & ~wrong(off) & near
    lost = right_off & ~np.isfinite(on.index)
    assert lost.sum() <= 3, int(lost.sum())
    # elsewhere nothing changes
    assert np.array_equal(np.isfinite(on.index[~near]), np.isfinite(off.index[~near]))


@pytest.fixture(scope="module")
def steep_surfaces():
    """A plane, a sphere (its rim: surfaces seen edge-on, depth changing fast along the lines) and a box turned
    60° to the view (its sides seen obliquely), every junction labelled as the labeller found it."""
    from drivers.sim import Box, Plane, Sphere

    procam = pinhole_procam()
    a = np.deg2rad(60.0)
    R = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    objects = [Plane(np.array([0, 0, 950.0]), np.array([0.1, -0.2, -1.0])), Sphere(np.array([-40.0, 30.0, 780.0]), 70.0),
               Box(np.array([90.0, -20.0, 760.0]), np.array([80.0, 120.0, 80.0]), R)]
    image, truth = render_pinhole(objects)
    model, obs, labels = _labels(procam, image)
    return image, truth, model, obs, labels


def test_steep_continuous_surfaces_keep_their_labels(steep_surfaces):
    image, truth, model, obs, labels = steep_surfaces
    off = _samples(model, obs, labels, image, far_end_check=False)
    on = _samples(model, obs, labels, image)
    t = true_index(truth, PATTERN, off.q, obs.family)
    right = np.isfinite(off.index) & np.isfinite(t) & (np.abs(t - off.index) <= 0.5)
    assert right.sum() > 5000
    # on the sphere and the box many labelled samples lie on steep faces (seen at more than 60° from the view)
    assert np.isfinite(off.index[_steep(truth, obs.q)]).sum() > 200
    # the check takes no right label away, anywhere (on the steep faces included)
    lost = right & ~np.isfinite(on.index)
    assert lost.sum() == 0, np.round(off.q[lost]).tolist()[:10]
    assert np.array_equal(on.index[np.isfinite(on.index)], off.index[np.isfinite(on.index)])


def _steep(truth, q: np.ndarray) -> np.ndarray:
    """Samples whose surface is seen at more than 60° from the camera's viewing ray (truth normals)."""
    m = q.astype(np.float32).reshape(-1, 1, 2)
    n = cv2.remap(truth.normal_proj.astype(np.float32), m[..., 0], m[..., 1], cv2.INTER_NEAREST).reshape(-1, 3)
    p = cv2.remap(truth.p_proj.astype(np.float32), m[..., 0], m[..., 1], cv2.INTER_NEAREST).reshape(-1, 3)
    ray = p - pinhole_procam().t_proj_cam
    c = np.abs((n * ray).sum(axis=1)) / np.linalg.norm(ray, axis=1)
    return np.isfinite(c) & (c < np.cos(np.deg2rad(60.0)))


# --- Round 4b: a labelled end that runs into a collinear line of its family with another index ------------------
# Analytic traces, the layout of the paper-intermediate leak (decision 0084, round 4b): a junction of line k = 4
# seeds a piece whose last samples lie past an occluding edge on the background, where the next samples of the
# same image line are a background junction's snapped seeds labelled 3 (the junction's mixing zone separates the
# two). Ridge brightness: plate 175, background 165, the two samples next to the edge dimmed (their line profiles
# cut by the edge), grey noise of ±2.


def _collinear_ends(edge_dip: bool, k_far: int = 3):
    from reconstruction.labelling import _sample_grid

    rng = np.random.default_rng(3)
    d = np.array([1.0, -1.0]) / np.sqrt(2.0)  # the line's direction in the image
    o = np.array([555.0, 313.0])  # the plate's junction (k = 4)
    t_piece = 2.0 + 1.4 * np.arange(15)  # the piece of line k: 15 samples from the junction outwards
    t_edge = 17.5  # the occluding edge along the line (camera px from the junction)
    t_far = t_piece[-1] + 5.5 + 1.4 * np.arange(4)  # the background junction's snapped seeds
    t_other = 2.0 + 1.4 * np.arange(15)  # a parallel line of the other family's pitch away: no part in it
    q = np.vstack([o + t_piece[:, None] * d, o + t_far[:, None] * d, o + [0.0, 14.0] + t_other[:, None] * d])
    n_p, n_f = len(t_piece), len(t_far)
    P = len(q)
    fam = np.full(P, 2, np.intp)
    index = np.concatenate([np.full(n_p, 4.0), np.full(n_f, float(k_far)), np.full(len(t_other), 5.0)])
    seed_jid = np.concatenate([np.zeros(n_p, np.int64), np.ones(n_f, np.int64), np.full(len(t_other), 2, np.int64)])
    q_junction = np.array([o, o + (t_far[-1] + 3.0) * d, o + [0.0, 14.0]])
    ridge = np.where(t_piece < t_edge, 175.0, 165.0)
    if edge_dip:
        ridge[np.argsort(np.abs(t_piece - t_edge))[:2]] -= 25.0
    ridge = np.concatenate([ridge, np.full(n_f, 165.0), np.full(len(t_other), 170.0)]) + rng.integers(-2, 3, P)
    # traces: the piece of line k and the parallel line (the snapped seeds lie on no trace)
    sid = np.concatenate([np.arange(n_p), np.arange(n_p + n_f, P)]).astype(np.intp)
    piece = np.concatenate([np.zeros(n_p, np.intp), np.ones(len(t_other), np.intp)])
    tangent = np.tile(d, (len(sid), 1))
    grid = _sample_grid(q, np.ones(P, bool), sid, 20.0)
    truth_bg = np.concatenate([t_piece > t_edge, np.zeros(n_f + len(t_other), bool)])
    return q, fam, sid, piece, tangent, index, seed_jid, q_junction, grid, ridge.astype(np.float32), truth_bg


def test_a_labelled_end_running_into_a_collinear_line_of_another_index_is_cut_at_the_edge():
    from reconstruction.trace_ends import cut_facing_ends

    q, fam, sid, piece, tangent, index, seed_jid, q_junction, grid, ridge, truth_bg = _collinear_ends(True)
    before = index.copy()
    n = cut_facing_ends(q, fam, sid, piece, tangent, index, seed_jid, q_junction, grid, reach_px=10.0, lateral_px=1.0, ridge=ridge)
    # the samples past the edge (on the background, wrongly 4) lose their label; of the plate's, at most the one
    # dimmed sample next to the edge goes; nothing else changes (the background's 3, the parallel line)
    assert truth_bg.sum() == 3  # as on paper-intermediate
    assert not np.isfinite(index[truth_bg]).any()
    lost_right = np.isfinite(before) & ~truth_bg & ~np.isfinite(index)
    assert lost_right.sum() <= 1, int(lost_right.sum())
    assert n == truth_bg.sum() + lost_right.sum()
    assert np.array_equal(index[np.isfinite(index)], before[np.isfinite(index)])
    assert np.isfinite(index[~truth_bg & (before != 4)]).all()
    assert np.all(seed_jid[~np.isfinite(index)] == -1)


def test_collinear_ends_keep_right_labels():
    from reconstruction.trace_ends import cut_facing_ends

    # the same line index beyond the gap (a crossing's gap on one surface): nothing is cut
    q, fam, sid, piece, tangent, index, seed_jid, q_junction, grid, ridge, _ = _collinear_ends(True, k_far=4)
    before = index.copy()
    assert cut_facing_ends(q, fam, sid, piece, tangent, index, seed_jid, q_junction, grid, reach_px=10.0, lateral_px=1.0, ridge=ridge) == 0
    assert np.array_equal(index, before)
    # another index beyond the gap, but the edge is the gap itself (the brightness changes across it, evenly
    # along the piece): the piece keeps every label
    q, fam, sid, piece, tangent, index, seed_jid, q_junction, grid, ridge, truth_bg = _collinear_ends(False)
    ridge[: len(truth_bg)][truth_bg] = ridge[0]  # the plate's brightness all along the piece
    before = index.copy()
    assert cut_facing_ends(q, fam, sid, piece, tangent, index, seed_jid, q_junction, grid, reach_px=10.0, lateral_px=1.0, ridge=ridge) == 0
    assert np.array_equal(index, before)
    # beyond reach, or off the end's tangent by more than lateral_px: not facing, nothing is cut
    q, fam, sid, piece, tangent, index, seed_jid, q_junction, grid, ridge, _ = _collinear_ends(True)
    assert cut_facing_ends(q, fam, sid, piece, tangent, index, seed_jid, q_junction, grid, reach_px=4.0, lateral_px=1.0, ridge=ridge) == 0
    q2 = q.copy()
    q2[index == 3] += np.array([1.0, 1.0]) * 1.5 / np.sqrt(2.0)  # the far samples 1.5 px to the side
    grid2 = _collinear_grid(q2, sid)
    assert cut_facing_ends(q2, fam, sid, piece, tangent, index, seed_jid, q_junction, grid2, reach_px=10.0, lateral_px=1.0, ridge=ridge) == 0


def _collinear_grid(q, sid):
    from reconstruction.labelling import _sample_grid

    return _sample_grid(q, np.ones(len(q), bool), sid, 20.0)
