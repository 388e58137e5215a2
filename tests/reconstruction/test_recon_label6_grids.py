"""Round six of the label stage's speed (decision 0090): the bucket grids split by family, and the searches that
read only one family's part of a cell, against the plain grid and plain loops (bit for bit)."""

from __future__ import annotations

import numpy as np
import pytest

from reconstruction import _continuation_kernels as CK
from reconstruction import _label_kernels as K
from reconstruction import crossing_fill as CF
from reconstruction.trace_ends import line_goes_on


def _samples(rng, n, lattice):
    """Positions (n, 2) over ~120×90 px (on a half-pixel lattice when `lattice`: many exact distance ties), a
    few NaN; families 1, 2 and some 0; valid = family 1 or 2 and finite (as label_samples' valid)."""
    q = rng.uniform(0, [120, 90], (n, 2))
    if lattice:
        q = np.round(q * 2) / 2
    q[rng.random(n) < 0.02] = np.nan
    fam = rng.choice([1, 2, 2, 1, 0], n).astype(np.intp)
    valid = ((fam == 1) | (fam == 2)) & np.isfinite(q).all(axis=1)
    return q, fam, valid


def _cells(start, items, nc):
    return [items[start[c]:start[c + 1]].tolist() for c in range(nc)]


@pytest.mark.parametrize("lattice", [False, True])
def test_split_grid_is_the_plain_grid_with_each_cell_split_by_family(lattice):
    rng = np.random.default_rng(61)
    for _ in range(20):
        q, fam, valid = _samples(rng, int(rng.integers(1, 400)), lattice)
        sid = rng.permutation(np.flatnonzero(valid))[: int(valid.sum() * 0.7)].astype(np.intp)
        cell = float(rng.choice([3.0, 7.5, 20.0]))
        x0, y0, gw, gh, start, items, pos_of = K.sample_grid(q, valid, sid, cell)
        sx0, sy0, sgw, sgh, sstart, sitems, spos = K.sample_grid_split(q, valid, fam, sid, cell)
        assert (sx0, sy0, sgw, sgh) == (x0, y0, gw, gh)
        nc = gw * gh
        assert len(sstart) == 2 * nc + 1
        assert np.array_equal(sstart[: nc + 1], start)
        assert np.array_equal(spos, pos_of)
        for c, plain in enumerate(_cells(start, items, nc)):
            mid = sstart[nc + 1 + c]
            assert sitems[sstart[c]:mid].tolist() == [s for s in plain if fam[s] == 1]
            assert sitems[mid:sstart[c + 1]].tolist() == [s for s in plain if fam[s] != 1]


def test_searches_on_the_split_grid_equal_those_on_the_plain_grid():
    """crossing_nearest / crossing_hits_traces, crossing_in_gap and line_goes_on read one family's part of
    each cell of a split grid: the same answers as on the plain grid, ties (lattice positions) included."""
    rng = np.random.default_rng(62)
    checked = [0, 0, 0]
    for trial in range(30):
        q, fam, valid = _samples(rng, 500, lattice=trial % 2 == 0)
        P = len(q)
        sid = rng.permutation(np.flatnonzero(valid)).astype(np.intp)[: int(valid.sum() * 0.8)]
        index = np.where(rng.random(P) < 0.6, rng.integers(-5, 5, P).astype(float), np.nan)
        tangent = rng.normal(size=(len(sid), 2))
        tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
        radius = float(rng.choice([4.0, 6.5, 10.0]))
        cell = radius * float(rng.choice([1.0, 1.5]))
        plain = K.sample_grid(q, valid, sid, cell)
        split = K.sample_grid_split(q, valid, fam, sid, cell)
        gp = (float(plain[0]), float(plain[1]), cell, int(plain[2]), int(plain[3]), plain[4], plain[5], plain[6])
        gs = (float(split[0]), float(split[1]), cell, int(split[2]), int(split[3]), split[4], split[5], split[6])
        E = 60
        e = rng.uniform(-5, [125, 95], (E, 2))
        if trial % 2 == 0:
            e = np.round(e * 2) / 2
        e[0] = np.nan
        fe = rng.choice([1, 2], E).astype(np.intp)
        for labelled_only in (True, False):
            a = K.crossing_nearest(e, fe, q, fam, index, labelled_only, radius, *gp)
            b = K.crossing_nearest(e, fe, q, fam, index, labelled_only, radius, *gs)
            assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
            checked[0] += int((a[1] >= 0).sum())
        te = tangent[rng.integers(0, len(sid), E)]
        sign = rng.choice([-1.0, 1.0], E)
        a = K.crossing_hits_traces(e, te, sign, fe, q, sid, tangent, fam, index, True, radius, 0.34, *gp)
        b = K.crossing_hits_traces(e, te, sign, fe, q, sid, tangent, fam, index, True, radius, 0.34, *gs)
        assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1], equal_nan=True)
        li = rng.integers(0, E, 40)
        lj = rng.integers(0, E, 40)
        gap = rng.uniform(0, 2 * radius, 40)
        e2 = np.nan_to_num(e, nan=50.0)
        a = CK.crossing_in_gap(q, fam, e2, fe, li, lj, gap, *gp[:7])
        b = CK.crossing_in_gap(q, fam, e2, fe, li, lj, gap, *gs[:7])
        assert np.array_equal(a, b)
        checked[1] += int(a.sum())
        c = e2 + sign[:, None] * te * rng.uniform(0, 4, (E, 1))
        a = line_goes_on(c, e2, te, sign, fe, q, fam, 1.5, *gp[:7], gp[7])
        b = line_goes_on(c, e2, te, sign, fe, q, fam, 1.5, *gs[:7], gs[7])
        assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
        checked[2] += int(a[0].sum())
    assert min(checked) > 20  # the searches found something to compare


def test_family_grid_is_sample_grid_split_by_family():
    rng = np.random.default_rng(63)
    no_trace = np.zeros(0, np.intp)
    for _ in range(20):
        q, fam, valid = _samples(rng, int(rng.integers(1, 400)), lattice=bool(rng.random() < 0.5))
        cell = float(rng.choice([4.0, 13.3]))
        x0, y0, gw, gh, start, items, _ = K.sample_grid(q, valid, no_trace, cell)
        fx0, fy0, fgw, fgh, fstart, fmid, fitems = CF._family_grid(q, fam, cell)
        assert (fx0, fy0, fgw, fgh) == (x0, y0, gw, gh)
        assert np.array_equal(fstart, start)
        for c, plain in enumerate(_cells(start, items, gw * gh)):
            assert fitems[fstart[c]:fmid[c]].tolist() == [s for s in plain if fam[s] == 1]
            assert fitems[fmid[c]:fstart[c + 1]].tolist() == [s for s in plain if fam[s] == 2]


def _other_run_plain(mx, my, rad, f, qs, fs, cell):
    """The search as 0086 wrote it: the plain grid of both families, the 3×3 cells around the middle's cell,
    every item of the other family tested; sums in that order."""
    skeep = ((fs == 1) | (fs == 2)) & np.isfinite(qs).all(axis=1)
    x0, y0, gw, gh, start, items, _ = K.sample_grid(qs, skeep, np.zeros(0, np.intp), cell)
    gx = int((mx - x0) / cell)
    gy = int((my - y0) / cell)
    hits = []
    for cy in range(max(gy - 1, 0), min(gy + 2, gh)):
        for cx in range(max(gx - 1, 0), min(gx + 2, gw)):
            c = cy * gw + cx
            for i in items[start[c]:start[c + 1]]:
                if fs[i] == f:
                    continue
                ex = qs[i, 0] - mx
                ey = qs[i, 1] - my
                if ex * ex + ey * ey <= rad * rad:
                    hits.append(i)
    cnt = len(hits)
    if cnt < 4:
        return cnt, None
    sx = sy = 0.0
    for i in hits:
        sx += qs[i, 0]
        sy += qs[i, 1]
    cxm, cym = sx / cnt, sy / cnt
    cxx = cxy = cyy = 0.0
    for i in hits:
        ex, ey = qs[i, 0] - cxm, qs[i, 1] - cym
        cxx += ex * ex
        cxy += ex * ey
        cyy += ey * ey
    return cnt, (cxm, cym, cxx / cnt, cxy / cnt, cyy / cnt)


def test_the_crossing_run_search_equals_the_plain_3x3_search():
    """`crossing_fill._other_run` (the bounding box's cells, the family's part) = the plain 3×3 search over
    both families, count and moments bit for bit, with samples exactly on the disc's rim (lattice, integer
    radii) and middles anywhere, also outside the samples' box."""
    rng = np.random.default_rng(64)
    n_runs = 0
    for trial in range(60):
        q, fam, _ = _samples(rng, 600, lattice=trial % 2 == 0)
        fam[fam == 0] = 1
        cell = float(rng.choice([8.0, 13.3]))
        x0, y0, gw, gh, start, mid, items = CF._family_grid(q, fam, cell)
        hits = np.empty(len(items), np.intp)
        for _ in range(40):
            mx, my = (np.round(rng.uniform(-10, [130, 100]) * 2) / 2) if trial % 2 == 0 else rng.uniform(-10, [130, 100])
            rad = float(rng.choice([2.0, 3.0, 0.5 * cell, 0.75 * cell])) if trial % 2 == 0 else float(rng.uniform(1, 0.75 * cell))
            f = int(rng.choice([1, 2]))
            cnt, mom = _other_run_plain(mx, my, rad, f, q, fam, cell)
            got = CF._other_run(mx, my, rad, f, q, x0, y0, cell, gw, gh, start, mid, items, hits)
            assert got[0] == cnt
            if mom is not None:
                n_runs += 1
                assert tuple(got[1:]) == mom
    assert n_runs > 100
