"""The label stage's third round (decision 0070): faster kernels that must give the same outputs as the
round-2 code they replaced, checked here against that code (kept in this file as the reference) or against
libm, OpenCV and brute force, to the bit."""

from __future__ import annotations

import math
import platform

import cv2
import numba
import numpy as np
import pytest

from reconstruction import _label_kernels as K


def _replica_is_libm() -> bool:
    """Whether `_label_kernels._hypot` replicates this machine's libm hypot to the bit: it copies glibc's
    algorithm as glibc >= 2.35 builds it for x86-64 (decision 0070). Elsewhere (macOS, musl, an older glibc,
    another CPU) libm may round the last bit differently, which changes no decision of the kernels."""
    lib, version = platform.libc_ver()
    if platform.system() != "Linux" or platform.machine().lower() not in ("x86_64", "amd64") or lib != "glibc":
        return False
    try:
        major, minor = (int(v) for v in version.split(".")[:2])
    except ValueError:
        return False
    return (major, minor) >= (2, 35)


REPLICA_EXACT = _replica_is_libm()


def _assert_within_ulp(got, want, maxulp):
    """Equal where either is NaN or infinite, else at most maxulp units in the last place apart."""
    got, want = np.asarray(got, np.float64), np.asarray(want, np.float64)
    odd = ~np.isfinite(want) | ~np.isfinite(got)
    np.testing.assert_array_equal(got[odd], want[odd])
    np.testing.assert_array_max_ulp(got[~odd], want[~odd], maxulp=maxulp)


@numba.njit
def _libm_hypot(x, y):
    out = np.empty(x.shape[0])
    for i in range(x.shape[0]):
        out[i] = math.hypot(x[i], y[i])
    return out


@numba.njit
def _inlined_hypot(x, y):
    out = np.empty(x.shape[0])
    for i in range(x.shape[0]):
        out[i] = K._hypot(x[i], y[i])
    return out


def test_hypot_equals_libm_to_the_bit():
    rng = np.random.default_rng(11)
    xs, ys = [], []
    for scale in (1e-300, 1e-140, 1e-3, 1.0, 30.0, 1e4, 1e150, 1e300):
        x = rng.normal(size=200_000) * scale
        y = rng.normal(size=200_000) * scale * rng.uniform(0, 1, 200_000) ** 8  # down to ratios past 2^-54
        xs += [x, y, np.round(x, 3)]
        ys += [y, x, np.round(y, 2)]
    special = np.array([0.0, -0.0, 1.0, -1.0, 3.0, 4.0, np.inf, -np.inf, np.nan, 5e-324, 1e-320, 1e-17, 1e17, 1e308])
    sx, sy = np.meshgrid(special, special)
    x = np.concatenate(xs + [sx.ravel()])
    y = np.concatenate(ys + [sy.ravel()])
    got, want = _inlined_hypot(x, y), _libm_hypot(x, y)
    if REPLICA_EXACT:
        np.testing.assert_array_equal(got, want)  # NaN where NaN, else equal bits
    else:
        _assert_within_ulp(got, want, 1)  # another libm may round the last bit differently


@pytest.mark.parametrize("rad", [1, 2, 3, 5])
def test_mixing_zone_bit_rows_equal_a_dilation(rad):
    rng = np.random.default_rng(20 + rad)
    H, W, P = 60, 150, {1: 900, 2: 600, 3: 400, 5: 150}[rad]
    r = rng.integers(0, H, P).astype(np.intp)
    c = rng.integers(0, W, P).astype(np.intp)
    fam = rng.integers(1, 3, P).astype(np.intp)
    valid = rng.random(P) > 0.1
    kernels = [cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * rad + 1, 2 * rad + 1)),
               cv2.getStructuringElement(cv2.MORPH_RECT, (2 * rad + 1, 2 * rad + 1))]
    gap = kernels[1].copy()
    gap[rad, rad + 1] = 0  # a row with a gap: offset by offset
    kernels.append(gap)
    for kernel in kernels:
        dr, dc = np.nonzero(kernel)
        got = K.mixing_zone(r, c, fam, valid, H, W, (dr - rad).astype(np.intp), (dc - rad).astype(np.intp))
        want = np.zeros(P, bool)
        for f in (1, 2):
            other = np.zeros((H, W), np.uint8)
            so = valid & (fam == 3 - f)
            other[r[so], c[so]] = 1
            sf = valid & (fam == f)
            want[sf] = cv2.dilate(other, kernel, borderType=cv2.BORDER_CONSTANT, borderValue=0)[r[sf], c[sf]] > 0
        assert want.sum() > 50 and (~want & valid).sum() > 50
        np.testing.assert_array_equal(got, want)


@numba.njit
def _traces_round2(q, fam, r, c, H, W, link_px, lateral_px, cos_turn, w, ridge, ridge_step, use_ridge):
    """The round-2 `traces` kernel, kept here as the reference of the round-3 one."""
    n = q.shape[0]
    # Neighbour lookups sweep the rows with three row tables per family (prev, this, next row) instead of
    # one table of the whole image: the tables stay in cache and no page of a large table is touched.
    # A cell's owner is the highest sample id in it (as when ids were written in order into one table);
    # the others look at their whole 3×3 neighbourhood.
    rstart = np.zeros(2 * H + 1, np.intp)
    for i in range(n):
        rstart[(fam[i] - 1) * H + r[i] + 1] += 1
    for k in range(2 * H):
        rstart[k + 1] += rstart[k]
    fill = rstart[:-1].copy()
    byrow = np.empty(n, np.intp)
    for i in range(n):
        key = (fam[i] - 1) * H + r[i]
        byrow[fill[key]] = i
        fill[key] += 1
    rows = np.full((3, W), -1, np.int32)  # rows[(row) % 3]
    parent = np.arange(n)
    link2 = link_px * link_px
    for f in range(2):
        for row in range(H):
            if row == 0:
                for rr in range(min(2, H)):
                    key = f * H + rr
                    for s in range(rstart[key], rstart[key + 1]):
                        rows[rr % 3, c[byrow[s]]] = byrow[s]
            elif row + 1 < H:
                key = f * H + row + 1
                for s in range(rstart[key], rstart[key + 1]):
                    rows[(row + 1) % 3, c[byrow[s]]] = byrow[s]
            key = f * H + row
            for s in range(rstart[key], rstart[key + 1]):
                a = byrow[s]
                ca = c[a]
                dup = rows[row % 3, ca] != a
                for dy in range(-1, 2):
                    rr = row + dy
                    if rr < 0 or rr >= H:
                        continue
                    for dxx in range(-1, 2):
                        # the forward half of the 8-neighbourhood (all 9 cells for a cell's non-owner)
                        if not dup and (dy < 0 or (dy == 0 and dxx <= 0)):
                            continue
                        cc = ca + dxx
                        if cc < 0 or cc >= W:
                            continue
                        b = rows[rr % 3, cc]
                        if b < 0:
                            continue
                        d0 = q[b, 0] - q[a, 0]
                        d1 = q[b, 1] - q[a, 1]
                        if d0 * d0 + d1 * d1 <= link2:
                            ra = K._union_find_root(parent, a)
                            rb = K._union_find_root(parent, b)
                            if ra != rb:
                                if ra < rb:
                                    parent[rb] = ra
                                else:
                                    parent[ra] = rb
            if row >= 1:  # row − 1 is no longer needed: clear it
                key = f * H + row - 1
                for s in range(rstart[key], rstart[key + 1]):
                    rows[(row - 1) % 3, c[byrow[s]]] = -1
        for rr in range(max(H - 2, 0), H):
            key = f * H + rr
            for s in range(rstart[key], rstart[key + 1]):
                rows[rr % 3, c[byrow[s]]] = -1
    # Component ids in order of each component's lowest sample id.
    comp = np.empty(n, np.int64)
    label_of_root = np.full(n, -1, np.int64)
    ncomp = 0
    for i in range(n):
        ro = K._union_find_root(parent, i)
        if label_of_root[ro] < 0:
            label_of_root[ro] = ncomp
            ncomp += 1
        comp[i] = label_of_root[ro]
    # Principal axis of each component (sums in sample order, as np.bincount).
    cnt = np.zeros(ncomp)
    sx = np.zeros(ncomp)
    sy = np.zeros(ncomp)
    for i in range(n):
        cnt[comp[i]] += 1.0
        sx[comp[i]] += q[i, 0]
        sy[comp[i]] += q[i, 1]
    mx = sx / cnt
    my = sy / cnt
    sxy = np.zeros(ncomp)
    sd = np.zeros(ncomp)
    for i in range(n):
        dx = q[i, 0] - mx[comp[i]]
        dy = q[i, 1] - my[comp[i]]
        sxy[comp[i]] += dx * dy
        sd[comp[i]] += dx * dx - dy * dy
    cth = np.empty(ncomp)
    sth = np.empty(ncomp)
    for k in range(ncomp):
        th = 0.5 * math.atan2(2 * sxy[k], sd[k])
        cth[k] = math.cos(th)
        sth[k] = math.sin(th)
    t = np.empty(n)
    for i in range(n):
        t[i] = (q[i, 0] - mx[comp[i]]) * cth[comp[i]] + (q[i, 1] - my[comp[i]]) * sth[comp[i]]
    # Order: by component (counting sort), then along the axis.
    start = np.zeros(ncomp + 1, np.int64)
    for i in range(n):
        start[comp[i] + 1] += 1
    for k in range(ncomp):
        start[k + 1] += start[k]
    fill = start[:-1].copy()
    order = np.empty(n, np.intp)
    for i in range(n):
        order[fill[comp[i]]] = i
        fill[comp[i]] += 1
    for k in range(ncomp):
        a, b = start[k], start[k + 1]
        if b - a > 32:
            seg = order[a:b].copy()
            srt = np.argsort(t[seg], kind="mergesort")
            for m in range(b - a):
                order[a + m] = seg[srt[m]]
        else:  # short components: insertion sort in place (stable, no allocation)
            for m in range(a + 1, b):
                v = order[m]
                tv = t[v]
                j = m - 1
                while j >= a and t[order[j]] > tv:
                    order[j + 1] = order[j]
                    j -= 1
                order[j + 1] = v
    qs = np.empty((n, 2))
    ts = np.empty(n)
    for k in range(n):
        qs[k, 0] = q[order[k], 0]
        qs[k, 1] = q[order[k], 1]
        ts[k] = t[order[k]]
    # Per component: the chord tangent at each position (tan = qs[k + w] − qs[k − w], clipped to the
    # component), and the cut between consecutive positions (the former back/fwd/tan tables, computed on
    # the fly in the same operations).
    piece = np.zeros(n, np.int64)
    tangent = np.empty((n, 2))
    eps32 = np.float32(1e-6)
    link2_hi = link_px * link_px * (1.0 + 1e-9)
    link2_lo = link_px * link_px * (1.0 - 1e-9)
    cur = 0
    for cpt in range(ncomp):
        first = start[cpt]
        last = start[cpt + 1] - 1
        for k in range(first, last + 1):
            piece[k] = cur
            kb = max(k - w, first)
            kf = min(k + w, last)
            tan0 = qs[kf, 0] - qs[kb, 0]
            tan1 = qs[kf, 1] - qs[kb, 1]
            lt = max(math.hypot(tan0, tan1), 1e-12)
            tangent[k, 0] = tan0 / lt
            tangent[k, 1] = tan1 / lt
            if k == last:
                continue
            d0 = qs[k + 1, 0] - qs[k, 0]
            d1 = qs[k + 1, 1] - qs[k, 1]
            # dist > link_px, with hypot only where the squared distance cannot decide
            dd = d0 * d0 + d1 * d1
            if dd > link2_hi:
                cut = True
            elif dd < link2_lo:
                cut = False
            else:
                cut = math.hypot(d0, d1) > link_px
            if not cut:
                back0 = qs[k, 0] - qs[kb, 0]
                back1 = qs[k, 1] - qs[kb, 1]
                kf1 = min(k + 1 + w, last)
                fwd0 = qs[kf1, 0] - qs[k + 1, 0]
                fwd1 = qs[kf1, 1] - qs[k + 1, 1]
                lb = math.hypot(back0, back1)
                lf = math.hypot(fwd0, fwd1)
                if lb >= 1.0:
                    B0 = back0 / max(lb, 1e-12)
                    B1 = back1 / max(lb, 1e-12)
                else:
                    B0 = tan0 / lt
                    B1 = tan1 / lt
                if lf >= 1.0:
                    F0 = fwd0 / max(lf, 1e-12)
                    F1 = fwd1 / max(lf, 1e-12)
                else:
                    F0 = tan0 / lt
                    F1 = tan1 / lt
                lateral = max(abs(d0 * B1 - d1 * B0), abs(d0 * F1 - d1 * F0))
                along = abs(d0 * B0 + d1 * B1)
                turn = B0 * F0 + B1 * F1
                cut = lateral > lateral_px or along < lateral or turn < cos_turn
            if not cut and use_ridge:
                r0 = ridge[order[k]]
                r1 = ridge[order[k + 1]]
                top = max(r1, r0)
                if top < eps32:
                    top = eps32
                cut = abs(r1 - r0) > ridge_step * top
            if cut:
                cur += 1
        cur += 1
    return order, piece, ts, tangent




def _raster_lines(rng):
    """Samples of lines in raster order (as the extraction writes them): both families, every direction
    (lines running backwards against the raster order, nearly horizontal ones whose rows come in blocks),
    sideways jumps, and a dense cloud that links into one component far from sorted (the fallback sort)."""
    pts, fams = [], []
    for k in range(24):
        ang = rng.uniform(0, np.pi)
        d = np.array([np.cos(ang), np.sin(ang)])
        n = int(rng.integers(5, 120))
        p0 = rng.uniform(20, 280, 2)
        t = np.arange(n) * rng.uniform(0.7, 1.3) + rng.normal(0, 0.05, n)
        p = p0 + t[:, None] * d + rng.normal(0, 0.08, (n, 2)) * d[::-1]
        if k % 5 == 0:
            p[n // 2 :] += 0.9 * d[::-1]  # a sideways jump
        pts.append(p)
        fams.append(np.full(n, 1 + k % 2))
    cloud = rng.uniform(150, 160, (300, 2))
    pts.append(cloud)
    fams.append(np.ones(300, int))
    q = np.concatenate(pts)
    fam = np.concatenate(fams)
    order = np.lexsort((q[:, 0], np.rint(q[:, 1])))
    return np.ascontiguousarray(q[order]), fam[order].astype(np.intp)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_traces_equal_the_round2_kernel(seed):
    rng = np.random.default_rng(seed)
    q, fam = _raster_lines(rng)
    valid, r, c, H, W, _ = K.sample_cells(q, fam, 1.0, 2)
    sel = np.flatnonzero(valid).astype(np.intp)
    ridge = rng.uniform(50, 60, len(q)).astype(np.float32)
    ridge[::37] = 5.0  # brightness jumps
    args = (1.6, 0.5, float(np.cos(np.deg2rad(10.0))), 3, ridge, np.float32(0.15), True)
    got = K.traces_of(q, fam, r, c, sel, int(H), int(W), *args)
    want = _traces_round2(q[sel], fam[sel], r[sel], c[sel], int(H), int(W), *args[:4], ridge[sel], *args[5:])
    for g, w in zip(got, want):
        if REPLICA_EXACT or g.dtype.kind != "f":
            np.testing.assert_array_equal(g, w)
        else:  # positions and tangents go through hypot: another libm may differ in the last bits
            np.testing.assert_allclose(g, w, rtol=1e-12, atol=1e-12)
    assert got[1][-1] > 30  # many pieces: links and cuts both occur


def _junction_seeds_round2(q, fam, valid, near_other, qj, labelled, lab, jdir, radius, seed_lateral_px, snap):
    """The round-2 junction_seeds: nearest_within_cells over the gathered valid samples."""
    P = len(q)
    seed = np.full(P, -9, np.int64)
    seed_jid = np.full(P, -1, np.int64)
    q_out = q.copy()
    index = np.full(P, np.nan)
    vi = np.flatnonzero(valid)
    arg, _ = K.nearest_within_cells(np.ascontiguousarray(q[vi]), np.ascontiguousarray(qj[labelled]), radius)
    for s in np.flatnonzero(arg >= 0):
        pid, jid = vi[s], labelled[arg[s]]
        f = fam[pid]
        d0, d1 = jdir[jid, f - 1]
        o0, o1 = q[pid] - qj[jid]
        if not abs(o0 * d1 - o1 * d0) <= seed_lateral_px:
            continue
        seed[pid] = lab[jid, f - 1]
        seed_jid[pid] = jid
        if snap and near_other[pid]:
            along = o0 * d0 + o1 * d1
            q_out[pid] = (qj[jid, 0] + along * d0, qj[jid, 1] + along * d1)
            index[pid] = seed[pid]
    return seed, seed_jid, q_out, index


def test_junction_seeds_equal_the_round2_search():
    rng = np.random.default_rng(5)
    P, M = 4000, 150
    q = rng.uniform(0, 400, (P, 2))
    fam = rng.integers(0, 3, P).astype(np.intp)  # 0: not a line sample
    valid = (fam > 0) & (rng.random(P) > 0.05)
    near_other = rng.random(P) > 0.7
    qj = rng.uniform(-5, 405, (M, 2))
    labelled = np.flatnonzero(rng.random(M) > 0.2).astype(np.int64)
    lab = rng.integers(-20, 20, (M, 2)).astype(np.int64)
    ang = rng.uniform(0, np.pi, (M, 2))
    jdir = np.ascontiguousarray(np.stack([np.cos(ang), np.sin(ang)], axis=-1))
    want = _junction_seeds_round2(q, fam, valid, near_other, qj, labelled, lab, jdir, 12.0, 4.0, True)
    seed = np.full(P, -9, np.int64)
    seed_jid = np.full(P, -1, np.int64)
    q_out = q.copy()
    index = np.full(P, np.nan)
    n = K.junction_seeds(q, fam, valid, near_other, qj, labelled, lab, jdir, 12.0, 4.0, True, -9, seed, seed_jid, q_out, index)
    for g, w in zip((seed, seed_jid, q_out, index), want):
        np.testing.assert_array_equal(g, w)
    assert n == int(np.isfinite(want[3]).sum()) > 20 and (want[0] != -9).sum() > 100


def test_gap_candidates_equal_the_numpy_masks():
    rng = np.random.default_rng(8)
    P = 3000
    valid = rng.random(P) > 0.1
    index = np.where(rng.random(P) > 0.5, rng.integers(-5, 5, P).astype(float), np.nan)
    sid = np.sort(rng.choice(P, 2000, replace=False)).astype(np.int64)
    rng.shuffle(sid)
    piece = np.sort(rng.integers(0, 300, len(sid))).astype(np.int64)
    cut_samples = rng.choice(sid, 100, replace=False).astype(np.intp)
    got = K.gap_candidates(valid, index, sid, piece, cut_samples)
    profile_cut = np.zeros(P, bool)
    profile_cut[cut_samples] = True
    cand = np.flatnonzero(valid & ~np.isfinite(index) & ~profile_cut)
    in_trace = np.zeros(P, bool)
    in_trace[sid] = True
    lab_piece = np.zeros(int(piece[-1]) + 1, bool)
    lab_piece[piece[np.isfinite(index[sid])]] = True
    piece_of = np.full(P, -1, np.int64)
    piece_of[sid] = piece
    want = cand[~in_trace[cand] | lab_piece[np.maximum(piece_of[cand], 0)]]
    np.testing.assert_array_equal(got, want)
    assert len(want) > 100 and len(want) < len(cand)  # both kinds kept, some dropped
