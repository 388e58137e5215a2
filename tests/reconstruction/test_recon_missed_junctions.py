"""Corner junctions (decision 0102, reconstruction.corner_junctions): which rejected crossing candidates are T's,
which T's have a dark side beyond the stem, and, on a simulated scene, that the corners extraction keeps are true
junctions with the labels the simulator gives them."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from benchmarks._common import bench_scenes, render_scene
from benchmarks.bench_extraction import truth_grid
from reconstruction.corner_junctions import corner_candidates, corner_kinds, dark_beyond
from reconstruction.pipeline import ReconstructOptions, extract_frame, finish_frame


def _fits(shapes):
    """Per-candidate arrays as `junction_fits` / `junction_verdicts` give them, from a list of dicts: the sides
    (n_neg, n_pos) of the i- and the j-fit, and optionally cnt, rms, jump, par, offc, valid, qj."""
    ns = len(shapes)
    cnt = np.zeros(2 * ns)
    n_neg = np.zeros(2 * ns)
    n_pos = np.zeros(2 * ns)
    rms = np.zeros(2 * ns)
    valid = np.zeros(ns, bool)
    jump = np.zeros(ns, bool)
    par = np.zeros(ns, bool)
    offc = np.zeros(ns, bool)
    qj = np.zeros((ns, 2))
    for k, s in enumerate(shapes):
        for f, (a, b) in enumerate(s["sides"]):
            n_neg[2 * k + f] = a
            n_pos[2 * k + f] = b
            cnt[2 * k + f] = s.get("cnt", a + b)
            rms[2 * k + f] = s.get("rms", 0.1)
        valid[k] = s.get("valid", False)
        jump[k] = s.get("jump", False)
        par[k] = s.get("par", False)
        offc[k] = s.get("offc", False)
        qj[k] = s.get("qj", (10.0 * k, 5.0))
    return valid, cnt, n_neg, n_pos, rms, jump, par, offc, qj


def test_only_straight_t_shapes_are_corners():
    shapes = [
        {"sides": ((4, 4), (4, 4)), "valid": True},  # an X the arm tests kept: not a corner, it is a junction
        {"sides": ((4, 4), (0, 5))},  # T: i through, j ends -> corner
        {"sides": ((0, 5), (4, 4))},  # T: j through, i ends -> corner
        {"sides": ((0, 5), (5, 0))},  # L: neither through
        {"sides": ((4, 4), (0, 0))},  # one family only
        {"sides": ((4, 4), (0, 5)), "rms": 0.9},  # crooked
        {"sides": ((4, 4), (0, 5)), "jump": True},  # a sideways jump (two surfaces' lines)
        {"sides": ((4, 4), (0, 5)), "par": True},
        {"sides": ((4, 4), (0, 5)), "offc": True},
        {"sides": ((1, 1), (0, 2))},  # too few arm samples (< 3 in the j-fit)
        {"sides": ((4, 4), (0, 5)), "qj": (np.nan, 3.0)},
    ]
    valid, cnt, n_neg, n_pos, rms, jump, par, offc, qj = _fits(shapes)
    corner = corner_candidates(valid, cnt, n_neg, n_pos, rms, jump, par, offc, qj, 0.6)
    assert corner.tolist() == [False, True, True] + [False] * 8
    # kinds of the kept junctions: candidate k kept as junction new_id[k]; candidate 0 an X, 1 and 2 corners
    new_id = np.array([0, 1, 2] + [-1] * 9)
    kind = corner_kinds(corner, n_neg, n_pos, new_id, 3)
    assert kind.tolist() == [0, 1, 2]


def _t_at_origin(extra):
    """A T at (0, 0): the i-line through along x (samples on both sides), the j-line's stem along +y only; the
    stem's missing side is −y. `extra`: more samples (x, y)."""
    valid, cnt, n_neg, n_pos, rms, jump, par, offc, _ = _fits([{"sides": ((5, 5), (0, 5))}])
    dr = np.array([[1.0, 0.0], [0.0, 1.0]])
    line = [(x, 0.0) for x in np.arange(-20.0, 21.0, 2.0)] + [(0.0, y) for y in np.arange(2.0, 21.0, 2.0)]
    q = np.array(line + list(extra), np.float32).reshape(-1, 2)
    corner = np.ones(1, bool)
    return corner, np.zeros((1, 2)), dr, n_neg, n_pos, q[:, 0].copy(), q[:, 1].copy()


@pytest.mark.parametrize(
    "extra, kept",
    [
        ([], True),  # shadow or pattern rim: nothing beyond the through line
        ([(0.0, -8.0), (2.0, -10.0), (-3.0, -12.0)], False),  # lit surface with lines beyond: an occluding edge?
        ([(0.0, -8.0), (2.0, -10.0)], True),  # two stray samples are allowed
        ([(0.0, -3.0), (1.0, -3.5), (-1.0, -2.5)], True),  # inside r_in: the through line's own light
        ([(0.0, -25.0), (1.0, -26.0), (2.0, -27.0)], True),  # beyond r_out
        ([(15.0, -8.0), (16.0, -9.0), (17.0, -10.0)], True),  # beyond the half width
        ([(0.0, 8.0), (1.0, 9.0), (2.0, 10.0)], True),  # on the stem's own side
    ],
)
def test_dark_beyond_the_stem(extra, kept):
    corner, qj, dr, n_neg, n_pos, qx, qy = _t_at_origin(extra)
    dropped = dark_beyond(corner, qj, dr, n_neg, n_pos, qx, qy, 5.0, 20.0, 10.0, 2)
    assert corner.tolist() == [kept]
    assert dropped == (0 if kept else 1)


@pytest.fixture(scope="module")
def orthogonal():
    s = bench_scenes(["paper-orthogonal"], [], noise_grey=2.0)[0]
    image, truth = render_scene(s.procam, s.scene, s.pattern, noise_grey=s.noise_grey)
    return s, image, truth


def test_switch_off_gives_no_corners_and_on_adds_junctions(orthogonal):
    s, image, truth = orthogonal
    base = ReconstructOptions(depth_min_mm=s.depth_range_mm[0], depth_max_mm=s.depth_range_mm[1])
    off = extract_frame(image, s.procam, s.pattern, options=base)
    on_opts = dataclasses.replace(base, extract=dataclasses.replace(base.extract, corner_junctions=True, corner_dark=False))
    on = extract_frame(image, s.procam, s.pattern, options=on_opts)
    assert "junction_corner" not in off.obs.stats
    kind = on.obs.stats["junction_corner"]
    n_corner = int((kind > 0).sum())
    assert n_corner >= 1
    assert len(on.obs.q_junction) == len(off.obs.q_junction) + n_corner
    # every junction found without the switch is found with it, at the same place
    d = np.array([np.hypot(*(on.obs.q_junction - q).T).min() for q in off.obs.q_junction])
    assert (d < 1e-9).all()
    # the labelled corners carry the simulator's labels at a true junction within 1.5 px
    res = finish_frame(on)
    tg = truth_grid(truth, s.pattern, r_vis=0.0)
    n_lab = 0
    for q, lab in zip(res.junctions_cam[kind > 0], res.junction_labels[kind > 0]):
        if lab[0] < -1000:
            continue
        n_lab += 1
        near = np.hypot(*(tg["q"] - q).T) < 1.5
        assert (tg["label"][near] == lab).all(axis=1).any(), (q, lab)
    assert n_lab >= 1
