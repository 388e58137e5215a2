"""Compiled kernels of the label stage (decision 0062; the port: decision 0064).

Plain loops over flat arrays, called from `reconstruction.labelling`. Each kernel keeps the semantics of
the NumPy code it replaced (same neighbours, same order of float operations where a result is compared
against a threshold), so the labels do not change; docstrings say what each one replaces.
"""

from __future__ import annotations

import math

import numpy as np
from numba import types
from numba.extending import intrinsic

from reconstruction._jit import njit
from reconstruction.geometry import _k_triangulate_rays


@njit
def mixing_zone(r, c, fam, valid, H, W, dr, dc):
    """near_other (P,) bool: a valid sample of family f has a valid sample of family 3 − f in a pixel at one
    of the offsets (dr, dc) (the structuring element of the former cv2.dilate) from its own pixel.
    r, c (P,) pixel row/column (padded grid H×W).

    Each family's pixels are bits of 64-bit words along the rows; the element's offsets in one row are a
    run of columns (an ellipse is convex), so a sample tests one mask per row of the element instead of
    one pixel per offset. An element with a gap in a row is looked at offset by offset."""
    P = r.shape[0]
    out = np.zeros(P, np.bool_)
    K = dr.shape[0]
    if K == 0:
        return out
    # the element's column run in each of its rows
    r_lo = dr.min()
    nr = dr.max() - r_lo + 1
    c_lo = np.full(nr, 1 << 30, np.intp)
    c_hi = np.full(nr, -(1 << 30), np.intp)
    cnt = np.zeros(nr, np.intp)
    for k in range(K):
        j = dr[k] - r_lo
        c_lo[j] = min(c_lo[j], dc[k])
        c_hi[j] = max(c_hi[j], dc[k])
        cnt[j] += 1
    runs = True
    for j in range(nr):
        if cnt[j] > 0 and cnt[j] != c_hi[j] - c_lo[j] + 1:
            runs = False  # duplicates or a gap: offset by offset
    if not runs:
        return mixing_zone_offsets(r, c, fam, valid, H, W, dr, dc)
    # Bit rows padded by the element's reach (rows) and one word (64 columns) on each side, so that no
    # test needs a bounds check; a run is read as one 64-bit window from two neighbouring words.
    width = 0
    for j in range(nr):
        width = max(width, c_hi[j] - c_lo[j] + 1)
    if width > 63 or c_lo.min() < -64 or c_hi.max() > 64:
        return mixing_zone_offsets(r, c, fam, valid, H, W, dr, dc)
    HP = H + nr
    WW = ((W + 128) >> 6) + 2
    bits = np.zeros(2 * HP * WW, np.uint64)
    one = np.uint64(1)
    for i in range(P):
        if valid[i]:
            cc = c[i] + 64
            bits[((fam[i] - 1) * HP + r[i] - r_lo) * WW + (cc >> 6)] |= one << np.uint64(cc & 63)
    mask = np.zeros(nr, np.uint64)
    for j in range(nr):
        if cnt[j] > 0:
            mask[j] = (one << np.uint64(c_hi[j] - c_lo[j] + 1)) - one
    for i in range(P):
        if not valid[i]:
            continue
        base = ((2 - fam[i]) * HP + r[i]) * WW  # the other family's bits, element row 0
        ci = c[i] + 64
        acc = np.uint64(0)
        for j in range(nr):
            a = ci + c_lo[j]
            k = base + j * WW + (a >> 6)
            sh = np.uint64(a & 63)
            win = (bits[k] >> sh) | ((bits[k + 1] << one) << (np.uint64(63) - sh))
            acc |= win & mask[j]
        out[i] = acc != 0
    return out


@njit
def mixing_zone_offsets(r, c, fam, valid, H, W, dr, dc):
    """`mixing_zone` offset by offset on a byte grid (any element)."""
    P = r.shape[0]
    out = np.zeros(P, np.bool_)
    K = dr.shape[0]
    grid = np.zeros(H * W, np.uint8)
    for i in range(P):
        if valid[i]:
            grid[r[i] * W + c[i]] |= np.uint8(fam[i])  # bit 1: family 1, bit 2: family 2
    for i in range(P):
        if not valid[i]:
            continue
        bit = np.uint8(3 - fam[i])
        for k in range(K):
            rr = r[i] + dr[k]
            cc = c[i] + dc[k]
            if rr < 0 or rr >= H or cc < 0 or cc >= W:
                continue
            if grid[rr * W + cc] & bit:
                out[i] = True
                break
    return out


@njit
def nearest_within_cells(q, pts, radius):
    """labelling._nearest_within: for each q, the nearest of pts among one entry per `radius`-wide cell in
    the 3×3 cells around q's own (the last point written into a cell owns it); −1 beyond `radius`.
    Returns arg (N,) intp and distance (N,) float64."""
    n = q.shape[0]
    m = pts.shape[0]
    best = np.full(n, np.inf)
    arg = np.full(n, -1, np.intp)
    if n == 0 or m == 0:
        return arg, best
    lox = min(q[:, 0].min(), pts[:, 0].min())
    loy = min(q[:, 1].min(), pts[:, 1].min())
    cpx = np.empty(m, np.intp)
    cpy = np.empty(m, np.intp)
    for k in range(m):
        cpx[k] = np.intp(math.floor((pts[k, 0] - lox) / radius)) + 1
        cpy[k] = np.intp(math.floor((pts[k, 1] - loy) / radius)) + 1
    cqx = np.empty(n, np.intp)
    cqy = np.empty(n, np.intp)
    for k in range(n):
        cqx[k] = np.intp(math.floor((q[k, 0] - lox) / radius)) + 1
        cqy[k] = np.intp(math.floor((q[k, 1] - loy) / radius)) + 1
    gw = max(cpx.max(), cqx.max()) + 2
    gh = max(cpy.max(), cqy.max()) + 2
    grid = np.full(gh * gw, -1, np.intp)
    for k in range(m):
        grid[cpy[k] * gw + cpx[k]] = k
    for i in range(n):
        base = cqy[i] * gw + cqx[i]
        for sy in range(-1, 2):
            for sx in range(-1, 2):
                j = grid[base + sy * gw + sx]
                if j < 0:
                    continue
                d0 = q[i, 0] - pts[j, 0]
                d1 = q[i, 1] - pts[j, 1]
                d2 = d0 * d0 + d1 * d1
                if d2 < best[i]:
                    best[i] = d2
                    arg[i] = j
    for i in range(n):
        best[i] = math.sqrt(best[i])
        if best[i] > radius:
            arg[i] = -1
    return arg, best


@njit
def _hypot(x, y):
    """math.hypot(x, y) to the bit, inlined: glibc's (2.35+) algorithm for x86-64 without FMA (Borges' corrected
    sqrt(x² + y²), sysdeps/ieee754/dbl-64/e_hypot.c), which is what libm's hypot runs here; infinities, NaN
    and the scaled ranges (huge, tiny) call libm's. math.hypot is a call into libm that LLVM cannot inline
    or schedule around; this is a square root, a division and a few products in line (decision 0070).
    `test_hypot_equals_libm_to_the_bit` checks it against libm; on a libm with another algorithm the test
    fails and the kernels should go back to math.hypot."""
    ax = abs(x)
    ay = abs(y)
    if ax < ay:
        ax, ay = ay, ax
    if not (ax <= 6.703903964971299e153 and ay >= 6.717876107567089e-139):  # 0x1p+511, 0x1p-459; NaN
        return math.hypot(x, y)
    if ay <= ax * 5.551115123125783e-17:  # 0x1p-54
        return ax + ay
    h = math.sqrt(ax * ax + ay * ay)
    if h <= 2.0 * ay:
        delta = h - ay
        t1 = ax * (2.0 * delta - ax)
        t2 = (delta - 2.0 * (ax - ay)) * delta
    else:
        delta = h - ax
        t1 = 2.0 * delta * (ax - 2.0 * ay)
        t2 = (4.0 * delta - ay) * ay + delta * delta
    h -= (t1 + t2) / (2.0 * h)
    return h


@njit
def _union_find_root(parent, a):
    while parent[a] != a:
        parent[a] = parent[parent[a]]
        a = parent[a]
    return a


@njit
def _union_find_join(parent, a, b):
    """Join the sets of a and b: the larger root points to the smaller (the rule every caller uses, so that a
    component's root is its smallest member)."""
    ra = _union_find_root(parent, a)
    rb = _union_find_root(parent, b)
    if ra < rb:
        parent[rb] = ra
    elif rb < ra:
        parent[ra] = rb


@njit
def _component_order(comp, t, n, ncomp):
    """Positions 0..n−1 ordered by component (counting sort), then along it: a stable sort by t, i.e. by
    (t, position). The samples come in raster order, so a component is nearly sorted one way or the other:
    reversed when it runs backwards, then an insertion sort on (t, position) (the same order as a stable
    mergesort, without allocations); a component that needs many moves falls back to the mergesort.
    Returns order (n,) and start (ncomp + 1,), the components' first positions in order (used by `traces`
    and `traces_from_segments`, once per call)."""
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
        if b - a < 2:
            continue
        if t[order[b - 1]] < t[order[a]]:
            for m in range((b - a) // 2):
                v = order[a + m]
                order[a + m] = order[b - 1 - m]
                order[b - 1 - m] = v
        budget = 8 * (b - a) + 64
        moves = 0
        for m in range(a + 1, b):
            v = order[m]
            tv = t[v]
            j = m - 1
            while j >= a and (t[order[j]] > tv or (t[order[j]] == tv and order[j] > v)):
                order[j + 1] = order[j]
                j -= 1
            order[j + 1] = v
            moves += m - 1 - j
            if moves > budget:
                break
        if moves > budget:
            seg = np.sort(order[a:b])  # ids in increasing order, then a stable sort by t
            srt = np.argsort(t[seg], kind="mergesort")
            for m in range(b - a):
                order[a + m] = seg[srt[m]]
    return order, start


@njit
def traces(q, fam, r, c, H, W, link_px, lateral_px, cos_turn, w, ridge, ridge_step, use_ridge):
    """The trace pieces of label_samples (step 3): link same-family samples in neighbouring pixels (within link_px), take connected
    components (numbered by their lowest sample id, as scipy's connected_components), order each along its
    principal axis and cut between consecutive samples where the line jumps sideways, turns, or (use_ridge)
    the ridge brightness (float32) jumps. Returns order (n,), piece (n,), t (n,) and unit tangents (n, 2)
    in order's order."""
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
                            _union_find_join(parent, a, b)
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
        ro = _union_find_root(parent, i)
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
    # Order: by component, then along the axis (a stable sort by (t, sample id), `_component_order`).
    order, start = _component_order(comp, t, n, ncomp)
    qs = np.empty((n, 2))
    ts = np.empty(n)
    for k in range(n):
        qs[k, 0] = q[order[k], 0]
        qs[k, 1] = q[order[k], 1]
        ts[k] = t[order[k]]
    # Per component: the chord tangent at each position (tan = qs[k + w] − qs[k − w], clipped to the
    # component), and the cut between consecutive positions (the former back/fwd/tan tables, computed on
    # the fly in the same operations). The tangent keeps hypot's value to the bit (`_hypot`); the cut's
    # lengths are square roots, and only a link whose lengths or tests lie within 1e-9 of a limit is
    # decided again with hypot (a few ulp cannot change a decision that far from its limit).
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
            lt = max(_hypot(tan0, tan1), 1e-12)
            T0 = tan0 / lt
            T1 = tan1 / lt
            tangent[k, 0] = T0
            tangent[k, 1] = T1
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
                cut = _hypot(d0, d1) > link_px
            if not cut:
                back0 = qs[k, 0] - qs[kb, 0]
                back1 = qs[k, 1] - qs[kb, 1]
                kf1 = min(k + 1 + w, last)
                fwd0 = qs[kf1, 0] - qs[k + 1, 0]
                fwd1 = qs[kf1, 1] - qs[k + 1, 1]
                sb = back0 * back0 + back1 * back1
                sf = fwd0 * fwd0 + fwd1 * fwd1
                exact = abs(sb - 1.0) <= 1e-9 or abs(sf - 1.0) <= 1e-9
                if not exact:
                    if sb >= 1.0:
                        lb = math.sqrt(sb)
                        B0 = back0 / lb
                        B1 = back1 / lb
                    else:
                        B0 = T0
                        B1 = T1
                    if sf >= 1.0:
                        lf = math.sqrt(sf)
                        F0 = fwd0 / lf
                        F1 = fwd1 / lf
                    else:
                        F0 = T0
                        F1 = T1
                    lateral = max(abs(d0 * B1 - d1 * B0), abs(d0 * F1 - d1 * F0))
                    along = abs(d0 * B0 + d1 * B1)
                    turn = B0 * F0 + B1 * F1
                    tol = 1e-9 * (1.0 + abs(d0) + abs(d1))
                    if lateral > lateral_px + tol or along < lateral - tol or turn < cos_turn - 1e-9:
                        cut = True
                    elif lateral < lateral_px - tol and along > lateral + tol and turn > cos_turn + 1e-9:
                        cut = False
                    else:
                        exact = True
                if exact:
                    lb = _hypot(back0, back1)
                    lf = _hypot(fwd0, fwd1)
                    if lb >= 1.0:
                        B0 = back0 / max(lb, 1e-12)
                        B1 = back1 / max(lb, 1e-12)
                    else:
                        B0 = T0
                        B1 = T1
                    if lf >= 1.0:
                        F0 = fwd0 / max(lf, 1e-12)
                        F1 = fwd1 / max(lf, 1e-12)
                    else:
                        F0 = T0
                        F1 = T1
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


@njit
def traces_of(q, fam, r, c, sel, H, W, link_px, lateral_px, cos_turn, w, ridge, ridge_step, use_ridge):
    """`traces` on the samples sel (n,) of q, fam, r, c (and ridge, when used), gathered here; order is
    returned as positions in sel."""
    n = sel.shape[0]
    qs = np.empty((n, 2))
    fs = np.empty(n, np.intp)
    rs = np.empty(n, np.intp)
    cs = np.empty(n, np.intp)
    rg = np.empty(n if use_ridge else 0, np.float32)
    for k in range(n):
        s = sel[k]
        qs[k, 0] = q[s, 0]
        qs[k, 1] = q[s, 1]
        fs[k] = fam[s]
        rs[k] = r[s]
        cs[k] = c[s]
        if use_ridge:
            rg[k] = ridge[s]
    return traces(qs, fs, rs, cs, H, W, link_px, lateral_px, cos_turn, w, rg, ridge_step, use_ridge)


@njit
def nearest_seed(piece, t, has):
    """labelling._nearest_seed: the position of the nearest seed along the same piece (the earlier one on
    a tie), or −1."""
    n = piece.shape[0]
    out = np.full(n, -1, np.intp)
    fwd = np.full(n, -1, np.intp)
    last = -1
    for k in range(n):
        if has[k]:
            last = k
        if last >= 0 and piece[last] == piece[k]:
            fwd[k] = last
    nxt = -1
    for k in range(n - 1, -1, -1):
        if has[k]:
            nxt = k
        ok_b = nxt >= 0 and piece[nxt] == piece[k]
        f = fwd[k]
        if f >= 0:
            df = abs(t[k] - t[f])
            db = abs(t[nxt] - t[k]) if ok_b else np.inf
            out[k] = f if df <= db else nxt
        elif ok_b:
            out[k] = nxt
    return out


@njit
def _buckets(pts, x0, y0, cell, gw, gh):
    """CSR buckets of points (M, 2) in cells `cell` wide from (x0, y0): start (gw·gh + 1,), items (M,)
    (ids in increasing order within a cell)."""
    m = pts.shape[0]
    key = np.empty(m, np.intp)
    start = np.zeros(gw * gh + 1, np.intp)
    for k in range(m):
        cx = min(max(int(math.floor((pts[k, 0] - x0) / cell)), 0), gw - 1)
        cy = min(max(int(math.floor((pts[k, 1] - y0) / cell)), 0), gh - 1)
        key[k] = cy * gw + cx
        start[key[k] + 1] += 1
    for k in range(gw * gh):
        start[k + 1] += start[k]
    fill = start[:-1].copy()
    items = np.empty(m, np.intp)
    for k in range(m):
        items[fill[key[k]]] = k
        fill[key[k]] += 1
    return start, items


@njit
def knn_within(pts, queries, k, radius):
    """Like cKDTree(pts).query(queries, k=k, distance_upper_bound=radius): distances (Q, k) ascending, inf
    where fewer than k points lie closer than radius, and their ids (Q, k) (M where none). Per query the
    points of the 3×3 cells in the disc are gathered first (branch-free), then sorted into the best k:
    the k smallest (distance², id) do not depend on the order (decision 0090)."""
    m = pts.shape[0]
    nq = queries.shape[0]
    dist = np.full((nq, k), np.inf)
    idx = np.full((nq, k), m, np.intp)
    if m == 0 or nq == 0:
        return dist, idx
    x0 = pts[:, 0].min()
    y0 = pts[:, 1].min()
    cell = radius if radius > 0 else 1.0
    gw = int((pts[:, 0].max() - x0) / cell) + 1
    gh = int((pts[:, 1].max() - y0) / cell) + 1
    start, items = _buckets(pts, x0, y0, cell, gw, gh)
    r2 = radius * radius
    bd = np.empty(k)
    cd = np.empty(m + 1)
    ci = np.empty(m + 1, np.intp)
    bi = np.empty(k, np.intp)
    for qi in range(nq):
        qx = queries[qi, 0]
        qy = queries[qi, 1]
        if not (math.isfinite(qx) and math.isfinite(qy)):
            continue
        cx = int(math.floor((qx - x0) / cell))
        cy = int(math.floor((qy - y0) / cell))
        # the points in the disc, gathered branch-free (a store per point, the count advanced by the test)
        nc = 0
        # a row's 3 cells are consecutive buckets: their items one run, read in the same order (decision 0157)
        xa = max(cx - 1, 0)
        xb = min(cx + 2, gw)
        for yy in range(max(cy - 1, 0), min(cy + 2, gh)):
            if xa >= xb:
                break
            for s in range(start[yy * gw + xa], start[yy * gw + xb]):
                j = items[s]
                d0 = pts[j, 0] - qx
                d1 = pts[j, 1] - qy
                d2 = d0 * d0 + d1 * d1
                cd[nc] = d2
                ci[nc] = j
                nc += not (d2 >= r2)  # (the former `if d2 >= r2: continue`, NaN included)
        nfound = 0
        for h in range(nc):
            d2 = cd[h]
            j = ci[h]
            # insert into the sorted best-k list (ties: lower id first)
            if nfound == k and (d2 > bd[k - 1] or (d2 == bd[k - 1] and j > bi[k - 1])):
                continue
            pos = nfound if nfound < k else k - 1
            while pos > 0 and (bd[pos - 1] > d2 or (bd[pos - 1] == d2 and bi[pos - 1] > j)):
                if pos < k:
                    bd[pos] = bd[pos - 1]
                    bi[pos] = bi[pos - 1]
                pos -= 1
            bd[pos] = d2
            bi[pos] = j
            if nfound < k:
                nfound += 1
        for s in range(nfound):
            dist[qi, s] = math.sqrt(bd[s])
            idx[qi, s] = bi[s]
    return dist, idx


@njit
def fill_gaps(q, fam, sid, piece, tangent, index, seed_jid, q_out, candidates, reach_px, anchor, seed_lateral_px):
    """labelling._fill_gaps (same tests, same order of operations): writes index, seed_jid and q_out of the
    candidates filled in place and returns their number."""
    n = sid.shape[0]
    # Labelled pieces' first and last labelled positions (in trace order).
    if candidates.shape[0] == 0:
        return 0
    lab_pos = np.empty(n, np.intp)
    nlab = 0
    for k in range(n):
        if math.isfinite(index[sid[k]]):
            lab_pos[nlab] = k
            nlab += 1
    return fill_gaps_at(q, fam, sid, piece, tangent, index, seed_jid, q_out, candidates, reach_px, anchor, seed_lateral_px,
                        lab_pos[:nlab])


@njit
def fill_gaps_at(q, fam, sid, piece, tangent, index, seed_jid, q_out, candidates, reach_px, anchor, seed_lateral_px, lab_pos):
    """`fill_gaps` given its labelled trace positions lab_pos (increasing; = np.flatnonzero(np.isfinite(index[sid])),
    which the caller may know already: decision 0115)."""
    if candidates.shape[0] == 0:
        return 0
    nlab = lab_pos.shape[0]
    if nlab == 0:
        return 0
    npl = 0
    for k in range(nlab):
        if k == 0 or piece[lab_pos[k]] != piece[lab_pos[k - 1]]:
            npl += 1
    f_first = np.empty(npl, np.intp)
    f_last = np.empty(npl, np.intp)
    m = 0
    for k in range(nlab):
        if k == 0 or piece[lab_pos[k]] != piece[lab_pos[k - 1]]:
            f_first[m] = k
            if m > 0:
                f_last[m - 1] = k - 1
            m += 1
    f_last[npl - 1] = nlab - 1
    ne = 2 * npl
    anchors = np.empty(ne, np.intp)
    ends = np.empty(ne, np.intp)
    out_dir = np.empty((ne, 2))
    for k in range(npl):
        a0 = lab_pos[min(f_first[k] + anchor, f_last[k])]
        a1 = lab_pos[max(f_last[k] - anchor, f_first[k])]
        anchors[k] = a0
        anchors[npl + k] = a1
        out_dir[k, 0] = -tangent[a0, 0]
        out_dir[k, 1] = -tangent[a0, 1]
        out_dir[npl + k, 0] = tangent[a1, 0]
        out_dir[npl + k, 1] = tangent[a1, 1]
        ends[k] = lab_pos[f_first[k]]
        ends[npl + k] = lab_pos[f_last[k]]
    total = 0
    nb = 6
    # each end's sample, family and piece, and each candidate's family, read once (decision 0127: the loops below
    # read these arrays instead of chasing sid[ends[·]] again; q, piece and fam are not written here)
    end_s = np.empty(ne, np.intp)
    end_f = np.empty(ne, np.intp)
    end_p = np.empty(ne, piece.dtype)
    for k in range(ne):
        end_s[k] = sid[ends[k]]
        end_f[k] = fam[end_s[k]]
        end_p[k] = piece[ends[k]]
    nC = candidates.shape[0]
    cand_f = np.empty(nC, np.intp)
    for k in range(nC):
        cand_f[k] = fam[candidates[k]]
    for f in (1, 2):
        ea = np.empty(ne, np.intp)
        na = 0
        for k in range(ne):
            if end_f[k] == f:
                ea[na] = k
                na += 1
        cs = np.empty(nC, np.intp)
        nc = 0
        for k in range(nC):
            if cand_f[k] == f:
                cs[nc] = candidates[k]
                nc += 1
        if na < 2 or nc == 0:
            continue
        pts = np.empty((na, 2))
        for k in range(na):
            pts[k, 0] = q[end_s[ea[k]], 0]
            pts[k, 1] = q[end_s[ea[k]], 1]
        qq = np.empty((nc, 2))
        for k in range(nc):
            qq[k, 0] = q[cs[k], 0]
            qq[k, 1] = q[cs[k], 1]
        dist, kk = knn_within(pts, qq, nb, 2 * reach_px)
        for ci in range(nc):
            cid = cs[ci]
            cx = qq[ci, 0]
            cy = qq[ci, 1]
            # the nearest end beyond which the sample lies
            e1 = -1
            for s in range(nb):
                if not math.isfinite(dist[ci, s]):
                    break
                e = ea[kk[ci, s]]
                v0 = cx - pts[kk[ci, s], 0]
                v1 = cy - pts[kk[ci, s], 1]
                along = v0 * out_dir[e, 0] + v1 * out_dir[e, 1]
                lateral = abs(v0 * out_dir[e, 1] - v1 * out_dir[e, 0])
                if along > 0 and lateral <= 2 * seed_lateral_px:
                    e1 = e
                    break
            if e1 < 0:
                continue
            # the nearest facing end of another piece with the same index
            e2 = -1
            idx1 = index[end_s[e1]]
            for s in range(nb):
                if not math.isfinite(dist[ci, s]):
                    break
                e = ea[kk[ci, s]]
                v0 = cx - pts[kk[ci, s], 0]
                v1 = cy - pts[kk[ci, s], 1]
                along = v0 * out_dir[e, 0] + v1 * out_dir[e, 1]
                lateral = abs(v0 * out_dir[e, 1] - v1 * out_dir[e, 0])
                if not (along > 0 and lateral <= 2 * seed_lateral_px):
                    continue
                if end_p[e] == end_p[e1] or index[end_s[e]] != idx1:
                    continue
                if out_dir[e, 0] * out_dir[e1, 0] + out_dir[e, 1] * out_dir[e1, 1] < -0.9:
                    e2 = e
                    break
            if e2 < 0:
                continue
            p10 = q[sid[anchors[e1]], 0]
            p11 = q[sid[anchors[e1]], 1]
            ch0 = q[sid[anchors[e2]], 0] - p10
            ch1 = q[sid[anchors[e2]], 1] - p11
            L = max(math.hypot(ch0, ch1), 1e-9)
            u0 = ch0 / L
            u1 = ch1 / L
            w0 = cx - p10
            w1 = cy - p11
            t = w0 * u0 + w1 * u1
            lat = abs(w0 * u1 - w1 * u0)
            if lat <= seed_lateral_px and t > 0 and t < L:
                q_out[cid, 0] = p10 + t * u0
                q_out[cid, 1] = p11 + t * u1
                index[cid] = idx1
                seed_jid[cid] = seed_jid[end_s[e1]]
                total += 1
    return total


@njit
def junction_seeds(q, fam, valid, near_other, qj, labelled, lab, jdir, radius, seed_lateral_px, snap, unlabelled,
                   seed, seed_jid, q_out, index):
    """Step 2 of labelling.label_samples: a valid sample whose nearest labelled junction (`nearest_within_cells`,
    within radius) has its fitted line of the sample's family (jdir (M, 2, 2) unit directions) within
    seed_lateral_px becomes a seed with the junction's index; with `snap`, seeds in the mixing zone are
    moved onto that line and labelled at once. Writes seed, seed_jid, q_out, index in place; returns the
    number of samples snapped.

    The search is `nearest_within_cells`'s (same origin, cells, owners and order), done in place over the
    valid samples, from each cell's list of candidates (the owners of its 3×3 cells in the order they were
    looked at) instead of nine lookups."""
    P = q.shape[0]
    m = labelled.shape[0]
    if m == 0:
        return 0
    # origin: the smallest coordinates of the valid samples and the junctions (as nearest_within_cells)
    lox = np.inf
    loy = np.inf
    nv = 0
    for i in range(P):
        if valid[i]:
            lox = min(lox, q[i, 0])
            loy = min(loy, q[i, 1])
            nv += 1
    if nv == 0:
        return 0
    for k in range(m):
        lox = min(lox, qj[labelled[k], 0])
        loy = min(loy, qj[labelled[k], 1])
    cpx = np.empty(m, np.intp)
    cpy = np.empty(m, np.intp)
    gw = 0
    gh = 0
    for k in range(m):
        cpx[k] = np.intp(math.floor((qj[labelled[k], 0] - lox) / radius)) + 1
        cpy[k] = np.intp(math.floor((qj[labelled[k], 1] - loy) / radius)) + 1
        gw = max(gw, cpx[k])
        gh = max(gh, cpy[k])
    cqx = np.empty(P, np.int32)  # (int32: decision 0150)
    cqy = np.empty(P, np.int32)
    for i in range(P):
        if valid[i]:
            cqx[i] = np.intp(math.floor((q[i, 0] - lox) / radius)) + 1
            cqy[i] = np.intp(math.floor((q[i, 1] - loy) / radius)) + 1
            gw = max(gw, cqx[i])
            gh = max(gh, cqy[i])
    gw += 2
    gh += 2
    grid = np.full(gh * gw, -1, np.intp)
    for k in range(m):
        grid[cpy[k] * gw + cpx[k]] = k
    # each cell's candidates: the owners of its 3×3 cells, in the order the cells are looked at (the
    # owned cells listed once, in increasing order: the passes below visit only them)
    ncell = gh * gw
    occ = np.empty(m, np.intp)
    n_occ = 0
    for cell in range(ncell):
        if grid[cell] >= 0:
            occ[n_occ] = cell
            n_occ += 1
    cstart = np.zeros(ncell + 1, np.intp)
    for o in range(n_occ):
        cell = occ[o]
        for sy in range(-1, 2):
            for sx in range(-1, 2):
                cstart[cell - sy * gw - sx + 1] += 1
    for cell in range(ncell):
        cstart[cell + 1] += cstart[cell]
    cfill = cstart[:-1].copy()
    cand = np.empty(cstart[ncell], np.intp)
    for sy in range(-1, 2):
        for sx in range(-1, 2):
            for o in range(n_occ):
                cell = occ[o]
                cq = cell - sy * gw - sx
                cand[cfill[cq]] = grid[cell]
                cfill[cq] += 1
    snapped = 0
    for pid in range(P):
        if not valid[pid]:
            continue
        base = cqy[pid] * gw + cqx[pid]
        best = np.inf
        arg = -1
        for t in range(cstart[base], cstart[base + 1]):
            j = cand[t]
            d0 = q[pid, 0] - qj[labelled[j], 0]
            d1 = q[pid, 1] - qj[labelled[j], 1]
            d2 = d0 * d0 + d1 * d1
            if d2 < best:
                best = d2
                arg = j
        if arg < 0 or math.sqrt(best) > radius:
            continue
        jid = labelled[arg]
        f = fam[pid]
        d0 = jdir[jid, f - 1, 0]
        d1 = jdir[jid, f - 1, 1]
        o0 = q[pid, 0] - qj[jid, 0]
        o1 = q[pid, 1] - qj[jid, 1]
        if not abs(o0 * d1 - o1 * d0) <= seed_lateral_px:
            continue
        seed[pid] = lab[jid, f - 1]
        seed_jid[pid] = jid
        if snap and near_other[pid]:
            along = o0 * d0 + o1 * d1
            q_out[pid, 0] = qj[jid, 0] + along * d0
            q_out[pid, 1] = qj[jid, 1] + along * d1
            index[pid] = seed[pid]
            snapped += 1
    return snapped


@njit
def spread_seeds(sid, piece, ts, seed, seed_jid, index, unlabelled):
    """Step 4 of labelling.label_samples: every trace sample takes the index (and junction) of the nearest
    seed along its piece (`nearest_seed`); samples without one get junction −1. Writes index and seed_jid
    in place. Returns got (n,) bool and the numbers of pieces with a seed and with disagreeing seeds."""
    n = sid.shape[0]
    has = np.empty(n, np.bool_)
    for k in range(n):
        has[k] = seed[sid[k]] != unlabelled
    near = nearest_seed(piece, ts, has)
    seeded = 0
    conflicting = 0
    prev_piece = -1
    prev_val = unlabelled
    last_seeded = -1
    last_conflict = -1
    for k in range(n):
        if not has[k]:
            continue
        pc = piece[k]
        v = seed[sid[k]]
        if pc != last_seeded:
            seeded += 1
            last_seeded = pc
        if pc == prev_piece and v != prev_val and pc != last_conflict:
            conflicting += 1
            last_conflict = pc
        prev_piece = pc
        prev_val = v
    got = near >= 0
    # one pass (decision 0090): a position's nearest seed is a seed position, whose own nearest seed is
    # itself, so its seed_jid is rewritten with its own value and reading it after that write is the same
    for k in range(n):
        if got[k]:
            s = sid[near[k]]
            v = seed[s]
            j = seed_jid[s]
            index[sid[k]] = v
            seed_jid[sid[k]] = j
        else:
            seed_jid[sid[k]] = -1
    return got, seeded, conflicting


# --- the junction graph (label_epipolar) -------------------------------------------------------------------


@njit
def _adjacency(n, a, b):
    """CSR lists of the directed edges a → b per node: out[ptr_o[p]:ptr_o[p+1]] the edge ids leaving p, sorted
    by target and then by edge id; inn likewise for the edges entering p, sorted by source, then edge id
    (two stable counting sorts)."""
    E = a.shape[0]
    ptr_o = np.zeros(n + 1, np.intp)
    ptr_i = np.zeros(n + 1, np.intp)
    cnt_b = np.zeros(n + 1, np.intp)
    cnt_a = np.zeros(n + 1, np.intp)
    for e in range(E):
        ptr_o[a[e] + 1] += 1
        ptr_i[b[e] + 1] += 1
        cnt_b[b[e] + 1] += 1
        cnt_a[a[e] + 1] += 1
    for k in range(n):
        ptr_o[k + 1] += ptr_o[k]
        ptr_i[k + 1] += ptr_i[k]
        cnt_b[k + 1] += cnt_b[k]
        cnt_a[k + 1] += cnt_a[k]
    by_b = np.empty(E, np.intp)  # edge ids sorted by target (stable)
    by_a = np.empty(E, np.intp)  # edge ids sorted by source (stable)
    for e in range(E):
        by_b[cnt_b[b[e]]] = e
        cnt_b[b[e]] += 1
        by_a[cnt_a[a[e]]] = e
        cnt_a[a[e]] += 1
    out = np.empty(E, np.intp)
    inn = np.empty(E, np.intp)
    fo = ptr_o[:-1].copy()
    fi = ptr_i[:-1].copy()
    for s in range(E):
        e = by_b[s]
        out[fo[a[e]]] = e
        fo[a[e]] += 1
        e = by_a[s]
        inn[fi[b[e]]] = e
        fi[b[e]] += 1
    return ptr_o, out, ptr_i, inn


@njit
def propagate(n, a, b, d0, d1, keep):
    """labelling._propagate on the edges a → b with (i, j) changes (d0, d1) where keep: labels relative to the
    lowest-numbered junction of each connected component, summed along the breadth-first spanning tree that
    scipy's breadth_first_order builds (each node's neighbours: targets of its edges in increasing order,
    then sources of the edges entering it; the first unvisited one joins the tree), and the component ids
    (numbered by their lowest junction, as scipy's connected_components). A tree edge p → c takes the
    delta of the first edge a → b = p → c, else minus that of the first edge c → p.
    Returns rel (n, 2) int64 and comp (n,) int64."""
    E = a.shape[0]
    m = 0
    for e in range(E):
        if keep[e]:
            m += 1
    ka = np.empty(m, np.intp)
    kb = np.empty(m, np.intp)
    kd0 = np.empty(m, np.int64)
    kd1 = np.empty(m, np.int64)
    m = 0
    for e in range(E):
        if keep[e]:
            ka[m] = a[e]
            kb[m] = b[e]
            kd0[m] = d0[e]
            kd1[m] = d1[e]
            m += 1
    ptr_o, out, ptr_i, inn = _adjacency(n, ka, kb)
    rel = np.zeros((n, 2), np.int64)
    comp = np.full(n, -1, np.int64)
    queue = np.empty(n, np.intp)
    ncomp = 0
    for root in range(n):
        if comp[root] >= 0:
            continue
        comp[root] = ncomp
        queue[0] = root
        head = 0
        tail = 1
        while head < tail:
            p = queue[head]
            head += 1
            for s in range(ptr_o[p], ptr_o[p + 1]):
                e = out[s]
                c = kb[e]
                if comp[c] < 0:
                    comp[c] = ncomp
                    rel[c, 0] = rel[p, 0] + kd0[e]
                    rel[c, 1] = rel[p, 1] + kd1[e]
                    queue[tail] = c
                    tail += 1
            for s in range(ptr_i[p], ptr_i[p + 1]):
                e = inn[s]
                c = ka[e]
                if comp[c] < 0:
                    comp[c] = ncomp
                    rel[c, 0] = rel[p, 0] - kd0[e]
                    rel[c, 1] = rel[p, 1] - kd1[e]
                    queue[tail] = c
                    tail += 1
        ncomp += 1
    return rel, comp


@njit
def clean_edges(n, a, b, d0, d1, rounds):
    """labelling.clean_edges: up to `rounds` times, propagate labels over the kept edges; where an edge
    contradicts them, drop every kept edge touching an endpoint of a contradicting edge. Returns keep (E,)
    bool and the number of edges dropped."""
    E = a.shape[0]
    keep = np.ones(E, np.bool_)
    removed = 0
    mark = np.zeros(n, np.bool_)
    for _ in range(rounds):
        nk = 0
        for e in range(E):
            if keep[e]:
                nk += 1
        if nk == 0:
            break
        rel, _ = propagate(n, a, b, d0, d1, keep)
        nbad = 0
        for e in range(E):
            if keep[e] and (rel[b[e], 0] - rel[a[e], 0] != d0[e] or rel[b[e], 1] - rel[a[e], 1] != d1[e]):
                mark[a[e]] = True
                mark[b[e]] = True
                nbad += 1
        if nbad == 0:
            break
        for e in range(E):
            if keep[e] and (mark[a[e]] or mark[b[e]]):
                keep[e] = False
                removed += 1
        for e in range(E):
            mark[a[e]] = False
            mark[b[e]] = False
    return keep, removed


@njit
def clean_edges_walk(n, a, b, d0, d1, rounds):
    """`clean_edges` and `propagate(n, a, b, d0, d1, keep)` on its result in one call (decision 0158): keep, removed,
    rel, comp. When the last round found no contradicting edge (or no edge was kept), the walk that round made on
    the final keep is returned as it is, instead of walking the same edges again: `propagate` is a function of
    (n, a, b, d0, d1, keep) alone, so it is the same rel and comp bit for bit. Otherwise (edges dropped in the last
    round) the walk is made on the final keep."""
    E = a.shape[0]
    keep = np.ones(E, np.bool_)
    removed = 0
    mark = np.zeros(n, np.bool_)
    have = False  # rel, comp are the walk on the current keep
    rel = np.zeros((0, 2), np.int64)
    comp = np.zeros(0, np.int64)
    for _ in range(rounds):
        nk = 0
        for e in range(E):
            if keep[e]:
                nk += 1
        if nk == 0:
            break
        rel, comp = propagate(n, a, b, d0, d1, keep)
        have = True
        nbad = 0
        for e in range(E):
            if keep[e] and (rel[b[e], 0] - rel[a[e], 0] != d0[e] or rel[b[e], 1] - rel[a[e], 1] != d1[e]):
                mark[a[e]] = True
                mark[b[e]] = True
                nbad += 1
        if nbad == 0:
            break
        for e in range(E):
            if keep[e] and (mark[a[e]] or mark[b[e]]):
                keep[e] = False
                removed += 1
                have = False
        for e in range(E):
            mark[a[e]] = False
            mark[b[e]] = False
    if not have:
        rel, comp = propagate(n, a, b, d0, d1, keep)
    return keep, removed, rel, comp


# --- image reads: cv2.remap(uint8, INTER_LINEAR, BORDER_REPLICATE) at single points -------------------------


@intrinsic
def _fma_f32(typingctx, a, b, c):
    """a·b + c in float32 with one rounding (llvm.fma), as OpenCV's v_fma."""
    sig = types.float32(types.float32, types.float32, types.float32)

    def codegen(context, builder, signature, args):
        return builder.fma(args[0], args[1], args[2])

    return sig, codegen


@intrinsic
def _rint_f32(typingctx, a):
    """float32 rounded to the nearest integer, ties to even (llvm.rint: one instruction, like cvRound)."""
    sig = types.float32(types.float32)

    def codegen(context, builder, signature, args):
        fn = builder.module.declare_intrinsic("llvm.rint", [args[0].type])
        return builder.call(fn, [args[0]])

    return sig, codegen


_READ_BLOCK = 64  # points read at once by `_bilinear_u8_block` (decision 0156)


@njit
def _bilinear_u8_block(fl, W, H, xs, ys, m, idx, a, out):
    """out[:m] = the value cv2.remap(img, x, y, INTER_LINEAR, borderMode=BORDER_REPLICATE) gives at the float32
    map coordinates (xs, ys)[:m] (finite) of the uint8 image img (H, W), flattened to fl (see `ridge_brightness_u8`
    for the arithmetic). In three loops over the points (decision 0156): the fractions and the four clipped pixel
    indices, the four reads, the interpolation; the first and last are branch-free and compile to SIMD code, and
    every point's value is computed by the same float32 operations as one point at a time. idx (4, ≥ m) int64 and
    a (6, ≥ m) float32 are scratch. (A pixel inside the image is its own clip, so clipping all four is the
    same as clipping at the border only.)"""
    Wm = W - 1
    Hm = H - 1
    for j in range(m):
        x = xs[j]
        y = ys[j]
        fx = np.floor(x)
        fy = np.floor(y)
        a[0, j] = np.float32(x - fx)
        a[1, j] = np.float32(y - fy)
        sx = np.int64(fx)
        sy = np.int64(fy)
        x0 = min(max(sx, 0), Wm)
        x1 = min(max(sx + 1, 0), Wm)
        y0 = min(max(sy, 0), Hm)
        y1 = min(max(sy + 1, 0), Hm)
        idx[0, j] = y0 * W + x0
        idx[1, j] = y0 * W + x1
        idx[2, j] = y1 * W + x0
        idx[3, j] = y1 * W + x1
    for j in range(m):
        a[2, j] = np.float32(fl[idx[0, j]])
        a[3, j] = np.float32(fl[idx[1, j]])
        a[4, j] = np.float32(fl[idx[2, j]])
        a[5, j] = np.float32(fl[idx[3, j]])
    for j in range(m):
        ax = a[0, j]
        ay = a[1, j]
        p00 = a[2, j]
        p01 = a[3, j]
        p10 = a[4, j]
        p11 = a[5, j]
        f0 = _fma_f32(ax, np.float32(p01 - p00), p00)
        f1 = _fma_f32(ax, np.float32(p11 - p10), p10)
        v = _fma_f32(ay, np.float32(f1 - f0), f0)
        out[j] = min(max(_rint_f32(v), np.float32(0.0)), np.float32(255.0))


@njit
def ridge_brightness_u8(img, q):
    """labelling._ridge_brightness for a uint8 image: the image at q (N, 2) (NaN read as 0), as float32.

    The value cv2.remap(img, x, y, INTER_LINEAR, borderMode=BORDER_REPLICATE) gives at float32 map
    coordinates (x, y) (OpenCV 5's SIMD path, warp_common.vector.hpp): α = x − ⌊x⌋, β = y − ⌊y⌋ in float32,
    f0 = fma(α, p01 − p00, p00), f1 = fma(α, p11 − p10, p10), v = fma(β, f1 − f0, f0), rounded half to even
    and saturated; each of the four pixels clipped into the image. (On a CPU without FMA OpenCV's v_fma is
    a multiply and an add, and a value at exactly .5 could round the other way.) Read in blocks
    (`_bilinear_u8_block`, decision 0156)."""
    n = q.shape[0]
    H = img.shape[0]
    W = img.shape[1]
    fl = img.ravel()
    out = np.empty(n, np.float32)
    B = _READ_BLOCK
    xs = np.empty(B, np.float32)
    ys = np.empty(B, np.float32)
    idx = np.empty((4, B), np.int64)
    a = np.empty((6, B), np.float32)
    for base in range(0, n, B):
        m = min(B, n - base)
        for j in range(m):
            qx = q[base + j, 0]
            qy = q[base + j, 1]
            xs[j] = np.float32(qx) if math.isfinite(qx) else np.float32(0.0)
            ys[j] = np.float32(qy) if math.isfinite(qy) else np.float32(0.0)
        _bilinear_u8_block(fl, W, H, xs, ys, m, idx, a, out[base:base + m])
    return out


@njit
def profile_drop_u8(img, q, sid, tangent, pos, width_px, ridge, have_ridge):
    """labelling._profile_drop_box3 for a uint8 image at the trace positions pos: sample q[sid[k]], unit
    tangent tangent[k]; probes at d·n, d ∈ {0, ±w/4, ±w/2, ±w} (float32, as the NumPy code), read as
    cv2.remap does (see `ridge_brightness_u8`). With have_ridge the probe at the sample is ridge[sid[k]]
    (`ridge_brightness_u8` of the same image reads the same coordinates); the outer probes are read only
    where the sample is not the brightest inner point (the drop is 0 there whatever the outer points:
    99 % of the positions on the bench's pitch-16 frame). Returns (len(pos),) float32.

    The inner probes of 64 positions at a time are read in one block (`_bilinear_u8_block`, decision 0156),
    the outer ones position by position; each probe's value is the one read alone."""
    n = pos.shape[0]
    H = img.shape[0]
    W = img.shape[1]
    fl = img.ravel()
    out = np.empty(n, np.float32)
    w = np.float32(width_px)
    d = np.empty(7, np.float32)
    d[0] = np.float32(0.0) * w
    d[1] = np.float32(-0.25) * w
    d[2] = np.float32(0.25) * w
    d[3] = np.float32(-0.5) * w
    d[4] = np.float32(0.5) * w
    d[5] = np.float32(-1.0) * w
    d[6] = np.float32(1.0) * w
    B = _READ_BLOCK
    p0 = 1 if have_ridge else 0  # the first probe read from the image
    NP = 5 - p0
    xs = np.empty(NP * B, np.float32)
    ys = np.empty(NP * B, np.float32)
    vals = np.empty(5 * B, np.float32)  # the inner probes p of position j at vals[p·m + j]
    idx = np.empty((4, NP * B), np.int64)
    a = np.empty((6, NP * B), np.float32)
    ox = np.empty(2, np.float32)
    oy = np.empty(2, np.float32)
    ov = np.empty(2, np.float32)
    one = np.float32(1.0)
    for base in range(0, n, B):
        m = min(B, n - base)
        for j in range(m):
            k = pos[base + j]
            s = sid[k]
            qx = np.float32(q[s, 0])
            qy = np.float32(q[s, 1])
            nx = np.float32(-tangent[k, 1])
            ny = np.float32(tangent[k, 0])
            for p in range(p0, 5):
                xs[(p - p0) * m + j] = np.float32(qx + np.float32(d[p] * nx))
                ys[(p - p0) * m + j] = np.float32(qy + np.float32(d[p] * ny))
            if have_ridge:
                vals[j] = ridge[s]
        _bilinear_u8_block(fl, W, H, xs, ys, NP * m, idx, a, vals[p0 * m:])
        for j in range(m):
            v0 = vals[j]
            inner = max(max(max(v0, vals[m + j]), max(vals[2 * m + j], vals[3 * m + j])), vals[4 * m + j])
            if inner == v0:
                out[base + j] = np.float32(0.0)  # the sample is the brightest inner point
                continue
            k = pos[base + j]
            s = sid[k]
            qx = np.float32(q[s, 0])
            qy = np.float32(q[s, 1])
            nx = np.float32(-tangent[k, 1])
            ny = np.float32(tangent[k, 0])
            for p in range(2):
                ox[p] = np.float32(qx + np.float32(d[5 + p] * nx))
                oy[p] = np.float32(qy + np.float32(d[5 + p] * ny))
            _bilinear_u8_block(fl, W, H, ox, oy, 2, idx, a, ov)
            outer = min(ov[0], ov[1])
            out[base + j] = (inner - v0) / max(inner - outer, one)
    return out


@njit
def sample_grid(q, valid, sid, cell):
    """A bucket grid of the valid samples in square cells `cell` px wide, built once per frame and shared
    by the crossing searches (`crossing_hits_traces`, `_continuation_kernels.crossing_in_gap`): origin
    (x0, y0), gw, gh, CSR start (gw·gh + 1,), items (sample ids, increasing within a cell), and pos_of (P,)
    each sample's trace position (sid[k] = s ⇒ pos_of[s] = k; −1 off the traces)."""
    P = q.shape[0]
    pos_of = np.full(P, -1, np.intp)
    for k in range(sid.shape[0]):
        pos_of[sid[k]] = k
    x0 = np.inf
    y0 = np.inf
    x1 = -np.inf
    y1 = -np.inf
    nv = 0
    for s in range(P):
        if valid[s]:
            x0 = min(x0, q[s, 0])
            y0 = min(y0, q[s, 1])
            x1 = max(x1, q[s, 0])
            y1 = max(y1, q[s, 1])
            nv += 1
    if nv == 0:
        x0 = 0.0
        y0 = 0.0
        x1 = 0.0
        y1 = 0.0
    gw = int((x1 - x0) / cell) + 1
    gh = int((y1 - y0) / cell) + 1
    key = np.empty(P, np.intp)
    start = np.zeros(gw * gh + 1, np.intp)
    for s in range(P):
        if valid[s]:
            cx = min(max(int(math.floor((q[s, 0] - x0) / cell)), 0), gw - 1)
            cy = min(max(int(math.floor((q[s, 1] - y0) / cell)), 0), gh - 1)
            key[s] = cy * gw + cx
            start[key[s] + 1] += 1
    for k in range(gw * gh):
        start[k + 1] += start[k]
    fill = start[:-1].copy()
    items = np.empty(nv, np.intp)
    for s in range(P):
        if valid[s]:
            items[fill[key[s]]] = s
            fill[key[s]] += 1
    return x0, y0, gw, gh, start, items, pos_of


@njit
def sample_grid_split(q, valid, fam, sid, cell):
    """`sample_grid` with each cell's items split by family (decision 0090): family 1 first, then the
    others, each part in increasing sample id (so a search that keeps one family reads the same sequence
    as in `sample_grid`'s cell). Returns the same (x0, y0, gw, gh, start, items, pos_of) with start
    extended to (2·gw·gh + 1,): start[:gw·gh + 1] as in sample_grid, and start[gw·gh + 1 + c] the first
    item of cell c that is not of family 1. Kernels that know it (`crossing_nearest`, by the length of
    start) read only the family they look for; the others read whole cells as before. The grid (no label in
    it) is `sample_grid_cells`, pos_of `positions_of` (decision 0115)."""
    pos_of = positions_of(q.shape[0], sid)
    x0, y0, gw, gh, start, items = sample_grid_cells(q, valid, fam, cell)
    return x0, y0, gw, gh, start, items, pos_of


@njit
def positions_of(P, sid):
    """(P,) int32: each sample's trace position (sid[k] = s ⇒ pos_of[s] = k; −1 off the traces). int32: the steps read
    it scattered, by sample (decision 0150)."""
    pos_of = np.full(P, -1, np.int32)
    for k in range(sid.shape[0]):
        pos_of[sid[k]] = k
    return pos_of


@njit
def sample_grid_cells(q, valid, fam, cell):
    """`sample_grid_split` without pos_of: (x0, y0, gw, gh, start, items) of the valid samples, each cell's
    items split by family. Needs no label: the extraction stage builds it (`labelling.prepare_samples`,
    decision 0115)."""
    P = q.shape[0]
    x0 = np.inf
    y0 = np.inf
    x1 = -np.inf
    y1 = -np.inf
    nv = 0
    for s in range(P):
        if valid[s]:
            x0 = min(x0, q[s, 0])
            y0 = min(y0, q[s, 1])
            x1 = max(x1, q[s, 0])
            y1 = max(y1, q[s, 1])
            nv += 1
    if nv == 0:
        x0 = 0.0
        y0 = 0.0
        x1 = 0.0
        y1 = 0.0
    gw = int((x1 - x0) / cell) + 1
    gh = int((y1 - y0) / cell) + 1
    nc = gw * gh
    key = np.empty(P, np.intp)
    start = np.zeros(2 * nc + 1, np.intp)
    n1 = np.zeros(nc, np.intp)
    for s in range(P):
        if valid[s]:
            cx = min(max(int(math.floor((q[s, 0] - x0) / cell)), 0), gw - 1)
            cy = min(max(int(math.floor((q[s, 1] - y0) / cell)), 0), gh - 1)
            key[s] = cy * gw + cx
            start[key[s] + 1] += 1
            if fam[s] == 1:
                n1[key[s]] += 1
    for k in range(nc):
        start[k + 1] += start[k]
    fill1 = np.empty(nc, np.intp)
    fill2 = np.empty(nc, np.intp)
    for k in range(nc):
        fill1[k] = start[k]
        fill2[k] = start[k] + n1[k]
        start[nc + 1 + k] = fill2[k]
    items = np.empty(nv, np.intp)
    for s in range(P):
        if valid[s]:
            b = key[s]
            if fam[s] == 1:
                items[fill1[b]] = s
                fill1[b] += 1
            else:
                items[fill2[b]] = s
                fill2[b] += 1
    return x0, y0, gw, gh, start, items


@njit
def sample_grid_cells_two(q, valid, fam, cell, cell_f):
    """`sample_grid_cells(q, valid, fam, cell)` and `crossing_fill._family_grid(q, fam, cell_f)` of the same samples in
    one kernel (decision 0156): valid must be the samples of family 1 or 2 with a finite position (`sample_cells`'
    valid), the set `_family_grid` keeps, so both grids have the same origin (the valid samples' smallest x and
    y). One pass for the extent, one for both grids' cells and counts, one for both item lists; each grid's
    cells, clamping and items are computed by the same operations as in its own kernel. Returns
    ((x0, y0, gw, gh, start, items), (x0, y0, gw_f, gh_f, start_f, mid_f, items_f))."""
    P = q.shape[0]
    x0 = np.inf
    y0 = np.inf
    x1 = -np.inf
    y1 = -np.inf
    nv = 0
    for s in range(P):
        if valid[s]:
            x0 = min(x0, q[s, 0])
            y0 = min(y0, q[s, 1])
            x1 = max(x1, q[s, 0])
            y1 = max(y1, q[s, 1])
            nv += 1
    if nv == 0:
        x0 = 0.0
        y0 = 0.0
        x1 = 0.0
        y1 = 0.0
    gw = int((x1 - x0) / cell) + 1
    gh = int((y1 - y0) / cell) + 1
    gwf = int((x1 - x0) / cell_f) + 1
    ghf = int((y1 - y0) / cell_f) + 1
    nc = gw * gh
    ncf = gwf * ghf
    key = np.empty(P, np.intp)
    keyf = np.empty(P, np.intp)
    start = np.zeros(2 * nc + 1, np.intp)
    startf = np.zeros(ncf + 1, np.intp)
    n1 = np.zeros(nc, np.intp)
    n1f = np.zeros(ncf, np.intp)
    for s in range(P):
        if valid[s]:
            b = min(max(int(math.floor((q[s, 1] - y0) / cell)), 0), gh - 1) * gw + min(max(int(math.floor((q[s, 0] - x0) / cell)), 0), gw - 1)
            bf = (min(max(int(math.floor((q[s, 1] - y0) / cell_f)), 0), ghf - 1) * gwf
                  + min(max(int(math.floor((q[s, 0] - x0) / cell_f)), 0), gwf - 1))
            key[s] = b
            keyf[s] = bf
            start[b + 1] += 1
            startf[bf + 1] += 1
            if fam[s] == 1:
                n1[b] += 1
                n1f[bf] += 1
    for k in range(nc):
        start[k + 1] += start[k]
    for k in range(ncf):
        startf[k + 1] += startf[k]
    fill1 = np.empty(nc, np.intp)
    fill2 = np.empty(nc, np.intp)
    for k in range(nc):
        fill1[k] = start[k]
        fill2[k] = start[k] + n1[k]
        start[nc + 1 + k] = fill2[k]
    fill1f = np.empty(ncf, np.intp)
    midf = np.empty(ncf, np.intp)
    for k in range(ncf):
        fill1f[k] = startf[k]
        midf[k] = startf[k] + n1f[k]
    fill2f = midf.copy()
    items = np.empty(nv, np.intp)
    itemsf = np.empty(nv, np.intp)
    for s in range(P):
        if valid[s]:
            b = key[s]
            bf = keyf[s]
            if fam[s] == 1:
                items[fill1[b]] = s
                fill1[b] += 1
                itemsf[fill1f[bf]] = s
                fill1f[bf] += 1
            else:
                items[fill2[b]] = s
                fill2[b] += 1
                itemsf[fill2f[bf]] = s
                fill2f[bf] += 1
    return (x0, y0, gw, gh, start, items), (x0, y0, gwf, ghf, startf, midf, itemsf)


@njit
def crossing_hits_traces(e, te, sign, fe, q, sid, tangent, fam, index, labelled_only, radius, sin_min,
                         x0, y0, cell, gw, gh, start, items, pos_of):
    """The crossing at each piece end (the former kernel `crossing_hits`, now the reference in
    tests/reconstruction/test_label_kernels_round2.py) with the candidates read from the traces in place: trace position k (sample sid[k],
    unit tangent tangent[k]) is a candidate when its sample is labelled (finite index; every position when
    not labelled_only). For each end the nearest candidate of the other family closer than radius (the
    lowest position on a tie, as the k-d tree query over the gathered candidates), then the same crossing
    test. Candidates come from the bucket grid of `sample_grid` (cell ≥ radius). Returns o (E,) the trace
    position (−1: none) and c (E, 2)."""
    _, bk = crossing_nearest(e, fe, q, fam, index, labelled_only, radius, x0, y0, cell, gw, gh, start, items, pos_of)
    return crossing_test(e, te, sign, bk, q, sid, tangent, radius, sin_min)


@njit
def crossing_nearest(e, fe, q, fam, index, labelled_only, radius, x0, y0, cell, gw, gh, start, items, pos_of):
    """The first half of `crossing_hits_traces` (decision 0078): for each end e (E, 2) of family fe the nearest
    candidate of the other family closer than radius, as (d2, k): squared distance (inf: none) and trace
    position (−1), the lowest position on a tie. `crossing_test` of it gives crossing_hits_traces' answer.
    With a grid from `sample_grid_split` only the wanted family's part of each cell is read (the answer
    does not depend on the order of the candidates: decision 0090)."""
    E = e.shape[0]
    bd_out = np.full(E, np.inf)
    bk_out = np.full(E, -1, np.intp)
    r2 = radius * radius
    nc = gw * gh
    split = start.shape[0] == 2 * nc + 1
    for i in range(E):
        ex = e[i, 0]
        ey = e[i, 1]
        if not (math.isfinite(ex) and math.isfinite(ey)):
            continue
        want = 3 - fe[i]
        cx = int(math.floor((ex - x0) / cell))
        cy = int(math.floor((ey - y0) / cell))
        bd = np.inf
        bk = -1
        for yy in range(max(cy - 1, 0), min(cy + 2, gh)):
            for xx in range(max(cx - 1, 0), min(cx + 2, gw)):
                b = yy * gw + xx
                t0 = start[b]
                t1 = start[b + 1]
                if split:  # the family's part of the cell only (`sample_grid_split`)
                    if want == 1:
                        t1 = start[nc + 1 + b]
                    elif want == 2:
                        t0 = start[nc + 1 + b]
                for t in range(t0, t1):
                    s = items[t]
                    k = pos_of[s]
                    if k < 0 or fam[s] != want:
                        continue
                    if labelled_only and not math.isfinite(index[s]):
                        continue
                    d0 = q[s, 0] - ex
                    d1 = q[s, 1] - ey
                    d2 = d0 * d0 + d1 * d1
                    if d2 < r2 and (d2 < bd or (d2 == bd and k < bk)):
                        bd = d2
                        bk = k
        bd_out[i] = bd
        bk_out[i] = bk
    return bd_out, bk_out


@njit
def crossing_nearest_update(e, fe, q, fam, pos_of, new_s, radius, bd, bk):
    """Bring `crossing_nearest`'s (bd, bk) of ends e (E, 2) up to date after the samples new_s became
    candidates (labelled), in place: a new sample of the other family closer than radius replaces the
    nearest if it is nearer (or as near with a lower trace position). Candidates are only ever added
    between crossing rounds, so the result equals a new search over all candidates. Returns changed (E,)."""
    E = e.shape[0]
    changed = np.zeros(E, np.bool_)
    nn = new_s.shape[0]
    if nn == 0 or E == 0:
        return changed
    cell = radius if radius > 0 else 1.0
    gx0 = np.inf
    gy0 = np.inf
    gx1 = -np.inf
    gy1 = -np.inf
    for a in range(nn):
        s = new_s[a]
        gx0 = min(gx0, q[s, 0])
        gy0 = min(gy0, q[s, 1])
        gx1 = max(gx1, q[s, 0])
        gy1 = max(gy1, q[s, 1])
    gw = int((gx1 - gx0) / cell) + 1
    gh = int((gy1 - gy0) / cell) + 1
    start = np.zeros(gw * gh + 1, np.intp)
    key = np.empty(nn, np.intp)
    for a in range(nn):
        s = new_s[a]
        cx = min(max(int(math.floor((q[s, 0] - gx0) / cell)), 0), gw - 1)
        cy = min(max(int(math.floor((q[s, 1] - gy0) / cell)), 0), gh - 1)
        key[a] = cy * gw + cx
        start[key[a] + 1] += 1
    for b in range(gw * gh):
        start[b + 1] += start[b]
    fill = start[:-1].copy()
    items = np.empty(nn, np.intp)
    for a in range(nn):
        items[fill[key[a]]] = new_s[a]
        fill[key[a]] += 1
    r2 = radius * radius
    for i in range(E):
        ex = e[i, 0]
        ey = e[i, 1]
        if not (math.isfinite(ex) and math.isfinite(ey)):
            continue
        want = 3 - fe[i]
        fx = math.floor((ex - gx0) / cell)
        fy = math.floor((ey - gy0) / cell)
        if fx < -1.0 or fy < -1.0 or fx > gw or fy > gh:
            continue  # no new sample within a cell of it
        cx = int(fx)
        cy = int(fy)
        for yy in range(max(cy - 1, 0), min(cy + 2, gh)):
            for xx in range(max(cx - 1, 0), min(cx + 2, gw)):
                b = yy * gw + xx
                for t in range(start[b], start[b + 1]):
                    s = items[t]
                    k = pos_of[s]
                    if k < 0 or fam[s] != want:
                        continue
                    d0 = q[s, 0] - ex
                    d1 = q[s, 1] - ey
                    d2 = d0 * d0 + d1 * d1
                    if d2 < r2 and (d2 < bd[i] or (d2 == bd[i] and k < bk[i])):
                        bd[i] = d2
                        bk[i] = k
                        changed[i] = True
    return changed


@njit
def crossing_test(e, te, sign, bk, q, sid, tangent, radius, sin_min):
    """The second half of `crossing_hits_traces` (decision 0078): the crossing of each end e (E, 2) (tangent
    te, sign −1 first / +1 last end) with the trace position bk (−1: none): the two tangent lines'
    intersection c when they differ by more than sin_min and it lies within radius of both along their
    lines and not behind the end. Returns o (E,) (−1: none) and c (E, 2)."""
    E = e.shape[0]
    o = np.full(E, -1, np.intp)
    c = np.full((E, 2), np.nan)
    for i in range(E):
        k = bk[i]
        if k < 0:
            continue
        ex = e[i, 0]
        ey = e[i, 1]
        s = sid[k]
        den = te[i, 0] * tangent[k, 1] - te[i, 1] * tangent[k, 0]
        if not abs(den) > sin_min:
            continue
        w0 = q[s, 0] - ex
        w1 = q[s, 1] - ey
        a = (w0 * tangent[k, 1] - w1 * tangent[k, 0]) / den
        bb = (w0 * te[i, 1] - w1 * te[i, 0]) / den
        if abs(a) <= radius and abs(bb) <= radius and sign[i] * a >= -1.0:
            o[i] = k
            c[i, 0] = ex + a * te[i, 0]
            c[i, 1] = ey + a * te[i, 1]
    return o, c


@njit
def cross_round_ends_after(todo_prev, new_s, pos_of, piece, first, last, q, sid, tangent, fam):
    """`cross_round_ends` for a later round (decision 0078), from the pieces to do at the round before
    (todo_prev, increasing) and the samples labelled since (new_s): a piece stays to do unless one of them
    lies on it (pieces never lose labels; their length and ends do not change). Returns todo, e, te, sign, fe
    as cross_round_ends (first and last are that call's)."""
    npc = first.shape[0]
    gone = np.zeros(npc, np.bool_)
    for a in range(new_s.shape[0]):
        k = pos_of[new_s[a]]
        if k >= 0:
            gone[piece[k]] = True
    nt = 0
    for a in range(todo_prev.shape[0]):
        if not gone[todo_prev[a]]:
            nt += 1
    todo = np.empty(nt, np.intp)
    c = 0
    for a in range(todo_prev.shape[0]):
        if not gone[todo_prev[a]]:
            todo[c] = todo_prev[a]
            c += 1
    e = np.empty((2 * nt, 2))
    te = np.empty((2 * nt, 2))
    sign = np.empty(2 * nt)
    fe = np.empty(2 * nt, np.int64)
    for a in range(nt):
        for side in range(2):
            k = first[todo[a]] if side == 0 else last[todo[a]]
            r = side * nt + a
            e[r, 0] = q[sid[k], 0]
            e[r, 1] = q[sid[k], 1]
            te[r, 0] = tangent[k, 0]
            te[r, 1] = tangent[k, 1]
            sign[r] = -1.0 if side == 0 else 1.0
            fe[r] = fam[sid[k]]
    return todo, e, te, sign, fe


# --- label_epipolar: offsets of one component ----------------------------------------------------------------


@njit
def _pairwise_block(a, lo, n):
    """NumPy's pairwise summation of a[lo:lo + n] for n ≤ 128: a plain loop below 8, else 8 accumulators
    combined as ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7)), then the remainder."""
    if n < 8:
        res = 0.0
        for i in range(lo, lo + n):
            res += a[i]
        return res
    r0 = a[lo]
    r1 = a[lo + 1]
    r2 = a[lo + 2]
    r3 = a[lo + 3]
    r4 = a[lo + 4]
    r5 = a[lo + 5]
    r6 = a[lo + 6]
    r7 = a[lo + 7]
    i = 8
    while i < n - (n % 8):
        r0 += a[lo + i]
        r1 += a[lo + i + 1]
        r2 += a[lo + i + 2]
        r3 += a[lo + i + 3]
        r4 += a[lo + i + 4]
        r5 += a[lo + i + 5]
        r6 += a[lo + i + 6]
        r7 += a[lo + i + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        res += a[lo + i]
        i += 1
    return res


@njit
def _pairwise_sum(a, lo, n):
    """NumPy's pairwise summation of a[lo:lo + n] (so that a mean equals np.mean's to the bit): blocks of at
    most 128 (`_pairwise_block`), above that the sum of the two halves split at a multiple of 8. The
    recursion runs on an explicit stack (numba's cache does not reload recursive functions safely)."""
    if n <= 128:
        return _pairwise_block(a, lo, n)
    s_lo = np.empty(64, np.int64)
    s_n = np.empty(64, np.int64)
    s_stage = np.empty(64, np.int64)
    s_left = np.empty(64)
    top = 0
    s_lo[0] = lo
    s_n[0] = n
    s_stage[0] = 0
    val = 0.0
    have = False  # a finished child value is waiting to be delivered to the node at `top`
    while True:
        if have:
            if s_stage[top] == 1:  # left half done: keep it, do the right half
                s_left[top] = val
                s_stage[top] = 2
                n2 = s_n[top] // 2
                n2 -= n2 % 8
                lo_r = s_lo[top] + n2
                n_r = s_n[top] - n2
                have = False
                if n_r <= 128:
                    val = _pairwise_block(a, lo_r, n_r)
                    have = True
                else:
                    top += 1
                    s_lo[top] = lo_r
                    s_n[top] = n_r
                    s_stage[top] = 0
                continue
            val = s_left[top] + val  # both halves done
            if top == 0:
                return val
            top -= 1
            continue
        # a fresh node with n > 128: do its left half
        s_stage[top] = 1
        n2 = s_n[top] // 2
        n2 -= n2 % 8
        if n2 <= 128:
            val = _pairwise_block(a, s_lo[top], n2)
            have = True
        else:
            top += 1
            s_lo[top] = s_lo[top - 1]
            s_n[top] = n2
            s_stage[top] = 0


@njit
def _admissible_scores(ks, adm, n_adm, S, I0, J0, rel, okpos, ln, xy_junction, index_min, index_max, fx, cap2):
    """The admissible candidates' offsets off (n_adm, 2) (keys ks (C,), adm (C,) bool; key = (I − I0)·S + (J − J0)),
    their scores (the mean over the junctions okpos with finite lines of min(residual², cap2), pairwise summation;
    labels outside the pattern count cap2) and ranked (stable argsort). Shared by `offset_scores` and
    `offset_scores_b`."""
    n_ok = okpos.shape[0]
    off = np.empty((n_adm, 2), np.int64)
    c = 0
    for k in range(ks.shape[0]):
        if adm[k]:
            off[c, 0] = ks[k] // S + I0
            off[c, 1] = ks[k] % S + J0
            c += 1
    score = np.empty(n_adm)
    row = np.empty(n_ok)
    for k in range(n_adm):
        for t in range(n_ok):
            a = okpos[t]
            i = rel[a, 0] + off[k, 0]
            j = rel[a, 1] + off[k, 1]
            if i >= index_min and i <= index_max and j >= index_min and j <= index_max:
                x = xy_junction[i - index_min, j - index_min, 0]
                y = xy_junction[i - index_min, j - index_min, 1]
                res = abs(ln[a, 0] * x + ln[a, 1] * y + ln[a, 2]) * fx
                row[t] = min(res * res, cap2)
            else:
                row[t] = cap2
        score[k] = _pairwise_sum(row, 0, n_ok) / n_ok
    ranked = np.argsort(score, kind="mergesort")
    return off, score, ranked


@njit
def _reference_junctions(ln, n_refs):
    """The junctions with finite epipolar lines ln (m, 3) (ids, ascending) and the reference junctions among
    them (ids, sorted): n_refs spread over them as np.linspace would. Shared by `offset_scores` and
    `offset_scores_b`."""
    m = ln.shape[0]
    okpos = np.empty(m, np.intp)
    n_ok = 0
    for a in range(m):
        if math.isfinite(ln[a, 0]) and math.isfinite(ln[a, 1]) and math.isfinite(ln[a, 2]):
            okpos[n_ok] = a
            n_ok += 1
    okpos = okpos[:n_ok]
    if n_ok == 0:
        return okpos, np.zeros(0, np.intp)
    num = min(n_refs, n_ok)
    pick = np.empty(num, np.intp)
    if num == 1:
        pick[0] = 0
    else:
        step = (n_ok - 1) / (num - 1)
        for i in range(num - 1):
            pick[i] = int(i * step + 0.0)
        pick[num - 1] = n_ok - 1
    return okpos, np.unique(okpos[pick])


@njit
def offset_scores(rel, ln, xy_junction, index_min, index_max, fx, n_refs, band_px, min_inside, cap2):
    """The candidate offsets of one component and their scores (labelling._choose_offset, first half).

    rel (m, 2) relative labels, ln (m, 3) epipolar lines (normalised projector coordinates), xy_junction
    (L, L, 2) the pattern's junctions. Candidates: pattern junctions within band_px (projector px) of the
    epipolar lines of n_refs reference junctions spread over the component (np.linspace over the
    junctions with finite lines, as before), sorted by (i, j); admissible when at least min_inside of the
    component's labels fall inside the pattern. Score: the mean over junctions with finite lines of
    min(residual², cap2) (np.mean's pairwise summation; labels outside the pattern count cap2).
    Returns status (0 ok, 1 no finite line, 2 no candidate, 3 none admissible), off (C, 2), score (C,),
    ranked (C,) (stable argsort of score) and the number of junctions with finite lines."""
    m = rel.shape[0]
    L = index_max - index_min + 1
    off = np.zeros((0, 2), np.int64)
    score = np.zeros(0)
    ranked = np.zeros(0, np.intp)
    okpos, refs = _reference_junctions(ln, n_refs)
    n_ok = okpos.shape[0]
    if n_ok == 0:
        return 1, off, score, ranked, n_ok
    # candidate keys (I, J) -> (I − I0)·S + (J − J0), I0/J0 and S covering every possible offset
    rmax0 = rel[:, 0].max()
    rmin1 = rel[:, 1].min()
    rmax1 = rel[:, 1].max()
    I0 = index_min - rmax0
    J0 = index_min - rmax1
    S = (index_max - rmin1) - J0 + 1
    keys = np.empty(refs.shape[0] * L * L, np.int64)
    nk = 0
    for r in refs:
        l0 = ln[r, 0]
        l1 = ln[r, 1]
        l2 = ln[r, 2]
        for a in range(L):
            for b in range(L):
                d = abs(xy_junction[a, b, 0] * l0 + xy_junction[a, b, 1] * l1 + l2) * fx
                if d <= band_px:
                    I = a + index_min - rel[r, 0]
                    J = b + index_min - rel[r, 1]
                    keys[nk] = (I - I0) * S + (J - J0)
                    nk += 1
    if nk == 0:
        return 2, off, score, ranked, n_ok
    ks = np.unique(keys[:nk])
    C_all = ks.shape[0]
    adm = np.zeros(C_all, np.bool_)
    n_adm = 0
    for k in range(C_all):
        oi = ks[k] // S + I0
        oj = ks[k] % S + J0
        cnt = 0
        for a in range(m):
            i = rel[a, 0] + oi
            j = rel[a, 1] + oj
            if i >= index_min and i <= index_max and j >= index_min and j <= index_max:
                cnt += 1
        if cnt / m >= min_inside:
            adm[k] = True
            n_adm += 1
    if n_adm == 0:
        return 3, off, score, ranked, n_ok
    off, score, ranked = _admissible_scores(ks, adm, n_adm, S, I0, J0, rel, okpos, ln, xy_junction, index_min, index_max, fx, cap2)
    return 0, off, score, ranked, n_ok


_BLOCK = 8  # pattern junctions per side of `junction_blocks`' blocks


@njit
def junction_blocks(xy_junction, B):
    """The bounding boxes (nA, nB, 4) [x_min, x_max, y_min, y_max] of the pattern's junctions xy_junction (L, L, 2) in
    blocks of B × B (a, b) (the last ones smaller); NaN junctions are left out (a block of them only: x_min > x_max)."""
    L0 = xy_junction.shape[0]
    L1 = xy_junction.shape[1]
    nA = (L0 + B - 1) // B
    nB = (L1 + B - 1) // B
    box = np.empty((nA, nB, 4))
    for ba in range(nA):
        for bb in range(nB):
            x0 = np.inf
            x1 = -np.inf
            y0 = np.inf
            y1 = -np.inf
            for a in range(ba * B, min(ba * B + B, L0)):
                for b in range(bb * B, min(bb * B + B, L1)):
                    x = xy_junction[a, b, 0]
                    y = xy_junction[a, b, 1]
                    if x < x0:
                        x0 = x
                    if x > x1:
                        x1 = x
                    if y < y0:
                        y0 = y
                    if y > y1:
                        y1 = y
            box[ba, bb, 0] = x0
            box[ba, bb, 1] = x1
            box[ba, bb, 2] = y0
            box[ba, bb, 3] = y1
    return box


@njit
def offset_scores_b(rel, ln, xy_junction, blocks, B, index_min, index_max, fx, n_refs, band_px, min_inside, cap2):
    """`offset_scores` given `junction_blocks(xy_junction, B)` (decision 0124): the same outputs, bit for bit
    (`offset_scores` stays the reference and the path of `offset_choice`).
    The candidates are read block by block, skipping a block whose bounding box lies entirely farther than
    band_px from the reference's line (the line's value is affine: its extremes over the box are at the corners;
    the margin, 1e-9 of the terms' magnitudes, is far above the rounding of either side); the candidates' keys
    are then sorted as before (np.unique), so the order they are found in does not matter. The admissibility
    counts are the same integers, from a 2-D prefix sum over the relative labels where that is cheaper than
    the direct count."""
    m = rel.shape[0]
    L = index_max - index_min + 1
    off = np.zeros((0, 2), np.int64)
    score = np.zeros(0)
    ranked = np.zeros(0, np.intp)
    okpos, refs = _reference_junctions(ln, n_refs)
    n_ok = okpos.shape[0]
    if n_ok == 0:
        return 1, off, score, ranked, n_ok
    # candidate keys (I, J) -> (I − I0)·S + (J − J0), I0/J0 and S covering every possible offset
    rmin0 = rel[:, 0].min()
    rmax0 = rel[:, 0].max()
    rmin1 = rel[:, 1].min()
    rmax1 = rel[:, 1].max()
    I0 = index_min - rmax0
    J0 = index_min - rmax1
    S = (index_max - rmin1) - J0 + 1
    keys = np.empty(refs.shape[0] * L * L, np.int64)
    nk = 0
    nA = blocks.shape[0]
    nB = blocks.shape[1]
    for r in refs:
        l0 = ln[r, 0]
        l1 = ln[r, 1]
        l2 = ln[r, 2]
        for ba in range(nA):
            for bb in range(nB):
                x0 = blocks[ba, bb, 0]
                x1 = blocks[ba, bb, 1]
                y0 = blocks[ba, bb, 2]
                y1 = blocks[ba, bb, 3]
                if not (x0 <= x1 and y0 <= y1):
                    continue  # no finite junction in the block
                vx0 = x0 * l0
                vx1 = x1 * l0
                vy0 = y0 * l1
                vy1 = y1 * l1
                lo = min(vx0, vx1) + min(vy0, vy1) + l2
                hi = max(vx0, vx1) + max(vy0, vy1) + l2
                marg = 1e-9 * (max(abs(vx0), abs(vx1)) + max(abs(vy0), abs(vy1)) + abs(l2) + band_px / fx)
                if lo - marg > band_px / fx or hi + marg < -band_px / fx:
                    continue
                for a in range(ba * B, min(ba * B + B, L)):
                    for b in range(bb * B, min(bb * B + B, L)):
                        d = abs(xy_junction[a, b, 0] * l0 + xy_junction[a, b, 1] * l1 + l2) * fx
                        if d <= band_px:
                            I = a + index_min - rel[r, 0]
                            J = b + index_min - rel[r, 1]
                            keys[nk] = (I - I0) * S + (J - J0)
                            nk += 1
    if nk == 0:
        return 2, off, score, ranked, n_ok
    ks = np.unique(keys[:nk])
    C_all = ks.shape[0]
    adm = np.zeros(C_all, np.bool_)
    n_adm = 0
    w0 = rmax0 - rmin0 + 1
    w1 = rmax1 - rmin1 + 1
    if C_all * m > 4 * (w0 + 1) * (w1 + 1):
        # cnt = #{a: index_min ≤ rel[a] + (oi, oj) ≤ index_max}: a rectangle of the relative labels' histogram
        cum = np.zeros((w0 + 1, w1 + 1), np.int64)
        for a in range(m):
            cum[rel[a, 0] - rmin0 + 1, rel[a, 1] - rmin1 + 1] += 1
        for u in range(1, w0 + 1):
            for v in range(1, w1 + 1):
                cum[u, v] += cum[u - 1, v] + cum[u, v - 1] - cum[u - 1, v - 1]
        for k in range(C_all):
            oi = ks[k] // S + I0
            oj = ks[k] % S + J0
            u0 = max(index_min - oi - rmin0, 0)
            u1 = min(index_max - oi - rmin0, w0 - 1)
            v0 = max(index_min - oj - rmin1, 0)
            v1 = min(index_max - oj - rmin1, w1 - 1)
            cnt = 0
            if u0 <= u1 and v0 <= v1:
                cnt = cum[u1 + 1, v1 + 1] - cum[u0, v1 + 1] - cum[u1 + 1, v0] + cum[u0, v0]
            if cnt / m >= min_inside:
                adm[k] = True
                n_adm += 1
    else:
        for k in range(C_all):
            oi = ks[k] // S + I0
            oj = ks[k] % S + J0
            cnt = 0
            for a in range(m):
                i = rel[a, 0] + oi
                j = rel[a, 1] + oj
                if i >= index_min and i <= index_max and j >= index_min and j <= index_max:
                    cnt += 1
            if cnt / m >= min_inside:
                adm[k] = True
                n_adm += 1
    if n_adm == 0:
        return 3, off, score, ranked, n_ok
    off, score, ranked = _admissible_scores(ks, adm, n_adm, S, I0, J0, rel, okpos, ln, xy_junction, index_min, index_max, fx, cap2)
    return 0, off, score, ranked, n_ok


@njit
def median_finite(r):
    """np.median of the finite values of r (NaN when none)."""
    n = 0
    for v in r:
        if math.isfinite(v):
            n += 1
    if n == 0:
        return np.nan
    a = np.empty(n)
    c = 0
    for v in r:
        if math.isfinite(v):
            a[c] = v
            c += 1
    # the middle order statistics by selection instead of a sort (decision 0090): the same values
    h = n // 2
    p = np.partition(a, h)
    if n % 2 == 1:
        return p[h]
    lo = p[0]  # the largest of the h smallest
    for i in range(1, h):
        if p[i] > lo:
            lo = p[i]
    return ((0.0 + lo) + p[h]) / 2.0


@intrinsic
def _rint_f64(typingctx, a):
    """float64 rounded to the nearest integer, ties to even (llvm.rint, as np.rint)."""
    sig = types.float64(types.float64)

    def codegen(context, builder, signature, args):
        fn = builder.module.declare_intrinsic("llvm.rint", [args[0].type])
        return builder.call(fn, [args[0]])

    return sig, codegen


@njit
def sample_cells(q, fam, cell, pad):
    """The start of labelling.label_samples: valid (P,) (family 1 or 2, finite position) and the cells
    r, c (P,) of the valid samples on the grid of the sampling step (rint(q / cell), shifted so that the
    smallest is `pad`; 0 for the others), and the padded grid size H, W."""
    P = q.shape[0]
    valid = np.empty(P, np.bool_)
    r = np.zeros(P, np.intp)
    c = np.zeros(P, np.intp)
    cmin = 0
    rmin = 0
    cmax = 0
    rmax = 0
    nv = 0
    for i in range(P):
        valid[i] = (fam[i] == 1 or fam[i] == 2) and math.isfinite(q[i, 0]) and math.isfinite(q[i, 1])
        if valid[i]:
            c[i] = np.intp(_rint_f64(q[i, 0] / cell))
            r[i] = np.intp(_rint_f64(q[i, 1] / cell))
            if nv == 0 or c[i] < cmin:
                cmin = c[i]
            if nv == 0 or r[i] < rmin:
                rmin = r[i]
            nv += 1
    sc = pad - min(0, cmin)
    sr = pad - min(0, rmin)
    for i in range(P):
        if valid[i]:
            c[i] += sc
            r[i] += sr
            cmax = max(cmax, c[i])
            rmax = max(rmax, r[i])
    return valid, r, c, rmax + pad + 1, cmax + pad + 1, nv


@njit
def project_nearest_line(p, family, K, dist, distorted, cu, cv, n12, offs, hyp, indices):
    """Intrinsics.project of projector-frame points p (N, 3) (5-coefficient distortion when `distorted`;
    no pixel where z ≤ 0), then continuation.nearest_line: the nearest line of `family` (N,) (1 or 2) to the
    pixel, its index indices[k] (0 where none) and its perpendicular distance min(|s − c[k−1]|, |s − c[k]|)
    / hyp[f − 1] in projector px (inf where none), s = (v − cv) − n·(u − cu); n12 (2,) the families'
    slopes, offs (2, L) their line offsets (increasing), hyp (2,) np.hypot(1, n). The same float
    operations in the same order as `Intrinsics.distort`, `normalised_to_pixels` and `nearest_line`."""
    N = p.shape[0]
    L = offs.shape[1]
    idx = np.zeros(N, np.int64)
    dmin = np.full(N, np.inf)
    k1 = dist[0]
    k2 = dist[1]
    p1 = dist[2]
    p2 = dist[3]
    k3 = dist[4]
    fx = K[0, 0]
    k01 = K[0, 1]
    cx = K[0, 2]
    fy = K[1, 1]
    cy = K[1, 2]
    for a in range(N):
        f = family[a]
        if f != 1 and f != 2:
            continue
        z = p[a, 2]
        if z <= 0:
            continue  # NaN pixel: no line (tested before dividing: z = 0 exactly is a point in the projector's plane)
        x = p[a, 0] / z
        y = p[a, 1] / z
        if distorted:
            r2 = x * x + y * y
            radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
            xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
            yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        else:
            xd = x
            yd = y
        u = fx * xd + k01 * yd + cx
        v = fy * yd + cy
        s = (v - cv) - n12[f - 1] * (u - cu)
        if not math.isfinite(s):
            continue
        # np.searchsorted(offs, s) (left), clipped to [1, L − 1]
        lo = 0
        hi = L
        while lo < hi:
            mid = (lo + hi) >> 1
            if offs[f - 1, mid] < s:
                lo = mid + 1
            else:
                hi = mid
        k = min(max(lo, 1), L - 1)
        da = abs(s - offs[f - 1, k - 1])
        db = abs(s - offs[f - 1, k])
        if da <= db:
            idx[a] = indices[k - 1]
            dmin[a] = da / hyp[f - 1]
        else:
            idx[a] = indices[k]
            dmin[a] = db / hyp[f - 1]
    return idx, dmin


@njit
def offset_points(rel, off, top, k0, k1, xy_cam, xy_junction, index_min, index_max, R, t):
    """The junctions of one component triangulated with the offsets off[top[k0:k1]] (labelling._choose_offset's
    depth walk): labels rel + offset clipped into the pattern, projector rays of those pattern junctions,
    closest approach to the camera rays xy_cam (m, 2) (`geometry._k_triangulate_rays`, rows offset-major).
    Returns p ((k1 − k0)·m, 3) and in_pattern ((k1 − k0), m) bool."""
    m = rel.shape[0]
    nc = k1 - k0
    xy_c = np.empty((nc * m, 2))
    xy_p = np.empty((nc * m, 2))
    inpat = np.empty((nc, m), np.bool_)
    for c in range(nc):
        oi = off[top[k0 + c], 0]
        oj = off[top[k0 + c], 1]
        for a in range(m):
            i = rel[a, 0] + oi
            j = rel[a, 1] + oj
            inpat[c, a] = i >= index_min and i <= index_max and j >= index_min and j <= index_max
            i = min(max(i, index_min), index_max)
            j = min(max(j, index_min), index_max)
            xy_c[c * m + a, 0] = xy_cam[a, 0]
            xy_c[c * m + a, 1] = xy_cam[a, 1]
            xy_p[c * m + a, 0] = xy_junction[i - index_min, j - index_min, 0]
            xy_p[c * m + a, 1] = xy_junction[i - index_min, j - index_min, 1]
    p = np.empty((nc * m, 3))
    gap = np.empty(nc * m)
    _k_triangulate_rays(xy_c, xy_p, R, t, p, gap)
    return p, inpat


@njit
def offset_depth_walk(rel, off, top, xy_cam, xy_junction, index_min, index_max, R, t, z_min, z_max, min_inside_fraction):
    """labelling._choose_offset's depth walk in one call (decision 0078): the offsets off[top[k]] in ranking
    order, each component triangulated with it (`offset_points`), until two put at least
    min_inside_fraction of the junctions inside the pattern and the depth range z = R[:, 2]·(p − t)
    (`geometry.depth_cam`) in [z_min, z_max]. Returns (pass_k (2,) positions k in top of the first two that
    pass, −1 where fewer, the number that failed before the first pass, inside (m,) bool of the first).
    The same results as the chunked NumPy walk: each offset's test is independent of the others, and the
    chunks only decided when to stop (the walk also stops at the end of a chunk of 4 with two passes, so
    offsets after the second pass are never looked at)."""
    m = rel.shape[0]
    pass_k = np.full(2, -1, np.int64)
    inside = np.zeros(m, np.bool_)
    n_fail = 0
    n_pass = 0
    r02, r12, r22 = R[0, 2], R[1, 2], R[2, 2]
    t0, t1, t2 = t[0], t[1], t[2]
    ntop = top.shape[0]
    xy_p = np.empty((m, 2))
    p = np.empty((m, 3))
    gap = np.empty(m)
    ins = np.empty(m, np.bool_)
    for k in range(ntop):
        oi = off[top[k], 0]
        oj = off[top[k], 1]
        for a in range(m):
            i = rel[a, 0] + oi
            j = rel[a, 1] + oj
            ins[a] = i >= index_min and i <= index_max and j >= index_min and j <= index_max
            i = min(max(i, index_min), index_max)
            j = min(max(j, index_min), index_max)
            xy_p[a, 0] = xy_junction[i - index_min, j - index_min, 0]
            xy_p[a, 1] = xy_junction[i - index_min, j - index_min, 1]
        _k_triangulate_rays(xy_cam, xy_p, R, t, p, gap)
        cnt = 0
        for a in range(m):
            z = (p[a, 0] - t0) * r02 + (p[a, 1] - t1) * r12 + (p[a, 2] - t2) * r22
            ins[a] = ins[a] and z >= z_min and z <= z_max
            if ins[a]:
                cnt += 1
        if cnt / m >= min_inside_fraction:
            if n_pass < 2:
                pass_k[n_pass] = k
                if n_pass == 0:
                    for a in range(m):
                        inside[a] = ins[a]
            n_pass += 1
        elif n_pass == 0:
            n_fail += 1
        if n_pass >= 2 and k % 4 == 3:
            break
    return pass_k, n_fail, inside


@njit
def offset_residuals(rel, oi, oj, ln, xy_junction, index_min, index_max, fx):
    """Epipolar residuals (m,) in projector px of the labels rel + (oi, oj) (labelling._epipolar_residual_px
    on the clipped labels), NaN for labels outside the pattern (and where the line is not finite)."""
    m = rel.shape[0]
    r = np.empty(m)
    for a in range(m):
        i = rel[a, 0] + oi
        j = rel[a, 1] + oj
        if i < index_min or i > index_max or j < index_min or j > index_max:
            r[a] = np.nan
            continue
        x = xy_junction[i - index_min, j - index_min, 0]
        y = xy_junction[i - index_min, j - index_min, 1]
        r[a] = abs(ln[a, 0] * x + ln[a, 1] * y + ln[a, 2]) * fx
    return r


@njit
def cross_round_ends(q, sid, piece, tangent, fam, index, n_pieces, min_samples):
    """One round of labelling._crossing_seeds, first half: the pieces with no labelled sample and at least
    min_samples samples (todo, increasing), and both ends of each (first samples, then last samples): end
    positions e (2·nt, 2), tangents te, sign (−1 first, +1 last), family fe; and every piece's first and
    last trace position."""
    n = sid.shape[0]
    first = np.full(n_pieces, -1, np.intp)
    last = np.full(n_pieces, -1, np.intp)
    done = np.zeros(n_pieces, np.bool_)
    for k in range(n):
        p = piece[k]
        if first[p] < 0:
            first[p] = k
        last[p] = k
        if math.isfinite(index[sid[k]]):
            done[p] = True
    nt = 0
    for p in range(n_pieces):
        if not done[p] and last[p] - first[p] + 1 >= min_samples:
            nt += 1
    todo = np.empty(nt, np.intp)
    c = 0
    for p in range(n_pieces):
        if not done[p] and last[p] - first[p] + 1 >= min_samples:
            todo[c] = p
            c += 1
    e = np.empty((2 * nt, 2))
    te = np.empty((2 * nt, 2))
    sign = np.empty(2 * nt)
    fe = np.empty(2 * nt, np.int64)
    for a in range(nt):
        for side in range(2):
            k = first[todo[a]] if side == 0 else last[todo[a]]
            r = side * nt + a
            e[r, 0] = q[sid[k], 0]
            e[r, 1] = q[sid[k], 1]
            te[r, 0] = tangent[k, 0]
            te[r, 1] = tangent[k, 1]
            sign[r] = -1.0 if side == 0 else 1.0
            fe[r] = fam[sid[k]]
    return todo, e, te, sign, fe, first, last


@njit
def cross_round_write(todo, k_end, jid_end, both_ends, unlabelled, first, last, ts, sid, trim, index, seed_jid):
    """One round of labelling._crossing_seeds, second half: a piece to do takes line k when both its ends
    name k (both_ends; else one end suffices unless they disagree); its samples at least `trim` (along the
    piece) from both ends take k and the junction of the first end that named it. Writes index and seed_jid
    (sample ids) in place; returns the number of pieces taken and of samples written."""
    nt = todo.shape[0]
    taken = 0
    written = 0
    for a in range(nt):
        k0 = k_end[a]
        k1 = k_end[nt + a]
        has0 = k0 != unlabelled
        has1 = k1 != unlabelled
        if both_ends:
            take = has0 and has1 and k0 == k1
        else:
            take = (has0 or has1) and not (has0 and has1 and k0 != k1)
        if not take:
            continue
        taken += 1
        kv = k0 if has0 else k1
        jv = jid_end[a] if has0 else jid_end[nt + a]
        p = todo[a]
        f = first[p]
        g = last[p]
        for k in range(f, g + 1):
            if min(ts[k] - ts[f], ts[g] - ts[k]) >= trim:
                index[sid[k]] = kv
                seed_jid[sid[k]] = jv
                written += 1
    return taken, written


@njit
def gap_candidates(valid, index, sid, piece, cut_samples):
    """The candidates of labelling._fill_gaps in increasing sample order: valid samples without an index
    and not cut by the profile test (cut_samples), either off the traces (the mixing zone) or on a piece
    that has a labelled sample (its unlabelled ends). One pass instead of the NumPy masks it replaces."""
    P = valid.shape[0]
    n = sid.shape[0]
    state = np.zeros(P, np.int8)  # 1: on a trace, 2: cut by the profile test
    for k in range(cut_samples.shape[0]):
        state[cut_samples[k]] = 2
    npc = piece[n - 1] + 1 if n else 0
    lab_piece = np.zeros(npc, np.bool_)
    piece_of = np.empty(P, np.int32)  # (int32: decision 0150)
    for k in range(n):
        s = sid[k]
        if state[s] == 0:
            state[s] = 1
        piece_of[s] = piece[k]
        if not lab_piece[piece[k]] and math.isfinite(index[s]):  # a labelled piece's index is not read again (decision 0150)
            lab_piece[piece[k]] = True
    out = np.empty(P, np.intp)
    m = 0
    for s in range(P):
        if not valid[s] or math.isfinite(index[s]) or state[s] == 2:
            continue
        if state[s] == 0 or lab_piece[piece_of[s]]:
            out[m] = s
            m += 1
    return out[:m]


@njit
def cut_and_gap_candidates(index, sid, piece, valid, drop, max_drop, cut, gaps):
    """The end of labelling.label_samples' step 5 and step 6's candidates in one pass over the trace positions
    (decision 0157): `labelled_positions` (the positions whose sample carries an index and the number without one,
    both taken before the cut), with `cut` the profile test on them (drop (n,) float32, every trace position's
    measure, `TracePrep.drop`; max_drop float32: NumPy compares the float32 array with the option in float32) that
    clears the index of the cut samples, and with `gaps` `gap_candidates` of the result. Returns the labelled
    positions left after the cut (g[~cut]), the number unlabelled before it, the cut samples (sid[g[cut]], in
    position order) and the gap candidates (increasing sample order; empty without `gaps`). The trace positions
    are distinct samples, so a cut at one position changes no other position's test."""
    n = sid.shape[0]
    P = index.shape[0]
    lab_pos = np.empty(n, np.intp)
    cut_s = np.empty(n if cut else 0, np.intp)
    state = np.zeros(P if gaps else 0, np.int8)  # as gap_candidates: 1 on a trace, 2 cut by the profile test
    npc = piece[n - 1] + 1 if (n and gaps) else 0
    lab_piece = np.zeros(npc, np.bool_)
    piece_of = np.empty(P if gaps else 0, np.int32)
    nlab = 0
    ncut = 0
    nun = 0
    for k in range(n):
        s = sid[k]
        fin = math.isfinite(index[s])
        if fin:
            if cut and drop[k] > max_drop:
                index[s] = np.nan
                cut_s[ncut] = s
                ncut += 1
                fin = False
                if gaps:
                    state[s] = 2
            else:
                lab_pos[nlab] = k
                nlab += 1
        else:
            nun += 1
        if gaps:
            if state[s] == 0:
                state[s] = 1
            piece_of[s] = piece[k]
            if fin:
                lab_piece[piece[k]] = True
    out = np.empty(P if gaps else 0, np.intp)
    m = 0
    if gaps:
        for s in range(P):
            if not valid[s] or math.isfinite(index[s]) or state[s] == 2:
                continue
            if state[s] == 0 or lab_piece[piece_of[s]]:
                out[m] = s
                m += 1
    return lab_pos[:nlab], nun, cut_s[:ncut], out[:m]


@njit
def labels_out(index, seed_jid):
    """`drop_unlabelled_junctions` and the result's types in one pass (decision 0157): index as float64, the
    junctions as int64 with −1 where no index, and the number labelled. The narrow arrays (decision 0150) are
    left as they were."""
    P = index.shape[0]
    idx = np.empty(P, np.float64)
    jid = np.empty(P, np.int64)
    m = 0
    for s in range(P):
        v = index[s]
        idx[s] = v
        if math.isfinite(v):
            m += 1
            jid[s] = seed_jid[s]
        else:
            jid[s] = -1
    return idx, jid, m


@njit
def drop_unlabelled_junctions(index, seed_jid):
    """The end of labelling.label_samples: junction −1 where no index; returns the number labelled."""
    m = 0
    for s in range(index.shape[0]):
        if math.isfinite(index[s]):
            m += 1
        else:
            seed_jid[s] = -1
    return m


@njit
def traces_from_segments(q, fam, seg, cen, dr, sel, link_px, lateral_px, cos_turn, w, ridge, ridge_step, use_ridge):
    """The trace pieces of label_samples (step 3) from extraction's segments instead of a second neighbour
    search over all samples (decision 0085). The samples sel (n,) (ascending ids) of one segment seg (P,)
    (extraction's link before junctions and trims took samples out; −1: none, then the sample is a group
    on its own) are a group, ordered along the segment's fitted line (t = (q − cen[g])·dr[g], camera px).
    Groups whose end samples (first or last along t) lie within link_px of another group's end sample of
    the same family are joined (where `traces` links samples across a break of the segments: a crossing's
    core sample outside the mixing zone, a pair of segments the extraction's probes did not link); a joined
    component is ordered along its principal axis, as `traces`. Components are numbered by their lowest
    sample id, ordered by (t, id) and cut between consecutive samples where `traces` cuts: farther apart
    than link_px, a sideways jump (lateral_px), a turn (cos_turn), or (use_ridge) a ridge brightness step;
    ridge is indexed by sample id. Returns order (n,) positions in sel, piece (n,), t (n,) and unit
    tangents (n, 2) in order's order, as `traces_of`."""
    n = sel.shape[0]
    S = cen.shape[0]
    grp = np.empty(n, np.int64)
    t = np.zeros(n)
    gid = np.full(S, -1, np.int64)
    # each group's two end samples (positions in sel; the lowest and highest t, the first on a tie)
    e_lo = np.empty(n, np.intp)
    e_hi = np.empty(n, np.intp)
    t_lo = np.empty(n)
    t_hi = np.empty(n)
    ng = 0
    for k in range(n):
        s = sel[k]
        g = seg[s]
        if g < 0:
            grp[k] = ng
            e_lo[ng] = k
            e_hi[ng] = k
            ng += 1
            continue
        # t increases to the right (downwards on a vertical line), as along `traces`' principal axis
        tk = (q[s, 0] - cen[g, 0]) * dr[g, 0] + (q[s, 1] - cen[g, 1]) * dr[g, 1]
        if dr[g, 0] < 0 or (dr[g, 0] == 0 and dr[g, 1] < 0):
            tk = -tk
        if tk != tk:  # a degenerate fit: no order along it
            tk = 0.0
        t[k] = tk
        h = gid[g]
        if h < 0:
            h = ng
            gid[g] = h
            ng += 1
            e_lo[h] = k
            e_hi[h] = k
            t_lo[h] = tk
            t_hi[h] = tk
        elif tk < t_lo[h]:
            e_lo[h] = k
            t_lo[h] = tk
        elif tk > t_hi[h]:
            e_hi[h] = k
            t_hi[h] = tk
        grp[k] = h
    # join groups at their ends
    parent = join_group_ends(q, fam, sel, e_lo, e_hi, ng, link_px)
    # components numbered by their lowest sample id (groups are, and a root is its lowest group)
    cid = np.full(ng, -1, np.int64)
    ngrp = np.zeros(ng, np.int64)
    ncomp = 0
    for g in range(ng):
        ro = _union_find_root(parent, g)
        if cid[ro] < 0:
            cid[ro] = ncomp
            ncomp += 1
        cid[g] = cid[ro]
        ngrp[cid[g]] += 1
    comp = np.empty(n, np.int64)
    for k in range(n):
        comp[k] = cid[grp[k]]
    # a joined component: t along its principal axis (as `traces`)
    joined = False
    for c in range(ncomp):
        if ngrp[c] > 1:
            joined = True
            break
    if joined:
        jk = np.empty(n, np.intp)
        nj = 0
        for k in range(n):
            if ngrp[comp[k]] > 1:
                jk[nj] = k
                nj += 1
        cnt = np.zeros(ncomp)
        sx = np.zeros(ncomp)
        sy = np.zeros(ncomp)
        for m in range(nj):
            k = jk[m]
            c = comp[k]
            cnt[c] += 1.0
            sx[c] += q[sel[k], 0]
            sy[c] += q[sel[k], 1]
        for c in range(ncomp):
            if cnt[c] > 0:
                sx[c] /= cnt[c]
                sy[c] /= cnt[c]
        sxy = np.zeros(ncomp)
        sd = np.zeros(ncomp)
        for m in range(nj):
            k = jk[m]
            c = comp[k]
            dx = q[sel[k], 0] - sx[c]
            dy = q[sel[k], 1] - sy[c]
            sxy[c] += dx * dy
            sd[c] += dx * dx - dy * dy
        cth = np.zeros(ncomp)
        sth = np.zeros(ncomp)
        for c in range(ncomp):
            if cnt[c] > 0:
                th = 0.5 * math.atan2(2 * sxy[c], sd[c])
                cth[c] = math.cos(th)
                sth[c] = math.sin(th)
        for m in range(nj):
            k = jk[m]
            c = comp[k]
            t[k] = (q[sel[k], 0] - sx[c]) * cth[c] + (q[sel[k], 1] - sy[c]) * sth[c]
    order, start = _component_order(comp, t, n, ncomp)
    qs = np.empty((n, 2))
    ts = np.empty(n)
    for k in range(n):
        s = sel[order[k]]
        qs[k, 0] = q[s, 0]
        qs[k, 1] = q[s, 1]
        ts[k] = t[order[k]]
    # runs: the components split where consecutive samples lie farther apart than link_px (the mixing
    # zone cut out, a segment running on across a crossing); the tangents' chords stay within a run, as
    # within a component of `traces`
    link2 = link_px * link_px
    rstart = np.empty(n + 1, np.int64)
    nrun = 0
    for cpt in range(ncomp):
        rstart[nrun] = start[cpt]
        nrun += 1
        for k in range(start[cpt], start[cpt + 1] - 1):
            d0 = qs[k + 1, 0] - qs[k, 0]
            d1 = qs[k + 1, 1] - qs[k, 1]
            if d0 * d0 + d1 * d1 > link2:
                rstart[nrun] = k + 1
                nrun += 1
    rstart[nrun] = n
    piece = np.zeros(n, np.int64)
    tangent = np.empty((n, 2))
    eps32 = np.float32(1e-6)
    cur = 0
    for run in range(nrun):
        first = rstart[run]
        last = rstart[run + 1] - 1
        for k in range(first, last + 1):
            piece[k] = cur
            kb = max(k - w, first)
            kf = min(k + w, last)
            tan0 = qs[kf, 0] - qs[kb, 0]
            tan1 = qs[kf, 1] - qs[kb, 1]
            lt = max(math.sqrt(tan0 * tan0 + tan1 * tan1), 1e-12)
            T0 = tan0 / lt
            T1 = tan1 / lt
            tangent[k, 0] = T0
            tangent[k, 1] = T1
            if k == last:
                continue
            d0 = qs[k + 1, 0] - qs[k, 0]
            d1 = qs[k + 1, 1] - qs[k, 1]
            # (consecutive samples of a run are within link_px)
            back0 = qs[k, 0] - qs[kb, 0]
            back1 = qs[k, 1] - qs[kb, 1]
            kf1 = min(k + 1 + w, last)
            fwd0 = qs[kf1, 0] - qs[k + 1, 0]
            fwd1 = qs[kf1, 1] - qs[k + 1, 1]
            sb = back0 * back0 + back1 * back1
            sf = fwd0 * fwd0 + fwd1 * fwd1
            if sb >= 1.0:
                lb = math.sqrt(sb)
                B0 = back0 / lb
                B1 = back1 / lb
            else:
                B0 = T0
                B1 = T1
            if sf >= 1.0:
                lf = math.sqrt(sf)
                F0 = fwd0 / lf
                F1 = fwd1 / lf
            else:
                F0 = T0
                F1 = T1
            lateral = max(abs(d0 * B1 - d1 * B0), abs(d0 * F1 - d1 * F0))
            along = abs(d0 * B0 + d1 * B1)
            cut = lateral > lateral_px or along < lateral or B0 * F0 + B1 * F1 < cos_turn
            if not cut and use_ridge:
                r0 = ridge[sel[order[k]]]
                r1 = ridge[sel[order[k + 1]]]
                top = max(r1, r0)
                if top < eps32:
                    top = eps32
                cut = abs(r1 - r0) > ridge_step * top
            if cut:
                cur += 1
        cur += 1
    return order, piece, ts, tangent


@njit
def join_group_ends(q, fam, sel, e_lo, e_hi, ng, link_px):
    """`traces_from_segments`' joins: union–find parents (ng,) of the groups whose end samples (positions
    e_lo, e_hi in sel) lie within link_px of another group's end of the same family. The ends are
    bucketed per family in cells at least link_px wide (a cell and its forward neighbours hold every
    pair once), their positions and groups copied in bucket order so that the search reads them in
    sequence."""
    parent = np.arange(ng)
    if ng < 2:
        return parent
    cs = max(link_px, 8.0)
    ne = 2 * ng
    ex = np.empty(ne)
    ey = np.empty(ne)
    ef = np.empty(ne, np.intp)
    for m in range(ne):
        g = m if m < ng else m - ng
        s = sel[e_lo[g] if m < ng else e_hi[g]]
        ex[m] = q[s, 0]
        ey[m] = q[s, 1]
        # a single sample's second end is the same point: left out
        ef[m] = -1 if (m >= ng and e_hi[g] == e_lo[g]) or (fam[s] != 1 and fam[s] != 2) else fam[s] - 1
    x0 = ex.min()
    y0 = ey.min()
    gw = int((ex.max() - x0) / cs) + 1
    gh = int((ey.max() - y0) / cs) + 1
    nc = gw * gh
    key = np.empty(ne, np.intp)
    bstart = np.zeros(2 * nc + 1, np.intp)
    for m in range(ne):
        if ef[m] < 0:
            key[m] = -1
            continue
        cx = min(int((ex[m] - x0) / cs), gw - 1)
        cy = min(int((ey[m] - y0) / cs), gh - 1)
        key[m] = ef[m] * nc + cy * gw + cx
        bstart[key[m] + 1] += 1
    for m in range(2 * nc):
        bstart[m + 1] += bstart[m]
    bfill = bstart[:-1].copy()
    bx = np.empty(ne)
    by = np.empty(ne)
    bg = np.empty(ne, np.intp)
    bk = np.empty(ne, np.intp)
    nb = 0
    for m in range(ne):
        if key[m] < 0:
            continue
        it = bfill[key[m]]
        bx[it] = ex[m]
        by[it] = ey[m]
        bg[it] = m if m < ng else m - ng
        bk[it] = key[m]
        bfill[key[m]] += 1
        nb += 1
    link2 = link_px * link_px
    for i0 in range(nb):
        k0 = bk[i0]
        base = (k0 // nc) * nc
        cell = k0 - base
        cx = cell % gw
        cy = cell // gw
        g = bg[i0]
        x = bx[i0]
        y = by[i0]
        for yy in range(cy, min(cy + 2, gh)):
            # this row: the cell's later items and the next cell; the row below: three cells
            if yy == cy:
                lo = i0 + 1
                hi = bstart[base + yy * gw + min(cx + 1, gw - 1) + 1]
            else:
                lo = bstart[base + yy * gw + max(cx - 1, 0)]
                hi = bstart[base + yy * gw + min(cx + 1, gw - 1) + 1]
            for it in range(lo, hi):
                d0 = bx[it] - x
                d1 = by[it] - y
                if d0 * d0 + d1 * d1 <= link2:
                    g2 = bg[it]
                    _union_find_join(parent, g, g2)
    return parent


# --- glue round five (decision 0087): label_samples' per-sample NumPy steps in one pass each ---------------


@njit
def kept_samples(valid, near_other, seed, unlabelled):
    """label_samples after the seeds: the samples outside the mixing zone, k_idx (K,) intp in increasing
    order (= np.flatnonzero(valid & ~near_other)), the number of valid samples in the mixing zone and the
    number of kept samples that are seeds (seed != unlabelled). One pass over the samples."""
    P = valid.shape[0]
    out = np.empty(P, np.intp)
    m = 0
    n_mix = 0
    n_seeds = 0
    for s in range(P):
        if not valid[s]:
            continue
        if near_other[s]:
            n_mix += 1
            continue
        out[m] = s
        m += 1
        if seed[s] != unlabelled:
            n_seeds += 1
    return out[:m], n_mix, n_seeds


@njit
def seeds_among(k_idx, seed, unlabelled):
    """The number of samples k_idx that are seeds (seed != unlabelled): `kept_samples`' count when the kept samples
    are known already (decision 0140)."""
    n = 0
    for m in range(k_idx.shape[0]):
        if seed[k_idx[m]] != unlabelled:
            n += 1
    return n


@njit
def labelled_positions(index, sid):
    """The trace positions whose sample carries an index, (g,) intp increasing (= np.flatnonzero(np.isfinite(
    index[sid]))), and the number of positions without one."""
    n = sid.shape[0]
    out = np.empty(n, np.intp)
    m = 0
    for k in range(n):
        if math.isfinite(index[sid[k]]):
            out[m] = k
            m += 1
    return out[:m], n - m


@njit
def newly_labelled(index, seen, have_seen):
    """A crossing round's start: labelled (P,) bool = np.isfinite(index), and when have_seen the samples
    labelled since `seen` (P,) bool was taken, (N,) intp increasing (= np.flatnonzero(labelled & ~seen));
    else an empty list."""
    P = index.shape[0]
    lab = np.empty(P, np.bool_)
    out = np.empty(P if have_seen else 0, np.intp)
    m = 0
    for s in range(P):
        f = math.isfinite(index[s])
        lab[s] = f
        if have_seen and f and not seen[s]:
            out[m] = s
            m += 1
    return lab, out[:m]


@njit
def group_order(comp):
    """labelling._groups' arrays: order (n,) intp = np.argsort(comp, kind="stable") (a stable counting
    sort) and bounds (G + 1,) intp, the starts of each run of equal ids in that order and n. Both empty when
    an id is negative."""
    n = comp.shape[0]
    top = 0
    for i in range(n):
        if comp[i] < 0:
            return np.empty(0, np.intp), np.empty(0, np.intp)  # not for negative ids: the caller sorts
        top = max(top, comp[i])
    cnt = np.zeros(top + 2, np.intp)
    for i in range(n):
        cnt[comp[i] + 1] += 1
    for v in range(top + 1):
        cnt[v + 1] += cnt[v]
    order = np.empty(n, np.intp)
    for i in range(n):
        v = comp[i]
        order[cnt[v]] = i
        cnt[v] += 1
    bounds = np.empty(n + 1, np.intp)
    g = 0
    for k in range(n):
        if k == 0 or comp[order[k]] != comp[order[k - 1]]:
            bounds[g] = k
            g += 1
    bounds[g] = n
    return order, bounds[: g + 1]


@njit
def write_component(members, lab, r, inside, limit, labels, residual):
    """label_epipolar's accepted offset: the junctions with a finite residual r ≤ limit inside the depth range
    take their labels lab (m, 2) and residual (labels, residual written at members); returns bad (m,) bool,
    the others, and their number."""
    m = members.shape[0]
    bad = np.empty(m, np.bool_)
    nb = 0
    for k in range(m):
        x = r[k]
        b = (not math.isfinite(x)) or (x > limit) or (not inside[k])
        bad[k] = b
        if b:
            nb += 1
        else:
            labels[members[k], 0] = lab[k, 0]
            labels[members[k], 1] = lab[k, 1]
            residual[members[k]] = x
    return bad, nb


@njit
def _as_int64(x):
    """int64(x) as NumPy's float → int64 cast gives it on x86-64 (NaN, ±inf and values beyond int64:
    INT64_MIN)."""
    if not (abs(x) < 9.2e18):
        return np.iinfo(np.int64).min
    return np.int64(x)


@njit
def crossing_hits(o, c, redo, have_redo, fe, index, sid):
    """After `crossing_test` (o (R,) the crossing's labelled sample or −1, c (R, 2) the crossing): the rows
    with a crossing, as the light-sheet check takes them. sel (K,) the ends (redo[r], or r without
    have_redo), o_sel (K,), c_sel (K, 2), the other family 3 − fe[sel] (K,) intp, and that sample's line
    index (K,) int64. Formerly NumPy's nonzero and gathers."""
    R = o.shape[0]
    k = 0
    for r in range(R):
        k += o[r] >= 0
    sel = np.empty(k, np.intp)
    o_sel = np.empty(k, o.dtype)
    c_sel = np.empty((k, 2))
    f_other = np.empty(k, np.intp)
    m = np.empty(k, np.int64)
    i = 0
    for r in range(R):
        if o[r] < 0:
            continue
        s = redo[r] if have_redo else r
        sel[i] = s
        o_sel[i] = o[r]
        c_sel[i, 0] = c[r, 0]
        c_sel[i, 1] = c[r, 1]
        f_other[i] = 3 - fe[s]
        m[i] = _as_int64(index[sid[o[r]]])
        i += 1
    return sel, o_sel, c_sel, f_other, m


@njit
def crossing_hits_write(sel, o_sel, kk, res, z, tol, z_min, z_max, k_end, jid_end, seed_jid, sid):
    """The hits that pass the check (residual ≤ tol, depth within [z_min, z_max]) give their end the line kk
    and the junction of their labelled sample (k_end, jid_end written at sel)."""
    for r in range(sel.shape[0]):
        if res[r] <= tol and z[r] >= z_min and z[r] <= z_max:
            k_end[sel[r]] = kk[r]
            jid_end[sel[r]] = seed_jid[sid[o_sel[r]]]


@njit
def label_arrays(q, family, unlabelled):
    """label_samples' per-sample arrays, in one pass: the families as int8 (0, 1, 2: a byte per sample instead of
    eight keeps the array in cache for the steps' scattered reads, decision 0150), index (P,) NaN as float32 (every
    value a step writes is a line index, an integer, exact in float32; label_samples returns it as float64, decision
    0150), q_out (P, 2) a copy of q, seed_jid (P,) −1 and seed (P,) `unlabelled` (both int32: junction ids and line
    indices, `unlabelled` the int32 minimum; label_samples returns seed_jid as int64, decision 0150)."""
    P = q.shape[0]
    fam = np.empty(P, np.int8)
    index = np.empty(P, np.float32)
    q_out = np.empty((P, 2))
    seed_jid = np.empty(P, np.int32)
    seed = np.empty(P, np.int32)
    for i in range(P):
        fam[i] = family[i]
        index[i] = np.nan
        q_out[i, 0] = q[i, 0]
        q_out[i, 1] = q[i, 1]
        seed_jid[i] = -1
        seed[i] = unlabelled
    return fam, index, q_out, seed_jid, seed


@njit
def _choice_from_scores(status, off, score, ranked, n_eff, rel, ln, xy_cam, xy_junction, index_min, index_max, fx, min_inside, cap2,
                        R, t, z_min, z_max):
    """`offset_choice` after `offset_scores`: the depth walk over the 16 best and the best offset's residuals."""
    off_best = np.zeros(2, np.int64)
    if status != 0:
        return status, 0, False, 0.0, 0.0, n_eff, off_best, np.empty(0), np.empty(0, np.bool_)
    top = ranked[: min(len(ranked), 16)]
    pass_k, n_fail, inside = offset_depth_walk(rel, off, top, xy_cam, xy_junction, index_min, index_max, R, t, z_min, z_max,
                                               min_inside)
    if pass_k[0] < 0:
        return status, n_fail, False, 0.0, 0.0, n_eff, off_best, np.empty(0), np.empty(0, np.bool_)
    best = top[pass_k[0]]
    s1 = score[best]
    s2 = score[top[pass_k[1]]] if pass_k[1] >= 0 else cap2
    off_best[0] = off[best, 0]
    off_best[1] = off[best, 1]
    r_full = offset_residuals(rel, off_best[0], off_best[1], ln, xy_junction, index_min, index_max, fx)
    return status, n_fail, True, s1, s2, n_eff, off_best, r_full, inside


@njit
def offset_choice(rel, ln, xy_cam, xy_junction, index_min, index_max, fx, n_refs, band_px, min_inside, cap2, R, t, z_min,
                  z_max):
    """labelling._choose_offset's compiled part in one call (decision 0087): `offset_scores`, the depth walk
    over the 16 best (`offset_depth_walk`) and the best offset's residuals (`offset_residuals`), in that
    order with the same arguments. Returns status (offset_scores'), n_fail (offsets outside the depth range,
    0 when status ≠ 0), ok (an offset passed the walk), s1 and s2 (the scores of the best two passing
    offsets; s2 = cap2 without a second), n_eff, off_best (2,) int64, r_full (m,) and inside (m,) (the walk's
    output; empty unless ok)."""
    status, off, score, ranked, n_eff = offset_scores(rel, ln, xy_junction, index_min, index_max, fx, n_refs, band_px,
                                                      min_inside, cap2)
    return _choice_from_scores(status, off, score, ranked, n_eff, rel, ln, xy_cam, xy_junction, index_min, index_max, fx,
                               min_inside, cap2, R, t, z_min, z_max)


@njit
def offset_choice_b(rel, ln, xy_cam, xy_junction, blocks, B, index_min, index_max, fx, n_refs, band_px, min_inside, cap2, R, t, z_min,
                  z_max):
    """`offset_choice` with `offset_scores_b` on the given blocks (`junction_blocks(xy_junction, B)`): the same outputs."""
    status, off, score, ranked, n_eff = offset_scores_b(rel, ln, xy_junction, blocks, B, index_min, index_max, fx, n_refs, band_px,
                                                      min_inside, cap2)
    return _choice_from_scores(status, off, score, ranked, n_eff, rel, ln, xy_cam, xy_junction, index_min, index_max, fx,
                               min_inside, cap2, R, t, z_min, z_max)


@njit
def round_state_gather(todo, n_pieces, bd_all, bk_all, k_all, j_all):
    """A crossing round's kept search results for pieces todo (nt,): rows todo then todo + n_pieces of the
    per-end state (bd, bk, k_end, jid_end), as (2·nt,) copies (formerly four fancy gathers)."""
    nt = todo.shape[0]
    bd = np.empty(2 * nt, bd_all.dtype)
    bk = np.empty(2 * nt, bk_all.dtype)
    ke = np.empty(2 * nt, k_all.dtype)
    je = np.empty(2 * nt, j_all.dtype)
    for h in range(2):
        for i in range(nt):
            r = todo[i] + h * n_pieces
            k = h * nt + i
            bd[k] = bd_all[r]
            bk[k] = bk_all[r]
            ke[k] = k_all[r]
            je[k] = j_all[r]
    return bd, bk, ke, je


@njit
def round_state_scatter(todo, n_pieces, bd, bk, ke, je, bd_all, bk_all, k_all, j_all):
    """The inverse of `round_state_gather`: the round's results written back at rows todo, todo + n_pieces."""
    nt = todo.shape[0]
    for h in range(2):
        for i in range(nt):
            r = todo[i] + h * n_pieces
            k = h * nt + i
            bd_all[r] = bd[k]
            bk_all[r] = bk[k]
            k_all[r] = ke[k]
            j_all[r] = je[k]


@njit
def redo_rows(changed, e, te, sign, bk, k_end, jid_end, unlabelled):
    """The ends whose nearest candidate changed (`crossing_nearest_update`'s flags): redo (R,) intp, their rows
    of e, te, sign and bk for `crossing_test`, and their line and junction reset (k_end, jid_end in place)."""
    n = changed.shape[0]
    R = 0
    for i in range(n):
        R += changed[i] != 0
    redo = np.empty(R, np.intp)
    e_r = np.empty((R, 2), e.dtype)
    te_r = np.empty((R, 2), te.dtype)
    s_r = np.empty(R, sign.dtype)
    b_r = np.empty(R, bk.dtype)
    k = 0
    for i in range(n):
        if changed[i] == 0:
            continue
        redo[k] = i
        e_r[k, 0] = e[i, 0]
        e_r[k, 1] = e[i, 1]
        te_r[k, 0] = te[i, 0]
        te_r[k, 1] = te[i, 1]
        s_r[k] = sign[i]
        b_r[k] = bk[i]
        k_end[i] = unlabelled
        jid_end[i] = -1
        k += 1
    return redo, e_r, te_r, s_r, b_r


@njit
def epipolar_from_rays(d, t):
    """`geometry.epipolar_lines` after its ray directions d (N, 3) = `camera_rays_proj` (decision 0094): l = t × d
    (np.cross's products and differences), scaled by 1/hypot(l0, l1) (NaN where that is 0), the same float
    operations in the same order; np.cross's broadcasting and axis moves cost ~40 µs per call, this ~2."""
    N = d.shape[0]
    out = np.empty((N, 3))
    t0 = t[0]
    t1 = t[1]
    t2 = t[2]
    for n in range(N):
        c0 = t1 * d[n, 2] - t2 * d[n, 1]
        c1 = t2 * d[n, 0] - t0 * d[n, 2]
        c2 = t0 * d[n, 1] - t1 * d[n, 0]
        nm = math.hypot(c0, c1)
        if nm == 0.0:
            nm = np.nan
        out[n, 0] = c0 / nm
        out[n, 1] = c1 / nm
        out[n, 2] = c2 / nm
    return out


# --- label stage round seven (decision 0096) ------------------------------------------------------------------


@njit
def gather_members(members, rel, ln, xy):
    """The members' rows (members (m,) junction ids) of rel (M, 2) int64, ln (M, 3) and xy (M, 2), as new arrays:
    `offset_choice_b`'s inputs for one component."""
    m = members.shape[0]
    rm = np.empty((m, 2), np.int64)
    lm = np.empty((m, 3))
    xm = np.empty((m, 2))
    for p in range(m):
        i = members[p]
        rm[p, 0] = rel[i, 0]
        rm[p, 1] = rel[i, 1]
        lm[p, 0] = ln[i, 0]
        lm[p, 1] = ln[i, 1]
        lm[p, 2] = ln[i, 2]
        xm[p, 0] = xy[i, 0]
        xm[p, 1] = xy[i, 1]
    return rm, lm, xm


@njit
def offset_choice_groups(order, bounds, min_component, rel, ln, xy_cam, xy_junction, index_min, index_max, fx, n_refs,
                         band_px, min_inside, cap2, R, t, z_min, z_max, outlier_sigma, max_residual_px, noise_floor2, chi2,
                         rms_ratio2, labels, residual):
    """`offset_choice` for every component of label_epipolar's first round at once (decision 0096): group g's
    members order[bounds[g]:bounds[g + 1]] (increasing), skipped (status −1) when fewer than min_component.
    Each group's rel, ln and xy_cam rows are gathered as the former `_choose_offset` gathered them and
    passed to `offset_choice`. Returns per group status, n_fail, ok, s1, s2, n_eff, off_best (G, 2) and the
    outlier limit (`labelling._outlier_limit` of r_full, NaN unless ok), and per member (in order's order)
    r_full and inside (written where ok). A group that passes `_choose_offset`'s ambiguity test (σ² = Python's
    max(s1, noise_floor2); n_eff·(s2 − s1)/σ² ≥ chi2 and s2 ≥ rms_ratio2·σ²) is written at once as
    `write_component` writes it (labels rel + off, residual, where not bad): written[g] True, its bad members
    in bad (n,) and their number n_bad[g]; the ambiguous ones (the inlier retry) are left to the caller."""
    G = bounds.shape[0] - 1
    blocks = junction_blocks(xy_junction, _BLOCK)  # once for every group (decision 0124)
    n = order.shape[0]
    status = np.full(G, -1, np.int64)
    n_fail = np.zeros(G, np.int64)
    ok = np.zeros(G, np.bool_)
    s1 = np.zeros(G)
    s2 = np.zeros(G)
    n_eff = np.zeros(G, np.int64)
    off = np.zeros((G, 2), np.int64)
    limit = np.full(G, np.nan)
    r_all = np.full(n, np.nan)
    in_all = np.zeros(n, np.bool_)
    written = np.zeros(G, np.bool_)
    bad = np.zeros(n, np.bool_)
    n_bad = np.zeros(G, np.int64)
    for g in range(G):
        b0 = bounds[g]
        m = bounds[g + 1] - b0
        if m < min_component:
            continue
        rg, lg, xg = gather_members(order[b0 : b0 + m], rel, ln, xy_cam)
        st, nf, okg, a1, a2, ne, ob, r_full, inside = offset_choice_b(rg, lg, xg, xy_junction, blocks, _BLOCK, index_min, index_max, fx, n_refs,
                                                                   band_px, min_inside, cap2, R, t, z_min, z_max)
        status[g] = st
        n_fail[g] = nf
        ok[g] = okg
        s1[g] = a1
        s2[g] = a2
        n_eff[g] = ne
        off[g, 0] = ob[0]
        off[g, 1] = ob[1]
        if okg:
            for a in range(m):
                r_all[b0 + a] = r_full[a]
                in_all[b0 + a] = inside[a]
            # labelling._outlier_limit: max(outlier_sigma·σ̂, max_residual_px), σ̂ = 1.4826·median (inf when none),
            # with Python's max (the first argument unless the second is larger)
            med = median_finite(r_full)
            sigma_hat = 1.4826 * med if math.isfinite(med) else np.inf
            lim = outlier_sigma * sigma_hat
            if max_residual_px > lim:
                lim = max_residual_px
            limit[g] = lim
            sigma2 = a1
            if noise_floor2 > sigma2:
                sigma2 = noise_floor2
            if ne * (a2 - a1) / sigma2 < chi2 or a2 < rms_ratio2 * sigma2:
                continue  # ambiguous as a whole: the caller retries on the inliers
            written[g] = True
            nb = 0
            for a in range(m):
                x = r_full[a]
                b = (not math.isfinite(x)) or (x > lim) or (not inside[a])
                bad[b0 + a] = b
                if b:
                    nb += 1
                else:
                    i = order[b0 + a]
                    labels[i, 0] = rel[i, 0] + ob[0]
                    labels[i, 1] = rel[i, 1] + ob[1]
                    residual[i] = x
            n_bad[g] = nb
    return status, n_fail, ok, s1, s2, n_eff, off, limit, r_all, in_all, written, bad, n_bad
