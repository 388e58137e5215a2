"""Decision 0157: label_samples' end in fewer passes (the labelled positions, the cut profile and the gap candidates
in one compiled pass; the result's types with junction -1 in one) and `knn_within` reading a row's three cells as
one run of buckets. Every output must be the former code's, bit for bit."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import reconstruction.labelling as labelling
from reconstruction import _label_kernels as _k
from reconstruction.pipeline import ReconstructOptions, extract_frame, finish_frame


def _former_cut_and_gaps(index, sid, piece, valid, drop, max_drop: float, cut: bool, gaps: bool):
    """label_samples' lines before decision 0157 (labelled_positions, the NumPy cut, gap_candidates)."""
    g, n_un = _k.labelled_positions(index, sid)
    lab_pos = g
    cut_samples = np.zeros(0, np.intp)
    if cut:
        c = drop[g] > max_drop  # NumPy compares the float32 array with the Python float in float32 (NEP 50)
        cut_samples = sid[g[c]]
        index[cut_samples] = np.nan
        lab_pos = g[~c]
    cand = _k.gap_candidates(valid, index, sid, piece, cut_samples) if gaps else np.zeros(0, np.intp)
    return lab_pos, n_un, cut_samples, cand


def _random_traces(rng, P: int):
    n = int(rng.integers(1, P))
    sid = rng.permutation(P)[:n].astype(np.intp)
    piece = np.sort(rng.integers(0, max(1, n // 4), n)).astype(np.int64)
    piece = np.unique(piece, return_inverse=True)[1].astype(np.int64)  # ids 0, 1, … without holes
    index = rng.integers(-5, 30, P).astype(np.float32)
    index[rng.random(P) < 0.4] = np.nan
    valid = rng.random(P) < 0.9
    max_drop = float(rng.choice([0.15, 0.1, 0.3]))
    drop = rng.random(n).astype(np.float32) * np.float32(2 * max_drop)
    # measures at the option's float32 value: NumPy's float32 comparison keeps them, a float64 one would cut them
    drop[rng.random(n) < 0.2] = np.float32(max_drop)
    return index, sid, piece, valid, drop, max_drop


@pytest.mark.parametrize("cut,gaps", [(True, True), (True, False), (False, True), (False, False)])
def test_cut_and_gap_candidates_equal_the_former_steps(cut, gaps):
    rng = np.random.default_rng(157)
    n_cut = 0
    for _ in range(200):
        P = int(rng.integers(2, 400))
        index, sid, piece, valid, drop, max_drop = _random_traces(rng, P)
        i_old, i_new = index.copy(), index.copy()
        old = _former_cut_and_gaps(i_old, sid, piece, valid, drop, max_drop, cut, gaps)
        new = _k.cut_and_gap_candidates(i_new, sid, piece, valid, drop, np.float32(max_drop), cut, gaps)
        np.testing.assert_array_equal(new[0], old[0])
        assert int(new[1]) == int(old[1])
        np.testing.assert_array_equal(new[2], old[2])
        np.testing.assert_array_equal(new[3], old[3])
        np.testing.assert_array_equal(i_new, i_old)
        n_cut += len(old[2])
    assert n_cut > 0 or not cut


def test_labels_out_equals_drop_unlabelled_junctions_and_the_casts():
    rng = np.random.default_rng(1570)
    for _ in range(50):
        P = int(rng.integers(0, 300))
        index = rng.integers(-3, 40, P).astype(np.float32)
        index[rng.random(P) < 0.3] = np.nan
        jid = rng.integers(-1, 500, P).astype(np.int32)
        i_old, j_old = index.copy(), jid.copy()
        n_old = _k.drop_unlabelled_junctions(i_old, j_old)
        idx, j, n = _k.labels_out(index, jid)
        assert idx.dtype == np.float64 and j.dtype == np.int64
        np.testing.assert_array_equal(idx, i_old.astype(np.float64))
        np.testing.assert_array_equal(j, j_old.astype(np.int64))
        assert int(n) == int(n_old)


def _knn_brute(pts, queries, k, radius):
    m = len(pts)
    dist = np.full((len(queries), k), np.inf)
    idx = np.full((len(queries), k), m, np.intp)
    r2 = radius * radius
    for i, (x, y) in enumerate(queries):
        if not (np.isfinite(x) and np.isfinite(y)):
            continue
        d2 = (pts[:, 0] - x) ** 2 + (pts[:, 1] - y) ** 2
        inside = np.flatnonzero(~(d2 >= r2))
        o = inside[np.lexsort((inside, d2[inside]))][:k]
        dist[i, : len(o)] = np.sqrt(d2[o])
        idx[i, : len(o)] = o
    return dist, idx


def test_knn_within_equals_brute_force_with_ties_and_cell_edges():
    rng = np.random.default_rng(15700)
    for t in range(300):
        m = int(rng.integers(1, 200))
        nq = int(rng.integers(1, 120))
        r = float(rng.choice([0.5, 1.0, 3.0, 7.3, 20.0, 1 / 3]))
        if t % 2 == 0:  # a lattice on the cells' edges: points at exactly r, equal distances, duplicates
            step = r / float(rng.choice([1, 2, 3, 4]))
            pts = rng.integers(0, 30, (m, 2)).astype(float) * step
            qs = rng.integers(-2, 32, (nq, 2)).astype(float) * step
        else:
            pts = rng.uniform(0, 60, (m, 2))
            qs = rng.uniform(-10, 70, (nq, 2))
        if t % 5 == 0:
            qs[0] = np.nan
        k = int(rng.integers(1, 8))
        got = _k.knn_within(pts, qs, k, r)
        ref = _knn_brute(pts, qs, k, r)
        np.testing.assert_array_equal(got[1], ref[1])
        np.testing.assert_array_equal(got[0], ref[0])


def test_label_samples_fused_end_equals_the_former_path(small_scene_pitch16, monkeypatch):
    """The frame's label stage with the extraction stage's cut-profile measures (the compiled end) against the same
    frame without them (the former path: labelled_positions, the measure at those positions, the NumPy cut,
    gap_candidates)."""
    s = small_scene_pitch16
    opts = ReconstructOptions(depth_min_mm=s.depth_range_mm[0], depth_max_mm=s.depth_range_mm[1])
    frame = extract_frame(s.image, s.procam, s.pattern, options=opts)
    tp = frame.prep.traces
    assert tp is not None and tp.drop is not None and tp.drop.dtype == np.float32
    calls = {"fused": 0}
    orig = _k.cut_and_gap_candidates

    def spy(*a):
        calls["fused"] += 1
        return orig(*a)

    monkeypatch.setattr(_k, "cut_and_gap_candidates", spy)
    new = finish_frame(frame)
    assert calls["fused"] == 1
    former = finish_frame(dataclasses.replace(frame, prep=dataclasses.replace(frame.prep, traces=dataclasses.replace(tp, drop=None))))
    assert calls["fused"] == 1
    for name in ("points_proj", "q_cam", "label", "family", "junction_labels", "junctions_cam"):
        np.testing.assert_array_equal(getattr(new, name), getattr(former, name), err_msg=name)
    for key in ("samples_labelled", "samples_gap_filled"):
        assert new.stats[key] == former.stats[key], key
    assert new.stats["samples_gap_filled"] > 0
