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

Round 4b (`cut_facing_ends`): a labelled piece's end that runs, across a gap no longer than a crossing's, into
the nearest labelled sample of its own family on its tangent carrying another index is at a depth edge too (a
line cannot continue into another line of its family on one surface); the edge is put at the largest
ridge-brightness step between the two labels' junctions.
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
        m += _unlabel(sid, a, b, index, seed_jid)
    return m


@njit
def _unlabel(sid, a, b, index, seed_jid):
    """Trace positions a … b lose their labels (index NaN, seed_jid −1); returns how many had one."""
    m = 0
    for k in range(a, b + 1):
        s = sid[k]
        if math.isfinite(index[s]):
            index[s] = np.nan
            seed_jid[s] = -1
            m += 1
    return m


@njit
def mean_shift_split(x):
    """The maximum-likelihood position of one step in the mean of the sequence x (n,) under white noise of one
    variance: the split s (1 ≤ s < n; x[:s] | x[s:]) maximising |mean(x[:s]) − mean(x[s:])|·√(s(n−s)/n), the
    two-sample statistic whose square is the log-likelihood gain of a step at s. Every sample counts on its
    side, so a step spread over a few samples (a smoothed edge) outweighs a larger difference of two
    neighbouring samples that noise makes, which the largest single step does not (decision 0132). −1 when
    n < 2; the first split on a tie."""
    n = x.shape[0]
    if n < 2:
        return -1
    tot = 0.0
    for i in range(n):
        tot += x[i]
    best = -1.0
    at = -1
    left = 0.0
    for s in range(1, n):
        left += x[s - 1]
        d = left / s - (tot - left) / (n - s)
        t = abs(d) * math.sqrt(s * (n - s) / n)
        if t > best:
            best = t
            at = s
    return at


@njit
def unlabel_stretches_ml(cut, lo, hi, sign, beyond, sid, ridge, index, seed_jid):
    """`unlabel_stretches` with the edge at the maximum-likelihood step of the ridge brightness
    (`mean_shift_split`) instead of the largest step between consecutive samples (decision 0132). The
    sequence is the stretch with the seed's sample on its seed side and, when there is one (beyond[r] ≥ 0,
    a sample id), the line's first sample past the crossing on its end side; nothing when the split falls
    across the crossing (the edge is at the crossing), else the stretch loses its label from the split out
    to its end. Returns how many samples lost their label."""
    m = 0
    for r in range(cut.shape[0]):
        if not cut[r]:
            continue
        a = lo[r]
        b = hi[r]
        nb = 1 if beyond[r] >= 0 else 0
        n = b - a + 2 + nb
        x = np.empty(n)
        if sign[r] < 0:
            # beyond, lo .. hi, hi + 1 (the seed side); a split s keeps x[s:]
            if nb:
                x[0] = ridge[beyond[r]]
            for k in range(a, b + 2):
                x[nb + k - a] = ridge[sid[k]]
            s = mean_shift_split(x)
            if s <= nb:
                continue  # across the crossing
            b = a + s - nb - 1
        else:
            # lo − 1 (the seed side), lo .. hi, beyond; a split s keeps x[:s]
            for k in range(a - 1, b + 1):
                x[k - a + 1] = ridge[sid[k]]
            if nb:
                x[n - 1] = ridge[beyond[r]]
            s = mean_shift_split(x)
            if s >= n - nb:
                continue  # across the crossing
            a = a - 1 + s
        m += _unlabel(sid, a, b, index, seed_jid)
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
    nc = gw * gh
    split = start.shape[0] == 2 * nc + 1  # a grid from `sample_grid_split`: read the family's part only
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
                t0 = start[b]
                t1 = start[b + 1]
                if split:
                    if fe[r] == 1:
                        t1 = start[nc + 1 + b]
                    elif fe[r] == 2:
                        t0 = start[nc + 1 + b]
                for t in range(t0, t1):
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
                 ridge: np.ndarray | None = None, mean_shift: bool = False) -> int:
    """Take the label off the stretch of a seeded piece between its outermost seed and an end whose crossing
    with a labelled line of the other family names another line of the piece's family (module doc).

    q (P, 2) camera px; fam (P,); sid, piece, tangent: the traces (positions in order); seed (P,) the
    seeds' index; index (P,) float and seed_jid (P,), modified in place. radius_px: how far from the end the
    crossing's other line may be (camera px); tol_px: the crossing's largest distance from a line centre
    (projector px); min_samples: shorter stretches are not checked; lateral_px: `line_goes_on`; grid: `labelling._sample_grid` of the valid samples, cells at least radius_px wide.
    mean_shift: the edge at the ridge brightness's maximum-likelihood step (`unlabel_stretches_ml`, decision
    0132) instead of its largest step between consecutive samples.
    Returns the number of samples that lost their label."""
    from reconstruction import _label_kernels as _k

    e, te, sign, fe, kk, lo, hi = seeded_far_ends(sid, piece, seed, index, unlabelled, q, tangent, fam, int(min_samples))
    if len(e) == 0:
        return 0
    _, bk = _k.crossing_nearest(e, fe, q, fam, index, True, float(radius_px), *grid)
    o, c = _k.crossing_test(e, te, sign, bk, q, sid, tangent, float(radius_px), _SIN_20)
    sel, _, c_sel, f_other, m = _k.crossing_hits(o, c, o, False, fe, index, sid)  # (decision 0087)
    if len(sel) == 0:
        return 0
    _, z, k_other, res = model.sheet_check(c_sel, f_other, m)  # light sheet m: the line of family fe it names
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
    if use_ridge and mean_shift:
        return int(unlabel_stretches_ml(cut, lo, hi, sign, beyond, sid, ridge, index, seed_jid))
    return int(unlabel_stretches(cut, lo, hi, sign, beyond, sid, ridge if use_ridge else np.zeros(0, np.float32), use_ridge, index, seed_jid))


_SIN_20 = float(np.sin(np.deg2rad(20)))  # the crossing test's smallest crossing angle
DIP_SAMPLES = 2  # samples next to an occluding edge whose line profile it cuts (about a line width)


@njit
def _stretch_start(a, b, end, q, sid, q_junction, j):
    """The trace position in a..b nearest junction j (camera px), or the piece's other end when j < 0."""
    u0 = b if end == a else a
    if j >= 0:
        dmin = np.inf
        for u in range(a, b + 1):
            d = math.hypot(q[sid[u], 0] - q_junction[j, 0], q[sid[u], 1] - q_junction[j, 1])
            if d < dmin:
                dmin = d
                u0 = u
    return u0


@njit
def _facing_candidates(sid, piece, index, q, fam, pos_of, x0, y0, cell, gw, gh):
    """The samples an end can face, bucketed on the crossing grid's cells: the labelled ends of trace pieces and
    the labelled samples on no trace (a junction's snapped seeds in the mixing zone). (start, items) as the
    grid's (a third of its samples), and each one's record (x, y, family, index) in the same order (read
    contiguously by the search)."""
    n = sid.shape[0]
    cand = np.empty(2 * n + pos_of.shape[0] + 1, np.intp)
    m = 0
    # both loops branch-free (a store per item, the count advanced by the test; decision 0087): the tests
    # are unpredictable, the stores cheap
    for u in range(n):
        end = (u == 0) or (u == n - 1) or (piece[u - 1] != piece[u]) or (piece[u + 1] != piece[u])
        s = sid[u]
        cand[m] = s
        m += end & math.isfinite(index[s])
    for s in range(pos_of.shape[0]):  # samples on no trace (invalid ones carry no index)
        cand[m] = s
        m += (pos_of[s] < 0) & math.isfinite(index[s])
    nc = gw * gh
    cnt = np.zeros(nc + 1, np.intp)
    cid = np.empty(m, np.intp)
    for i in range(m):
        s = cand[i]
        xx = min(max(int(math.floor((q[s, 0] - x0) / cell)), 0), gw - 1)
        yy = min(max(int(math.floor((q[s, 1] - y0) / cell)), 0), gh - 1)
        cid[i] = yy * gw + xx
        cnt[cid[i] + 1] += 1
    for b in range(nc):
        cnt[b + 1] += cnt[b]
    out = np.empty(m, np.intp)
    rec = np.empty((m, 4))
    # per cell and family: the one index its candidates carry, −1 none, −2 several (the search skips an end
    # whose cells hold only its own index)
    one = np.full((nc, 2), -1, np.int32)
    fill = cnt[:nc].copy()
    for i in range(m):
        b = cid[i]
        j = fill[b]
        s = cand[i]
        out[j] = s
        rec[j, 0] = q[s, 0]
        rec[j, 1] = q[s, 1]
        rec[j, 2] = fam[s]
        rec[j, 3] = index[s]
        fill[b] += 1
        f = fam[s] - 1
        v = int(index[s])
        if one[b, f] == -1:
            one[b, f] = v
        elif one[b, f] != v:
            one[b, f] = -2
    return cnt, out, rec, one


@njit
def _run(u, sid, piece, index):
    """The trace positions (lo, hi) of the run of position u: its piece's consecutive samples with u's index."""
    n = sid.shape[0]
    v = index[sid[u]]
    lo = u
    while lo > 0 and piece[lo - 1] == piece[u] and index[sid[lo - 1]] == v:
        lo -= 1
    hi = u
    while hi + 1 < n and piece[hi + 1] == piece[u] and index[sid[hi + 1]] == v:
        hi += 1
    return lo, hi


@njit
def _edge_cut(pe, step, best, q, sid, piece, index, seed_jid, q_junction, ridge, use_ridge, pos_of):
    """Where the run ending at trace position pe (step +1: it ends at its last sample, −1 at its first) loses
    its label, given the facing sample best of another index: the trace position the cut starts from (the cut
    runs from there to pe), or −1 for none. `cut_facing_ends` explains the rule."""
    ra, rb = _run(pe, sid, piece, index)
    u0 = _stretch_start(ra, rb, pe, q, sid, q_junction, seed_jid[sid[pe]])
    m = (pe - u0) * step
    if m < 1:
        return -1
    if not use_ridge:
        return u0 + step
    # ridge steps along u0 .. end, across to the facing sample, and on along the facing run to its sample
    # nearest its junction: the largest one is the edge; on this run only if before the gap
    top = -1.0
    at = -1
    for i in range(m):
        d = abs(ridge[sid[u0 + (i + 1) * step]] - ridge[sid[u0 + i * step]])
        if d > top:
            top = d
            at = i
    across = abs(ridge[best] - ridge[sid[pe]])
    far = 0.0
    pf = pos_of[best]
    if pf >= 0:
        fa, fb = _run(pf, sid, piece, index)
        f0 = _stretch_start(fa, fb, pf, q, sid, q_junction, seed_jid[best])
        fs = 1 if f0 > pf else -1
        u = pf
        while u != f0:
            far = max(far, abs(ridge[sid[u + fs]] - ridge[sid[u]]))
            u += fs
    if across >= top or far > top:
        return -1  # the edge is at the gap or on the facing run: nothing on this one
    i0 = at + 1
    r_hi = ridge[sid[u0 + i0 * step]]
    if r_hi > ridge[sid[u0 + at * step]]:
        # rising towards the end: if the samples before the step are a short dip (brighter again before it),
        # they are the ones next to the edge whose line profile it cuts: the edge is among them, they go too
        i = at
        while i >= 1 and at - i < DIP_SAMPLES and ridge[sid[u0 + i * step]] < r_hi - 0.5 * top:
            i -= 1
        if ridge[sid[u0 + i * step]] >= r_hi - 0.5 * top:
            i0 = i + 1
    return u0 + i0 * step


@njit
def _facing_cuts(q, fam, sid, piece, tangent, index, seed_jid, q_junction, ridge, use_ridge, reach, lateral_px,
                 x0, y0, cell, gw, gh, start, items, rec, one, pos_of):
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
        # the piece's ends: the nearest labelled sample of the family ahead, off the piece
        for side in range(2):
            pe = a if side == 0 else b
            step = -1 if side == 0 else 1  # towards the end
            se = sid[pe]
            k = index[se]
            if not math.isfinite(k):
                continue
            dx = step * tangent[pe, 0]
            dy = step * tangent[pe, 1]
            ex = q[se, 0]
            ey = q[se, 1]
            fe = float(fam[se])
            # the cells under the box of the segment e .. e + reach·d (widened by lateral_px); skipped when
            # they hold no candidate of this family with another index
            bx0 = min(ex, ex + reach * dx) - lateral_px
            bx1 = max(ex, ex + reach * dx) + lateral_px
            by0 = min(ey, ey + reach * dy) - lateral_px
            by1 = max(ey, ey + reach * dy) + lateral_px
            ya = max(int(math.floor((by0 - y0) / cell)), 0)
            yb = min(int(math.floor((by1 - y0) / cell)) + 1, gh)
            xa = max(int(math.floor((bx0 - x0) / cell)), 0)
            xb = min(int(math.floor((bx1 - x0) / cell)) + 1, gw)
            other = False
            fi = fam[se] - 1
            for yy in range(ya, yb):
                for xx in range(xa, xb):
                    v = one[yy * gw + xx, fi]
                    if v != -1 and v != k:
                        other = True
            if not other:
                continue
            best = -1
            best_a = np.inf
            for yy in range(ya, yb):
                for xx in range(xa, xb):
                    bb = yy * gw + xx
                    for t in range(start[bb], start[bb + 1]):
                        if rec[t, 2] != fe:
                            continue
                        wx = rec[t, 0] - ex
                        wy = rec[t, 1] - ey
                        al = wx * dx + wy * dy
                        if al > 0.5 and al <= reach and al < best_a and abs(wx * dy - wy * dx) <= lateral_px:
                            s = items[t]
                            ps = pos_of[s]
                            if ps >= 0 and piece[ps] == p:
                                continue
                            best_a = al
                            best = s
            if best < 0 or index[best] == k:
                continue
            cf = _edge_cut(pe, step, best, q, sid, piece, index, seed_jid, q_junction, ridge, use_ridge, pos_of)
            if cf >= 0:
                lo_out[c] = min(cf, pe)
                hi_out[c] = max(cf, pe)
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
    k' ≠ k, a depth edge lies between the two labels' junctions. It is put at the largest ridge-brightness
    step along the stretch from the piece's sample nearest its junction (seed_jid) to the end, across the gap,
    and on along the facing run to its sample nearest its own junction. If that step is on this piece, the
    samples from it to the end lose their label; if it rises towards the end and the samples before it are a
    dip of at most DIP_SAMPLES (below the step's midpoint, brighter again before it: the samples on both sides
    of an occluding edge have their line profile cut by it), the dip goes too. If it is the gap's step or on
    the facing run, nothing on this piece is cut (the facing piece's own check decides for it). Without a
    ridge the whole stretch but its first sample goes. The stretch is not relabelled. Ends inside a piece
    (seeds that disagree, split by `spread_seeds`) are not checked (decision 0084, round 4b).

    q (P, 2) camera px; fam (P,); sid, piece, tangent: the traces (positions in order); index (P,) float and
    seed_jid (P,), modified in place (NaN, −1); q_junction (M, 2) camera px; grid: `labelling._sample_grid`
    (reach_px is capped at its cell width); ridge (P,): `labelling._ridge_brightness`. Contradictions are found on the
    labels as they are on entry, then all cuts applied. Returns the number of samples that lost their label.
    """
    if len(sid) == 0:
        return 0
    use_ridge = ridge is not None and len(ridge) == len(q)
    qj = np.ascontiguousarray(q_junction, np.float64).reshape(-1, 2)
    x0, y0, cell, gw, gh, _, items, pos_of = grid
    start, cand, rec, one = _facing_candidates(sid, piece, index, q, fam, pos_of, x0, y0, cell, gw, gh)
    lo, hi = _facing_cuts(q, fam, sid, piece, tangent, index, seed_jid, qj,
                          ridge if use_ridge else np.zeros(0, np.float32), use_ridge, float(min(reach_px, cell)),
                          float(lateral_px), x0, y0, cell, gw, gh, start, cand, rec, one, pos_of)
    m = 0
    for a, b in zip(lo, hi):
        s = sid[a:b + 1]
        f = np.isfinite(index[s])
        m += int(f.sum())
        index[s] = np.nan
        seed_jid[s] = -1
    return m
