"""Edges that no step along their line explains (decision 0130, `labelling.label_epipolar`'s `_restep`).

Decision 0125 reads each edge of an ambiguous component under its best offset: with a's label La, the jump of the
signed epipolar residual across the edge a → b for the step k·d (d the claimed step) is

    Δ_k = l_b · X(La + k·d) − l_a · X(La)        (× fx, projector px)

and is within the frame's neighbour noise τ for the true k. When the claimed step misses (|Δ_1| > τ) and exactly one
k in 2 … k_max fits, the edge skips missed crossings and takes k·d. When *no* k in 1 … k_max fits, no count of
crossings along the edge's own line explains the jump: the edge joins another line (a segment that ran from one line
onto its neighbour across a silhouette, a shadow or a crease) or another surface. Its claimed step is wrong whatever
the offset, since neighbouring epipolar lines are nearly parallel (0125), and one such edge puts the part of the
component beyond it on another offset: half a face one lattice vector off, the other half the opposite way, and no
offset fits either (unseen seed 133, a box face of 44 junctions). Such an edge is cut; what it held together is
labelled again, piece by piece, with every test as before.
"""

from __future__ import annotations

import math

import numpy as np

from reconstruction._ambiguity_kernels import _signed_residual as _signed
from reconstruction._jit import njit


@njit
def _local_median(k, skip, members, r, start, nbr, pos, buf):
    """Median of the signed residual r of member k and of its graph neighbours (members with a finite residual)
    other than member `skip`, and how many values it took."""
    n = 0
    if math.isfinite(r[k]):
        buf[n] = r[k]
        n += 1
    g = members[k]
    for t in range(start[g], start[g + 1]):
        p = pos[nbr[t]]
        if p < 0 or p == skip or not math.isfinite(r[p]):
            continue
        buf[n] = r[p]
        n += 1
    if n == 0:
        return np.nan, 0
    y = np.sort(buf[:n])
    h = n // 2
    return (y[h] if n % 2 == 1 else 0.5 * (y[h - 1] + y[h])), n


@njit
def edge_misfits(pa, pb, d_i, d_j, lab, ln, xy_junction, index_min, index_max, fx, k_max, tol_px, members, start, nbr, pos):
    """Edges no step along their own line explains (module doc).

    pa, pb (E,) intp: the edge ends' positions in the component (a → b); d_i, d_j (E,) the claimed step; lab (m, 2)
    int64 the members' labels under one offset (consistent along the kept edges: lab[b] = lab[a] + d); ln (m, 3)
    their epipolar lines (normalised projector coordinates, (l0, l1) unit); xy_junction (L, L, 2); fx (px); k_max;
    tol_px (τ); members (m,) the junction ids; start, nbr: the kept edges' CSR adjacency over all junctions
    (`residual_clusters.kept_adjacency`); pos (M,) intp all −1 (work space, restored on return).

    With r the members' signed residuals under lab, an edge is a misfit when
    - the jump Δ_1 = r_b − r_a is finite and |Δ_1| > tol_px, and no k in 2 … k_max (label La + k·d inside the
      pattern) has |Δ_k| ≤ tol_px (`_ambiguity_kernels.edge_steps`' jumps: no count of missed crossings explains it);
    - and the jump persists around the edge: with m_a the median of r over a and its neighbours other than b (and m_b
      likewise), both of at least 2 junctions, |m_b − m_a| > tol_px and no such k has |m_b − m_a + Δ_k − Δ_1| ≤ tol_px.
      A single junction a crossing or a silhouette biases jumps on its own; a wrong edge moves everything beyond it.
    Returns (E,) bool."""
    n = pa.shape[0]
    m = members.shape[0]
    L = index_max - index_min + 1
    out = np.zeros(n, np.bool_)
    r = np.full(m, np.nan)
    deg = 1
    for k in range(m):
        pos[members[k]] = k
        i = lab[k, 0] - index_min
        j = lab[k, 1] - index_min
        if 0 <= i < L and 0 <= j < L:
            r[k] = _signed(ln, k, xy_junction, i, j, fx)
        g = members[k]
        if start[g + 1] - start[g] + 1 > deg:
            deg = start[g + 1] - start[g] + 1
    buf = np.empty(deg)
    shifts = np.empty(k_max + 1)
    for e in range(n):
        a = pa[e]
        b = pb[e]
        ia = lab[a, 0] - index_min
        ja = lab[a, 1] - index_min
        if not (0 <= ia < L and 0 <= ja < L):
            continue
        ib = ia + d_i[e]
        jb = ja + d_j[e]
        if not (0 <= ib < L and 0 <= jb < L):
            continue
        ra = _signed(ln, a, xy_junction, ia, ja, fx)
        d1 = _signed(ln, b, xy_junction, ib, jb, fx) - ra
        if not math.isfinite(d1) or abs(d1) <= tol_px:
            continue
        fits = False
        nk = 0
        for k in range(2, k_max + 1):
            ib = ia + k * d_i[e]
            jb = ja + k * d_j[e]
            if not (0 <= ib < L and 0 <= jb < L):
                continue
            dk = _signed(ln, b, xy_junction, ib, jb, fx) - ra
            if abs(dk) <= tol_px:
                fits = True
                break
            shifts[nk] = dk - d1
            nk += 1
        if fits:
            continue
        ma, na = _local_median(a, b, members, r, start, nbr, pos, buf)
        mb, nb = _local_median(b, a, members, r, start, nbr, pos, buf)
        if na < 2 or nb < 2:
            continue
        dm = mb - ma
        if not abs(dm) > tol_px:
            continue
        for t in range(nk):
            if abs(dm + shifts[t]) <= tol_px:
                fits = True
                break
        out[e] = not fits
    for k in range(m):
        pos[members[k]] = -1
    return out
