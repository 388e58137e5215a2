"""Decision 0130: a rig whose labelling margin is under the runner-up miss the labeller needs (min_rms_ratio × the
epipolar floor, 0.15 px by default) is "ill-posed", and that is the physics, not an over-strict test.

The rig is unseen seed 103's (benchmarks/unseen.py): the tabletop camera (t3 = 0: parallel epipolar lines) and a
26 px grid at 53.1°/137.95°, whose lattice vector (1, −1) runs 0.24° off the epipolar direction: a junction one
(1, −1) away lies 0.106–0.117 px off the epipolar line everywhere in the pattern, at every depth. The frame gave no
points and the warning said "left out"."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from calibration.models import Intrinsics, ProCam
from drivers.sim.presets import tabletop_procam
from reconstruction.labelling import LabelOptions, label_epipolar
from reconstruction.patterns import GridPattern
from reconstruction.pipeline import ReconstructOptions, judged_margin, reconstruct
from reconstruction.placement import DECIDE_PX, EPIPOLAR_FLOOR_PX, MIN_RMS_RATIO, labelling_margin
from reconstruction.rigmodel import UNLABELLED, rig_model
from reconstruction.extraction import GridObservation
from tests.reconstruction._truth import lattice_edges

VOLUME = (785.0, 1196.0)  # seed 103's working volume (its scene's depth range)
WRONG = np.array([1, -1])


def _pattern() -> GridPattern:
    return GridPattern(pitch_px=26.0, lines=31, centre_px=(511.5, 511.5), line_width_px=3.0,
                       alpha1_deg=53.10768660901431, alpha2_deg=137.95030578242321)


def _shifted_projector(procam: ProCam, delta_px: np.ndarray) -> ProCam:
    """The same rig with the projector's principal point off by delta_px: a calibration error."""
    p = procam.projector
    K = p.K.copy()
    K[0, 2] += delta_px[0]
    K[1, 2] += delta_px[1]
    return ProCam(procam.camera, Intrinsics(p.width, p.height, K, p.dist), procam.R_proj_cam, procam.t_proj_cam)


def _plane(procam: ProCam, pattern: GridPattern, noise_px: float, seed: int = 0):
    """True labels (N, 2), camera pixels (N, 2) and grid edges (E, 2) with their deltas of the junctions on a tilted
    plane about 900 mm away, inside the pattern (|i|, |j| ≤ 12 of 15: the pattern's rim, which would rule offset WRONG
    out, is not seen, as on seed 103's surfaces)."""
    idx = pattern.indices
    ii, jj = np.meshgrid(idx, idx, indexing="ij")
    lab = np.column_stack([ii.ravel(), jj.ravel()])
    xy = procam.projector.pixels_to_normalised(pattern.junction_uv(lab[:, 0], lab[:, 1]))
    e = np.column_stack([xy, np.ones(len(xy))])
    n = np.array([0.1, -0.2, -1.0]) / np.linalg.norm([0.1, -0.2, -1.0])
    p = e * ((n @ np.array([0.0, 0.0, 900.0])) / (e @ n))[:, None]
    q = procam.camera.project(procam.proj_to_cam(p)) + np.random.default_rng(seed).normal(0, noise_px, (len(lab), 2))
    cam = procam.camera
    inside = (q[:, 0] > 5) & (q[:, 0] < cam.width - 6) & (q[:, 1] > 5) & (q[:, 1] < cam.height - 6) & (np.abs(lab) <= 12).all(axis=1)
    lab, q = lab[inside], q[inside]
    return (lab, q, *lattice_edges(lab))


def _obs(q: np.ndarray, edges: np.ndarray, delta: np.ndarray) -> GridObservation:
    M = len(q)
    return GridObservation(
        q=np.zeros((0, 2)), family=np.zeros(0, np.int8), segment=np.zeros(0, np.int64), junction=np.zeros(0, np.int64),
        strength=np.zeros(0), q_junction=q, junction_dir=np.zeros((M, 2, 2)), segment_family=np.zeros(0, np.int8),
        segment_ends=np.zeros((0, 2), np.int64), segment_rms=np.zeros(0), segment_centre=np.zeros((0, 2)),
        segment_dir=np.zeros((0, 2)), edges=edges, edge_family=np.zeros(len(edges), np.int8), edge_delta=delta,
        edge_segment=np.zeros(len(edges), np.int64), stats={})


def _label(truth_rig: ProCam, calibrated: ProCam, floor_px: float):
    """Junctions rendered by truth_rig (0.02 px of noise: seed 103's extracted junctions fit at 0.02 px RMS) and
    labelled with the calibration `calibrated`: (labelled, the label minus the truth of each labelled one)."""
    pattern = _pattern()
    truth, q, edges, delta = _plane(truth_rig, pattern, 0.02)
    model = rig_model(calibrated, pattern, VOLUME)
    lab = label_epipolar(_obs(q, edges, delta), model, calibrated.camera.pixels_to_normalised(q),
                         options=LabelOptions(depth_min_mm=VOLUME[0], depth_max_mm=VOLUME[1], noise_floor_px=floor_px))
    ok = lab.labels[:, 0] != UNLABELLED
    return ok, lab.labels[ok] - truth[ok]


def _across_epipolar(procam: ProCam, pattern: GridPattern) -> np.ndarray:
    """The projector-pixel vector by which a principal point error makes offset WRONG fit exactly: the part of the
    lattice vector WRONG across the epipolar lines (t3 = 0: they all run along (t1, t2); fx = fy)."""
    t = procam.t_proj_cam
    assert t[2] == 0.0 and procam.projector.K[0, 0] == procam.projector.K[1, 1]
    n = np.array([-t[1], t[0]]) / np.hypot(t[0], t[1])
    step = pattern.junction_uv(np.array([WRONG[0]]), np.array([WRONG[1]]))[0] - pattern.junction_uv(np.array([0]), np.array([0]))[0]
    return n * float(n @ step)


def test_the_constants_are_the_labellers_defaults():
    o = LabelOptions()
    assert (EPIPOLAR_FLOOR_PX, MIN_RMS_RATIO) == (o.noise_floor_px, o.min_rms_ratio)
    assert DECIDE_PX == pytest.approx(0.15)


def test_seed_103s_rig_is_ill_posed_at_the_labellers_floor():
    m = labelling_margin(tabletop_procam(), _pattern(), depth_range_mm=VOLUME)
    assert 0.1 < m.margin_px < 0.12 and m.offset in ((1, -1), (-1, 1))
    assert m.verdict == "ill-posed" and "0.11 projector px" in m.advice() and "0.15 px" in m.advice()
    # decision 0004's fixed 0.1 px called it marginal; a finer calibration (floor 0.05 px) would decide it
    assert judged_margin(m, replace(LabelOptions(), ill_posed_at_floor=False)).verdict == "marginal"
    assert judged_margin(m, replace(LabelOptions(), noise_floor_px=0.05)).verdict == "marginal"
    # a rough calibration (floor 0.31 px) makes a 0.3 px margin ill-posed too
    assert m.with_floor(0.31).decide_px == pytest.approx(0.465)


def test_a_calibration_error_under_the_floor_turns_a_confident_labelling_into_a_wrong_one():
    procam = tabletop_procam()
    delta = _across_epipolar(procam, _pattern())
    assert 0.1 < np.hypot(*delta) < 0.12  # within what the floor (0.1 px, ×1.5) allows a calibration to leave
    # Exact calibration, floor lowered to the junction noise: every junction labelled, every label right.
    ok, d = _label(procam, procam, 0.02)
    assert ok.sum() > 300 and ok.all() and not d.any()
    # The projector's principal point 0.11 px off across the epipolar lines: labelled as confidently, all wrong by
    # the lattice vector that runs along them. Nothing in one frame tells the two cases apart.
    for sign in (1.0, -1.0):
        ok, d = _label(procam, _shifted_projector(procam, sign * delta), 0.02)
        assert ok.sum() > 300 and ok.all()
        assert (d == sign * WRONG).all()
    # At the default floor both are left out (ambiguous): the frame warns that the rig is ill-posed.
    assert not _label(procam, procam, EPIPOLAR_FLOOR_PX)[0].any()
    assert not _label(procam, _shifted_projector(procam, delta), EPIPOLAR_FLOOR_PX)[0].any()


def test_the_frame_warns_ill_posed_with_the_margin():
    procam = tabletop_procam()
    blank = np.zeros((procam.camera.height, procam.camera.width), np.uint8)
    opts = ReconstructOptions(depth_min_mm=VOLUME[0], depth_max_mm=VOLUME[1])
    rec = reconstruct(blank, procam, _pattern(), options=opts)
    warned = [w for w in rec.warnings if "ill-posed" in w]
    assert len(warned) == 1 and "label offset (" in warned[0] and "0.11 projector px" in warned[0], rec.warnings
    off = replace(opts, label=replace(opts.label, ill_posed_at_floor=False))
    assert not [w for w in reconstruct(blank, procam, _pattern(), options=off).warnings if "ill-posed" in w]
