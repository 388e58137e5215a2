"""Compiled loops of `reconstruction.continuation` (decision 0062: numba, one thread)."""

from __future__ import annotations

import math

import numpy as np

from reconstruction._jit import njit
from reconstruction._label_kernels import _union_find_join, _union_find_root


@njit
def piece_ends(q, sid, piece, tangent, index, seed_jid, n_p, anchor):
    """Per piece (n_p): its two ends (rows 0..n_p−1 the first sample's end, n_p..2n_p−1 the last's): position
    e (2n_p, 2), outward unit direction u (2n_p, 2) (the chord from the sample `anchor` places inside, or the
    trace tangent on short pieces), the end's trace position; per piece: labelled (bool), its index (NaN
    when none; the first labelled sample's) and seed junction (−1)."""
    n = sid.shape[0]
    first = np.full(n_p, -1, np.intp)
    last = np.full(n_p, -1, np.intp)
    labelled = np.zeros(n_p, np.bool_)
    val = np.full(n_p, np.nan)
    jsrc = np.full(n_p, -1, np.int64)
    for k in range(n):
        p = piece[k]
        if first[p] < 0:
            first[p] = k
        last[p] = k
        if jsrc[p] >= 0:
            continue  # labelled, with its junction: the piece's later samples change nothing here (decision 0150)
        s = sid[k]
        if math.isfinite(index[s]):
            if not labelled[p]:
                labelled[p] = True
                val[p] = index[s]
            if seed_jid[s] >= 0:
                jsrc[p] = seed_jid[s]
    e = np.empty((2 * n_p, 2))
    u = np.empty((2 * n_p, 2))
    pos = np.empty(2 * n_p, np.intp)
    for p in range(n_p):
        for side in range(2):
            if side == 0:
                k = first[p]
                a = min(k + anchor, last[p])
                sgn = -1.0
            else:
                k = last[p]
                a = max(k - anchor, first[p])
                sgn = 1.0
            r = side * n_p + p
            pos[r] = k
            e[r, 0] = q[sid[k], 0]
            e[r, 1] = q[sid[k], 1]
            d0 = e[r, 0] - q[sid[a], 0]
            d1 = e[r, 1] - q[sid[a], 1]
            L = math.sqrt(d0 * d0 + d1 * d1)
            if L >= 1.5:
                u[r, 0] = d0 / L
                u[r, 1] = d1 / L
            else:
                u[r, 0] = sgn * tangent[k, 0]
                u[r, 1] = sgn * tangent[k, 1]
    return e, u, pos, labelled, val, jsrc


@njit
def facing_links(e, u, f_e, n_p, labelled, reach, lateral, cos_facing):
    """Pairs of piece ends (a, b piece ids, gap length) of one family, on different pieces not both
    labelled, closer than reach, facing each other (directions more opposite than cos_facing), each end
    beyond the other and within `lateral` of the other's line (i < j: the end ids, a, b their pieces).
    Ends are bucketed per family in cells `reach` wide and every pair of a cell and its forward neighbours
    is looked at once; the order of the pairs is the cells' (nothing downstream depends on it)."""
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
    # CSR buckets keyed by (family, cell): ids increasing within a bucket
    key = np.empty(m, np.intp)
    cxs = np.empty(m, np.intp)
    cys = np.empty(m, np.intp)
    start = np.zeros(2 * ng + 1, np.intp)
    for k in range(m):
        cx = min(max(int(math.floor((e[k, 0] - x0) / cell)), 0), gw - 1)
        cy = min(max(int(math.floor((e[k, 1] - y0) / cell)), 0), gh - 1)
        cxs[k] = cx
        cys[k] = cy
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
    # every unordered pair once: a cell with itself (later items) and with its four forward neighbours
    for f in range(2):
        base = f * ng
        for cy in range(gh):
            for cx in range(gw):
                bk = base + cy * gw + cx
                for s in range(start[bk], start[bk + 1]):
                    i0 = items[s]
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
                            i = min(i0, j0)
                            j = max(i0, j0)
                            v0 = e[j, 0] - e[i, 0]
                            v1 = e[j, 1] - e[i, 1]
                            g2 = v0 * v0 + v1 * v1
                            if g2 >= r2:
                                continue
                            pi = i - n_p if i >= n_p else i
                            pj = j - n_p if j >= n_p else j
                            if pi == pj or (labelled[pi] and labelled[pj]):
                                continue
                            if u[i, 0] * u[j, 0] + u[i, 1] * u[j, 1] >= -cos_facing:
                                continue
                            if v0 * u[i, 0] + v1 * u[i, 1] <= 0 or v0 * u[j, 0] + v1 * u[j, 1] >= 0:
                                continue
                            if abs(v0 * u[i, 1] - v1 * u[i, 0]) > lateral or abs(v0 * u[j, 1] - v1 * u[j, 0]) > lateral:
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


@njit
def crossing_in_gap(q, fam, e, f_e, li, lj, gap, x0, y0, cell, gw, gh, start, items):
    """Per link (ends li, lj of family f, gap length gap): is there a valid sample of family 3 − f within
    r = max(2, gap/2) of the gap's middle 0.5·(e[li] + e[lj])? (As the nearest such sample closer than the
    largest r of the links of that family, at distance ≤ r: the former k-d tree query.) Samples come from
    the frame's bucket grid of valid samples (`_label_kernels.sample_grid`)."""
    nl = li.shape[0]
    out = np.zeros(nl, np.bool_)
    if nl == 0:
        return out
    mid = np.empty((nl, 2))
    r = np.empty(nl)
    need = np.empty(nl, np.intp)
    rmax = np.zeros(3)
    for s in range(nl):
        mid[s, 0] = 0.5 * (e[li[s], 0] + e[lj[s], 0])
        mid[s, 1] = 0.5 * (e[li[s], 1] + e[lj[s], 1])
        r[s] = max(2.0, 0.5 * gap[s])
        need[s] = 3 - f_e[li[s]]
        if r[s] > rmax[need[s]]:
            rmax[need[s]] = r[s]
    r2max = np.empty(3)
    for f in range(3):
        r2max[f] = rmax[f] * rmax[f]
    nc = gw * gh
    split = start.shape[0] == 2 * nc + 1  # a grid from `sample_grid_split`: read the family's part only
    for s in range(nl):
        f = need[s]
        qx = mid[s, 0]
        qy = mid[s, 1]
        ring = max(1, int(math.ceil(r[s] / cell)))
        cx = int(math.floor((qx - x0) / cell))
        cy = int(math.floor((qy - y0) / cell))
        found = False
        for yy in range(max(cy - ring, 0), min(cy + ring + 1, gh)):
            for xx in range(max(cx - ring, 0), min(cx + ring + 1, gw)):
                bk = yy * gw + xx
                t0 = start[bk]
                t1 = start[bk + 1]
                if split:
                    if f == 1:
                        t1 = start[nc + 1 + bk]
                    elif f == 2:
                        t0 = start[nc + 1 + bk]
                for t in range(t0, t1):
                    p = items[t]
                    if fam[p] != f:
                        continue
                    d0 = q[p, 0] - qx
                    d1 = q[p, 1] - qy
                    d2 = d0 * d0 + d1 * d1
                    if d2 < r2max[f] and math.sqrt(d2) <= r[s]:
                        found = True
                        break
                if found:
                    break
            if found:
                break
        out[s] = found
    return out


@njit
def chain_values(n_p, a, b, keep_piece, labelled, val, jsrc):
    """Chains of pieces: the connected components of the links a–b between kept pieces (union–find). Per
    piece: the index of its chain's labelled pieces if they all agree (NaN otherwise or when none), and
    the seed junction of the chain's highest-numbered labelled piece (−1 when none)."""
    parent = np.arange(n_p)
    for k in range(a.shape[0]):
        if keep_piece[a[k]] and keep_piece[b[k]]:
            _union_find_join(parent, a[k], b[k])
    lo = np.full(n_p, np.inf)
    hi = np.full(n_p, -np.inf)
    src = np.full(n_p, -1, np.int64)
    root = np.empty(n_p, np.intp)
    for p in range(n_p):
        root[p] = _union_find_root(parent, p)
        if labelled[p]:
            rp = root[p]
            if val[p] < lo[rp]:
                lo[rp] = val[p]
            if val[p] > hi[rp]:
                hi[rp] = val[p]
            src[rp] = jsrc[p]
    k_of = np.empty(n_p)
    src_of = np.empty(n_p, np.int64)
    for p in range(n_p):
        rp = root[p]
        k_of[p] = lo[rp] if lo[rp] == hi[rp] else np.nan
        src_of[p] = src[rp]
    return k_of, src_of


@njit
def write_pieces(sid, piece, ts, new_piece, k_of, src_j, trim, index, seed_jid):
    """index[sid[k]] = k_of[piece[k]] (and seed_jid) for the samples of pieces flagged new, except those
    within `trim` (px along the piece) of its ends (the crossing's light pulls the ridge there); returns
    the count."""
    n = sid.shape[0]
    cnt = 0
    k0 = 0
    while k0 < n:
        k1 = k0
        while k1 + 1 < n and piece[k1 + 1] == piece[k0]:
            k1 += 1
        p = piece[k0]
        if new_piece[p]:
            lo = min(ts[k0], ts[k1])
            hi = max(ts[k0], ts[k1])
            for k in range(k0, k1 + 1):
                if ts[k] - lo >= trim and hi - ts[k] >= trim:
                    index[sid[k]] = k_of[p]
                    seed_jid[sid[k]] = src_j[p]
                    cnt += 1
        k0 = k1 + 1
    return cnt


@njit
def samples_of(piece, flag):
    """Trace positions (ascending) of the samples whose piece is flagged."""
    n = piece.shape[0]
    out = np.empty(n, np.intp)
    c = 0
    for k in range(n):
        if flag[piece[k]]:
            out[c] = k
            c += 1
    return out[:c]
