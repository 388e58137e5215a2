"""The trimmed ends of decision 0103's pieces (decision 0106, reconstruction.limb_lines `_label_ends`): which ends
are looked at on constructed traces, and the stage against simulator truth on the small rig's pitch-16 scene."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from reconstruction.extraction import extract_grid
from reconstruction.labelling import LabelOptions, TraceOptions, _sample_grid, label_epipolar, label_samples
from reconstruction.limb_lines import _k_end_rows, _k_write_ends
from reconstruction.rigmodel import rig_model

from tests.reconstruction._truth import object_at, true_index


def one_object_around(truth, q: np.ndarray) -> np.ndarray:
    """True where the truth's pixels within 1 px of each point (the four diagonal neighbours and the point) show
    one object: there `true_index`'s bilinear look-up does not mix two surfaces' projector positions across a
    silhouette (decision 0106: a sample 1.3 px from the sphere's silhouette read −13.62 where its own pixel is
    −14.04)."""
    ids = [object_at(truth, q + d) for d in ((0.0, 0.0), (-1.0, -1.0), (-1.0, 1.0), (1.0, -1.0), (1.0, 1.0))]
    return np.all([i == ids[0] for i in ids[1:]], axis=0)


def _line(x0: float, x1: float, y: float) -> np.ndarray:
    x = np.arange(x0, x1 + 1e-9, 1.0)
    return np.column_stack([x, np.full(len(x), y)])


def _three_pieces():
    """One horizontal line of family 1 in three pieces (x 0–16, 23–37, 44–60 at y = 50) and, on no trace, a
    vertical line of the other family through each gap: the trace arrays and the family-split bucket grid."""
    pieces = [_line(0, 16, 50.0), _line(23, 37, 50.0), _line(44, 60, 50.0)]
    extra = np.concatenate([np.column_stack([np.full(7, x), 50.0 + np.arange(-3, 4)]) for x in (19.6, 40.4)])
    q = np.concatenate(pieces + [extra])
    fam = np.concatenate([np.full(len(p), 1) for p in pieces] + [np.full(len(extra), 2)]).astype(np.intp)
    n = sum(len(p) for p in pieces)
    sid = np.arange(n)
    piece = np.concatenate([np.full(len(p), i) for i, p in enumerate(pieces)])
    tangent = np.tile([1.0, 0.0], (n, 1))
    grid = _sample_grid(q, np.ones(len(q), bool), sid, 7.0, fam)
    return q, fam, sid, piece, tangent, grid


def _end_rows(index, was_unlabelled):
    q, fam, sid, piece, tangent, grid = _three_pieces()
    x0, y0, cell, gw, gh, start, items, pos_of = grid
    return _k_end_rows(q, fam, sid, piece, tangent, index, was_unlabelled, 3, 3, 13.3, 1.0, x0, y0, cell, gw, gh, start, items, pos_of), sid


def test_end_rows_only_where_the_facing_piece_is_unlabelled():
    """The middle piece (samples 17–31, x 23–37) labelled 5 by the step with its two end samples trimmed on each
    side: both ends face an unlabelled piece, so both are looked at, their gap middles (x 19.5, 40.5) on sheet 5
    then the facing samples (x 16 and 44); once the right piece carries a line (any line: the same one is the gap
    fillings' case, another is a conflict) only the left end is; a piece labelled before the step is not looked
    at; writing puts line 5 on exactly the trimmed samples of the kept ends, with the junction of the first
    labelled sample inside."""
    n = 17 + 15 + 17 + 14
    index = np.full(n, np.nan)
    index[19:30] = 5.0  # x 25 … 35: the samples 17, 18 and 30, 31 trimmed
    was_unlabelled = np.ones(n, bool)
    (ends, rq, rf, rk, end_pos, val), _ = _end_rows(index, was_unlabelled)
    assert ends.tolist() == [[1, 0, 19], [1, 1, 29]]
    np.testing.assert_allclose(rq, [[19.5, 50.0], [16.0, 50.0], [40.5, 50.0], [44.0, 50.0]], atol=1e-12)
    assert rf.tolist() == [1, 1, 1, 1] and rk.tolist() == [5, 5, 5, 5]

    index_r = index.copy()
    index_r[32:49] = 7.0  # the right piece labelled (before the step: was_unlabelled False there)
    wu = was_unlabelled.copy()
    wu[32:49] = False
    (ends_r, *_), _ = _end_rows(index_r, wu)
    assert ends_r.tolist() == [[1, 0, 19]]

    wu_before = was_unlabelled.copy()
    wu_before[17:32] = False  # the middle piece was labelled before the step: not the step's
    (ends_b, *_), _ = _end_rows(index, wu_before)
    assert len(ends_b) == 0

    jid = np.arange(n) * 10
    out = index.copy()
    q = _three_pieces()[0]
    written = _k_write_ends(ends, np.array([True, False]), end_pos, 3, np.arange(49), out, jid, val, q, 3, 1.0)
    assert written == 2
    np.testing.assert_array_equal(out[17:19], [5.0, 5.0])
    assert np.isnan(out[30]) and np.isnan(out[31])
    np.testing.assert_array_equal(jid[17:19], [190, 190])
    np.testing.assert_array_equal(out[19:30], index[19:30])


@pytest.fixture(scope="module")
def stage16_outer(small_scene_pitch16):
    s = small_scene_pitch16
    model = rig_model(s.procam, s.pattern, s.depth_range_mm)
    obs = extract_grid(s.image, model)
    lab = label_epipolar(obs, model, model.cam_normalised(obs.q_junction),
                         options=LabelOptions(depth_min_mm=s.depth_range_mm[0], depth_max_mm=s.depth_range_mm[1])).labels.copy()
    return s, model, obs, lab, float(obs.stats["sigma_px"])


def _labels(stage, **trace):
    s, model, obs, lab, sigma = stage
    opts = dataclasses.replace(TraceOptions(), **trace)
    return label_samples(obs, lab, sigma_px=sigma, seed_radius_px=float(obs.stats["junction_radius_px"]), options=opts, model=model,
                         depth_range_mm=s.depth_range_mm, image=s.image, line_width_px=model.line_width_cam_px)


def test_limb_ends_take_their_true_indices(stage16_outer):
    """The small rig at pitch 16 (the sphere's limb compresses the grid): with the ends on, the samples labelled
    that were not labelled without them all carry their true line's index, and nothing labelled without them is
    lost; their count is the stage's `samples_ends`, counted in `samples_beside_lines`."""
    s, model, obs, _, _ = stage16_outer
    off = _labels(stage16_outer, beside_lines_ends=False)
    on = _labels(stage16_outer)
    new = np.isfinite(on.index) & ~np.isfinite(off.index)
    assert new.sum() >= 10, new.sum()  # (measured: see decision 0106)
    assert np.sum(np.isfinite(off.index) & ~np.isfinite(on.index)) == 0
    assert on.stats["samples_beside_lines"] > off.stats["samples_beside_lines"]
    t = true_index(s.truth, s.pattern, obs.q[new], np.asarray(obs.family)[new])
    ok = np.isfinite(t)
    assert ok.mean() > 0.9
    assert np.all(np.abs(t[ok] - on.index[new][ok]) < 0.3), np.abs(t[ok] - on.index[new][ok]).max()


def test_an_end_sample_off_the_line_stops_the_end():
    """The left end of the middle piece with its outermost sample (x 23) moved 1.5 px across the line (a
    crossing's light pulling the ridge): only the sample at x 24 is written; within 1 px (0.8) both are."""
    n = 63
    index = np.full(n, np.nan)
    index[19:30] = 5.0
    (ends, rq, rf, rk, end_pos, val), _ = _end_rows(index, np.ones(n, bool))
    for dy, expect in ((1.5, [np.nan, 5.0]), (0.8, [5.0, 5.0])):
        q = _three_pieces()[0].copy()
        q[17, 1] += dy
        out = index.copy()
        written = _k_write_ends(ends, np.array([True, False]), end_pos, 3, np.arange(49), out, np.zeros(n, np.int64), val, q, 3, 1.0)
        assert written == int(np.sum(np.isfinite(expect)))
        np.testing.assert_array_equal(out[17:19], expect)


@pytest.mark.parametrize("keep_object", [0, 1])
def test_ends_beside_the_sphere_silhouette_are_true(stage16_outer, keep_object):
    """Only the plane's (0) or only the sphere's (1) junctions labelled (decision 0103's one-sided case): the
    samples the ends add carry their true index wherever the truth is read on one object; within 1 px of the
    silhouette the bilinear truth mixes the two surfaces (one sample with keep_object 1), and there the label
    is checked against the nearest pixel's truth."""
    from reconstruction.rigmodel import UNLABELLED

    s, model, obs, lab, sigma = stage16_outer
    labels = lab.copy()
    labels[object_at(s.truth, obs.q_junction) != keep_object] = UNLABELLED
    stage = (s, model, obs, labels, sigma)
    off = _labels(stage, beside_lines_ends=False)
    on = _labels(stage)
    new = np.isfinite(on.index) & ~np.isfinite(off.index)
    assert new.sum() >= 10, new.sum()
    qn, fn, kn = obs.q[new], np.asarray(obs.family)[new], on.index[new]
    clean = one_object_around(s.truth, qn)
    t = true_index(s.truth, s.pattern, qn[clean], fn[clean])
    assert np.all(np.isfinite(t)) and np.all(np.abs(t - kn[clean]) < 0.3), np.abs(t - kn[clean]).max()
    t_px = true_index(s.truth, s.pattern, np.round(qn[~clean]), fn[~clean])
    assert np.all(np.abs(t_px - kn[~clean]) < 0.3), t_px
