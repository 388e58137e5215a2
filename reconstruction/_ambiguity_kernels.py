"""Compiled part of the ambiguity test's noise split (decision 0122, `labelling._choice_of`).

The ambiguity test's second condition (s2 ≥ min_rms_ratio²·max(s1, σ0²)) is there for error that every junction of
a component shares, which no number of junctions averages away. s1 also holds the junctions' own position noise,
which does average away. The two differ in one way a single frame can show: shared error is smooth across the
component, so graph neighbours carry nearly the same signed residual, while independent noise makes neighbours
differ. Half the mean squared difference of the signed residuals across the component's kept edges estimates the
independent part.
"""

from __future__ import annotations

import math

import numpy as np

from reconstruction._jit import njit


@njit
def _signed_residual(ln, k, xy_junction, i, j, fx):
    """The signed epipolar residual (projector px) of junction k (line ln[k], (l0, l1) unit) labelled with the
    pattern junction at array index (i, j) of xy_junction (L, L, 2): (l · (x, y, 1))·fx."""
    return (ln[k, 0] * xy_junction[i, j, 0] + ln[k, 1] * xy_junction[i, j, 1] + ln[k, 2]) * fx


@njit
def neighbour_noise2(members, rel, off_i, off_j, ln, xy_junction, index_min, index_max, fx, start, nbr, pos, cap2):
    """The independent junction noise of one component under one offset (module doc), in projector px².

    members (m,) junction ids; rel (m, 2) their relative labels; (off_i, off_j) the offset; ln (m, 3) their
    epipolar lines (normalised projector coordinates, (l0, l1) unit); xy_junction (L, L, 2) the pattern's
    junctions (normalised); fx: the projector's focal length (px). start, nbr: the kept edges' CSR adjacency
    (`residual_clusters.kept_adjacency`) over all junctions; pos (M,) intp all −1 (work space, restored on return).
    The signed residual of a member is (l · (x, y, 1))·fx for its label rel + offset (NaN outside the pattern or
    without a line). Over the kept edges with both ends in members and both residuals finite, each counted once,
    returns (mean of min((r_a − r_b)², 2·cap2) / 2, number of such edges); (NaN, 0) without one. The cap matches
    the offset score's (one junction far off weighs at most cap2, as in s1)."""
    m = members.shape[0]
    L = index_max - index_min + 1
    r = np.full(m, np.nan)
    for k in range(m):
        pos[members[k]] = k
        i = rel[k, 0] + off_i - index_min
        j = rel[k, 1] + off_j - index_min
        if 0 <= i < L and 0 <= j < L:
            r[k] = _signed_residual(ln, k, xy_junction, i, j, fx)
    total = 0.0
    n = 0
    lim = 2.0 * cap2
    for k in range(m):
        a = members[k]
        if not math.isfinite(r[k]):
            continue
        for t in range(start[a], start[a + 1]):
            b = nbr[t]
            p = pos[b]
            if p <= k or not math.isfinite(r[p]):
                continue  # each edge once (from its lower position), both ends members with a residual
            d = r[k] - r[p]
            d2 = d * d
            total += d2 if d2 < lim else lim
            n += 1
    for k in range(m):
        pos[members[k]] = -1
    if n == 0:
        return np.nan, 0
    return 0.5 * total / n, n


@njit
def edge_steps(pa, pb, d_i, d_j, lab, ln, xy_junction, index_min, index_max, fx, k_max, tol_px):
    """The step each edge of one component takes by the epipolar geometry (decision 0125, `label_epipolar`'s `_restep`).

    pa, pb (E,) intp: the edge ends' positions in the component (a → b); d_i, d_j (E,) the edge's claimed step;
    lab (m, 2) int64 the members' labels under one offset; ln (m, 3) their epipolar lines (normalised projector
    coordinates, (l0, l1) unit); xy_junction (L, L, 2); fx (px). With a's label La, the jump of the signed
    residual across the edge for the step k·d is Δ_k = (l_b · X(La + k·d) − l_a · X(La))·fx, projector px.
    Returns k* (E,) int64: the k in 2 … k_max whose |Δ_k| ≤ tol_px when it is the only one such k in 1 … k_max
    and Δ_1 is finite (both labels inside the pattern) and > tol_px; 1 otherwise (keep the claimed step).
    """
    n = pa.shape[0]
    L = index_max - index_min + 1
    out = np.ones(n, np.int64)
    for e in range(n):
        a = pa[e]
        b = pb[e]
        ia = lab[a, 0] - index_min
        ja = lab[a, 1] - index_min
        if not (0 <= ia < L and 0 <= ja < L):
            continue
        ra = _signed_residual(ln, a, xy_junction, ia, ja, fx)
        n_within = 0
        k_best = 1
        first_ok = False
        for k in range(1, k_max + 1):
            ib = ia + k * d_i[e]
            jb = ja + k * d_j[e]
            if not (0 <= ib < L and 0 <= jb < L):
                if k == 1:
                    break
                continue
            rb = _signed_residual(ln, b, xy_junction, ib, jb, fx)
            dr = abs(rb - ra)
            if k == 1:
                if not math.isfinite(dr) or dr <= tol_px:
                    break
                first_ok = True
            elif dr <= tol_px:
                n_within += 1
                k_best = k
        if first_ok and n_within == 1:
            out[e] = k_best
    return out


@njit
def edge_jump_median(a, b, keep, comp, labels, ln, xy_junction, index_min, fx, unlabelled):
    """The median |r_b − r_a| (projector px) over the kept edges a → b (a, b (E,) junction ids, keep (E,) bool) whose
    ends are both labelled (labels (M, 2), UNLABELLED = unlabelled) in one component (comp (M,)); r the signed epipolar
    residual of the label (ln (M, 3), xy_junction, fx as `edge_steps`), and the number of such edges (NaN, 0 without
    one). Decision 0125's noise scale (`labelling._edge_jump_tol`)."""
    n = a.shape[0]
    d = np.empty(n)
    c = 0
    for e in range(n):
        if not keep[e]:
            continue
        p = a[e]
        q = b[e]
        if labels[p, 0] == unlabelled or labels[q, 0] == unlabelled or comp[p] != comp[q]:
            continue
        ip = labels[p, 0] - index_min
        jp = labels[p, 1] - index_min
        iq = labels[q, 0] - index_min
        jq = labels[q, 1] - index_min
        rp = _signed_residual(ln, p, xy_junction, ip, jp, fx)
        rq = _signed_residual(ln, q, xy_junction, iq, jq, fx)
        d[c] = abs(rq - rp)
        c += 1
    if c == 0:
        return np.nan, 0
    return np.median(d[:c]), c


@njit
def component_edge_steps(members, pos, keep, edges, delta, rel, off_i, off_j, ln, xy_junction, index_min, index_max, fx, k_max,
                         tol_px):
    """`labelling.label_epipolar`'s `_restep` up to `edge_steps` in one call (decision 0127; formerly about ten NumPy
    calls over all edges per component): the kept edges (keep (E,) bool, edges (E, 2), delta (E, 2) int64) with both
    ends among members (m,) junction ids, in increasing edge order (sel), their ends' positions in members (pa, pb),
    and `edge_steps` of them with the members' labels rel[members] + (off_i, off_j) and lines ln[members]. pos (M,)
    intp all −1: work space, restored on return. Returns sel (n,) intp, pa, pb (n,) intp, k (n,) int64."""
    m = members.shape[0]
    for p in range(m):
        pos[members[p]] = p
    E = edges.shape[0]
    n = 0
    for e in range(E):
        if keep[e] and pos[edges[e, 0]] >= 0 and pos[edges[e, 1]] >= 0:
            n += 1
    sel = np.empty(n, np.intp)
    pa = np.empty(n, np.intp)
    pb = np.empty(n, np.intp)
    d_i = np.empty(n, np.int64)
    d_j = np.empty(n, np.int64)
    c = 0
    for e in range(E):
        if keep[e] and pos[edges[e, 0]] >= 0 and pos[edges[e, 1]] >= 0:
            sel[c] = e
            pa[c] = pos[edges[e, 0]]
            pb[c] = pos[edges[e, 1]]
            d_i[c] = delta[e, 0]
            d_j[c] = delta[e, 1]
            c += 1
    for p in range(m):
        pos[members[p]] = -1
    if n == 0:
        return sel, pa, pb, np.ones(0, np.int64)
    lab = np.empty((m, 2), np.int64)
    lm = np.empty((m, 3))
    for p in range(m):
        j = members[p]
        lab[p, 0] = rel[j, 0] + off_i
        lab[p, 1] = rel[j, 1] + off_j
        lm[p, 0] = ln[j, 0]
        lm[p, 1] = ln[j, 1]
        lm[p, 2] = ln[j, 2]
    return sel, pa, pb, edge_steps(pa, pb, d_i, d_j, lab, lm, xy_junction, index_min, index_max, fx, k_max, tol_px)
