"""Seeds beyond a depth edge at their junction (decision 0146).

A labelled junction's seeds are the samples within the junction radius that lie within `seed_lateral_px` of its
fitted lines (step 3 of the sample labelling). A junction that sits within that radius of a silhouette takes
samples of the other surface too wherever a line there continues one of its own lines in the image (a lattice
vector of the grid along the epipolar lines maps the pattern onto itself across the edge): those samples lie on
trace pieces of their own (the trace is cut at the edge, or the mixing zone cuts it), and the whole piece then
takes the junction's index, one or several lattice vectors off, and later steps (the limb step 9e above all)
copy it to the neighbouring lines of that surface.

The two surfaces return different light: the ridge brightness of a line depends on the surface's distance,
orientation and albedo, and changes little along a line on one surface (step 7's trace cut uses it between two
consecutive samples). Here the seeds a junction puts on one trace piece are taken back when their median ridge
brightness differs from the median over all that junction's seeds of the same family (its line on both sides of
the crossing; the two families' ridges differ by their width in the image, so they are not pooled) by more than
`TraceOptions.seed_brightness_share` (0.2) of the larger of the two. All the seeds lie within the junction radius
of one crossing, so shading and distance hardly change between them. The share is the smallest of 0.15, 0.2, 0.25
and 0.3 that costs no bench scene more than 0.1 coverage points (0.15: tabletop −0.19); on the 8 bench scenes and
16 unseen seeds other than 185, 0.2 is as accurate as 0.25 or more on every one (decision 0146). A piece on the
junction's own surface keeps its seeds; the others are not seeded by that junction (another junction, or a later
step, may label them). It never writes an index.
"""

from __future__ import annotations

import numpy as np

from reconstruction._jit import njit
from reconstruction._label_kernels import nearest_seed


@njit
def _group_medians(key, val, n_groups):
    """Median of val over each key in 0..n_groups−1 (NaN where a group is empty). Each group's values are kept
    sorted as they are placed (insertion into the group's segment; a group is one junction line's seeds, a few
    to a few tens), which needs no allocation per group."""
    cnt = np.zeros(n_groups + 1, np.intp)
    for k in range(key.shape[0]):
        cnt[key[k] + 1] += 1
    for g in range(n_groups):
        cnt[g + 1] += cnt[g]
    buf = np.empty(key.shape[0], np.float64)
    fill = cnt[:-1].copy()
    for k in range(key.shape[0]):
        g = key[k]
        t = fill[g]
        v = val[k]
        while t > cnt[g] and buf[t - 1] > v:
            buf[t] = buf[t - 1]
            t -= 1
        buf[t] = v
        fill[g] += 1
    med = np.full(n_groups, np.nan)
    for g in range(n_groups):
        if cnt[g + 1] > cnt[g]:
            med[g] = _median_sorted(buf, cnt[g], cnt[g + 1])
    return med


@njit
def _median_sorted(v, a, b):
    m = b - a
    return v[a + m // 2] if m % 2 else 0.5 * (v[a + m // 2 - 1] + v[a + m // 2])


@njit
def drop_seeds_off_brightness(sid, piece, fam, seed, seed_jid, ridge, max_step, unlabelled):
    """Take back (seed → unlabelled, seed_jid → −1, in place) a junction's seeds of one family on one trace piece
    when their median ridge brightness differs from the median over all that junction's seeds of that family by
    more than max_step × the larger of the two. sid (n,): the kept samples in trace order, each piece one run of
    positions (as the trace kernels give them); piece (n,): their piece; fam (P,): every sample's family (1, 2).
    Returns the number of seeds taken back.

    One pass over the samples (in trace order) reads what the rest needs into arrays that are then read in
    order: the samples are scattered in the per-sample arrays, the positions are not."""
    n = sid.shape[0]
    key = np.empty(n, np.intp)  # each position's junction line (2·junction + [family 2]); −1: not a seed
    n_j = 0
    n_s = 0
    for k in range(n):
        s = sid[k]
        if seed[s] != unlabelled and seed_jid[s] >= 0:
            kk = 2 * seed_jid[s] + (1 if fam[s] == 2 else 0)
            key[k] = kk
            n_s += 1
            if kk + 1 > n_j:
                n_j = kk + 1
        else:
            key[k] = -1
    if n_s == 0:
        return 0
    jk = np.empty(n_s, np.intp)
    jv = np.empty(n_s, np.float64)  # the seeds' ridge brightness, in position order
    m = 0
    for k in range(n):
        if key[k] >= 0:
            jk[m] = key[k]
            jv[m] = ridge[sid[k]]
            m += 1
    line_med = _group_medians(jk, jv, n_j)
    # per piece (one run of positions): its seeds grouped by junction line, each group's values kept sorted
    gkey = np.empty(n_s, np.intp)  # the piece's junction lines, in order of first appearance
    gcnt = np.empty(n_s + 1, np.intp)
    gof = np.empty(n_s, np.intp)  # each of the piece's seeds: its group
    val = np.empty(n_s, np.float64)
    pos = np.empty(n_s, np.intp)
    fill = np.empty(n_s, np.intp)
    dropped = 0
    m = 0  # seeds before this piece
    a = 0
    while a < n:
        b = a + 1
        while b < n and piece[b] == piece[a]:
            b += 1
        d = 0
        c = 0
        last = -1
        for k in range(a, b):
            kk = key[k]
            if kk >= 0:
                if last >= 0 and gkey[last] == kk:
                    g = last
                else:
                    g = -1
                    for t in range(d):
                        if gkey[t] == kk:
                            g = t
                            break
                    if g < 0:
                        g = d
                        gkey[d] = kk
                        gcnt[d + 1] = 0
                        d += 1
                gcnt[g + 1] += 1
                gof[c] = g
                c += 1
                last = g
        if c:
            gcnt[0] = 0
            for g in range(d):
                gcnt[g + 1] += gcnt[g]
                fill[g] = gcnt[g]
            c = 0
            for k in range(a, b):
                if key[k] >= 0:
                    g = gof[c]
                    v = jv[m + c]
                    c += 1
                    t = fill[g]
                    while t > gcnt[g] and val[t - 1] > v:
                        val[t] = val[t - 1]
                        pos[t] = pos[t - 1]
                        t -= 1
                    val[t] = v
                    pos[t] = sid[k]
                    fill[g] += 1
            m += c
            for g in range(d):
                g0, g1 = gcnt[g], gcnt[g + 1]
                pm = _median_sorted(val, g0, g1)
                lm = line_med[gkey[g]]
                if abs(pm - lm) > max_step * max(pm, lm):
                    for t in range(g0, g1):
                        seed[pos[t]] = unlabelled
                        seed_jid[pos[t]] = -1
                        dropped += 1
        a = b
    return dropped


@njit
def _insert_sorted(val, pos, g0, t, v, k):
    """Insert v (position k) into val[g0:t], sorted, as the group's t-th value: val[g0:t+1] sorted after."""
    while t > g0 and val[t - 1] > v:
        val[t] = val[t - 1]
        pos[t] = pos[t - 1]
        t -= 1
    val[t] = v
    pos[t] = k


@njit
def _take_back_off_brightness(sid, piece, fam, seed, seed_jid, ridge, max_step, unlabelled, sv, sj, has):
    """`drop_seeds_off_brightness` on the positions' seed values sv and junctions sj (n,) and has (sv ≠
    unlabelled), read once by the caller: the same groups, the same medians (each group's values inserted in
    position order, as there) and the same rule. A seed taken back is cleared in seed and seed_jid (per sample)
    and in sv, sj and has (per position). Returns the number taken back.

    A piece's seeds of one junction line usually form one run of positions (the samples near the junction):
    where every junction line of the piece is one run, each run is a group and is sorted on its own; otherwise
    the piece's seeds are grouped by a scan of its lines, as in `drop_seeds_off_brightness`."""
    n = sid.shape[0]
    key = np.empty(n, np.intp)  # each position's junction line (2·junction + [family 2]); −1: not a seed
    n_j = 0
    n_s = 0
    for k in range(n):
        if has[k] and sj[k] >= 0:
            kk = 2 * sj[k] + (1 if fam[sid[k]] == 2 else 0)
            key[k] = kk
            n_s += 1
            if kk + 1 > n_j:
                n_j = kk + 1
        else:
            key[k] = -1
    if n_s == 0:
        return 0
    jk = np.empty(n_s, np.intp)
    jv = np.empty(n_s, np.float64)  # the seeds' ridge brightness, in position order
    m = 0
    for k in range(n):
        if key[k] >= 0:
            jk[m] = key[k]
            jv[m] = ridge[sid[k]]
            m += 1
    line_med = _group_medians(jk, jv, n_j)
    rk = np.empty(n_s, np.intp)  # the piece's runs of one junction line: key, first position, first seed, length
    ra = np.empty(n_s, np.intp)
    rm = np.empty(n_s, np.intp)
    rl = np.empty(n_s, np.intp)
    gkey = np.empty(n_s, np.intp)  # the general grouping (a line in several runs of the piece)
    gcnt = np.empty(n_s + 1, np.intp)
    gof = np.empty(n_s, np.intp)
    fill = np.empty(n_s, np.intp)
    val = np.empty(n_s, np.float64)
    pos = np.empty(n_s, np.intp)
    dropped = 0
    m = 0  # seeds before this piece
    a = 0
    while a < n:
        b = a + 1
        while b < n and piece[b] == piece[a]:
            b += 1
        nr = 0
        c = 0
        for k in range(a, b):
            kk = key[k]
            if kk >= 0:
                if nr > 0 and rk[nr - 1] == kk and ra[nr - 1] + rl[nr - 1] == k:
                    rl[nr - 1] += 1
                else:
                    rk[nr] = kk
                    ra[nr] = k
                    rm[nr] = m + c
                    rl[nr] = 1
                    nr += 1
                c += 1
        if c == 0:
            a = b
            continue
        runs = True  # every junction line of the piece one run
        for i in range(1, nr):
            for t in range(i):
                if rk[t] == rk[i]:
                    runs = False
                    break
            if not runs:
                break
        if runs:
            for i in range(nr):
                for t in range(rl[i]):
                    _insert_sorted(val, pos, 0, t, jv[rm[i] + t], ra[i] + t)
                pm = _median_sorted(val, 0, rl[i])
                lm = line_med[rk[i]]
                if abs(pm - lm) > max_step * max(pm, lm):
                    for t in range(rl[i]):
                        k = pos[t]
                        seed[sid[k]] = unlabelled
                        seed_jid[sid[k]] = -1
                        sv[k] = unlabelled
                        sj[k] = -1
                        has[k] = False
                        dropped += 1
        else:
            d = 0
            for i in range(nr):
                g = -1
                for t in range(d):
                    if gkey[t] == rk[i]:
                        g = t
                        break
                if g < 0:
                    g = d
                    gkey[d] = rk[i]
                    gcnt[d + 1] = 0
                    d += 1
                gcnt[g + 1] += rl[i]
                gof[i] = g
            gcnt[0] = 0
            for g in range(d):
                gcnt[g + 1] += gcnt[g]
                fill[g] = gcnt[g]
            for i in range(nr):  # the runs in position order: each group's values inserted in position order
                g = gof[i]
                for t in range(rl[i]):
                    _insert_sorted(val, pos, gcnt[g], fill[g], jv[rm[i] + t], ra[i] + t)
                    fill[g] += 1
            for g in range(d):
                g0, g1 = gcnt[g], gcnt[g + 1]
                pm = _median_sorted(val, g0, g1)
                lm = line_med[gkey[g]]
                if abs(pm - lm) > max_step * max(pm, lm):
                    for t in range(g0, g1):
                        k = pos[t]
                        seed[sid[k]] = unlabelled
                        seed_jid[sid[k]] = -1
                        sv[k] = unlabelled
                        sj[k] = -1
                        has[k] = False
                        dropped += 1
        m += c
        a = b
    return dropped


@njit
def spread_checked_seeds(sid, piece, ts, fam, seed, seed_jid, index, ridge, max_step, check, unlabelled):
    """Steps 3b and 4 of labelling.label_samples in one pass over the trace positions: with check, the seeds
    `drop_seeds_off_brightness` takes back (same rule, same result), then `_label_kernels.spread_seeds` (every
    trace sample takes the index and junction of the nearest seed along its piece; junction −1 without one).
    The positions' seeds and junctions are read once, in trace order, for both (the samples are scattered in the
    per-sample arrays, the positions are not). Writes seed and seed_jid (the seeds taken back), index and seed_jid
    (the spread) in place. Returns got (n,) bool, the numbers of pieces with a seed and with disagreeing seeds, and
    the number of seeds taken back."""
    n = sid.shape[0]
    sv = np.empty(n, seed.dtype)  # each position's seed value and junction
    sj = np.empty(n, seed_jid.dtype)
    has = np.empty(n, np.bool_)
    for k in range(n):
        s = sid[k]
        v = seed[s]
        sv[k] = v
        sj[k] = seed_jid[s]
        has[k] = v != unlabelled
    dropped = 0
    if check:
        dropped = _take_back_off_brightness(sid, piece, fam, seed, seed_jid, ridge, max_step, unlabelled, sv, sj, has)
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
        v = sv[k]
        if pc != last_seeded:
            seeded += 1
            last_seeded = pc
        if pc == prev_piece and v != prev_val and pc != last_conflict:
            conflicting += 1
            last_conflict = pc
        prev_piece = pc
        prev_val = v
    got = near >= 0
    # a position's nearest seed is a seed position: its value and junction as read above (decision 0090's one pass)
    for k in range(n):
        if got[k]:
            index[sid[k]] = sv[near[k]]
            seed_jid[sid[k]] = sj[near[k]]
        else:
            seed_jid[sid[k]] = -1
    return got, seeded, conflicting, dropped
