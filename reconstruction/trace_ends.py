"""Seeded traces that run across a depth edge: the crossing at the far end names another line (decision 0084).

A trace piece takes the index k of the labelled junction whose seeds lie on it, out to both of its ends
(labelling.label_samples, step 4). Where a silhouette hides the rest of a line and another surface's line
continues it in the image *exactly* (collinear, no sideways jump, no turn), the trace runs on across the
silhouette and the other surface's samples are triangulated on the wrong light sheet. No test on the trace
alone can see this: the camera plane through the image line meets light sheet k in one 3D line, and every
sample of the image line, on either surface, triangulates onto it, so depth along the trace on sheet k stays
continuous (measured: 0.3–0.5 mm per sample across a 300 mm silhouette; decision 0084).

What does see it is the other family. A piece ends at a crossing's gap (the mixing zone is cut out of the
traces); where that crossing is with a labelled line m of the other family, the camera ray of the crossing
c meets light sheet m at a projector point that must lie on line k of the piece's family if the piece and
line m are on one surface (the check of decision 0052, `RigModel.sheet_check`). If it names another line
k' ≠ k within `cross_residual_px`, inside the depth range, the stretch of the piece between its outermost
seed and that end is not on line k's surface all the way: its samples lose the label (the seeded stretch
and the other side keep it; the stretch is not relabelled k': the edge lies somewhere inside it).
"""

from __future__ import annotations

import math

import numpy as np

from reconstruction._jit import njit


@njit
def seeded_far_ends(sid, piece, seed, index, unlabelled, q, tangent, fam, min_samples):
    """The ends of seeded trace pieces beyond their seeds.

    Trace positions in order (sid (n,) sample ids, piece (n,) non-decreasing from 0); seed (P,) the junction
    index of seed samples (unlabelled elsewhere); index (P,) float: the samples' line index. For every piece
    whose seeds all carry one value and that has at least min_samples labelled samples past its outermost seed
    towards an end: the end sample's position e (E, 2), its tangent te (E, 2), sign (E,) (−1 first end, +1
    last end), family fe (E,), the piece's index k (E,), and the trace positions lo, hi (E,) of the stretch
    between the seed and that end (inclusive). One pass."""
    n = sid.shape[0]
    n_pieces = piece[n - 1] + 1 if n else 0
    e = np.empty((2 * n_pieces, 2))
    te = np.empty((2 * n_pieces, 2))
    sign = np.empty(2 * n_pieces)
    fe = np.empty(2 * n_pieces, np.int64)
    kk = np.empty(2 * n_pieces, np.int64)
    lo = np.empty(2 * n_pieces, np.intp)
    hi = np.empty(2 * n_pieces, np.intp)
    c = 0
    a = 0
    while a < n:
        p = piece[a]
        fs = -1
        ls = -1
        v = unlabelled
        one = True
        b = a
        while b < n and piece[b] == p:
            s = seed[sid[b]]
            if s != unlabelled:
                if fs < 0:
                    fs = b
                    v = s
                elif s != v:
                    one = False
                ls = b
            b += 1
        b -= 1
        if fs >= 0 and one:
            for side in range(2):
                if side == 0:
                    k_end = a
                    k_lo = a
                    k_hi = fs - 1
                else:
                    k_end = b
                    k_lo = ls + 1
                    k_hi = b
                if k_hi - k_lo + 1 < min_samples:
                    continue
                x = index[sid[k_end]]
                if not math.isfinite(x):
                    continue
                e[c, 0] = q[sid[k_end], 0]
                e[c, 1] = q[sid[k_end], 1]
                te[c, 0] = tangent[k_end, 0]
                te[c, 1] = tangent[k_end, 1]
                sign[c] = -1.0 if side == 0 else 1.0
                fe[c] = fam[sid[k_end]]
                kk[c] = int(x)
                lo[c] = k_lo
                hi[c] = k_hi
                c += 1
        a = b + 1
    return e[:c], te[:c], sign[:c], fe[:c], kk[:c], lo[:c], hi[:c]


@njit
def unlabel_stretches(cut, lo, hi, sign, beyond, sid, ridge, use_ridge, index, seed_jid):
    """For the rows r with cut[r]: the stretch lo[r]..hi[r] (trace positions; the seed beyond hi when
    sign −1, beyond lo when sign +1) loses its label from the largest step of the ridge brightness between
    consecutive samples (the seed's sample included) out to its end (the whole stretch without ridge);
    nothing when the largest step is the one across the crossing, from the end to beyond[r] (the line's first
    sample past the crossing; −1: none): the edge is at the crossing. index = NaN, seed_jid = −1 there.
    Returns how many samples lost their label."""
    m = 0
    for r in range(cut.shape[0]):
        if not cut[r]:
            continue
        a = lo[r]
        b = hi[r]
        if use_ridge:
            best = -1.0
            across = -1.0
            if beyond[r] >= 0:
                across = abs(ridge[beyond[r]] - ridge[sid[a if sign[r] < 0 else b]])
            if sign[r] < 0:
                # steps (k, k+1) for k in lo..hi (hi+1: the seed side); unlabel lo..k
                at = b
                for k in range(lo[r], hi[r] + 1):
                    d = abs(ridge[sid[k + 1]] - ridge[sid[k]])
                    if d > best:
                        best = d
                        at = k
                b = at
            else:
                at = a
                for k in range(lo[r], hi[r] + 1):
                    d = abs(ridge[sid[k]] - ridge[sid[k - 1]])
                    if d > best:
                        best = d
                        at = k
                a = at
            if across > best:
                continue
        for k in range(a, b + 1):
            s = sid[k]
            if math.isfinite(index[s]):
                index[s] = np.nan
                seed_jid[s] = -1
                m += 1
    return m


@njit
def line_goes_on(c, e, te, sign, fe, q, fam, lateral_px, x0, y0, cell, gw, gh, start, items, pos_of):
    """For each crossing c (E, 2) at the end e (E, 2) of a piece (tangent te, sign −1 first / +1 last end,
    family fe): is there a sample of family fe past the crossing, on the end's tangent line (within
    lateral_px across it) and no farther beyond c than the end is before it plus 2 px? (E,) bool. A line
    that goes on through the crossing makes an X (both lines on one surface there); a line that ends at it
    (a T: a silhouette next to another surface's line) does not. Candidates: the valid samples of the
    frame's bucket grid. Also (E,) the sample on a trace (pos_of ≥ 0, outside the mixing zone) among them
    farthest past c (−1: none): the line's first sample beyond the crossing's gap."""
    E = c.shape[0]
    out = np.zeros(E, np.bool_)
    beyond = np.full(E, -1, np.intp)
    for r in range(E):
        dx = sign[r] * te[r, 0]
        dy = sign[r] * te[r, 1]
        gap = (c[r, 0] - e[r, 0]) * dx + (c[r, 1] - e[r, 1]) * dy
        reach = max(gap, 0.0) + 2.0
        best = -1.0
        cx = int(math.floor((c[r, 0] - x0) / cell))
        cy = int(math.floor((c[r, 1] - y0) / cell))
        for yy in range(max(cy - 1, 0), min(cy + 2, gh)):
            for xx in range(max(cx - 1, 0), min(cx + 2, gw)):
                b = yy * gw + xx
                for t in range(start[b], start[b + 1]):
                    s = items[t]
                    if fam[s] != fe[r]:
                        continue
                    wx = q[s, 0] - c[r, 0]
                    wy = q[s, 1] - c[r, 1]
                    a = wx * dx + wy * dy
                    if a > 0.5 and a <= reach and abs(wx * dy - wy * dx) <= lateral_px:
                        out[r] = True
                        if pos_of[s] >= 0 and a > best:
                            best = a
                            beyond[r] = s
    return out, beyond


def cut_far_ends(q, fam, sid, piece, tangent, seed, index, seed_jid, model, depth_range_mm, radius_px: float,
                 tol_px: float, grid: tuple, unlabelled: int, min_samples: int, lateral_px: float,
                 ridge: np.ndarray | None = None) -> int:
    """Take the label off the stretch of a seeded piece between its outermost seed and an end whose crossing
    with a labelled line of the other family names another line of the piece's family (module doc).

    q (P, 2) camera px; fam (P,); sid, piece, tangent: the traces (positions in order); seed (P,) the
    seeds' index; index (P,) float and seed_jid (P,), modified in place. radius_px: how far from the end the
    crossing's other line may be (camera px); tol_px: the crossing's largest distance from a line centre
    (projector px); min_samples: shorter stretches are not checked; lateral_px: `line_goes_on`; grid: `labelling._sample_grid` of the valid samples, cells at least radius_px wide.
    Returns the number of samples that lost their label."""
    from reconstruction import _label_kernels as _k

    e, te, sign, fe, kk, lo, hi = seeded_far_ends(sid, piece, seed, index, unlabelled, q, tangent, fam, int(min_samples))
    if len(e) == 0:
        return 0
    _, bk = _k.crossing_nearest(e, fe, q, fam, index, True, float(radius_px), *grid)
    o, c = _k.crossing_test(e, te, sign, bk, q, sid, tangent, float(radius_px), float(np.sin(np.deg2rad(20))))
    sel = np.flatnonzero(o >= 0)
    if len(sel) == 0:
        return 0
    m = index[sid[o[sel]]].astype(np.int64)
    _, z, k_other, res = model.sheet_check(c[sel], 3 - fe[sel], m)  # light sheet m: the line of family fe it names
    cut = np.zeros(len(e), np.bool_)
    cut[sel] = (res <= tol_px) & (z >= depth_range_mm[0]) & (z <= depth_range_mm[1]) & (k_other != kk[sel])
    if cut.any():
        # only a crossing that the piece's line goes on through is a crossing of two lines on one surface: at a
        # T (this line ends at a silhouette beside another surface's line) the tangents meet in empty space
        r = np.flatnonzero(cut)
        beyond = np.full(len(e), -1, np.intp)
        cut[r], beyond[r] = line_goes_on(c[r], e[r], te[r], sign[r], fe[r], q, fam, float(lateral_px), *grid[:7], grid[7])
    if not cut.any():
        return 0
    use_ridge = ridge is not None and len(ridge) == len(q)
    return int(unlabel_stretches(cut, lo, hi, sign, beyond, sid, ridge if use_ridge else np.zeros(0, np.float32), use_ridge, index, seed_jid))


@njit
def _facing_cuts(q, fam, sid, piece, tangent, index, seed_jid, q_junction, ridge, use_ridge, reach, lateral_px,
                 x0, y0, cell, gw, gh, start, items, pos_of):
    """`cut_facing_ends`' loop (its doc). Returns the trace positions (lo, hi) of the stretches to unlabel."""
    n = sid.shape[0]
    lo_out = np.empty(2 * n, np.intp)
    hi_out = np.empty(2 * n, np.intp)
    c = 0
    a = 0
    while a < n:
        p = piece[a]
        b = a
        while b + 1 < n and piece[b + 1] == p:
            b += 1
        for side in range(2):
            pe = a if side == 0 else b
            step = -1 if side == 0 else 1  # towards the end
            se = sid[pe]
            k = index[se]
            if not math.isfinite(k):
                continue
            dx = step * tangent[pe, 0]
            dy = step * tangent[pe, 1]
            # the nearest labelled sample of the family ahead of the end, on its tangent line, not on this piece
            best = -1
            best_a = np.inf
            cx = int(math.floor((q[se, 0] - x0) / cell))
            cy = int(math.floor((q[se, 1] - y0) / cell))
            for yy in range(max(cy - 1, 0), min(cy + 2, gh)):
                for xx in range(max(cx - 1, 0), min(cx + 2, gw)):
                    bb = yy * gw + xx
                    for t in range(start[bb], start[bb + 1]):
                        s = items[t]
                        if fam[s] != fam[se] or not math.isfinite(index[s]):
                            continue
                        ps = pos_of[s]
                        if ps >= 0 and piece[ps] == p:
                            continue
                        wx = q[s, 0] - q[se, 0]
                        wy = q[s, 1] - q[se, 1]
                        al = wx * dx + wy * dy
                        if al > 0.5 and al <= reach and abs(wx * dy - wy * dx) <= lateral_px and al < best_a:
                            best_a = al
                            best = s
            if best < 0 or index[best] == k:
                continue
            # the stretch: from the piece's sample nearest its junction (not past it) out to the end
            u0 = b if side == 0 else a
            j = seed_jid[se]
            if j >= 0:
                dmin = np.inf
                for u in range(a, b + 1):
                    d = math.hypot(q[sid[u], 0] - q_junction[j, 0], q[sid[u], 1] - q_junction[j, 1])
                    if d < dmin:
                        dmin = d
                        u0 = u
            m = (pe - u0) * step  # steps inside the stretch
            if m < 1:
                continue
            if not use_ridge:
                cut_from = u0 + step
            else:
                # ridge steps along u0 -> end -> the facing sample; the largest one is the edge
                top = -1.0
                at = -1
                for i in range(m + 1):
                    r0 = ridge[sid[u0 + i * step]]
                    r1 = ridge[best] if i == m else ridge[sid[u0 + (i + 1) * step]]
                    d = abs(r1 - r0)
                    if d > top:
                        top = d
                        at = i
                if at >= m:
                    continue  # the edge is between the end and the facing line: nothing on this piece
                i0 = at + 1
                r_hi = ridge[sid[u0 + i0 * step]]
                if r_hi > ridge[sid[u0 + at * step]]:
                    # rising towards the end: the samples before the step are the dimmed ones next to the edge
                    # (each line's profile is cut by the occluding edge); the edge lies among them
                    i = at
                    while i >= 1 and ridge[sid[u0 + i * step]] < r_hi - 0.5 * top:
                        i0 = i
                        i -= 1
                cut_from = u0 + i0 * step
            if step > 0:
                lo_out[c] = cut_from
                hi_out[c] = pe
            else:
                lo_out[c] = pe
                hi_out[c] = cut_from
            c += 1
        a = b + 1
    return lo_out[:c], hi_out[:c]


def cut_facing_ends(q, fam, sid, piece, tangent, index, seed_jid, q_junction, grid: tuple, *, reach_px: float,
                    lateral_px: float, ridge: np.ndarray | None = None) -> int:
    """Take the label off a labelled piece's end that runs into a collinear labelled line of its own family
    with another index (decision 0084, round 4b).

    A line of the pattern cannot continue into another line of the same family on one continuous surface:
    where a piece labelled k ends and, within reach_px ahead on its end's tangent (within lateral_px across
    it), the nearest labelled sample of its family (another piece, or a junction's snapped seed) carries
    k' ≠ k, a depth edge lies between the two labels' junctions. On this piece it is put at the largest
    ridge-brightness step along the stretch from the piece's sample nearest its junction (seed_jid) to the
    end and on to the facing sample; if that step rises towards the end, the dimmed samples before it (below
    its midpoint: both lines' profiles are cut by the edge) go too. If the largest step is the one across to
    the facing sample, nothing on this piece is cut (the other piece's own check decides for it). Without a
    ridge the whole stretch but its first sample goes. The stretch is not relabelled.

    q (P, 2) camera px; fam (P,); sid, piece, tangent: the traces (positions in order); index (P,) float and
    seed_jid (P,), modified in place (NaN, −1); q_junction (M, 2) camera px; grid: `labelling._sample_grid`,
    cells at least reach_px wide; ridge (P,): `labelling._ridge_brightness`. Contradictions are found on the
    labels as they are on entry, then all cuts applied. Returns the number of samples that lost their label.
    """
    if len(sid) == 0:
        return 0
    use_ridge = ridge is not None and len(ridge) == len(q)
    qj = np.ascontiguousarray(q_junction, np.float64).reshape(-1, 2)
    lo, hi = _facing_cuts(q, fam, sid, piece, tangent, index, seed_jid, qj,
                          ridge if use_ridge else np.zeros(0, np.float32), use_ridge, float(min(reach_px, grid[2])),
                          float(lateral_px), *grid[:7], grid[7])
    m = 0
    for a, b in zip(lo, hi):
        s = sid[a:b + 1]
        f = np.isfinite(index[s])
        m += int(f.sum())
        index[s] = np.nan
        seed_jid[s] = -1
    return m
