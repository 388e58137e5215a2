"""Decision 0124 (label stage, round eleven): the changed paths give the outputs of the ones they replace.

- `_label_kernels.offset_scores_b` (the candidate scan block by block, the admissibility counts from a prefix sum)
  against `offset_scores` (every pattern junction, every label counted), on random components: small and large,
  pattern junctions missing (NaN) in part of a block and in a whole block, several block sizes;
- `offset_choice_groups` (which now takes `offset_choice_b`) against `offset_choice` per group;
- the one-sided fill's end rows (`crossing_fill_one_sided._k_ends`) sized from the run breaks: exactly the ends
  looked at, on the small pitch 16 scene; the crossing fill's gap rows (`crossing_fill._k_gaps`) written when made.
"""

from __future__ import annotations

import numpy as np
import pytest

import reconstruction.crossing_fill as CF
import reconstruction.crossing_fill_one_sided as OS
from reconstruction import _label_kernels as K
from reconstruction.pipeline import ReconstructOptions, extract_frame, finish_frame


def _pattern(rng, L):
    """xy_junction (L, L, 2) of a slanted grid in normalised coordinates, slightly perturbed."""
    ii, jj = np.meshgrid(np.arange(L), np.arange(L), indexing="ij")
    s = 1.0 / L
    return np.ascontiguousarray(np.stack([s * (ii - jj) + 1e-3 * s * rng.normal(size=ii.shape),
                                          1.5 * s * (ii + jj) - 1.5 + 1e-3 * s * rng.normal(size=ii.shape)], axis=-1))


def _component(rng, xy_junction, imin, m, spread):
    L = xy_junction.shape[0]
    rel = rng.integers(-spread, spread + 1, (m, 2)).astype(np.int64)
    true = rel + rng.integers(-3, 4, 2)
    p = xy_junction[np.clip(true[:, 0] - imin, 0, L - 1), np.clip(true[:, 1] - imin, 0, L - 1)]
    p = np.where(np.isfinite(p), p, 0.0)
    ang = rng.uniform(0, np.pi, m)
    ln = np.column_stack([np.sin(ang), -np.cos(ang), -(np.sin(ang) * p[:, 0] - np.cos(ang) * p[:, 1])])
    ln[:, 2] += rng.normal(0, 2e-4, m)
    ln[rng.random(m) < 0.1] = np.nan
    return rel, np.ascontiguousarray(ln)


def _equal(a, b):
    assert len(a) == len(b)
    for x, y in zip(a, b):
        if isinstance(x, np.ndarray):
            assert x.dtype == y.dtype and x.shape == y.shape
            np.testing.assert_array_equal(x, y)
        else:
            assert x == y or (x != x and y != y)


@pytest.mark.parametrize("L", [41, 81])
def test_offset_scores_by_blocks_equal_the_full_scan(L):
    rng = np.random.default_rng(11 + L)
    imin = -(L // 2)
    imax = imin + L - 1
    xy = _pattern(rng, L)
    xy[3, 5] = np.nan  # a junction missing inside a block
    xy[16:24, 8:16] = np.nan  # a whole block of 8 missing
    fx, band, cap2, frac = 800.0, 4.0, 9.0, 0.9
    statuses = set()
    n_prefix = n_direct = 0
    for trial in range(40):
        m = int(rng.choice([1, 2, 5, 30, 200, 600]))
        spread = int(rng.choice([2, 6, L // 3]))
        rel, ln = _component(rng, xy, imin, m, spread)
        ref = K.offset_scores(rel, ln, xy, imin, imax, fx, 5, band, frac, cap2)
        statuses.add(int(ref[0]))
        for B in (1, 3, 8, 64):
            got = K.offset_scores_b(rel, ln, xy, K.junction_blocks(xy, B), B, imin, imax, fx, 5, band, frac, cap2)
            _equal(got, ref)
        if ref[0] in (0, 3):  # candidates counted: which count path ran
            w = (np.ptp(rel[:, 0]) + 2) * (np.ptp(rel[:, 1]) + 2)
            n_cand = len(ref[1]) if ref[0] == 0 else 1
            if n_cand * m > 4 * w:
                n_prefix += 1
            else:
                n_direct += 1
    assert 0 in statuses and n_prefix > 0 and n_direct > 0


def test_junction_blocks_bound_their_junctions():
    rng = np.random.default_rng(3)
    xy = _pattern(rng, 20)
    xy[0:8, 0:8] = np.nan
    box = K.junction_blocks(xy, 8)
    assert box.shape == (3, 3, 4)
    assert box[0, 0, 0] > box[0, 0, 1]  # an empty block
    blk = xy[8:16, 16:20].reshape(-1, 2)
    np.testing.assert_array_equal(box[1, 2], [blk[:, 0].min(), blk[:, 0].max(), blk[:, 1].min(), blk[:, 1].max()])


def test_offset_choice_groups_equal_offset_choice_per_group():
    rng = np.random.default_rng(7)
    L = 41
    imin, imax = -20, 20
    xy = _pattern(rng, L)
    rels, lns = [], []
    sizes = [1, 4, 60, 300, 2]
    for m in sizes:
        r, ln_ = _component(rng, xy, imin, m, 8)
        rels.append(r)
        lns.append(ln_)
    rel = np.ascontiguousarray(np.concatenate(rels))
    ln = np.ascontiguousarray(np.concatenate(lns))
    n = len(rel)
    xy_cam = np.ascontiguousarray(rng.normal(0, 0.2, (n, 2)))
    order = np.arange(n, dtype=np.intp)
    bounds = np.concatenate([[0], np.cumsum(sizes)]).astype(np.intp)
    R = np.eye(3)
    t = np.array([100.0, 0.0, 0.0])
    args = (800.0, 5, 4.0, 0.9, 9.0, R, t, 1.0, 1e6)
    labels = np.full((n, 2), -(2 ** 40), np.int64)
    residual = np.full(n, np.nan)
    out = K.offset_choice_groups(order, bounds, 1, rel, ln, xy_cam, xy, imin, imax, *args, 6.0, 0.3, 0.01, 25.0, 2.25, labels, residual)
    status, n_fail, ok, s1, s2, n_eff, off = out[:7]
    n_ok = 0
    for g in range(len(sizes)):
        mem = slice(bounds[g], bounds[g + 1])
        ref = K.offset_choice(np.ascontiguousarray(rel[mem]), np.ascontiguousarray(ln[mem]), np.ascontiguousarray(xy_cam[mem]), xy,
                              imin, imax, *args)
        assert (status[g], n_fail[g], ok[g], s1[g], s2[g], n_eff[g]) == tuple(ref[:6])
        np.testing.assert_array_equal(off[g], ref[6])
        if ref[2]:
            np.testing.assert_array_equal(out[8][mem], ref[7])
            n_ok += 1
    assert n_ok >= 2


def test_one_sided_end_rows_are_the_ends_and_gap_rows_are_written(small_scene_pitch16, monkeypatch):
    s = small_scene_pitch16
    opts = ReconstructOptions(depth_min_mm=s.depth_range_mm[0], depth_max_mm=s.depth_range_mm[1])
    seen = {}

    def spy(mod, name):
        f = getattr(mod, name)

        def w(*a):
            r = f(*a)
            seen[name] = (a, tuple(np.copy(x) if isinstance(x, np.ndarray) else x for x in r))  # as returned (callers write acc)
            return r
        monkeypatch.setattr(mod, name, w)

    spy(OS, "_k_ends")
    spy(CF, "_k_gaps")
    res = finish_frame(extract_frame(s.image, s.procam, s.pattern, options=opts))
    assert res.n_points > 1000
    # _k_ends: q, fam, idx, order, ..., min_gap at position 24
    a, (n_ends, ends, acc, c_q, m_out, why, why_run) = seen["_k_ends"]
    brk = OS._k_run_breaks(a[0], a[1], a[2], a[3], a[24])
    assert n_ends == 2 * int(brk.sum()) - 2 > 0
    assert len(ends) == len(acc) == len(c_q) == len(m_out) <= n_ends
    assert len(ends) + int(why.sum()) == n_ends  # every end looked at is a row or a rejection
    # _k_gaps: each returned row's acc and c_q were written (an accepted gap has no crossing to check)
    _, (n_gaps, gaps, acc_g, c_q_g, why_g, *_more) = seen["_k_gaps"]  # decision 0149 added the gaps' positions and the lines' boxes
    assert len(gaps) > 10 and acc_g.dtype == np.bool_
    assert set(np.unique(acc_g.view(np.uint8)).tolist()) <= {0, 1}
    assert np.isnan(c_q_g[acc_g]).all()
    fin = np.isfinite(c_q_g[:, 0])
    assert fin.any() and (np.isfinite(c_q_g[:, 1]) == fin).all()


def test_needed_samples_read_each_cell_once_give_the_same_ids_in_order():
    """`surface_labels._k_needed` reads a cell at its first visit only; the former loop read it at every visit."""
    from reconstruction.surface_labels import _k_cell_box, _k_needed

    rng = np.random.default_rng(12)
    P, cell, gw, gh = 3000, 6.0, 30, 25
    q = np.column_stack([rng.uniform(0, gw * cell, P), rng.uniform(0, gh * cell, P)])
    key = (q[:, 1] // cell).astype(np.intp) * gw + (q[:, 0] // cell).astype(np.intp)
    items = np.argsort(key, kind="stable").astype(np.intp)
    start = np.searchsorted(key[items], np.arange(gw * gh + 1)).astype(np.intp)
    index = np.where(rng.random(P) < 0.7, rng.integers(-5, 5, P).astype(float), np.nan)
    w = np.where(rng.random(P) < 0.3, 1.0, np.nan)
    cen = rng.uniform(0, min(gw, gh) * cell, (80, 2))  # overlapping neighbourhoods
    rad = rng.uniform(5.0, 25.0, 80)
    seen0 = rng.random(P) < 0.1
    # the former loop, every cell read at every visit
    seen_ref = seen0.copy()
    want = []
    for r in range(len(cen)):
        gx0, gx1, gy0, gy1 = _k_cell_box(cen[r, 0], cen[r, 1], rad[r], 0.0, 0.0, cell, gw, gh)
        for yy in range(gy0, gy1 + 1):
            for xx in range(gx0, gx1 + 1):
                b = yy * gw + xx
                for s in items[start[b]:start[b + 1]]:
                    if seen_ref[s] or not np.isfinite(index[s]) or np.isfinite(w[s]):
                        continue
                    seen_ref[s] = True
                    want.append(s)
    seen = seen0.copy()
    got = _k_needed(cen, rad, index, w, seen, 0.0, 0.0, cell, gw, gh, start, items)
    assert len(want) > 100
    np.testing.assert_array_equal(got, np.array(want, np.intp))
    np.testing.assert_array_equal(seen, seen_ref)
