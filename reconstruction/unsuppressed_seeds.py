"""Crossing candidates a rejected maximum hid: a maximum that is no crossing suppresses nothing (decision 0152).

Crossing candidates are the crossing pixels (weaker Hessian curvature −λ2 strong) that hold the maximum score over
their 3×3 cells of 0.2 junction steps (`_extract_kernels.crossing_seeds`). That maximum is taken over every crossing
pixel, also over those of a blob that is no crossing: a wide line's own flat top, a spot, a line's end, whose
maximum the ring test (`keep_crossings`: at least 2 ring samples of each family) then drops. Such a blob hides every
weaker maximum within a cell and a half of it, and a true X there gets no candidate at all (decision 0148 section 3:
paper-intermediate (658.5, 527.4), 22.5 px from a one-family blob).

Physically the suppression stands for "this is one crossing, not several": a candidate whose ring shows it is no
crossing says nothing about its neighbours. `unsuppressed_seeds` takes the ring counts the pipeline computes at the
candidates anyway (one `ring_counts`), masks the crossing pixels of the rejected candidates' blobs (within the
centroid radius of one), and looks for the maxima of the rest in the cells next to a masked pixel only: pixels that
were no maximum before and are one now. Each is moved to its blob's centroid (as `centroids`), dropped where it
lies within r0 of a candidate (the same blob) or of a stronger new one, or within the attachment reach of a
candidate that passes the ring test (that crossing's own ring), and kept only where its own ring (samples nearer
to it than to the candidate that holds them) has 2 samples of each family. `stamp_more` then adds the kept ones to
the lookup grid as `stamp` would have stamped them last, and `relook` updates the samples' candidate, distance and
ring counts in the rows the new ones reach: no second seeding pass, no second full stamp or look-up.
"""

from __future__ import annotations

import math

import numpy as np
from reconstruction._jit import njit


@njit
def _row_from(xu, a, b, x0):
    """The first index in [a, b) of a row's pixels (columns ascending) with column ≥ x0 (binary search)."""
    while a < b:
        mid = (a + b) >> 1
        if xu[mid] < x0:
            a = mid + 1
        else:
            b = mid
    return a


@njit
def unsuppressed_seeds(xu, xv, xs, seed, cell, m, sx, sy, n_ring, r_mask, n_line):
    """Crossing pixels (xu, xv int, row-major: rows xv ascending, columns ascending in a row; xs float32 score; seed:
    the maxima `crossing_seeds` flagged) that are the maximum over their 3×3 cells once the pixels within `r_mask` of
    a line's own blob are left out, were no maximum before, and have a left-out pixel in their 3×3 cells. A line's
    own blob: a candidate (sx, sy) whose ring (n_ring (ns, 2)) holds no sample of one family and at least `n_line`
    of the other. m: the cells' maxima `crossing_seeds_max` used ((gh, gw) float32; overwritten: a cell holding a
    left-out pixel gets −1 − the maximum of its other pixels). Only the pixels around the blobs are read. Returns
    (pixel ids (k,) int64, masked (n,) bool)."""
    ns = len(sx)
    n = len(xs)
    gh, gw = m.shape
    masked = np.zeros(n, np.bool_)
    if n == 0:
        return np.zeros(0, np.int64), masked
    H = xv[n - 1] + 1
    rs = np.empty(H + 1, np.int64)  # pixels of row y: rs[y] .. rs[y + 1]
    j = 0
    for y in range(H + 1):
        while j < n and xv[j] < y:
            j += 1
        rs[y] = j
    r2 = r_mask * r_mask
    hit = np.empty((n, 2), np.int64)  # the cells holding a left-out pixel
    nh = 0
    for k in range(ns):  # the pixels within r_mask of a blob
        if not (min(n_ring[k, 0], n_ring[k, 1]) == 0 and max(n_ring[k, 0], n_ring[k, 1]) >= n_line):
            continue
        for y in range(max(int(math.floor(sy[k] - r_mask)), 0), min(int(math.floor(sy[k] + r_mask)) + 1, H)):
            dy = np.float64(y) - sy[k]
            if dy * dy > r2:
                continue
            for i in range(_row_from(xu, rs[y], rs[y + 1], sx[k] - r_mask), rs[y + 1]):
                dx = np.float64(xu[i]) - sx[k]
                if dx > r_mask:
                    break
                if dx * dx + dy * dy <= r2 and not masked[i]:
                    masked[i] = True
                    a = int(xv[i] / cell)
                    c = int(xu[i] / cell)
                    if m[a, c] >= 0:
                        m[a, c] = np.float32(-1.0)
                        hit[nh, 0] = a
                        hit[nh, 1] = c
                        nh += 1
    for t in range(nh):  # a hit cell: −1 − the maximum of its pixels left in
        a = hit[t, 0]
        c = hit[t, 1]
        for y in range(max(int(a * cell), 0), min(int((a + 1) * cell) + 1, H)):
            for i in range(_row_from(xu, rs[y], rs[y + 1], int(c * cell)), rs[y + 1]):
                if xu[i] > (c + 1) * cell:
                    break
                if int(xv[i] / cell) == a and int(xu[i] / cell) == c and not masked[i]:
                    m[a, c] = min(m[a, c], np.float32(-1.0) - xs[i])
    out = np.empty(n, np.int64)
    done = np.zeros(n, np.bool_)
    k = 0
    for t in range(nh):  # the pixels of the cells around each hit cell
        for a in range(max(hit[t, 0] - 1, 0), min(hit[t, 0] + 2, gh)):
            for c in range(max(hit[t, 1] - 1, 0), min(hit[t, 1] + 2, gw)):
                for y in range(max(int(a * cell), 0), min(int((a + 1) * cell) + 1, H)):
                    for i in range(_row_from(xu, rs[y], rs[y + 1], int(c * cell)), rs[y + 1]):
                        if xu[i] > (c + 1) * cell:
                            break
                        if done[i] or masked[i] or seed[i] or int(xv[i] / cell) != a or int(xu[i] / cell) != c:
                            continue
                        done[i] = True
                        best = np.float32(0.0)
                        for rr in range(max(a - 1, 0), min(a + 2, gh)):
                            for cc in range(max(c - 1, 0), min(c + 2, gw)):
                                v = m[rr, cc]
                                best = max(best, np.float32(-1.0) - v if v < 0 else v)
                        if xs[i] >= best:
                            out[k] = i
                            k += 1
    out = np.sort(out[:k])
    return out, masked


@njit
def new_candidates(ids, xu, xv, xs, masked, rc, sx, sy, n_ring, r0, r_att, qx, qy, fam, near, dist, row_start, v_lo, v_hi):
    """The pixels `ids` (strongest first is not assumed) moved to the score-weighted centroid of the unmasked crossing
    pixels within `rc`, then dropped where within r0 of a candidate (sx, sy) or of a stronger new one, within
    r_att of a candidate with 2 ring samples of each family (n_ring), or with fewer than 2 samples of a family in
    its own ring: samples (qx, qy float32, family fam) in (r0, r_att] of it and nearer to it than to the candidate
    that holds them (near, dist). Returns positions (k, 2) float64 and scores (k,) float32 of the kept ones."""
    m = len(ids)
    cx = np.zeros(m)
    cy = np.zeros(m)
    for t in range(m):
        ax = np.float64(xu[ids[t]])
        ay = np.float64(xv[ids[t]])
        ws = 0.0
        su = 0.0
        sv = 0.0
        for i in range(np.searchsorted(xv, int(math.floor(ay - rc))), np.searchsorted(xv, int(math.floor(ay + rc)) + 1)):
            if masked[i]:
                continue
            if math.hypot(np.float64(xu[i]) - ax, np.float64(xv[i]) - ay) <= rc:
                w = np.float64(xs[i])
                ws += w
                su += w * xu[i]
                sv += w * xv[i]
        cx[t] = su / max(ws, 1e-12)
        cy[t] = sv / max(ws, 1e-12)
    ok = np.ones(m, np.bool_)
    ns = len(sx)
    for t in range(m):
        for k in range(ns):
            if abs(cx[t] - sx[k]) > r_att or abs(cy[t] - sy[k]) > r_att:
                continue
            d = math.hypot(cx[t] - sx[k], cy[t] - sy[k])
            if d <= r0 or (d <= r_att and n_ring[k, 0] >= 2 and n_ring[k, 1] >= 2):
                ok[t] = False
                break
    for t in range(m):  # two new maxima of one blob: the stronger (ties: the first)
        if not ok[t]:
            continue
        for s in range(m):
            if s != t and ok[s] and math.hypot(cx[t] - cx[s], cy[t] - cy[s]) <= r0:
                if xs[ids[s]] > xs[ids[t]] or (xs[ids[s]] == xs[ids[t]] and s < t):
                    ok[t] = False
                    break
    ra = np.float32(r_att)
    r0f = np.float32(r0)
    for t in range(m):
        if not ok[t]:
            continue
        c1 = 0
        c2 = 0
        x32 = np.float32(cx[t])
        y32 = np.float32(cy[t])
        lo = max(int(cy[t] - r_att) - 1, v_lo)
        hi = min(int(cy[t] + r_att) + 2, v_hi)
        for i in range(row_start[lo], row_start[hi]):
            dx = qx[i] - x32
            dy = qy[i] - y32
            d = np.float32(math.sqrt(dx * dx + dy * dy))
            if d <= ra and d > r0f and (near[i] < 0 or d < dist[i]):
                if fam[i] == 1:
                    c1 += 1
                else:
                    c2 += 1
        ok[t] = c1 >= 2 and c2 >= 2
    k = 0
    for t in range(m):
        k += ok[t]
    pos = np.empty((k, 2))
    sc = np.empty(k, np.float32)
    j = 0
    for t in range(m):
        if ok[t]:
            pos[j, 0] = cx[t]
            pos[j, 1] = cy[t]
            sc[j] = xs[ids[t]]
            j += 1
    return pos, sc


@njit
def stamp_more(cx, cy, first, radius, cs, grid, pad):
    """`_extract_kernels.stamp` of the centres from `first` on onto a grid that holds the earlier ones already (the
    result is that of stamping them all in one call: the nearer centre to a cell's centre, ties the later)."""
    GH, GW = grid.shape
    gh = GH - 2 * pad
    gw = GW - 2 * pad
    n = len(cx)
    rr = min(int(math.ceil(radius / cs)) + 1, pad - 1)
    lim = (radius + cs) ** 2
    lo = 1 - pad + rr
    hix = gw + pad - rr - 2
    hiy = gh + pad - rr - 2
    c0x = np.empty(n, np.int64)
    c0y = np.empty(n, np.int64)
    fx = np.empty(n, np.float32)
    fy = np.empty(n, np.float32)
    for i in range(n):
        ccx = cx[i] / cs
        ccy = cy[i] / cs
        c0x[i] = min(max(int(ccx), lo), hix)
        c0y[i] = min(max(int(ccy), lo), hiy)
        fx[i] = np.float32(ccx - c0x[i] - 0.5)
        fy[i] = np.float32(ccy - c0y[i] - 0.5)
    for i in range(first, n):
        for oy in range(-rr, rr + 1):
            dy = np.float32(oy) - fy[i]
            dy2 = dy * dy
            r = c0y[i] + pad + oy
            for ox in range(-rr, rr + 1):
                if np.float64(ox * ox + oy * oy) * cs * cs > lim:
                    continue
                dx = np.float32(ox) - fx[i]
                d2 = dx * dx + dy2
                c = c0x[i] + pad + ox
                o = grid[r, c]
                if o >= 0:
                    odx = np.float32(c - pad - c0x[o]) - fx[o]
                    ody = np.float32(r - pad - c0y[o]) - fy[o]
                    if d2 > odx * odx + ody * ody:
                        continue
                grid[r, c] = i


@njit
def relook(grid, qx, qy, inv_cs, pad, cx, cy, first, rmax, reach, r0, fam, near, dist, n_ring, row_start, v_lo, v_hi):
    """`_extract_kernels.look_dist` again (in place: near, dist) for the samples in the rows within `reach` of the
    centres from `first` on, and the ring counts (n_ring (n, 2), in place; the rows from `first` on zero on entry)
    moved with the samples whose candidate changed (`ring_counts`: beyond r0 of it)."""
    GH, GW = grid.shape
    n = len(cx)
    for t in range(first, n):  # a sample in two windows is looked at twice: the same answer, the counts unchanged
        lo = max(int(cy[t] - reach) - 1, v_lo)
        hi = min(int(cy[t] + reach) + 2, v_hi)
        if lo >= hi:
            continue
        for i in range(row_start[lo], row_start[hi]):
            c = min(max(int(qx[i] * inv_cs) + pad, 0), GW - 1)
            r = min(max(int(qy[i] * inv_cs) + pad, 0), GH - 1)
            k = grid[r, c]
            kn = -1
            dn = np.float32(np.inf)
            if k >= 0:
                dx = qx[i] - cx[k]
                dy = qy[i] - cy[k]
                dn = np.float32(math.sqrt(dx * dx + dy * dy))
                if dn <= rmax:
                    kn = k
            ko = near[i]
            if ko >= 0 and dist[i] > r0:
                n_ring[ko, fam[i] - 1] -= 1
            if kn >= 0 and dn > r0:
                n_ring[kn, fam[i] - 1] += 1
            near[i] = kn
            dist[i] = dn



@njit
def past_blobs(cx, cy, first, n_ring, n_line, near_px, r_att, qx, qy, fam, row_start, v_lo, v_hi, drop):
    """Samples past the line's own blobs that released the new candidates (decision 0153): for each new candidate
    (cx, cy from `first` on) and each line's own blob (a candidate before `first`, `n_ring` as in
    `unsuppressed_seeds`) within `near_px` of it, the samples of the blob's line within `r_att` of the blob on the
    side away from the new candidate ((q − blob)·(blob − new) > 0) are flagged in `drop` (P,) bool, in place.
    Returns the number flagged."""
    n = len(cx)
    nd = 0
    own = np.empty(first, np.int64)  # the line's own blobs, listed once
    no = 0
    for b in range(first):
        a0, a1 = n_ring[b, 0], n_ring[b, 1]
        if min(a0, a1) == 0 and max(a0, a1) >= n_line:
            own[no] = b
            no += 1
    for t in range(first, n):
        for ib in range(no):
            b = own[ib]
            a0 = n_ring[b, 0]
            ux = cx[b] - cx[t]
            uy = cy[b] - cy[t]
            if ux * ux + uy * uy > near_px * near_px:
                continue
            f = 1 if a0 > 0 else 2
            lo = max(int(cy[b] - r_att) - 1, v_lo)
            hi = min(int(cy[b] + r_att) + 2, v_hi)
            if lo >= hi:
                continue
            for i in range(row_start[lo], row_start[hi]):
                if fam[i] != f or drop[i]:
                    continue
                dx = np.float64(qx[i]) - cx[b]
                dy = np.float64(qy[i]) - cy[b]
                if dx * dx + dy * dy <= r_att * r_att and dx * ux + dy * uy > 0:
                    drop[i] = True
                    nd += 1
    return nd
