"""Seeds beyond a depth edge at their junction (decision 0146).

A labelled junction's seeds are the samples within the junction radius that lie within `seed_lateral_px` of its
fitted lines (step 3 of the sample labelling). A junction that sits within that radius of a silhouette takes
samples of the other surface too wherever a line there continues one of its own lines in the image (a lattice
vector of the grid along the epipolar lines maps the pattern onto itself across the edge): those samples lie on
trace pieces of their own (the trace is cut at the edge, or the mixing zone cuts it), and the whole piece then
takes the junction's index, one or several lattice vectors off, and later steps (the limb step 9e above all)
copy it to the neighbouring lines of that surface.

The two surfaces return different light: the ridge brightness of a line depends on the surface's distance,
orientation and albedo, and is the same along a line on one surface (step 7's trace cut uses it between two
consecutive samples). Here a seeded piece whose median ridge brightness differs from the median over all of its
junction's seeds by more than step 7's share (`TraceOptions.max_ridge_step` of the larger of the two) is on
another surface than most of the junction's seeds: those seeds are taken back before the seeds spread along
the pieces. A piece on the junction's own surface keeps them.
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
def drop_seeds_off_brightness(sid, piece, seed, seed_jid, ridge, max_step, unlabelled):
    """Take back (seed → unlabelled, seed_jid → −1, in place) the seeds of a junction on a trace piece whose
    median ridge brightness differs from the median over all that junction's seeds by more than max_step × the
    larger of the two. sid (n,): the kept samples in trace order; piece (n,): their piece. Returns the number of
    seeds taken back."""
    n = sid.shape[0]
    if n == 0:
        return 0
    n_p = 0
    n_j = 0
    n_s = 0
    for k in range(n):
        if piece[k] + 1 > n_p:
            n_p = piece[k] + 1
        s = sid[k]
        if seed[s] != unlabelled and seed_jid[s] >= 0:
            n_s += 1
            if seed_jid[s] + 1 > n_j:
                n_j = seed_jid[s] + 1
    if n_s == 0:
        return 0
    rv = np.empty(n, np.float64)
    for k in range(n):
        rv[k] = ridge[sid[k]]
    piece_med = _group_medians(piece, rv, n_p)
    jk = np.empty(n_s, np.intp)
    jv = np.empty(n_s, np.float64)
    m = 0
    for k in range(n):
        s = sid[k]
        if seed[s] != unlabelled and seed_jid[s] >= 0:
            jk[m] = seed_jid[s]
            jv[m] = rv[k]
            m += 1
    junction_med = _group_medians(jk, jv, n_j)
    dropped = 0
    for k in range(n):
        s = sid[k]
        if seed[s] == unlabelled or seed_jid[s] < 0:
            continue
        a = piece_med[piece[k]]
        b = junction_med[seed_jid[s]]
        if abs(a - b) > max_step * max(a, b):
            seed[s] = unlabelled
            seed_jid[s] = -1
            dropped += 1
    return dropped
