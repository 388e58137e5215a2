"""The first version of decision 0146's seed check (an np.sort per junction line, and per piece an insertion sort
by (key, value) over the scattered samples), kept as the test reference of reconstruction.seed_brightness (as
decision 0097 kept its references). Verbatim from commit a7405de but for this paragraph.

Seeds beyond a depth edge at their junction (decision 0146).

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


@njit
def _group_medians(key, val, n_groups):
    """Median of val over each key in 0..n_groups−1 (NaN where a group is empty)."""
    cnt = np.zeros(n_groups + 1, np.intp)
    for k in range(key.shape[0]):
        cnt[key[k] + 1] += 1
    for g in range(n_groups):
        cnt[g + 1] += cnt[g]
    buf = np.empty(key.shape[0], np.float64)
    fill = cnt[:-1].copy()
    for k in range(key.shape[0]):
        g = key[k]
        buf[fill[g]] = val[k]
        fill[g] += 1
    med = np.full(n_groups, np.nan)
    for g in range(n_groups):
        a, b = cnt[g], cnt[g + 1]
        if b > a:
            s = np.sort(buf[a:b])
            m = b - a
            med[g] = s[m // 2] if m % 2 else 0.5 * (s[m // 2 - 1] + s[m // 2])
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
    Returns the number of seeds taken back."""
    n = sid.shape[0]
    n_j = 0
    n_s = 0
    for k in range(n):
        s = sid[k]
        if seed[s] != unlabelled and seed_jid[s] >= 0:
            n_s += 1
            if 2 * seed_jid[s] + 2 > n_j:
                n_j = 2 * seed_jid[s] + 2
    if n_s == 0:
        return 0
    # the median over each junction line's seeds (key 2·junction + [family 2])
    jk = np.empty(n_s, np.intp)
    jv = np.empty(n_s, np.float64)
    m = 0
    for k in range(n):
        s = sid[k]
        if seed[s] != unlabelled and seed_jid[s] >= 0:
            jk[m] = 2 * seed_jid[s] + (1 if fam[s] == 2 else 0)
            jv[m] = ridge[s]
            m += 1
    line_med = _group_medians(jk, jv, n_j)
    # per piece (one run of positions), the median over each junction line's seeds on it
    key = np.empty(n, np.intp)
    val = np.empty(n, np.float64)
    pos = np.empty(n, np.intp)
    dropped = 0
    a = 0
    while a < n:
        b = a + 1
        while b < n and piece[b] == piece[a]:
            b += 1
        c = 0
        for k in range(a, b):
            s = sid[k]
            if seed[s] != unlabelled and seed_jid[s] >= 0:
                kk = 2 * seed_jid[s] + (1 if fam[s] == 2 else 0)
                vv = float(ridge[s])
                # insertion sort by (key, value); a piece holds few seeds
                t = c
                while t > 0 and (key[t - 1] > kk or (key[t - 1] == kk and val[t - 1] > vv)):
                    key[t] = key[t - 1]
                    val[t] = val[t - 1]
                    pos[t] = pos[t - 1]
                    t -= 1
                key[t] = kk
                val[t] = vv
                pos[t] = s
                c += 1
        g0 = 0
        while g0 < c:
            g1 = g0 + 1
            while g1 < c and key[g1] == key[g0]:
                g1 += 1
            pm = _median_sorted(val, g0, g1)
            lm = line_med[key[g0]]
            if abs(pm - lm) > max_step * max(pm, lm):
                for t in range(g0, g1):
                    seed[pos[t]] = unlabelled
                    seed_jid[pos[t]] = -1
                    dropped += 1
            g0 = g1
        a = b
    return dropped
