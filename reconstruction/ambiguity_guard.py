"""Sample labels that an ambiguous junction component rules out (decision 0141).

A component of found junctions that `labelling.label_epipolar` leaves out as *ambiguous* still has a best offset:
its runner-up fits nearly as well, but offsets further along the same lattice vector fit far worse, and the best one
is the surface's own evidence (many junctions, both families). The steps of `labelling.label_samples` that carry an
index along a line or beside it (the continuation across crossings, the crossing rounds, the limb step, the surface
fit, the gap fills) never read it. Where a depth edge maps the pattern onto itself by a lattice vector that runs
nearly along the epipolar lines (unseen seeds 175, 181, 198: (1, −4)·2, (3, −5)·3, (3, −7)), a background line
continues a foreground line in the image and those steps carry the background's index across the silhouette onto
the foreground surface, a whole number of such vectors off, and spread it there. Every check those steps make on
one crossing passes on that ghost (decision 0113); the foreground's own junctions do not agree with it.

So: a labelled sample of family f on an ambiguous junction's line (within the seed radius of the junction and within
seed_lateral_px of its fitted line of that family: the rule by which a labelled junction seeds its lines, step 3 of
the doc) must carry that junction's index of family f under the component's best offset. Where it does not, the
trace piece holding the sample loses its label (every sample of it), and so does the sample when it is in no piece
(a mixing-zone sample a gap fill labelled). The check runs after every labelling step of `label_samples`, so that a
ghost is taken out before the next step spreads it. It never writes an index: it can only leave samples out.
"""

from __future__ import annotations

import math

import numpy as np

from reconstruction._jit import njit


@njit
def attached_pairs(q, fam, valid, qj, amb, amb_lab, jdir, radius, lateral):
    """The (sample, expected index) pairs: every valid sample of family f (1, 2) within `radius` of an ambiguous
    junction a (ids amb, best labels amb_lab (A, 2)) and within `lateral` of its fitted line of family f (jdir (M, 2, 2)
    unit directions, [a, f − 1]); expected index amb_lab[k, f − 1]. Junctions bucketed in cells `radius` wide."""
    A = amb.shape[0]
    P = q.shape[0]
    if A == 0 or P == 0:
        return np.zeros(0, np.intp), np.zeros(0, np.float64)
    x0 = np.inf
    y0 = np.inf
    for k in range(A):
        x0 = min(x0, qj[amb[k], 0])
        y0 = min(y0, qj[amb[k], 1])
    gw = 0
    gh = 0
    cx = np.empty(A, np.intp)
    cy = np.empty(A, np.intp)
    for k in range(A):
        cx[k] = np.intp(math.floor((qj[amb[k], 0] - x0) / radius))
        cy[k] = np.intp(math.floor((qj[amb[k], 1] - y0) / radius))
        gw = max(gw, cx[k] + 1)
        gh = max(gh, cy[k] + 1)
    cnt = np.zeros(gw * gh + 1, np.intp)
    for k in range(A):
        cnt[cy[k] * gw + cx[k] + 1] += 1
    for c in range(gw * gh):
        cnt[c + 1] += cnt[c]
    items = np.empty(A, np.intp)
    fill = cnt[:-1].copy()
    for k in range(A):
        c = cy[k] * gw + cx[k]
        items[fill[c]] = k
        fill[c] += 1
    out_s = np.empty(16 + 4 * A, np.intp)
    out_e = np.empty(16 + 4 * A, np.float64)
    n = 0
    r2 = radius * radius
    for s in range(P):
        if not valid[s]:
            continue
        f = fam[s]
        if f != 1 and f != 2:
            continue
        sx = np.intp(math.floor((q[s, 0] - x0) / radius))
        sy = np.intp(math.floor((q[s, 1] - y0) / radius))
        if sx < -1 or sx > gw or sy < -1 or sy > gh:
            continue  # none of the 3×3 cells around it is on the grid (decision 0145: most samples, before the cell loop)
        for yy in range(sy - 1, sy + 2):
            if yy < 0 or yy >= gh:
                continue
            for xx in range(sx - 1, sx + 2):
                if xx < 0 or xx >= gw:
                    continue
                c = yy * gw + xx
                for t in range(cnt[c], cnt[c + 1]):
                    k = items[t]
                    a = amb[k]
                    dx = q[s, 0] - qj[a, 0]
                    dy = q[s, 1] - qj[a, 1]
                    if dx * dx + dy * dy > r2:
                        continue
                    ux = jdir[a, f - 1, 0]
                    uy = jdir[a, f - 1, 1]
                    if not (abs(dx * uy - dy * ux) <= lateral):
                        continue
                    if n == out_s.shape[0]:
                        ns = np.empty(2 * n, np.intp)
                        ne = np.empty(2 * n, np.float64)
                        ns[:n] = out_s[:n]
                        ne[:n] = out_e[:n]
                        out_s = ns
                        out_e = ne
                    out_s[n] = s
                    out_e[n] = np.float64(amb_lab[k, f - 1])
                    n += 1
    return out_s[:n].copy(), out_e[:n].copy()


@njit
def unlabel_conflicts(pair_s, pair_e, index, seed_jid, pos_of, piece, sid, protected):
    """Samples of the pairs labelled with another index than expected: their trace pieces (piece (T,) non-decreasing
    along the trace positions, sid (T,) the positions' samples, pos_of (P,) each sample's position or −1) lose their
    labels (index NaN, seed_jid −1), and so does the sample itself when it is on no piece; protected (P,) bool samples
    are neither read nor unlabelled. Returns the number of samples unlabelled."""
    n_out = 0
    T = piece.shape[0]
    for k in range(pair_s.shape[0]):
        s = pair_s[k]
        v = index[s]
        if protected[s] or not math.isfinite(v) or v == pair_e[k]:
            continue
        p = pos_of[s]
        if p < 0:
            index[s] = np.nan
            seed_jid[s] = -1
            n_out += 1
            continue
        pc = piece[p]
        lo = p
        while lo > 0 and piece[lo - 1] == pc:
            lo -= 1
        hi = p
        while hi + 1 < T and piece[hi + 1] == pc:
            hi += 1
        for t in range(lo, hi + 1):
            u = sid[t]
            if math.isfinite(index[u]) and not protected[u]:
                index[u] = np.nan
                seed_jid[u] = -1
                n_out += 1
    return n_out


class Guard:
    """The pairs of one frame, and the check (`__call__`) run after each labelling step of `label_samples`.
    stats["samples_ambiguity_guard"] counts the samples it unlabelled (a sample unlabelled twice counts twice).
    index: the samples' indices when the guard is made (after the labelled junctions' seeds have spread along their
    pieces): those labelled then carry the index of a component the labeller accepted, stronger evidence than an
    ambiguous component's best offset, and are protected (neither read nor unlabelled)."""

    def __init__(self, q, fam, valid, q_junction, junction_dir, ambiguous_labels, radius_px: float, lateral_px: float,
                 index: np.ndarray | None = None):
        amb_all = np.asarray(ambiguous_labels, np.int64).reshape(-1, 2)
        from reconstruction.rigmodel import UNLABELLED

        amb = np.flatnonzero(amb_all[:, 0] != UNLABELLED).astype(np.intp)
        self.n = 0
        self.pair_s, self.pair_e = attached_pairs(
            q, np.ascontiguousarray(fam), np.ascontiguousarray(valid, np.bool_), np.ascontiguousarray(q_junction, np.float64).reshape(-1, 2),
            amb, np.ascontiguousarray(amb_all[amb]), np.ascontiguousarray(junction_dir, np.float64).reshape(-1, 2, 2),
            float(radius_px), float(lateral_px))
        self.pos_of = None
        self.protected = np.zeros(len(q), np.bool_) if index is None else np.isfinite(index)

    def __call__(self, index, seed_jid, piece, sid) -> int:
        if len(self.pair_s) == 0:
            return 0
        if self.pos_of is None or len(self.pos_of) != len(index):
            from reconstruction._label_kernels import positions_of

            self.pos_of = positions_of(len(index), sid)
        n = int(unlabel_conflicts(self.pair_s, self.pair_e, index, seed_jid, self.pos_of, piece, sid, self.protected))
        self.n += n
        return n
