"""Acute crossings: sides counted from the arms' intersection where the candidate sits off it along the acute
bisector (decision 0133, `acute_recentre.py`).

1. The retry's geometry against analytic crossings: two straight lines crossing at θ, a candidate moved off their
   intersection by a known offset. Along the acute bisector it is retried up to the tolerance × sin 45° / sin(θ/2)
   (the crossing blob's elongation), across it never beyond the tolerance, and never where the fits passed or
   failed for another reason.
2. A simulator scene with ground truth (unseen seed 133: the left face of the left box, cells about 6 × 8 px,
   crossings at about 50°): with the retry on, more junctions are kept there, and every one of them lies within
   1 px of a true junction (`bench_extraction.truth_grid`)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from reconstruction.acute_recentre import acute_retry

TOL = 1.5


def _crossing(theta_deg: float, offset: tuple[float, float]):
    """One candidate at the intersection (0, 0) of two lines at θ (directions ±θ/2 about the x axis: the acute
    bisector is x) moved by `offset`; fits as `junction_fits` rows (2 · k + family − 1)."""
    h = math.radians(theta_deg / 2)
    dr = np.array([[math.cos(h), math.sin(h)], [math.cos(h), -math.sin(h)]])
    cnt = np.array([6, 6], np.int64)
    n_neg = np.array([0.0, 3.0])  # family 1 has no samples on one side of the (moved) candidate
    n_pos = np.array([6.0, 3.0])
    qj = np.zeros((1, 2))
    sx, sy = np.array([float(offset[0])]), np.array([float(offset[1])])
    return dict(valid=np.zeros(1, bool), cnt=cnt, n_neg=n_neg, n_pos=n_pos, par=np.zeros(1, bool),
                offc=np.array([math.hypot(*offset) > TOL]), qj=qj, dr=dr, sx=sx, sy=sy)


def _retry(c):
    return acute_retry(c["valid"], c["cnt"], c["n_neg"], c["n_pos"], c["par"], c["offc"], c["qj"], c["dr"], c["sx"], c["sy"], TOL)


@pytest.mark.parametrize("theta", [30.0, 50.0, 70.0, 90.0])
def test_retried_along_the_bisector_within_the_blob_elongation(theta):
    bound = TOL * math.sqrt(0.5) / math.sin(math.radians(theta / 2))
    for d in (0.5 * bound, 0.98 * bound):
        retry, x, y = _retry(_crossing(theta, (d, 0.0)))
        assert retry[0] and abs(x[0]) < 1e-12 and abs(y[0]) < 1e-12  # moved onto the intersection
    retry, x, y = _retry(_crossing(theta, (1.02 * bound, 0.0)))
    assert not retry[0] and x[0] == pytest.approx(1.02 * bound)


@pytest.mark.parametrize("theta", [30.0, 50.0, 90.0])
def test_not_retried_across_the_bisector(theta):
    assert not _retry(_crossing(theta, (0.0, 1.05 * TOL)))[0][0]
    assert _retry(_crossing(theta, (0.0, 0.95 * TOL)))[0][0]  # within the old tolerance: the sides are recounted


def test_obtuse_labelling_of_the_families_gives_the_same_bisector():
    """The fitted directions' signs are arbitrary: d2 reversed (the angle between the fits 180° − θ) is the same
    crossing."""
    c = _crossing(50.0, (2.5, 0.0))
    c["dr"][1] *= -1
    assert _retry(c)[0][0]
    c = _crossing(50.0, (0.0, 2.5))
    c["dr"][1] *= -1
    assert not _retry(c)[0][0]


def test_only_through_and_off_centre_failures_are_retried():
    c = _crossing(50.0, (2.0, 0.0))
    c["valid"][0] = True
    assert not _retry(c)[0][0]
    c = _crossing(50.0, (2.0, 0.0))
    c["cnt"][1] = 2  # too few samples
    assert not _retry(c)[0][0]
    c = _crossing(50.0, (2.0, 0.0))
    c["par"][0] = True
    assert not _retry(c)[0][0]
    c = _crossing(50.0, (1.0, 0.0))  # through and on centre: failed later (crooked, jump, turn)
    c["n_neg"][:] = 3
    c["offc"][0] = False
    assert not _retry(c)[0][0]
    c = _crossing(50.0, (2.0, 0.0))
    c["qj"][0] = np.nan
    assert not _retry(c)[0][0]


def test_seed_133_compressed_face_keeps_true_junctions():
    cv2 = pytest.importorskip("cv2")
    from scipy.spatial import cKDTree

    from benchmarks._common import render_scene
    from benchmarks.bench_extraction import truth_grid
    from benchmarks.unseen import draw_scene
    from drivers.sim.presets import depth_range
    from reconstruction.extraction import ExtractOptions, extract_grid
    from reconstruction.rigmodel import rig_model

    cv2.setNumThreads(1)
    rig, procam, scene, pattern, noise = draw_scene(133)
    img, truth = render_scene(procam, scene, pattern, noise_grey=noise, seed=133)
    dr = depth_range(procam, scene)
    model = rig_model(procam, pattern, (float(dr[0]), float(dr[1])))
    tg = truth_grid(truth, pattern, r_vis=3.0)
    tree = cKDTree(tg["q"])

    def on_face(q):  # the left box's left face: object 3, normal along −x of the projector frame
        u = np.clip(np.rint(q[:, 0]).astype(int), 0, img.shape[1] - 1)
        v = np.clip(np.rint(q[:, 1]).astype(int), 0, img.shape[0] - 1)
        n = truth.normal_proj[v, u]
        return (truth.object_id[v, u] == 3) & (np.argmax(np.abs(n), axis=1) == 0) & (n[:, 0] < 0)

    kept = {}
    for on in (False, True):
        obs = extract_grid(img, model, options=ExtractOptions(acute_recentre=on))
        qj = obs.q_junction
        kept[on] = qj[on_face(qj)]
        assert (tree.query(qj)[0] > 1.5).sum() <= 3  # anywhere: no more than a few junctions off the truth
    assert len(kept[True]) >= len(kept[False]) + 4, (len(kept[False]), len(kept[True]))
    assert (tree.query(kept[True])[0] <= 1.0).all()
