"""Decision 0162: the extraction kernels changed for speed return what the former kernels returned, bit for bit.

The former kernels (main at 234c7bf) are kept here verbatim as references (only renamed): `albedo_and_families` (the
direction cells now in a loop of their own), `link_segments` (the slopes in a loop of their own), `junction_fits` /
`_fits_of_groups` (the second line fit only for groups that lost an outlier) and `shared_arm_fits` (its refits over
each group's run, `_fits_of_runs`)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numba import njit

from reconstruction import _extract_kernels as K
from reconstruction._extract_kernels import _RING, _row_span, line_fit_xy

@njit
def _albedo_ref(u, v, ox, oy, nx, ny, st, xu, xv, xs, Hw, Ww, min_rel, cross_rel, dir4, gh_d, gw_d, cell_d, margin):
    """The uneven-albedo test (a fraction of the strongest ridge in the 3×3 cells of 16 px around: the
    per-cell maximum, then its 3×3 dilation within the grid) on line samples and crossing candidates,
    then the family of each line sample from the model's direction grid `dir4` ((gh_d·gw_d, 4) float32:
    i-line (dx, dy), j-line (dx, dy); nearest cell of `cell_d` px).

    min_rel, cross_rel, margin: float32. Returns the kept samples (u, v, ox, oy, nx, ny, strength, fam int8,
    qx, qy float32 = u + ox, v + oy) and the kept crossing candidates (xu, xv, xs), in input order, as
    views of arrays of the input's length (every sample is written at the next free place, the place
    advances only where it is kept: branch-free)."""
    cell_s = 16  # pixel coordinates are ≥ 0: `>> 4` below is their `// cell_s` without the signed floor (0079)
    gh = Hw // cell_s + 1
    gw = Ww // cell_s + 1
    n = len(u)
    m0 = np.zeros((gh, gw), np.float32)
    for k in range(n):
        r = v[k] >> 4
        c = u[k] >> 4
        if st[k] > m0[r, c]:
            m0[r, c] = st[k]
    local = np.zeros((gh, gw), np.float32)
    for r in range(gh):
        for c in range(gw):
            best = m0[r, c]
            for rr in range(max(r - 1, 0), min(r + 2, gh)):
                for cc in range(max(c - 1, 0), min(c + 2, gw)):
                    if m0[rr, cc] > best:
                        best = m0[rr, cc]
            local[r, c] = best
    ou = np.empty(n, np.int64)
    ov = np.empty(n, np.int64)
    oox = np.empty(n, np.float32)
    ooy = np.empty(n, np.float32)
    onx = np.empty(n, np.float32)
    ony = np.empty(n, np.float32)
    ost = np.empty(n, np.float32)
    ofam = np.empty(n, np.int8)
    qx = np.empty(n, np.float32)
    qy = np.empty(n, np.float32)
    m = 0
    for k in range(n):
        uk = u[k]
        vk = v[k]
        cd = int((uk + np.float64(ox[k])) / cell_d + 0.5)
        rd = int((vk + np.float64(oy[k])) / cell_d + 0.5)
        cd = min(max(cd, 0), gw_d - 1)
        rd = min(max(rd, 0), gh_d - 1)
        j = rd * gw_d + cd
        c1 = abs(dir4[j, 1] * nx[k] - dir4[j, 0] * ny[k])
        c2 = abs(dir4[j, 3] * nx[k] - dir4[j, 2] * ny[k])
        keep = (st[k] >= min_rel * local[vk >> 4, uk >> 4]) & (abs(c1 - c2) >= margin)
        ou[m] = uk
        ov[m] = vk
        oox[m] = ox[k]
        ooy[m] = oy[k]
        onx[m] = nx[k]
        ony[m] = ny[k]
        ost[m] = st[k]
        ofam[m] = 1 if c1 >= c2 else 2
        qx[m] = np.float32(uk) + ox[k]
        qy[m] = np.float32(vk) + oy[k]
        m += keep
    nxs = len(xs)
    oxu = np.empty(nxs, np.int64)
    oxv = np.empty(nxs, np.int64)
    oxs = np.empty(nxs, np.float32)
    j = 0
    for k in range(nxs):
        oxu[j] = xu[k]
        oxv[j] = xv[k]
        oxs[j] = xs[k]
        j += xs[k] >= cross_rel * local[xv[k] >> 4, xu[k] >> 4]
    return ou[:m], ov[:m], oox[:m], ooy[:m], onx[:m], ony[:m], ost[:m], ofam[:m], qx[:m], qy[:m], oxu[:j], oxv[:j], oxs[:j]


@njit(error_model="numpy")
def _link_ref(u, v, core, qx, qy, nx, ny, fam, Hw, Ww):
    """Segments: samples outside the cores linked to the samples their 4 probes along their own tangent
    hit (one and two steps along its dominant axis, the two pixels across that the line reaches) when on
    the same line (same family, |n_a·n_b| ≥ 0.9, offset across ≤ 0.5 + 0.25·distance; float32), then the
    connected components (union-find), numbered by their lowest sample index (as scipy's
    connected_components), single samples dropped. Samples must come sorted by row (v), as the ridge pass
    emits them: the sample ids are kept for a window of `_RING` rows (columns padded by 2 px). The
    components do not depend on the order of the unions (the smaller root always becomes the parent), so
    a sample's own root is looked up once, at its first link, and updated by its unions.

    Returns seg (P,) int64 (−1: none) and the number of segments S."""
    P = len(u)
    parent = np.arange(P).astype(np.int32)
    Wp = Ww + 4
    win = np.full(_RING * Wp, -1, np.int32)
    filled = -1  # rows up to this one are in the window
    nxt = 0  # next sample to put into the window
    for a in range(P):
        if core[a]:
            continue
        va = v[a]
        while filled < min(va + 3, Hw - 1):
            filled += 1
            base_r = (filled % _RING) * Wp
            win[base_r : base_r + Wp] = -1
            while nxt < P and v[nxt] == filled:
                if not core[nxt]:
                    win[base_r + u[nxt] + 2] = nxt
                nxt += 1
        tx = -ny[a]
        ty = nx[a]
        xdom = abs(tx) >= abs(ty)
        slope = ty / tx if xdom else tx / ty
        if not np.isfinite(slope):
            continue
        ra = -1  # a's root: found at its first link, then kept up to date by its unions (decision 0091)
        for k in range(1, 3):
            x = np.float32(k) * slope
            lo = int(x)  # floor(x), x finite, |x| <= 2
            lo -= x < lo
            for extra in range(2):
                if xdom:
                    pr = va + lo + extra
                    pc = u[a] + k
                else:
                    pr = va + k
                    pc = u[a] + lo + extra
                if pr < 0 or pr >= Hw:
                    continue
                b = win[(pr % _RING) * Wp + pc + 2]
                if b < 0 or fam[a] != fam[b]:
                    continue
                if abs(nx[a] * nx[b] + ny[a] * ny[b]) < np.float32(0.9):
                    continue
                dqx = qx[b] - qx[a]
                dqy = qy[b] - qy[a]
                across = max(abs(dqx * nx[a] + dqy * ny[a]), abs(dqx * nx[b] + dqy * ny[b]))
                if across <= np.float32(0.5) + np.float32(0.25) * np.float32(math.sqrt(dqx * dqx + dqy * dqy)):
                    if ra < 0:
                        ra = a
                        while parent[ra] != ra:
                            parent[ra] = parent[parent[ra]]
                            ra = parent[ra]
                    rb = b
                    while parent[rb] != rb:
                        parent[rb] = parent[parent[rb]]
                        rb = parent[rb]
                    if ra != rb:
                        if ra < rb:
                            parent[rb] = np.int32(ra)
                        else:
                            parent[ra] = np.int32(rb)
                            ra = rb
    # the smaller root always becomes the parent, so parent[a] <= a: in index order each root is known
    # from the parent's, and a component's root is its lowest sample
    root = np.empty(P, np.int32)
    size = np.zeros(P, np.int32)
    for a in range(P):
        r = a if parent[a] == a else root[parent[a]]
        root[a] = r
        if not core[a]:
            size[r] += 1
    label = np.full(P, -1, np.int32)
    seg = np.full(P, -1, np.int64)
    S = 0
    for a in range(P):
        if core[a]:
            continue
        r = root[a]
        if r == a and size[a] >= 2:
            label[a] = S
            S += 1
        seg[a] = label[r]
    return seg, S


@njit
def _fits_of_groups_ref(grp, X, Y, NX, NY, na, G, sx, sy):
    """`junction_fits` on collected arm samples: points (X, Y), own normals (NX, NY) float64 of group grp[k]
    (row 2·candidate + family − 1), k < na (overwritten: the inliers are compacted in place); candidates at
    (sx, sy). Same outputs as `junction_fits`."""
    cen, dr, rms, cnt = line_fit_xy(grp, X, Y, na, G)
    m = 0  # inliers, compacted in place (order kept)
    for k in range(na):
        g = grp[k]
        off = abs((X[k] - cen[g, 0]) * dr[g, 1] - (Y[k] - cen[g, 1]) * dr[g, 0])
        if off <= max(1.0, 3 * rms[g]):
            grp[m] = g
            X[m] = X[k]
            Y[m] = Y[k]
            NX[m] = NX[k]
            NY[m] = NY[k]
            m += 1
    cen, dr, rms, cnt = line_fit_xy(grp, X, Y, m, G)
    n_neg = np.zeros(G)
    n_pos = np.zeros(G)
    s_neg = np.zeros(G)
    s_pos = np.zeros(G)
    s_sin = np.zeros(G)
    for k in range(m):
        g = grp[k]
        c = g // 2
        bx = X[k]
        by = Y[k]
        s = (bx - sx[c]) * dr[g, 0] + (by - sy[c]) * dr[g, 1]
        off = (bx - cen[g, 0]) * dr[g, 1] - (by - cen[g, 1]) * dr[g, 0]
        neg = s < -0.5
        pos = s > 0.5
        n_neg[g] += 1.0 if neg else 0.0
        s_neg[g] += off if neg else 0.0
        n_pos[g] += 1.0 if pos else 0.0
        s_pos[g] += off if pos else 0.0
        s_sin[g] += abs(NX[k] * dr[g, 0] + NY[k] * dr[g, 1])
    m_neg = np.empty(G)
    m_pos = np.empty(G)
    mean_sin = np.empty(G)
    for g in range(G):
        m_neg[g] = s_neg[g] / max(n_neg[g], 1.0)
        m_pos[g] = s_pos[g] / max(n_pos[g], 1.0)
        mean_sin[g] = s_sin[g] / max(cnt[g], 1)
    return cen, dr, rms, cnt, n_neg, n_pos, m_neg, m_pos, mean_sin


@njit
def _junction_fits_ref(arm_of, fam, qx, qy, nx, ny, sx, sy, ns):
    """Per candidate and family (rows 2·k + family − 1): the straight-line fit of its arm samples with
    outliers (farther than max(1, 3·RMS) from a first fit) dropped, and along that fit the inliers' counts
    on either side of the candidate (beyond 0.5 px), their mean signed offsets from the fit on either
    side, and the mean |sin| between the fit and the samples' own directions.

    Returns cen (2ns, 2), dr (2ns, 2), rms (2ns,), cnt (2ns,), n_neg, n_pos, m_neg, m_pos, mean_sin (2ns,).
    The side counts and sums are taken branch-free (adding 0 where a sample is not on that side: the
    same sums)."""
    G = 2 * ns
    P = len(arm_of)
    grp = np.empty(P, np.int64)  # the arm samples (float64 coordinates and normals), in sample order
    X = np.empty(P)
    Y = np.empty(P)
    NX = np.empty(P)
    NY = np.empty(P)
    na = 0
    for i in range(P):  # branch-free: every sample written at the next place, kept where on an arm
        a = arm_of[i]
        grp[na] = 2 * a + fam[i] - 1
        X[na] = np.float64(qx[i])
        Y[na] = np.float64(qy[i])
        NX[na] = np.float64(nx[i])
        NY[na] = np.float64(ny[i])
        na += a >= 0
    return _fits_of_groups_ref(grp, X, Y, NX, NY, na, G, sx, sy)


@njit
def _shared_arm_fits_ref(fits, core, row_start, u, fam, qx, qy, nx, ny, sx, sy, R32):
    """Refit, in place, the arms that have fewer than 3 samples (`junction_fits`' outputs `fits`, rows
    2·k + family − 1) from every sample of that family within R32[k] (float32, per candidate) of candidate k outside the
    crossings' cores (`core`), whichever segment holds it or none: where the other family's lines are a few px
    apart, a line's pieces between two crossings hold one or two samples, too few to be segments or shared by
    both crossings (decision 0120). Samples in scan order (`row_start`). A row is replaced only where the new
    arm has more samples. Returns the number of candidates with a row replaced."""
    cen, dr, rms, cnt, n_neg, n_pos, m_neg, m_pos, mean_sin = fits
    G = len(cnt)
    ns = G // 2
    Hw = len(row_start) - 1
    want = np.zeros(G, np.bool_)
    cap = 0
    for g in range(G):
        if cnt[g] < 3:
            want[g] = True
            c = g // 2
            rr = int(math.ceil(R32[c])) + 1
            cy = int(sy[c])
            cx = int(sx[c])
            for r in range(max(cy - rr, 0), min(cy + rr, Hw - 1) + 1):
                a, b = _row_span(row_start, u, r, cx - rr, cx + rr)
                cap += b - a
    if cap == 0:
        return 0
    grp = np.empty(cap, np.int64)
    X = np.empty(cap)
    Y = np.empty(cap)
    NX = np.empty(cap)
    NY = np.empty(cap)
    na = 0
    for g in range(G):
        if not want[g]:
            continue
        c = g // 2
        f = g - 2 * c + 1
        cx32 = np.float32(sx[c])
        cy32 = np.float32(sy[c])
        cy = int(sy[c])
        cx = int(sx[c])
        rr = int(math.ceil(R32[c])) + 1
        for r in range(max(cy - rr, 0), min(cy + rr, Hw - 1) + 1):
            a, b = _row_span(row_start, u, r, cx - rr, cx + rr)
            for t in range(a, b):
                if fam[t] != f or core[t]:
                    continue
                dx = qx[t] - cx32
                dy = qy[t] - cy32
                if np.float32(math.sqrt(dx * dx + dy * dy)) <= R32[c]:
                    grp[na] = g
                    X[na] = np.float64(qx[t])
                    Y[na] = np.float64(qy[t])
                    NX[na] = np.float64(nx[t])
                    NY[na] = np.float64(ny[t])
                    na += 1
    c2, d2, r2, n2, neg2, pos2, mn2, mp2, ms2 = _fits_of_groups_ref(grp, X, Y, NX, NY, na, G, sx, sy)
    done = np.zeros(ns, np.bool_)
    for g in range(G):
        if want[g] and n2[g] > cnt[g]:
            cen[g, 0] = c2[g, 0]
            cen[g, 1] = c2[g, 1]
            dr[g, 0] = d2[g, 0]
            dr[g, 1] = d2[g, 1]
            rms[g] = r2[g]
            cnt[g] = n2[g]
            n_neg[g] = neg2[g]
            n_pos[g] = pos2[g]
            m_neg[g] = mn2[g]
            m_pos[g] = mp2[g]
            mean_sin[g] = ms2[g]
            done[g // 2] = True
    return int(done.sum())


def _same(a, b) -> None:
    """Bit-identical outputs (tuples of arrays or scalars), dtypes included."""
    if isinstance(a, tuple):
        assert len(a) == len(b)
        for x, y in zip(a, b):
            _same(x, y)
        return
    if isinstance(a, np.ndarray):
        assert a.dtype == b.dtype and a.shape == b.shape
        assert np.array_equal(a.view(np.uint8), np.ascontiguousarray(b).view(np.uint8)) if a.flags.c_contiguous and a.size else np.array_equal(a, b, equal_nan=True)
        return
    assert a == b


def _unit(rng, n):
    t = rng.uniform(0, 2 * np.pi, n)
    nx, ny = np.cos(t).astype(np.float32), np.sin(t).astype(np.float32)
    k = rng.choice(n, n // 10, replace=False)  # axis-aligned normals, and a few of zero length
    nx[k[::2]], ny[k[::2]] = 1.0, 0.0
    nx[k[1::2]], ny[k[1::2]] = 0.0, -1.0
    nx[k[:3]], ny[k[:3]] = 0.0, 0.0
    return nx, ny


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_albedo_and_families_equals_former(seed):
    rng = np.random.default_rng(seed)
    Hw, Ww, n, nxs = 180, 260, 6000, 900
    v = np.sort(rng.integers(0, Hw, n)).astype(np.int64)
    u = rng.integers(0, Ww, n).astype(np.int64)
    ox, oy = (rng.uniform(-0.5, 0.5, (2, n))).astype(np.float32)
    b = rng.random(n) < 0.3  # on the direction cells' rounding boundaries (cell 16: (8 + 16 i) / 16 + 0.5 is an integer)
    ox[b], oy[b] = 0.0, 0.0
    u[b] = (u[b] // 16) * 16 + 8
    v[b] = (v[b] // 16) * 16 + 8
    v.sort()  # (the kernel does not need it; scan order as the ridge pass emits)
    nx, ny = _unit(rng, n)
    st = rng.gamma(2.0, 1.0, n).astype(np.float32)
    xv = np.sort(rng.integers(0, Hw, nxs)).astype(np.int64)
    xu = rng.integers(0, Ww, nxs).astype(np.int64)
    xs = rng.gamma(2.0, 1.0, nxs).astype(np.float32)
    cell_d = [7.3, 16.0, 5.0][seed]
    gh_d, gw_d = int(Hw / cell_d) + 2, int(Ww / cell_d) + 2
    d = rng.normal(size=(gh_d * gw_d, 4)).astype(np.float32)
    d[:, :2] /= np.hypot(d[:, 0], d[:, 1])[:, None]
    d[:, 2:] /= np.hypot(d[:, 2], d[:, 3])[:, None]
    args = (u, v, ox, oy, nx, ny, st, xu, xv, xs, Hw, Ww, np.float32(0.3), np.float32(0.5), d, gh_d, gw_d, cell_d,
            np.float32(0.15))
    ref = _albedo_ref(*args)
    new = K.albedo_and_families(*args)
    _same(tuple(np.ascontiguousarray(x) for x in new), tuple(np.ascontiguousarray(x) for x in ref))
    m = len(ref[0])
    assert 0 < m < n and set(np.unique(ref[7])) == {1, 2}  # some samples dropped, both families: the test can fail
    assert 0 < len(ref[10]) < nxs


def _line_samples(rng, H, W, n_lines=14, clutter=400):
    """Samples of straight lines (one per pixel along the dominant axis, the line's normal with a little noise) and
    clutter, in scan order (rows, then columns), one per pixel."""
    pix = {}
    for li in range(n_lines):
        th = rng.uniform(0, np.pi)
        tx, ty = np.cos(th), np.sin(th)
        x0, y0 = rng.uniform(10, W - 10), rng.uniform(10, H - 10)
        fam = 1 + li % 2
        for s in np.arange(-300, 300, 0.8):
            x, y = x0 + s * tx, y0 + s * ty
            iu, iv = int(round(x)), int(round(y))
            if 0 <= iu < W and 0 <= iv < H and (iv, iu) not in pix:
                a = np.arctan2(tx, -ty) + rng.normal(0, 0.05)  # normal (−ty, tx), jittered
                pix[(iv, iu)] = (x + rng.normal(0, 0.1), y + rng.normal(0, 0.1), np.cos(a), np.sin(a), fam)
    for _ in range(clutter):
        iu, iv = int(rng.integers(0, W)), int(rng.integers(0, H))
        a = rng.uniform(0, 2 * np.pi)
        pix[(iv, iu)] = (iu + rng.uniform(-0.5, 0.5), iv + rng.uniform(-0.5, 0.5), np.cos(a), np.sin(a), int(rng.integers(1, 3)))
    keys = sorted(pix)
    v = np.array([k[0] for k in keys], np.int64)
    u = np.array([k[1] for k in keys], np.int64)
    arr = np.array([pix[k] for k in keys])
    qx, qy, nx, ny = (arr[:, j].astype(np.float32) for j in range(4))
    fam = arr[:, 4].astype(np.int8)
    return u, v, qx, qy, nx, ny, fam


@pytest.mark.parametrize("seed", [0, 1])
def test_link_segments_equals_former(seed):
    rng = np.random.default_rng(10 + seed)
    H, W = 150, 210
    u, v, qx, qy, nx, ny, fam = _line_samples(rng, H, W)
    nx[:4], ny[:4] = 0.0, 0.0  # no direction (a NaN slope): never linked
    nx[4:8], ny[4:8] = 0.0, 1.0  # exactly along an axis
    h = np.float32(math.sqrt(0.5))
    nx[8:60:2], ny[8:60:2] = h, h  # at 45 degrees: |tx| = |ty| (the dominant axis' tie)
    nx[9:60:2], ny[9:60:2] = h, -h
    core = rng.random(len(u)) < 0.05
    ref = _link_ref(u, v, core, qx, qy, nx, ny, fam, H, W)
    new = K.link_segments(u, v, core, qx, qy, nx, ny, fam, H, W)
    _same(new, ref)
    assert ref[1] >= 10  # the lines were linked: the test can fail


def _arm_samples(rng, ns, per=30):
    """Candidates and, per candidate and family, arm samples along a line through it with a few outliers; some
    arms empty, some samples on no arm; the samples in a shuffled (scan-like) order."""
    sx = rng.uniform(0, 500, ns)
    sy = rng.uniform(0, 400, ns)
    arm, fam, X, Y, NX, NY = [], [], [], [], [], []
    for k in range(ns):
        for f in (1, 2):
            if rng.random() < 0.1:
                continue
            th = rng.uniform(0, np.pi)
            m = int(rng.integers(1, per))
            s = rng.uniform(-12, 12, m)
            off = rng.normal(0, 0.3, m)
            off[rng.random(m) < 0.15] += rng.choice([-4.0, 4.0])  # outliers (a group loses them)
            X += list(sx[k] + s * np.cos(th) - off * np.sin(th))
            Y += list(sy[k] + s * np.sin(th) + off * np.cos(th))
            NX += list(np.full(m, -np.sin(th)) + rng.normal(0, 0.05, m))
            NY += list(np.full(m, np.cos(th)) + rng.normal(0, 0.05, m))
            arm += [k] * m
            fam += [f] * m
    P = len(arm) + 200
    arm = np.array(arm + [-1] * 200, np.int64)
    fam = np.array(fam + list(rng.integers(1, 3, 200)), np.int8)
    X = np.array(X + list(rng.uniform(0, 500, 200)))
    Y = np.array(Y + list(rng.uniform(0, 400, 200)))
    NX = np.array(NX + list(rng.normal(size=200)))
    NY = np.array(NY + list(rng.normal(size=200)))
    o = rng.permutation(P)
    return arm[o], fam[o], X[o].astype(np.float32), Y[o].astype(np.float32), NX[o].astype(np.float32), NY[o].astype(np.float32), sx, sy


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_junction_fits_equals_former(seed):
    rng = np.random.default_rng(20 + seed)
    ns = 60
    arm, fam, qx, qy, nx, ny, sx, sy = _arm_samples(rng, ns)
    ref = _junction_fits_ref(arm, fam, qx, qy, nx, ny, sx, sy, ns)
    new = K.junction_fits(arm, fam, qx, qy, nx, ny, sx, sy, ns)
    _same(new, ref)
    # groups that lost outliers and groups that kept every sample: both paths taken
    g = 2 * arm[arm >= 0] + fam[arm >= 0] - 1
    n_all = np.bincount(g, minlength=2 * ns)
    assert (ref[3] < n_all).any() and ((ref[3] == n_all) & (n_all > 0)).any()


@pytest.mark.parametrize("seed", [0, 1])
def test_fits_of_runs_equals_former(seed):
    """`_fits_of_runs` on samples ordered by group (as shared_arm_fits collects them) is `_fits_of_groups`, empty
    groups included."""
    rng = np.random.default_rng(30 + seed)
    ns = 50
    arm, fam, qx, qy, nx, ny, sx, sy = _arm_samples(rng, ns)
    keep = arm >= 0
    grp = (2 * arm[keep] + fam[keep] - 1).astype(np.int64)
    o = np.argsort(grp, kind="stable")
    grp = grp[o]
    cols = [np.asarray(a[keep][o], np.float64) for a in (qx, qy, nx, ny)]
    G = 2 * ns
    ref = _fits_of_groups_ref(grp.copy(), *[c.copy() for c in cols], len(grp), G, sx, sy)
    start = np.concatenate([[0], np.cumsum(np.bincount(grp, minlength=G))]).astype(np.int64)
    new = K._fits_of_runs(start, *[c.copy() for c in cols], G, sx, sy)
    _same(new, ref)
    assert (np.diff(start) == 0).any()


def test_shared_arm_fits_equals_former():
    rng = np.random.default_rng(40)
    H, W = 150, 210
    u, v, qx, qy, nx, ny, fam = _line_samples(rng, H, W, n_lines=20, clutter=300)
    P = len(u)
    row_start = np.searchsorted(v, np.arange(H + 1)).astype(np.int64)
    core = rng.random(P) < 0.03
    ns = 40
    sx = rng.uniform(5, W - 5, ns)
    sy = rng.uniform(5, H - 5, ns)
    # arms: samples within 8 px of a candidate, some of them only (so that some arms hold fewer than 3 samples)
    d = np.hypot(qx[:, None] - sx[None], qy[:, None] - sy[None])
    arm = np.where(d.min(1) < 8, d.argmin(1), -1).astype(np.int64)
    arm[rng.random(P) < 0.6] = -1
    fits = K.junction_fits(arm, fam, qx, qy, nx, ny, sx, sy, ns)
    assert (fits[3] < 3).sum() > 10
    R32 = rng.uniform(4, 12, ns).astype(np.float32)
    f_ref = tuple(a.copy() for a in fits)
    f_new = tuple(a.copy() for a in fits)
    n_ref = _shared_arm_fits_ref(f_ref, core, row_start, u, fam, qx, qy, nx, ny, sx, sy, R32)
    n_new = K.shared_arm_fits(f_new, core, row_start, u, fam, qx, qy, nx, ny, sx, sy, R32)
    assert n_new == n_ref and n_ref > 0
    _same(f_new, f_ref)
