"""The label stage's trace pieces built from extraction's segments (`_label_kernels.traces_from_segments`,
decision 0085) instead of a second neighbour search (`traces_of`): the same pieces on synthetic lines, the
same pieces for almost every sample on a rendered scene, and line indices as right as before against
simulator truth."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from reconstruction import _label_kernels as K
from reconstruction.extraction import ExtractOptions, extract_grid, sigma_for
from reconstruction.labelling import LabelOptions, TraceOptions, label_epipolar, label_samples
from reconstruction.rigmodel import rig_model
from tests.reconstruction._truth import true_index

LINK_PX = 1.6
LATERAL_PX = 0.5
COS_TURN = float(np.cos(np.deg2rad(10.0)))
W = 3


def _line(x0: float, y0: float, dx: float, dy: float, n: int) -> np.ndarray:
    return np.column_stack([x0 + dx * np.arange(n), y0 + dy * np.arange(n)])


def _synthetic():
    """Family-1 lines along +x (samples 1 px apart, ids in raster order as extraction emits them):
    segment 0 with a 6 px gap (a crossing's mixing zone cut out); segment 1 with a 1.5 px sideways jump (a
    depth edge) in its middle; segments 2 and 3 one line broken where extraction did not link, with a
    sample outside every segment (a crossing's core sample) between their ends; a family-2 segment 4 whose
    end lies 1 px from segment 2's end (never joined: other family)."""
    a = np.vstack([_line(10, 10.2, 1, 0, 12), _line(28, 10.2, 1, 0, 12)])  # gap 28 − 21 = 7 px
    b = np.vstack([_line(10, 30.3, 1, 0, 10), _line(20, 31.8, 1, 0, 10)])  # jump 1.5 px across
    c = _line(10, 50.1, 1, 0, 10)  # ends at x = 19
    core = np.array([[20.2, 50.2]])
    d = _line(21.3, 50.3, 1, 0, 10)
    e = _line(18.6, 51.0, 0.02, 1, 8)  # family 2, running down from 1 px below c's end
    parts = [(a, 1, 0), (b, 1, 1), (c, 1, 2), (core, 1, -1), (d, 1, 3), (e, 2, 4)]
    q = np.vstack([p for p, _, _ in parts])
    fam = np.concatenate([np.full(len(p), f) for p, f, _ in parts]).astype(np.intp)
    seg = np.concatenate([np.full(len(p), g) for p, _, g in parts]).astype(np.int64)
    # raster order (row, then column), as extraction's samples
    o = np.lexsort((q[:, 0], np.floor(q[:, 1])))
    q, fam, seg = q[o], fam[o], seg[o]
    S = 5
    cen = np.array([q[seg == g].mean(axis=0) for g in range(S)])
    dr = np.array([np.linalg.svd(q[seg == g] - cen[g])[2][0] for g in range(S)])
    return q, fam, seg, cen, dr


def _partition(sel: np.ndarray, order: np.ndarray, piece: np.ndarray) -> set[frozenset]:
    sid = sel[order]
    return {frozenset(sid[piece == p].tolist()) for p in np.unique(piece)}


def test_synthetic_lines_give_the_pieces_that_the_trace_rules_cut_and_traces_of_finds():
    q, fam, seg, cen, dr = _synthetic()
    sel = np.arange(len(q), dtype=np.intp)
    order, piece, ts, tangent = K.traces_from_segments(q, fam, seg, cen, dr, sel, LINK_PX, LATERAL_PX, COS_TURN, W,
                                                       np.zeros(0, np.float32), np.float32(0.15), False)
    got = _partition(sel, order, piece)

    def ids(g, lo=None, hi=None):
        m = seg == g
        if lo is not None:
            m &= (q[:, 0] >= lo) & (q[:, 0] < hi)
        return frozenset(np.flatnonzero(m).tolist())

    expected = {
        ids(0, 0, 25), ids(0, 25, 100),  # the gap cuts
        ids(1, 0, 20), ids(1, 20, 100),  # the jump cuts
        ids(2) | frozenset(np.flatnonzero(seg == -1).tolist()) | ids(3),  # joined across the core sample
        ids(4),  # the other family stays apart
    }
    assert got == expected
    # ordered along the line, positions increasing, tangents along it
    for p in np.unique(piece):
        k = np.flatnonzero(piece == p)
        assert (np.diff(ts[k]) > 0).all()
        assert np.allclose(np.linalg.norm(tangent[k], axis=1), 1.0)
        s = sel[order[k]]
        if fam[s[0]] == 1:
            assert (np.diff(q[s, 0]) > 0).all()
            assert np.abs(tangent[k, 1]).max() < 0.2
    # the second linking finds the same pieces on these samples
    valid, r, c, H, W_, _ = K.sample_cells(np.ascontiguousarray(q), fam, 1.0, 2)
    o2, p2, _, _ = K.traces_of(q, fam, r, c, sel, int(H), int(W_), LINK_PX, LATERAL_PX, COS_TURN, W,
                               np.zeros(0, np.float32), np.float32(0.15), False)
    assert _partition(sel, o2, p2) == expected


def test_a_ridge_step_cuts_a_segment():
    q, fam, seg, cen, dr = _synthetic()
    sel = np.flatnonzero(seg == 2).astype(np.intp)
    ridge = np.full(len(q), 100.0, np.float32)
    ridge[sel[q[sel, 0] >= 15]] = 60.0  # an occluding edge: the brightness drops by 40 %
    order, piece, _, _ = K.traces_from_segments(q, fam, seg, cen, dr, sel, LINK_PX, LATERAL_PX, COS_TURN, W, ridge,
                                                np.float32(0.15), True)
    got = _partition(sel, order, piece)
    assert got == {frozenset(sel[q[sel, 0] < 15].tolist()), frozenset(sel[q[sel, 0] >= 15].tolist())}


@pytest.fixture(scope="module")
def staged(small_scene):
    s = small_scene
    model = rig_model(s.procam, s.pattern, s.depth_range_mm)
    obs = extract_grid(s.image, model)
    lab = label_epipolar(obs, model, model.cam_normalised(obs.q_junction),
                         options=LabelOptions(depth_min_mm=s.depth_range_mm[0], depth_max_mm=s.depth_range_mm[1]))
    return s, model, obs, lab


def _samples(s, model, obs, labels, **trace):
    return label_samples(obs, labels, sigma_px=float(obs.stats.get("sigma_px", sigma_for(model, ExtractOptions()))),
                         seed_radius_px=float(obs.stats["junction_radius_px"]), options=TraceOptions(**trace), model=model,
                         depth_range_mm=s.depth_range_mm, image=s.image, line_width_px=model.line_width_cam_px)


def test_pieces_on_a_scene_are_those_of_the_second_linking_for_almost_every_sample(staged, monkeypatch):
    s, model, obs, lab = staged
    assert obs.segment_linked is not None and obs.segment_linked.shape == (len(obs.q),)
    seen = {}
    for name in ("traces_of", "traces_from_segments"):
        f = getattr(K, name)

        def wrap(*a, f=f, name=name):
            out = f(*a)
            seen[name] = (a[4] if name == "traces_of" else a[5], out)
            return out

        monkeypatch.setattr(K, name, wrap)
    a = _samples(s, model, obs, lab.labels, from_segments=False)
    b = _samples(s, model, obs, lab.labels)
    sel_a, (oa, pa, _, _) = seen["traces_of"]
    sel_b, (ob, pb, _, _) = seen["traces_from_segments"]
    assert np.array_equal(np.sort(sel_a), np.sort(sel_b))  # the same kept samples
    part_a, part_b = _partition(sel_a, oa, pa), _partition(sel_b, ob, pb)
    same = sum(len(p) for p in part_a & part_b)
    assert same >= 0.97 * len(sel_a), (same, len(sel_a))
    # most pieces longer than a few samples are exactly a piece of the other
    long_a = {p for p in part_a if len(p) >= 5}
    assert len(long_a & part_b) >= 0.95 * len(long_a)
    # the labels: as many, as right (against the simulator's truth)
    la, lb = np.isfinite(a.index), np.isfinite(b.index)
    assert lb.sum() >= 0.995 * la.sum()
    fam = np.asarray(obs.family)
    true = true_index(s.truth, s.pattern, b.q, fam)
    ok_b = np.abs(b.index[lb] - true[lb]) < 0.5
    ok_a = np.abs(a.index[la] - true_index(s.truth, s.pattern, a.q, fam)[la]) < 0.5
    known_b = np.isfinite(true[lb])
    assert ok_b[known_b].mean() >= ok_a.mean() - 0.001
    assert ok_b[known_b].mean() > 0.99


def test_without_segment_links_the_samples_are_linked_again(staged):
    s, model, obs, lab = staged
    old = dataclasses.replace(obs, segment_linked=None)
    a = _samples(s, model, old, lab.labels)
    b = _samples(s, model, obs, lab.labels, from_segments=False)
    assert np.array_equal(a.index, b.index, equal_nan=True)
    assert np.array_equal(a.q, b.q)
    assert a.stats == b.stats
    c = _samples(s, model, obs, lab.labels)
    assert c.stats["traces"] != b.stats["traces"] or not np.array_equal(c.index, b.index, equal_nan=True)
