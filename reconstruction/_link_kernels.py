"""Compiled links between trace pieces across a crossing's gap (decision 0072; numba, one thread, 0062).

`facing_links_mid` replaces the per-end lateral test of `_continuation_kernels.facing_links` by a test at
the gap's middle: both ends' tangent lines, extrapolated over half the gap, must meet there within
`lateral`. A line that bends smoothly (a curved surface) passes whatever the gap's length: by symmetry the
two extrapolations meet at the arc's apex, their first-order deviations cancel. A line that continues on
another surface, or a neighbouring line, is offset sideways by δ on the far side and the two points are δ
apart, as in the per-end test.
"""

from __future__ import annotations

import math

import numpy as np

from reconstruction._jit import njit


@njit
def _forward_cell(nb, cx, cy):
    """The nb-th (0..4) of a cell and its forward neighbours: every pair of cells is visited once."""
    if nb == 0:
        return cx, cy
    if nb == 1:
        return cx + 1, cy
    if nb == 2:
        return cx - 1, cy + 1
    if nb == 3:
        return cx, cy + 1
    return cx + 1, cy + 1


@njit
def _facing_pair(e, u, i0, j0, ex, ey, r2, cos_facing, lat2):
    """The pair test of `facing_links_mid` for ends i0 (at ex, ey) and j0: (ok, i, j, swapped, g²), i < j the
    end ids, swapped when i is j0; the gap vector runs from the lower end id to the higher (negation exact)."""
    w0 = e[j0, 0] - ex
    w1 = e[j0, 1] - ey
    g2 = w0 * w0 + w1 * w1
    if g2 >= r2:
        return False, i0, j0, False, g2
    if i0 < j0:
        i, j, swap, v0, v1 = i0, j0, False, w0, w1
    else:
        i, j, swap, v0, v1 = j0, i0, True, -w0, -w1
    if u[i, 0] * u[j, 0] + u[i, 1] * u[j, 1] >= -cos_facing:
        return False, i, j, swap, g2
    if v0 * u[i, 0] + v1 * u[i, 1] <= 0 or v0 * u[j, 0] + v1 * u[j, 1] >= 0:
        return False, i, j, swap, g2
    h = 0.5 * math.sqrt(g2)
    d0 = (e[i, 0] + h * u[i, 0]) - (e[j, 0] + h * u[j, 0])
    d1 = (e[i, 1] + h * u[i, 1]) - (e[j, 1] + h * u[j, 1])
    return d0 * d0 + d1 * d1 <= lat2, i, j, swap, g2


@njit
def facing_links_mid(e, u, f_e, n_p, labelled, reach, lateral, cos_facing):
    """Pairs of piece ends (a, b piece ids, gap length, end ids i < j) of one family, on different pieces not
    both labelled, closer than reach, facing each other (directions more opposite than cos_facing), each
    end beyond the other, whose tangent lines extrapolated to the middle of the gap (e + g/2 · u) are
    within `lateral` of each other. e (2n_p, 2) end positions, u (2n_p, 2) outward unit directions, f_e
    (2n_p,) families (rows as `_continuation_kernels.piece_ends`). Ends are bucketed per family in cells
    `reach` wide; every pair of a cell and its forward neighbours is looked at once; an end of a labelled
    piece looks only at the ends of unlabelled pieces (listed per bucket, in bucket order: decision 0090)."""
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
    # each bucket's ends of unlabelled pieces (their positions in items, increasing): a labelled end's
    # partners are only those (decision 0090: the same pairs in the same order, without visiting the
    # labelled–labelled ones)
    ustart = np.zeros(2 * ng + 1, np.intp)
    for t in range(start[2 * ng]):
        k = items[t]
        if not labelled[k - n_p if k >= n_p else k]:
            ustart[key[k] + 1] += 1
    for k in range(2 * ng):
        ustart[k + 1] += ustart[k]
    upos = np.empty(ustart[2 * ng], np.intp)
    nu = 0
    for t in range(start[2 * ng]):
        k = items[t]
        if not labelled[k - n_p if k >= n_p else k]:
            upos[nu] = t
            nu += 1
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
                        xx, yy = _forward_cell(nb, cx, cy)
                        if xx < 0 or xx >= gw or yy >= gh:
                            continue
                        bn = base + yy * gw + xx
                        # a labelled end reads only the unlabelled ends of the bucket (ustart/upos), others all
                        lo = ustart[bn] if lab0 else (s + 1 if nb == 0 else start[bn])
                        hi = ustart[bn + 1] if lab0 else start[bn + 1]
                        for ut in range(lo, hi):
                            t = upos[ut] if lab0 else ut
                            if lab0 and nb == 0 and t <= s:
                                continue
                            j0 = items[t]
                            p1 = j0 - n_p if j0 >= n_p else j0
                            if p0 == p1:
                                continue
                            ok, i, j, swap, g2 = _facing_pair(e, u, i0, j0, ex, ey, r2, cos_facing, lat2)
                            if not ok:
                                continue
                            if nl == out_a.shape[0]:
                                break
                            out_a[nl] = p1 if swap else p0
                            out_b[nl] = p0 if swap else p1
                            out_g[nl] = math.sqrt(g2)
                            out_i[nl] = i
                            out_j[nl] = j
                            nl += 1
    return out_a[:nl], out_b[:nl], out_g[:nl], out_i[:nl], out_j[:nl]


# --- continuation._check_pieces' gathers (glue round five, decision 0087) ------------------------------------


@njit
def _as_int64(x):
    """int64(x) as NumPy's float → int64 cast gives it on x86-64 (NaN, ±inf, beyond int64: INT64_MIN)."""
    if not (abs(x) < 9.2e18):
        return np.iinfo(np.int64).min
    return np.int64(x)


@njit
def check_ends(cand, n_p, e, u, f_e):
    """The two ends of pieces cand (nc,): first ends then last ends (rows cand and cand + n_p of e, u (2·n_p, 2)
    and f_e (2·n_p,)), as (2·nc, 2), (2·nc, 2), (2·nc,) arrays."""
    nc = cand.shape[0]
    E = np.empty((2 * nc, 2))
    U = np.empty((2 * nc, 2))
    fe = np.empty(2 * nc, f_e.dtype)
    for h in range(2):
        for i in range(nc):
            r = cand[i] + h * n_p
            k = h * nc + i
            E[k, 0] = e[r, 0]
            E[k, 1] = e[r, 1]
            U[k, 0] = u[r, 0]
            U[k, 1] = u[r, 1]
            fe[k] = f_e[r]
    return E, U, fe


@njit
def check_hits(o, c, fe, k_of, cand):
    """The ends (rows of `check_ends`) with a crossing (o ≥ 0): sel (K,) intp, their crossings (K, 2), their
    family (K,) and their piece's chain index k_of[cand[row mod nc]] as int64 (K,)."""
    R = o.shape[0]
    nc = cand.shape[0]
    k = 0
    for r in range(R):
        k += o[r] >= 0
    sel = np.empty(k, np.intp)
    c_sel = np.empty((k, 2))
    f_sel = np.empty(k, fe.dtype)
    kk = np.empty(k, np.int64)
    i = 0
    for r in range(R):
        if o[r] < 0:
            continue
        sel[i] = r
        c_sel[i, 0] = c[r, 0]
        c_sel[i, 1] = c[r, 1]
        f_sel[i] = fe[r]
        kk[i] = _as_int64(k_of[cand[r % nc]])
        i += 1
    return sel, c_sel, f_sel, kk


@njit
def check_verdicts(o, sel, res, tol, nc):
    """Per piece (nc,): at least one end evaluated (o ≥ 0) and none whose crossing lies farther than tol from
    a line (res (K,) at rows sel)."""
    passed = np.zeros(2 * nc, np.bool_)
    for i in range(sel.shape[0]):
        passed[sel[i]] = res[i] <= tol
    good = np.empty(nc, np.bool_)
    for i in range(nc):
        ev0 = o[i] >= 0
        ev1 = o[nc + i] >= 0
        fail = (ev0 and not passed[i]) or (ev1 and not passed[nc + i])
        good[i] = (ev0 or ev1) and not fail
    return good


@njit
def check_samples(pos, q, sid, fam, piece, k_of):
    """The samples at trace positions pos: positions (N, 2), families (N,) and their piece's chain index
    k_of[piece] as int64 (N,)."""
    N = pos.shape[0]
    qq = np.empty((N, 2))
    ff = np.empty(N, fam.dtype)
    kk = np.empty(N, np.int64)
    for i in range(N):
        s = sid[pos[i]]
        qq[i, 0] = q[s, 0]
        qq[i, 1] = q[s, 1]
        ff[i] = fam[s]
        kk[i] = _as_int64(k_of[piece[pos[i]]])
    return qq, ff, kk


@njit
def check_depth(good, cand, pos, piece, z, z_min, z_max, n_p):
    """good (nc,) &= no sample of the piece (positions pos, depths z) outside [z_min, z_max] (in place)."""
    bad = np.zeros(n_p, np.bool_)
    for i in range(pos.shape[0]):
        if not (z[i] >= z_min and z[i] <= z_max):
            bad[piece[pos[i]]] = True
    for i in range(cand.shape[0]):
        if bad[cand[i]]:
            good[i] = False


@njit
def linked_unlabelled(n_p, a, b, labelled, k_of):
    """continue_lines' pieces to check: linked (an end of a link a, b), unlabelled, with a chain index (finite
    k_of), in increasing order (= np.flatnonzero(linked & ~labelled & np.isfinite(k_of)))."""
    linked = np.zeros(n_p, np.bool_)
    for i in range(a.shape[0]):
        linked[a[i]] = True
        linked[b[i]] = True
    out = np.empty(n_p, np.intp)
    m = 0
    for p in range(n_p):
        if linked[p] and not labelled[p] and math.isfinite(k_of[p]):
            out[m] = p
            m += 1
    return out[:m]


@njit
def checked_pieces(labelled, cand, good):
    """keep = labelled plus the pieces cand[good] (n_p,), new = the pieces cand[good] only, and the number of
    pieces in cand that failed."""
    keep = labelled.copy()
    new = np.zeros(labelled.shape[0], np.bool_)
    n_failed = 0
    for i in range(cand.shape[0]):
        if good[i]:
            keep[cand[i]] = True
            new[cand[i]] = True
        else:
            n_failed += 1
    return keep, new, n_failed


@njit
def with_index(new, k_of):
    """new &= isfinite(k_of) in place; returns whether any piece is left."""
    anyp = False
    for p in range(new.shape[0]):
        if new[p] and not math.isfinite(k_of[p]):
            new[p] = False
        anyp |= new[p]
    return anyp
