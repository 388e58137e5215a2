"""Round six of the label stage's speed (decision 0090): the bucket grids split by family, and the searches that
read only one family's part of a cell, against the plain grid and plain loops (bit for bit)."""

from __future__ import annotations

import math

import numba
import numpy as np
import pytest

from reconstruction import _continuation_kernels as CK
from reconstruction import _label_kernels as K
from reconstruction import _link_kernels as LK
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


# --- facing_links_mid: the labelled ends look only at unlabelled ones ---------------------------------------


@numba.njit(cache=False)
def _facing_links_all_pairs(e, u, f_e, n_p, labelled, reach, lateral, cos_facing):
    """The kernel before decision 0090: every pair of a cell and its forward neighbours, labelled ones skipped."""
    m = e.shape[0]
    out_a = np.empty(8 * m, np.intp)
    out_b = np.empty(8 * m, np.intp)
    out_g = np.empty(8 * m)
    out_i = np.empty(8 * m, np.intp)
    out_j = np.empty(8 * m, np.intp)
    nl = 0
    if m == 0:
        return out_a[:0], out_b[:0], out_g[:0], out_i[:0], out_j[:0]
    x0 = e[:, 0].min()
    y0 = e[:, 1].min()
    cell = reach
    gw = int((e[:, 0].max() - x0) / cell) + 1
    gh = int((e[:, 1].max() - y0) / cell) + 1
    ng = gw * gh
    key = np.empty(m, np.intp)
    start = np.zeros(2 * ng + 1, np.intp)
    for k in range(m):
        cx = min(max(int(math.floor((e[k, 0] - x0) / cell)), 0), gw - 1)
        cy = min(max(int(math.floor((e[k, 1] - y0) / cell)), 0), gh - 1)
        key[k] = (f_e[k] - 1) * ng + cy * gw + cx if f_e[k] == 1 or f_e[k] == 2 else -1
        if key[k] >= 0:
            start[key[k] + 1] += 1
    for k in range(2 * ng):
        start[k + 1] += start[k]
    fill = start[:-1].copy()
    items = np.empty(m, np.intp)
    for k in range(m):
        if key[k] >= 0:
            items[fill[key[k]]] = k
            fill[key[k]] += 1
    r2 = reach * reach
    lat2 = lateral * lateral
    for f in range(2):
        base = f * ng
        for cy in range(gh):
            for cx in range(gw):
                bk = base + cy * gw + cx
                for s in range(start[bk], start[bk + 1]):
                    i0 = items[s]
                    p0 = i0 - n_p if i0 >= n_p else i0
                    lab0 = labelled[p0]
                    ex = e[i0, 0]
                    ey = e[i0, 1]
                    for nb in range(5):
                        if nb == 0:
                            xx, yy = cx, cy
                        elif nb == 1:
                            xx, yy = cx + 1, cy
                        elif nb == 2:
                            xx, yy = cx - 1, cy + 1
                        elif nb == 3:
                            xx, yy = cx, cy + 1
                        else:
                            xx, yy = cx + 1, cy + 1
                        if xx < 0 or xx >= gw or yy >= gh:
                            continue
                        bn = base + yy * gw + xx
                        t0 = s + 1 if nb == 0 else start[bn]
                        for t in range(t0, start[bn + 1]):
                            j0 = items[t]
                            p1 = j0 - n_p if j0 >= n_p else j0
                            if p0 == p1 or (lab0 and labelled[p1]):
                                continue
                            # the gap vector from the lower end id to the higher (negation is exact)
                            w0 = e[j0, 0] - ex
                            w1 = e[j0, 1] - ey
                            g2 = w0 * w0 + w1 * w1
                            if g2 >= r2:
                                continue
                            if i0 < j0:
                                i, j, pi, pj, v0, v1 = i0, j0, p0, p1, w0, w1
                            else:
                                i, j, pi, pj, v0, v1 = j0, i0, p1, p0, -w0, -w1
                            if u[i, 0] * u[j, 0] + u[i, 1] * u[j, 1] >= -cos_facing:
                                continue
                            if v0 * u[i, 0] + v1 * u[i, 1] <= 0 or v0 * u[j, 0] + v1 * u[j, 1] >= 0:
                                continue
                            h = 0.5 * math.sqrt(g2)
                            d0 = (e[i, 0] + h * u[i, 0]) - (e[j, 0] + h * u[j, 0])
                            d1 = (e[i, 1] + h * u[i, 1]) - (e[j, 1] + h * u[j, 1])
                            if d0 * d0 + d1 * d1 > lat2:
                                continue
                            if nl == out_a.shape[0]:
                                break
                            out_a[nl] = pi
                            out_b[nl] = pj
                            out_g[nl] = math.sqrt(g2)
                            out_i[nl] = i
                            out_j[nl] = j
                            nl += 1
    return out_a[:nl], out_b[:nl], out_g[:nl], out_i[:nl], out_j[:nl]


def _ends(rng, n_p, lattice):
    """Piece ends (2n_p, 2) over ~150×110 px, outward directions, families, labelled pieces (most)."""
    e = rng.uniform(0, [150, 110], (2 * n_p, 2))
    if lattice:
        e = np.round(e)
    # the two ends of a piece a few px apart, pointing away from each other
    d = rng.normal(size=(n_p, 2))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    e[n_p:] = e[:n_p] + d * rng.uniform(0, 30, (n_p, 1))
    u = np.concatenate([-d, d]) + rng.normal(scale=0.15, size=(2 * n_p, 2))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    fam = np.tile(rng.choice([1, 2, 2, 1, 0], n_p), 2).astype(np.intp)
    labelled = rng.random(n_p) < 0.7
    return e, u, fam, labelled


def test_facing_links_equal_the_all_pairs_scan():
    rng = np.random.default_rng(65)
    n_links = 0
    for trial in range(40):
        n_p = int(rng.integers(1, 400))
        e, u, fam, labelled = _ends(rng, n_p, lattice=trial % 2 == 0)
        reach = float(rng.choice([6.0, 12.0, 25.0]))
        for lateral in (0.5, 3.0):
            want = _facing_links_all_pairs(e, u, fam, n_p, labelled, reach, lateral, 0.95)
            got = LK.facing_links_mid(e, u, fam, n_p, labelled, reach, lateral, 0.95)
            for a, b in zip(want, got):
                assert np.array_equal(a, b)
            n_links += len(want[0])
    assert n_links > 200


def test_median_by_selection_equals_numpys_median():
    """`median_finite` selects the middle order statistics instead of sorting: np.median's value, ties,
    odd and even counts, NaN left out, none finite."""
    rng = np.random.default_rng(66)
    for n in list(range(0, 12)) + [57, 300, 1001]:
        for ties in (False, True):
            r = np.abs(rng.normal(size=n))
            if ties:
                r = np.round(r * 4) / 4
            r[rng.random(n) < 0.2] = np.nan
            fin = r[np.isfinite(r)]
            got = K.median_finite(r)
            if len(fin) == 0:
                assert np.isnan(got)
            else:
                assert got == np.median(fin)


def test_sorting_the_packed_keys_gives_the_argsort_order():
    """`crossing_fill._sorted_by_key` = sel[np.argsort(key)]: distinct keys (the packed integers' order),
    keys a few ulp apart and equal keys (the argsort itself), and the fast path taken where it can be."""
    rng = np.random.default_rng(67)
    fast = 0
    for trial in range(60):
        n = int(rng.integers(0, 3000))
        key = rng.uniform(1.0, 5e5, n)
        if trial % 3 == 1 and n > 2:
            key[rng.integers(0, n, 3)] = key[0]  # exact ties
        if trial % 3 == 2 and n > 2:
            key[1] = np.nextafter(key[0], np.inf)  # neighbours within the packed bits
        sel = rng.permutation(n + 5)[:n].astype(np.intp)
        want = sel[np.argsort(key)]
        assert np.array_equal(CF._sorted_by_key(sel, key), want)
        if n > 1:
            packed, ok = CF._k_pack(key, int(n - 1).bit_length())
            fast += bool(ok and CF._k_unpack(np.sort(packed), sel, int(n - 1).bit_length())[1])
    assert fast >= 15


def _spread_seeds_two_passes(sid, piece, ts, seed, seed_jid, index, unlabelled):
    """spread_seeds before decision 0090: every position's seed value and junction gathered first, then
    written (NumPy)."""
    has = seed[sid] != unlabelled
    near = K.nearest_seed(piece, ts, has)
    got = near >= 0
    val = seed[sid[near[got]]].astype(float)
    jid = seed_jid[sid[near[got]]].copy()
    index[sid[got]] = val
    seed_jid[sid[got]] = jid
    seed_jid[sid[~got]] = -1
    seeded = len(np.unique(piece[has]))
    return got, seeded


def test_spread_seeds_in_one_pass_equals_the_two_passes():
    rng = np.random.default_rng(68)
    for _ in range(50):
        P = int(rng.integers(1, 600))
        sid = rng.permutation(P)[: int(rng.integers(1, P + 1))].astype(np.intp)
        n = len(sid)
        piece = np.sort(rng.integers(0, max(1, n // 8), n)).astype(np.int64)
        piece -= piece[0]
        ts = np.cumsum(rng.uniform(0.5, 2.0, n))
        seed = np.where(rng.random(P) < 0.1, rng.integers(-5, 5, P), -99).astype(np.int64)
        seed_jid = rng.integers(-1, 50, P).astype(np.int64)
        index = np.where(rng.random(P) < 0.3, rng.normal(size=P), np.nan)
        i0, j0 = index.copy(), seed_jid.copy()
        got_ref, seeded_ref = _spread_seeds_two_passes(sid, piece, ts, seed, j0, i0, -99)
        got, seeded, _ = K.spread_seeds(sid, piece, ts, seed, seed_jid, index, -99)
        assert np.array_equal(got, got_ref) and seeded == seeded_ref
        assert np.array_equal(index, i0, equal_nan=True) and np.array_equal(seed_jid, j0)
