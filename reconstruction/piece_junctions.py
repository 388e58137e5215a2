"""Junctions built from the crossings of trace pieces where extraction found none (decision 0092).

Where the lines are compressed and cross at acute image angles (a surface the projector light grazes, the
rim of a cylinder) extraction finds the line samples of both families but no junction: its crossing
candidates need a blob with λ2/λ1 ≥ 0.25 and a ring of both families' samples (decisions 0068, 0083). Without
a labelled junction nothing seeds the pieces there, and the crossing rounds of `label_samples` (which need a
labelled line on the other side) cannot advance into a band where both families are unlabelled.

The crossings are still there: the mixing zone cuts every trace piece at every crossing, so each piece's end
faces a crossing's gap and its end line meets the other family's piece through that gap. Here

1. **Crossings.** Each end of every unlabelled piece of at least `min_samples` samples, and of every labelled
   piece within `ring_cells` junction steps of one (the labelled lines around the patch), is paired with the
   end of a piece of the other family ending in the same gap (within `reach_px`, half a crossing's gap): the
   crossing is the intersection of the two end lines beyond the crossing's pull (`piece_seeds._k_end_line`:
   from the first sample `trim_px` inside each end, along the chord `anchor` samples further in; the end's
   tangent on pieces too short for that), ahead of both ends, the nearest such one (`_k_end_pairs`). With
   `end_pairs=False` the partner is instead the nearest sample of the other family within `radius_px` (the
   crossing search of `label_samples`' step 6, `_label_kernels.crossing_hits_traces`), refined as decision
   0089 refines its far crossings (`piece_seeds._k_refine`): the same gains, more time.
2. **Nodes.** The estimates of one crossing (up to four: the two pieces of each line that end in its gap)
   closer than `merge_px` to one another are one node (single linkage, `_k_cluster`); it sits at their mean.
   An end without an estimate of its own takes the nearest node ahead of it on its end line (within
   `reach_px`, half a crossing's gap, and `lateral_px` across it; `_k_associate`).
3. **Crossings, not T's.** A node is kept only where both families' pieces end at it, each end line passes
   within `lateral_px` of it, one family's line has pieces on both sides of it, and the other family's line
   either has pieces on both sides too or shows a trace sample past the node on its end line within
   `continue_px` (`_k_continues`: a fragment too short to be a piece). A T or an L is a silhouette, a shadow
   or the pattern's rim (decision 0041); built as a node it joins two surfaces.
4. **Edges.** A piece with a node at each end is an edge: along a line of family f the other family's index
   changes by ±1 (the piece spans one cell), with the sign from the predicted camera→projector Jacobian as
   extraction's edges (`_extract_kernels.edge_steps`, which also drops an edge more than 1.6× the shortest
   edge of its family at either node: it skipped a crossing nobody saw).
5. **Labels.** The components of the node graph that hold an unlabelled piece between two of their nodes and
   at least 3 nodes go to the default labeller (`labelling.label_epipolar`): one integer offset per
   component, chosen by the epipolar residual of all its nodes, the pattern's extent, the depth range, the
   ambiguity margin and the outlier splitting, exactly as for found junctions.
6. **Anchors.** A node where a labelled piece of family f ends carries that piece's index for f; a node within
   `merge_px` of a labelled found junction carries its (i, j). A component any of whose labelled nodes
   disagrees with an anchor is left out entirely (one wrong edge, or a node joining two surfaces).
7. **Pieces.** An unlabelled piece whose two end nodes are labelled and give it the same index (the index of
   its family) takes that index. Its samples within `trim_px` of its ends (pulled by the crossings' light)
   are moved onto the piece's line, a total-least-squares fit through its other samples and its two nodes,
   when they lie within `lateral_px` of it: the pieces in these bands are 2–8 samples long, so the trims
   would leave little of them, and the gap filling needs anchors 3 samples inside each end.
   Evidence from two directions: the component's offset (many crossings, both families) and both ends of
   the piece. One-sided pieces (a labelled node at one end only) stay out (decision 0049; measured here too).

Speed (decision 0092, "Time, round 2"): with the method's options everything but `label_epipolar` and the fit's
angle runs in six compiled kernels (`_k_front`, `_k_nodes`, `_k_edge_inputs`, `_k_use`, `_k_anchors`,
`_k_select`/`_k_write`) around `_extract_kernels.edge_steps`; the measurement switches run the NumPy version
(`_label_piece_junctions_reference`), whose outputs the compiled path reproduces bit for bit (tested).
"""

from __future__ import annotations

import math

from types import SimpleNamespace

import numpy as np

from reconstruction import _extract_kernels as _ek
from reconstruction._continuation_kernels import piece_ends
from reconstruction._jit import njit
from reconstruction._label_kernels import _union_find_root, crossing_hits_traces
from reconstruction.piece_seeds import _SIN_MIN_CROSSING, _k_end_line, _k_refine
from reconstruction.rigmodel import UNLABELLED, RigModel


@njit
def _k_number(parent):
    """Component ids from a union–find forest, numbered by their lowest member."""
    n = parent.shape[0]
    out = np.empty(n, np.int64)
    ids = np.full(n, -1, np.int64)
    m = 0
    for a in range(n):
        r = _union_find_root(parent, a)
        if ids[r] < 0:
            ids[r] = m
            m += 1
        out[a] = ids[r]
    return out


@njit
def _k_components(n, edges):
    """Connected components (numbered by their lowest member) of n items joined by edges (E, 2)."""
    parent = np.arange(n)
    for k in range(edges.shape[0]):
        a = _union_find_root(parent, edges[k, 0])
        b = _union_find_root(parent, edges[k, 1])
        if a != b:
            parent[max(a, b)] = min(a, b)
    return _k_number(parent)


@njit
def _k_cluster(c, radius):
    """Single-linkage clusters of the points c (N, 2) closer than radius (bucket grid of cells radius wide,
    union–find): cluster ids numbered by their lowest member."""
    n = c.shape[0]
    parent = np.arange(n)
    if n == 0:
        return parent
    cs = radius
    x0 = c[:, 0].min()
    y0 = c[:, 1].min()
    gw = int((c[:, 0].max() - x0) / cs) + 1
    gh = int((c[:, 1].max() - y0) / cs) + 1
    cell = np.empty(n, np.int64)
    for i in range(n):
        cell[i] = int((c[i, 1] - y0) / cs) * gw + int((c[i, 0] - x0) / cs)
    order = np.argsort(cell, kind="mergesort")
    start = np.zeros(gw * gh + 1, np.int64)
    for i in range(n):
        start[cell[i] + 1] += 1
    for b in range(gw * gh):
        start[b + 1] += start[b]
    r2 = radius * radius
    for i in range(n):
        cx = int((c[i, 0] - x0) / cs)
        cy = int((c[i, 1] - y0) / cs)
        for yy in range(max(cy - 1, 0), min(cy + 2, gh)):
            for xx in range(max(cx - 1, 0), min(cx + 2, gw)):
                b = yy * gw + xx
                for t in range(start[b], start[b + 1]):
                    j = order[t]
                    if j <= i:
                        continue
                    dx = c[j, 0] - c[i, 0]
                    dy = c[j, 1] - c[i, 1]
                    if dx * dx + dy * dy < r2:
                        a = _union_find_root(parent, i)
                        bb = _union_find_root(parent, j)
                        if a != bb:
                            parent[max(a, bb)] = min(a, bb)
    return _k_number(parent)


@njit
def _k_near_mask(E, seed, cell, ring):
    """seed (N,) bool of points E (N, 2), grown to every point within `ring` cells (of size cell, a square
    neighbourhood on a bucket grid) of a seed point."""
    n = E.shape[0]
    out = seed.copy()
    if n == 0:
        return out
    x0 = E[:, 0].min()
    y0 = E[:, 1].min()
    gw = int((E[:, 0].max() - x0) / cell) + 1
    gh = int((E[:, 1].max() - y0) / cell) + 1
    mark = np.zeros((gh, gw), np.bool_)
    for i in range(n):
        if seed[i]:
            cx = int((E[i, 0] - x0) / cell)
            cy = int((E[i, 1] - y0) / cell)
            for yy in range(max(cy - ring, 0), min(cy + ring + 1, gh)):
                for xx in range(max(cx - ring, 0), min(cx + ring + 1, gw)):
                    mark[yy, xx] = True
    for i in range(n):
        if not out[i] and mark[int((E[i, 1] - y0) / cell), int((E[i, 0] - x0) / cell)]:
            out[i] = True
    return out


@njit
def _k_continues(pts, dirs, fams, q, fam, reach, lateral, x0, y0, cell, gw, gh, start, items, pos_of):
    """For each query (point pts[i], unit direction dirs[i], family fams[i]): is there a sample of that family on
    a trace piece (outside every mixing zone) ahead of the point, 0 < along ≤ reach, within lateral of the
    line? The line goes on through the point (an X), it does not stop there (a T). Samples from the frame's
    bucket grid (`_label_kernels.sample_grid`)."""
    n = pts.shape[0]
    out = np.zeros(n, np.bool_)
    ring = int(math.ceil(reach / cell))
    for i in range(n):
        px = pts[i, 0]
        py = pts[i, 1]
        cx = int(math.floor((px - x0) / cell))
        cy = int(math.floor((py - y0) / cell))
        for yy in range(max(cy - ring, 0), min(cy + ring + 1, gh)):
            if out[i]:
                break
            for xx in range(max(cx - ring, 0), min(cx + ring + 1, gw)):
                if out[i]:
                    break
                b = yy * gw + xx
                for t in range(start[b], start[b + 1]):
                    s = items[t]
                    if fam[s] != fams[i] or pos_of[s] < 0:
                        continue
                    wx = q[s, 0] - px
                    wy = q[s, 1] - py
                    a = wx * dirs[i, 0] + wy * dirs[i, 1]
                    if a > 0.0 and a <= reach and abs(wx * dirs[i, 1] - wy * dirs[i, 0]) <= lateral:
                        out[i] = True
                        break
    return out


@njit
def _k_node_ends(node_end, E, U, fe, xy, lateral):
    """Per node and family (columns 0, 1 = families 1, 2) from the ends joined to it (node_end (R,), −1: none;
    ends at E (R, 2), outward unit U (R, 2), family fe (R,)): has an end, the sums of the outward directions
    (sx, sy) and the number of ends; per node: off_line, an end line passing farther than lateral from it."""
    K = xy.shape[0]
    has = np.zeros((K, 2), np.bool_)
    sx = np.zeros((K, 2))
    sy = np.zeros((K, 2))
    ne = np.zeros((K, 2))
    off = np.zeros(K, np.bool_)
    for r in range(node_end.shape[0]):
        k = node_end[r]
        if k < 0:
            continue
        f = fe[r] - 1
        has[k, f] = True
        sx[k, f] += U[r, 0]
        sy[k, f] += U[r, 1]
        ne[k, f] += 1.0
        wx = xy[k, 0] - E[r, 0]
        wy = xy[k, 1] - E[r, 1]
        if abs(wx * U[r, 1] - wy * U[r, 0]) > lateral:
            off[k] = True
    return has, sx, sy, ne, off


@njit
def _k_end_pairs(E, U, pos, first, last, piece, ts, q, sid, trim_px, anchor, fe, rows, radius, sin_min):
    """The crossing at each end rows[i]: among the ends of the other family within radius of its end sample
    E (R, 2), the intersection of the two end lines that lies ahead of both ends (along their outward
    directions, from −1 px to radius) and nearest to this end; lines meeting at a sine below sin_min are
    skipped. An end's line lies beyond the crossing's pull (`piece_seeds._k_end_line` of trace position
    pos[r]: from the first sample trim_px inside the end, along the chord `anchor` samples further in), or is
    the end sample and its outward direction U where the piece is too short; computed when first needed.
    Returns the partner end (−1: none) and the crossing c (n, 2)."""
    R = E.shape[0]
    n = rows.shape[0]
    part = np.full(n, -1, np.int64)
    c = np.full((n, 2), np.nan)
    if R == 0:
        return part, c
    P = np.empty((R, 2))
    D = np.empty((R, 2))
    done = np.zeros(R, np.bool_)
    cs = radius
    x0 = E[:, 0].min()
    y0 = E[:, 1].min()
    gw = int((E[:, 0].max() - x0) / cs) + 1
    gh = int((E[:, 1].max() - y0) / cs) + 1
    start = np.zeros(gw * gh + 1, np.int64)
    cellr = np.empty(R, np.int64)
    for r in range(R):
        cellr[r] = int((E[r, 1] - y0) / cs) * gw + int((E[r, 0] - x0) / cs)
        start[cellr[r] + 1] += 1
    for b in range(gw * gh):
        start[b + 1] += start[b]
    fill = start[:-1].copy()
    items = np.empty(R, np.int64)
    for r in range(R):
        items[fill[cellr[r]]] = r
        fill[cellr[r]] += 1
    r2 = radius * radius
    for i in range(n):
        r = rows[i]
        cx = int((E[r, 0] - x0) / cs)
        cy = int((E[r, 1] - y0) / cs)
        bd = np.inf
        for yy in range(max(cy - 1, 0), min(cy + 2, gh)):
            for xx in range(max(cx - 1, 0), min(cx + 2, gw)):
                b = yy * gw + xx
                for t in range(start[b], start[b + 1]):
                    o = items[t]
                    if fe[o] == fe[r]:
                        continue
                    ddx = E[o, 0] - E[r, 0]
                    ddy = E[o, 1] - E[r, 1]
                    if ddx * ddx + ddy * ddy >= r2:
                        continue
                    for z in (r, o):
                        if not done[z]:
                            ok, ax, ay, ux, uy = _k_end_line(pos[z], first, last, piece, ts, q, sid, trim_px, anchor)
                            if ok:
                                P[z, 0] = ax
                                P[z, 1] = ay
                                D[z, 0] = ux
                                D[z, 1] = uy
                            else:
                                P[z, 0] = E[z, 0]
                                P[z, 1] = E[z, 1]
                                D[z, 0] = U[z, 0]
                                D[z, 1] = U[z, 1]
                            done[z] = True
                    den = D[r, 0] * D[o, 1] - D[r, 1] * D[o, 0]
                    if abs(den) < sin_min:
                        continue
                    wx = P[o, 0] - P[r, 0]
                    wy = P[o, 1] - P[r, 1]
                    tr = (wx * D[o, 1] - wy * D[o, 0]) / den
                    X = P[r, 0] + tr * D[r, 0]
                    Y = P[r, 1] + tr * D[r, 1]
                    ar = (X - E[r, 0]) * D[r, 0] + (Y - E[r, 1]) * D[r, 1]
                    ao = (X - E[o, 0]) * D[o, 0] + (Y - E[o, 1]) * D[o, 1]
                    if ar < -1.0 or ar > radius or ao < -1.0 or ao > radius:
                        continue
                    d2 = (X - E[r, 0]) ** 2 + (Y - E[r, 1]) ** 2
                    if d2 < bd:
                        bd = d2
                        part[i] = o
                        c[i, 0] = X
                        c[i, 1] = Y
    return part, c


@njit
def _k_end_pairs_f(E, U, pos, first, last, piece, ts, qt, trim_px, anchor, fe, rows, radius, sin_min):
    """`_k_end_pairs` with one bucket grid per family (the same candidates in the same order, half the
    look-ups) and the end lines on the trace-ordered positions qt (P×… → n, 2: qt[j] = q[sid[j]])."""
    R = E.shape[0]
    n = rows.shape[0]
    part = np.full(n, -1, np.int64)
    c = np.full((n, 2), np.nan)
    if R == 0:
        return part, c
    P = np.empty((R, 2))
    D = np.empty((R, 2))
    done = np.zeros(R, np.bool_)
    cs = radius
    x0 = E[:, 0].min()
    y0 = E[:, 1].min()
    gw = int((E[:, 0].max() - x0) / cs) + 1
    gh = int((E[:, 1].max() - y0) / cs) + 1
    G = gw * gh
    start = np.zeros(2 * G + 1, np.int64)
    cellr = np.empty(R, np.int64)
    for r in range(R):
        cellr[r] = (fe[r] - 1) * G + int((E[r, 1] - y0) / cs) * gw + int((E[r, 0] - x0) / cs)
        start[cellr[r] + 1] += 1
    for b in range(2 * G):
        start[b + 1] += start[b]
    fill = start[:-1].copy()
    items = np.empty(R, np.int64)
    Ec = np.empty((R, 2))  # the ends' positions in grid order (the scans below read them in sequence)
    for r in range(R):
        t = fill[cellr[r]]
        items[t] = r
        Ec[t, 0] = E[r, 0]
        Ec[t, 1] = E[r, 1]
        fill[cellr[r]] += 1
    r2 = radius * radius
    for i in range(n):
        r = rows[i]
        cx = int((E[r, 0] - x0) / cs)
        cy = int((E[r, 1] - y0) / cs)
        bd = np.inf
        g0 = (2 - fe[r]) * G  # the other family's grid
        for yy in range(max(cy - 1, 0), min(cy + 2, gh)):
            for xx in range(max(cx - 1, 0), min(cx + 2, gw)):
                b = g0 + yy * gw + xx
                for t in range(start[b], start[b + 1]):
                    ddx = Ec[t, 0] - E[r, 0]
                    ddy = Ec[t, 1] - E[r, 1]
                    if ddx * ddx + ddy * ddy >= r2:
                        continue
                    o = items[t]
                    for zz in range(2):
                        z = r if zz == 0 else o
                        if not done[z]:
                            # `piece_seeds._k_end_line` written out (a call per end costs more than the line),
                            # on the trace-ordered positions qt (qt[j] = q[sid[j]])
                            ok = False
                            p_end = pos[z]
                            pz = piece[p_end]
                            step = 1 if p_end == first[pz] else -1
                            stop = last[pz] if step == 1 else first[pz]
                            t0 = ts[p_end]
                            j = p_end
                            while j != stop and abs(ts[j] - t0) < trim_px:
                                j += step
                            if abs(ts[j] - t0) >= trim_px:
                                j2 = j
                                for _ in range(anchor):
                                    if j2 == stop:
                                        break
                                    j2 += step
                                ax = qt[j, 0]
                                ay = qt[j, 1]
                                dx = ax - qt[j2, 0]
                                dy = ay - qt[j2, 1]
                                Ln = math.hypot(dx, dy)
                                if Ln >= 1.5:
                                    ok = True
                                    P[z, 0] = ax
                                    P[z, 1] = ay
                                    D[z, 0] = dx / Ln
                                    D[z, 1] = dy / Ln
                            if not ok:
                                P[z, 0] = E[z, 0]
                                P[z, 1] = E[z, 1]
                                D[z, 0] = U[z, 0]
                                D[z, 1] = U[z, 1]
                            done[z] = True
                    den = D[r, 0] * D[o, 1] - D[r, 1] * D[o, 0]
                    if abs(den) < sin_min:
                        continue
                    wx = P[o, 0] - P[r, 0]
                    wy = P[o, 1] - P[r, 1]
                    tr = (wx * D[o, 1] - wy * D[o, 0]) / den
                    X = P[r, 0] + tr * D[r, 0]
                    Y = P[r, 1] + tr * D[r, 1]
                    ar = (X - E[r, 0]) * D[r, 0] + (Y - E[r, 1]) * D[r, 1]
                    ao = (X - E[o, 0]) * D[o, 0] + (Y - E[o, 1]) * D[o, 1]
                    if ar < -1.0 or ar > radius or ao < -1.0 or ao > radius:
                        continue
                    d2 = (X - E[r, 0]) ** 2 + (Y - E[r, 1]) ** 2
                    if d2 < bd:
                        bd = d2
                        part[i] = o
                        c[i, 0] = X
                        c[i, 1] = Y
    return part, c


@njit
def _k_associate(E, U, rows, xy, reach, lateral):
    """For the ends rows (position E[r], outward unit direction U[r]): the nearest node of xy (K, 2) within
    reach of the end, not behind it (along ≥ −1 px) and within lateral of its end line; −1 where none."""
    K = xy.shape[0]
    out = np.full(rows.shape[0], -1, np.int64)
    if K == 0:
        return out
    cs = reach
    x0 = xy[:, 0].min() - cs
    y0 = xy[:, 1].min() - cs
    gw = int((xy[:, 0].max() - x0) / cs) + 2
    gh = int((xy[:, 1].max() - y0) / cs) + 2
    start = np.zeros(gw * gh + 1, np.int64)
    cellk = np.empty(K, np.int64)
    for k in range(K):
        cellk[k] = int((xy[k, 1] - y0) / cs) * gw + int((xy[k, 0] - x0) / cs)
        start[cellk[k] + 1] += 1
    for b in range(gw * gh):
        start[b + 1] += start[b]
    fill = start[:-1].copy()
    items = np.empty(K, np.int64)
    for k in range(K):
        items[fill[cellk[k]]] = k
        fill[cellk[k]] += 1
    r2 = reach * reach
    for a in range(rows.shape[0]):
        r = rows[a]
        ex = E[r, 0]
        ey = E[r, 1]
        cx = int(math.floor((ex - x0) / cs))
        cy = int(math.floor((ey - y0) / cs))
        best = -1
        bd = np.inf
        for yy in range(max(cy - 1, 0), min(cy + 2, gh)):
            for xx in range(max(cx - 1, 0), min(cx + 2, gw)):
                b = yy * gw + xx
                for t in range(start[b], start[b + 1]):
                    k = items[t]
                    wx = xy[k, 0] - ex
                    wy = xy[k, 1] - ey
                    d2 = wx * wx + wy * wy
                    if d2 >= r2 or d2 >= bd:
                        continue
                    if wx * U[r, 0] + wy * U[r, 1] < -1.0 or abs(wx * U[r, 1] - wy * U[r, 0]) > lateral:
                        continue
                    bd = d2
                    best = k
        out[a] = best
    return out


def _label_piece_junctions_reference(
    q: np.ndarray,
    fam: np.ndarray,
    sid: np.ndarray,
    piece: np.ndarray,
    ts: np.ndarray,
    tangent: np.ndarray,
    index: np.ndarray,
    seed_jid: np.ndarray,
    *,
    model: RigModel,
    depth_range_mm: tuple[float, float],
    radius_px: float,
    grid: tuple,
    q_junction: np.ndarray,
    junction_labels: np.ndarray,
    trim_px: float = 0.0,
    merge_px: float | None = None,
    min_samples: int = 2,
    anchor: int = 3,
    reach_px: float = 0.0,
    lateral_px: float = 1.0,
    one_sided: bool = False,
    x_both: bool = True,
    move_ends: bool = True,
    fit_interior: bool = True,
    ring_cells: int = 1,
    continue_px: float | None = None,
    junction_nodes: bool = False,
    end_pairs: bool = True,
    q_out: np.ndarray | None = None,
    label_options=None,
    debug: dict | None = None,
) -> dict:
    """The NumPy-glue implementation `label_piece_junctions` replaced (decision 0092, "Time"): the measurement
    switches' path, and the fast path's reference in the tests (the same outputs bit for bit).

    Label unlabelled pieces from junctions built at the crossings of pieces (module doc).

    q (P, 2) camera px, fam (P,) 1/2 of all samples; the traces as `labelling.label_samples` builds them: sid
    (n,) sample ids by piece and position, piece (n,) non-decreasing piece ids, ts (n,) position along the piece
    (px), tangent (n, 2) unit. index (P,) float (NaN: unlabelled), seed_jid (P,) int and q_out (P, 2) (the
    positions to triangulate; None: the end samples are not moved) are written in place (seed_jid −1: no
    found junction). radius_px: how far from a piece's end the crossing is searched; grid: the frame's bucket
    grid of the samples (`labelling._sample_grid`, cells ≥ radius_px). q_junction (M, 2), junction_labels
    (M, 2): the found junctions and their labels (anchors). trim_px: the pull of a crossing along a piece
    (`cross_trim_sigma`·σ). merge_px: crossing estimates this close are one node (default 0.25 junction steps).
    min_samples: shorter pieces give no crossing estimates and no edges. anchor: the end lines' chord length
    in samples. reach_px: how far ahead of a piece's end its node may lie (half a crossing's gap; 0: only the
    end's own estimate); lateral_px: how far off the end's line (camera px). continue_px: how far past a node a
    one-sided family's line must show a trace sample (default reach_px). ring_cells: the labelled pieces whose
    ends are searched too lie within this many junction steps of an unlabelled piece's end. label_options:
    `labelling.LabelOptions` (default: min_component 3; the depth range is set from depth_range_mm).
    Measurement switches (defaults are the method): x_both (False: one family through the node suffices),
    move_ends (False: the samples within trim_px of a piece's ends stay unlabelled), fit_interior (False: moved
    onto the chord between the nodes), one_sided (True: also pieces with a labelled node at one end and no node
    at the other: decision 0049's one-sided evidence, measured wrong on tabletop), junction_nodes (True: the
    labelled pieces' ends around a patch are not searched; the labelled found junctions within ring_cells steps
    are nodes instead: less time, a third less gain), end_pairs (False: step 1's partner is the nearest sample
    of the other family, refined by `piece_seeds._k_refine`). debug: filled with the nodes'
    positions `xy` and labels `labels` (UNLABELLED where none).
    Returns counts: nodes, edges, nodes used and labelled, ends associated by position, nodes that are no
    crossing, components rejected by an anchor, the sub-labeller's left-out reasons, pieces and samples
    labelled, end samples moved."""
    from reconstruction.labelling import LabelOptions, label_epipolar

    stats = {"nodes": 0, "edges": 0, "nodes_labelled": 0, "components_anchor_conflict": 0, "pieces": 0, "samples": 0}
    n = len(piece)
    if n == 0:
        return stats
    n_p = int(piece[-1]) + 1
    if merge_px is None:
        merge_px = 0.25 * model.junction_step_cam_px
    e, u, end_pos, labelled, val, _ = piece_ends(q, sid, piece, tangent, index, seed_jid, n_p, int(anchor))
    first, last = end_pos[:n_p], end_pos[n_p:]
    count = last - first + 1
    cand = np.flatnonzero(count >= min_samples)
    nc = len(cand)
    if nc == 0:
        return stats
    rows = np.concatenate((cand, cand + n_p))
    E = np.ascontiguousarray(e[rows])
    U = np.ascontiguousarray(u[rows])
    fe = fam[sid[end_pos[rows]]].astype(np.int64)
    # 1. the crossing of each end of an unlabelled piece with the nearest sample of the other family, refined
    # beyond the crossing's pull (the ends of labelled pieces join the nodes below, by position)
    unl = ~np.concatenate((labelled[cand], labelled[cand]))
    unl0 = unl
    if ring_cells > 0 and not junction_nodes:
        # and the ends of labelled pieces near them (within ring_cells junction steps): their crossings join the
        # unlabelled patch's nodes to the labelled lines around it, whose nodes decide the offset with them
        unl = _k_near_mask(E, unl, float(model.junction_step_cam_px), int(ring_cells))
    srch = np.flatnonzero(unl)
    if len(srch) < 3:
        return stats
    if end_pairs:
        # the crossing as the intersection of the end's line with the end line of a piece of the other family
        # ending in the same gap (both beyond the crossing's pull): a search over the pieces' ends only
        o_s, c_s = _k_end_pairs(E, U, np.ascontiguousarray(end_pos[rows]), first, last, piece, ts, q, sid, float(trim_px), int(anchor),
                                fe, srch.astype(np.int64), float(reach_px if reach_px > 0 else radius_px), _SIN_MIN_CROSSING)
        hs = np.flatnonzero(o_s >= 0)
        if len(hs) < 3:
            return stats
        h = srch[hs]
        c = c_s[hs]
    else:
        o_s, c_s = crossing_hits_traces(np.ascontiguousarray(E[srch]), np.ascontiguousarray(U[srch]), np.ones(len(srch)), fe[srch],
                                        q, sid, tangent, fam, index, False, float(radius_px), _SIN_MIN_CROSSING, *grid)
        hs = np.flatnonzero(o_s >= 0)
        if len(hs) < 3:
            return stats
        h = srch[hs]
        c = c_s[hs]
        _k_refine(np.ascontiguousarray(end_pos[rows[h]], np.int64), np.ascontiguousarray(o_s[hs], np.int64), np.arange(len(h), dtype=np.int64),
                  c, first, last, piece, ts, q, sid, float(trim_px), int(anchor))
    # 2. nodes: estimates closer than merge_px, single linkage; a node is at their mean
    ch = c
    node_of_hit = _k_cluster(np.ascontiguousarray(ch), float(merge_px))
    n_nodes = int(node_of_hit.max()) + 1
    cnt = np.bincount(node_of_hit, minlength=n_nodes).astype(np.float64)
    xy = np.stack([np.bincount(node_of_hit, ch[:, 0], n_nodes), np.bincount(node_of_hit, ch[:, 1], n_nodes)], axis=1) / cnt[:, None]
    if junction_nodes:
        # the labelled found junctions within ring_cells junction steps of an unlabelled piece's end are nodes
        # too, at their own positions (a cluster within merge_px of one is that junction)
        jl0 = np.asarray(junction_labels, np.int64).reshape(-1, 2)
        qj0 = np.asarray(q_junction, np.float64).reshape(-1, 2)
        lj0 = np.flatnonzero(jl0[:, 0] != UNLABELLED)
        if len(lj0):
            allp = np.concatenate((E[unl0], qj0[lj0]))
            seed_m = np.zeros(len(allp), np.bool_)
            seed_m[: int(unl0.sum())] = True
            near = _k_near_mask(allp, seed_m, float(model.junction_step_cam_px), int(max(ring_cells, 1)))[int(unl0.sum()):]
            qjn = np.ascontiguousarray(qj0[lj0[near]])
            if len(qjn):
                dup = _k_associate(xy, np.zeros_like(xy), np.arange(n_nodes), qjn, float(merge_px), np.inf)
                keep_c = dup < 0
                remap = np.where(keep_c, np.cumsum(keep_c) - 1, int(keep_c.sum()) + dup)
                xy = np.concatenate((xy[keep_c], qjn))
                node_of_hit = remap[node_of_hit]
                n_nodes = len(xy)
    stats["nodes"] = n_nodes
    node_end = np.full(2 * nc, -1, np.int64)  # node of each end row (rows order: cand, cand + n_p)
    node_end[h] = node_of_hit
    if reach_px > 0:
        # ends whose own crossing search found nothing (a fragment as the nearest partner, a poor tangent) take
        # the nearest node ahead of them on their end line: within reach_px along it, lateral_px across
        free = np.flatnonzero(node_end < 0)
        if len(free):
            best = _k_associate(E, U, free, xy, float(reach_px), float(lateral_px))
            node_end[free] = best
            stats["ends_associated"] = int((best >= 0).sum())
    # a node is a crossing (an X), not a T or an L at a silhouette or shadow: ends of both families, and the
    # pieces of one family's line on both sides of it, each end line passing within lateral_px of it
    has, sx, sy, ne, off_line = _k_node_ends(node_end, E, U, fe, xy, float(lateral_px))
    two_sided = (ne >= 2) & (np.hypot(sx, sy) <= ne - 1.5)
    through = two_sided.copy()
    if continue_px is None:
        continue_px = reach_px  # the far half of the crossing's gap
    if continue_px > 0:
        # a family seen on one side only: its line goes on past the node (a sample of its family on a trace
        # beyond the node, on the end line: a fragment too short to be a piece counts)
        one = has & ~two_sided
        nq, fq = np.nonzero(one)
        if len(nq):
            dn = np.stack([sx[nq, fq], sy[nq, fq]], axis=1)  # outward: from the end through the node
            dn /= np.maximum(np.hypot(dn[:, 0], dn[:, 1]), 1e-12)[:, None]
            through[nq, fq] = _k_continues(np.ascontiguousarray(xy[nq]), np.ascontiguousarray(dn), (fq + 1).astype(np.int64), q, fam,
                                           float(continue_px), float(lateral_px), *grid)
    x_node = has.all(axis=1) & (through.all(axis=1) if x_both else through.any(axis=1)) & two_sided.any(axis=1) & ~off_line
    stats["nodes_not_crossing"] = int((~x_node).sum())
    node_end[(node_end >= 0) & ~x_node[np.maximum(node_end, 0)]] = -1
    # 3. edges: pieces with a node at both ends
    a_n, b_n = node_end[:nc], node_end[nc:]
    ed = np.flatnonzero((a_n >= 0) & (b_n >= 0) & (a_n != b_n))
    if len(ed) == 0:
        return stats
    a_j = a_n[ed]
    b_j = b_n[ed]
    fam_s = fam[sid[first[cand[ed]]]].astype(np.int64)
    dq = xy[b_j] - xy[a_j]
    mid = 0.5 * (xy[a_j] + xy[b_j])
    elen = np.hypot(dq[:, 0], dq[:, 1])
    edges, _, delta, eseg, _ = _ek.edge_steps(np.ascontiguousarray(ed, np.int64), np.ascontiguousarray(a_j), np.ascontiguousarray(b_j),
                                             fam_s, np.ascontiguousarray(mid), np.ascontiguousarray(dq), elen, model.J_proj_cam,
                                             float(model.cell_px), float(model.pattern.n1), float(model.pattern.n2), n_nodes)
    stats["edges"] = int(len(edges))
    if len(edges) == 0:
        return stats
    # 4. the default labeller on the node graph: only the components that hold an unlabelled piece between two
    # of their nodes and at least min_component nodes (the outlier split's smallest piece)
    lo = label_options if label_options is not None else LabelOptions(min_component=3)
    lo = LabelOptions(**{**lo.__dict__, "depth_min_mm": float(depth_range_mm[0]), "depth_max_mm": float(depth_range_mm[1])})
    cc = _k_components(n_nodes, np.ascontiguousarray(edges, np.int64))
    want = np.zeros(int(cc.max()) + 1, bool)
    want[cc[edges[~labelled[cand[eseg]], 0]]] = True
    size = np.bincount(cc)
    use = want[cc] & (size[cc] >= lo.min_component)
    stats["nodes_used"] = int(use.sum())
    if not use.any():
        return stats
    sub = np.flatnonzero(use)
    renum = np.full(n_nodes, -1, np.int64)
    renum[sub] = np.arange(len(sub))
    ek = use[edges[:, 0]]
    obs = SimpleNamespace(q_junction=xy[sub], edges=renum[edges[ek]], edge_delta=delta[ek])
    lab_sub = label_epipolar(obs, model, model.cam_normalised(xy[sub]), options=lo)
    lab = SimpleNamespace(labels=np.full((n_nodes, 2), UNLABELLED, np.int64), component=np.full(n_nodes, -1, np.int64), stats=lab_sub.stats)
    lab.labels[sub] = lab_sub.labels
    stats["left_out"] = {k: v for k, v in lab_sub.stats["junctions_left_out"].items() if v}
    lab.component[sub] = lab_sub.component
    L = lab.labels
    ok_node = L[:, 0] != UNLABELLED
    if not ok_node.any():
        return stats
    # 5. anchors: labelled pieces ending at a node (their family's index), labelled found junctions nearby
    conflict = np.zeros(n_nodes, bool)
    he = np.flatnonzero(node_end >= 0)
    p_hit = cand[np.concatenate((np.arange(nc), np.arange(nc)))[he]]
    anc = labelled[p_hit] & ok_node[node_end[he]]
    if anc.any():
        nd = node_end[he][anc]
        f_a = fam[sid[first[p_hit[anc]]]] - 1
        k_a = val[p_hit[anc]]
        conflict[nd[L[nd, f_a] != k_a]] = True
    jl = np.asarray(junction_labels, np.int64).reshape(-1, 2)
    lj = np.flatnonzero(jl[:, 0] != UNLABELLED)
    if len(lj):
        qj = np.ascontiguousarray(np.asarray(q_junction, np.float64).reshape(-1, 2)[lj])
        nn = _k_associate(qj, np.zeros_like(qj), np.arange(len(lj)), xy, float(merge_px), np.inf)
        m = nn >= 0
        if m.any():
            nd = nn[m]
            bad = ok_node[nd] & np.any(L[nd] != jl[lj[m]], axis=1)
            conflict[nd[bad]] = True
    if conflict.any():
        comp_bad = np.unique(lab.component[conflict])
        stats["components_anchor_conflict"] = int(len(comp_bad))
        drop = np.isin(lab.component, comp_bad)
        ok_node &= ~drop
    stats["nodes_labelled"] = int(ok_node.sum())
    if debug is not None:
        debug.update(xy=xy, labels=np.where(ok_node[:, None], L, UNLABELLED))
    # 6. unlabelled pieces whose two end nodes are labelled and agree on their index
    p_ed = cand[ed]
    f_ed = fam_s - 1
    both = ok_node[a_j] & ok_node[b_j] & ~labelled[p_ed]
    k_a = L[a_j, f_ed]
    k_b = L[b_j, f_ed]
    sel = np.flatnonzero(both & (k_a == k_b))
    p_sel = p_ed[sel]
    k = k_a[sel]
    if one_sided:
        # measurements only: a piece with a labelled node at one end and no crossing at the other
        a_all, b_all = node_end[:nc], node_end[nc:]
        one = ~labelled[cand] & (((a_all >= 0) & (b_all < 0)) | ((a_all < 0) & (b_all >= 0)))
        nd1 = np.maximum(a_all, b_all)
        one &= ok_node[np.maximum(nd1, 0)] & (nd1 >= 0)
        o1 = np.flatnonzero(one)
        p_sel = np.concatenate((p_sel, cand[o1]))
        k = np.concatenate((k, L[nd1[o1], fam[sid[first[cand[o1]]]] - 1]))
    if len(p_sel) == 0:
        return stats
    lens = count[p_sel]
    pos = np.repeat(first[p_sel], lens) + (np.arange(lens.sum()) - np.repeat(np.cumsum(lens) - lens, lens))
    owner = np.repeat(np.arange(len(p_sel)), lens)
    f0, l0 = first[p_sel][owner], last[p_sel][owner]
    keep = np.minimum(ts[pos] - ts[f0], ts[l0] - ts[pos]) >= trim_px
    if move_ends and q_out is not None and len(sel):
        # the samples near the crossings (pulled by the other line's light) of pieces between two nodes: moved
        # onto the piece's line (fit_interior; else the chord between the nodes) when within lateral_px of it
        n_two = int(lens[: len(sel)].sum())  # the two-node pieces come first
        ends = np.flatnonzero(~keep[:n_two])
        ow = owner[ends]
        npc = len(sel)
        na, nb = xy[a_j[sel]], xy[b_j[sel]]
        if fit_interior:
            # the piece's line: a total-least-squares fit through its interior samples (beyond the pull) and
            # its two nodes
            inner = np.flatnonzero(keep[:n_two])
            io = owner[inner]
            qi = q[sid[pos[inner]]]
            wsum = np.bincount(io, minlength=npc) + 2.0
            mx = (np.bincount(io, qi[:, 0], npc) + na[:, 0] + nb[:, 0]) / wsum
            my = (np.bincount(io, qi[:, 1], npc) + na[:, 1] + nb[:, 1]) / wsum
            dxi, dyi = qi[:, 0] - mx[io], qi[:, 1] - my[io]
            sxx = np.bincount(io, dxi * dxi, npc) + (na[:, 0] - mx) ** 2 + (nb[:, 0] - mx) ** 2
            syy = np.bincount(io, dyi * dyi, npc) + (na[:, 1] - my) ** 2 + (nb[:, 1] - my) ** 2
            sxy = np.bincount(io, dxi * dyi, npc) + (na[:, 0] - mx) * (na[:, 1] - my) + (nb[:, 0] - mx) * (nb[:, 1] - my)
            ang = 0.5 * np.arctan2(2 * sxy, sxx - syy)
            tdir = np.stack([np.cos(ang), np.sin(ang)], axis=1)
            tdir *= np.sign(np.sum(tdir * (nb - na), axis=1))[:, None]
            na = np.stack([mx, my], axis=1) + np.sum((na - np.stack([mx, my], axis=1)) * tdir, axis=1)[:, None] * tdir
            nb = np.stack([mx, my], axis=1) + np.sum((nb - np.stack([mx, my], axis=1)) * tdir, axis=1)[:, None] * tdir
        pa, pb = na[ow], nb[ow]
        d_ab = pb - pa
        L_ab = np.hypot(d_ab[:, 0], d_ab[:, 1])
        t_ab = d_ab / L_ab[:, None]
        qs = q[sid[pos[ends]]]
        w_ = qs - pa
        along = w_[:, 0] * t_ab[:, 0] + w_[:, 1] * t_ab[:, 1]
        across = np.abs(w_[:, 0] * t_ab[:, 1] - w_[:, 1] * t_ab[:, 0])
        mv = (across <= lateral_px) & (along > 0) & (along < L_ab)
        mvi = ends[mv]
        q_out[sid[pos[mvi]]] = pa[mv] + along[mv, None] * t_ab[mv]
        keep[mvi] = True
        stats["samples_moved"] = int(len(mvi))
    w = pos[keep]
    if len(w) == 0:
        return stats
    index[sid[w]] = k[owner[keep]]
    seed_jid[sid[w]] = -1  # no found junction (the PLY's residual of such a sample is junction 0's, pipeline's rule)
    stats["pieces"] = int(np.unique(owner[keep]).size)
    stats["samples"] = int(len(w))
    return stats


# ---- the compiled path (the default options): the same outputs as `_label_piece_junctions_reference` ----


@njit
def _k_nearest_grid(E, U, rows, xy, radius, cell, lateral, use_dir):
    """`_k_associate` with a bucket grid of cell ≥ radius over the nodes xy: for each end rows[a] the nearest
    node closer than radius, not behind the end (along ≥ −1 px) and within lateral of its line (use_dir False:
    the nearest closer than radius). −1 where none."""
    K = xy.shape[0]
    out = np.full(rows.shape[0], -1, np.int64)
    if K == 0:
        return out
    cs = cell
    x0 = xy[:, 0].min() - cs
    y0 = xy[:, 1].min() - cs
    gw = int((xy[:, 0].max() - x0) / cs) + 2
    gh = int((xy[:, 1].max() - y0) / cs) + 2
    start = np.zeros(gw * gh + 1, np.int64)
    cellk = np.empty(K, np.int64)
    for k in range(K):
        cellk[k] = int((xy[k, 1] - y0) / cs) * gw + int((xy[k, 0] - x0) / cs)
        start[cellk[k] + 1] += 1
    for b in range(gw * gh):
        start[b + 1] += start[b]
    fill = start[:-1].copy()
    items = np.empty(K, np.int64)
    for k in range(K):
        items[fill[cellk[k]]] = k
        fill[cellk[k]] += 1
    r2 = radius * radius
    for a in range(rows.shape[0]):
        r = rows[a]
        ex = E[r, 0]
        ey = E[r, 1]
        cx = int(math.floor((ex - x0) / cs))
        cy = int(math.floor((ey - y0) / cs))
        best = -1
        bd = np.inf
        for yy in range(max(cy - 1, 0), min(cy + 2, gh)):
            for xx in range(max(cx - 1, 0), min(cx + 2, gw)):
                b = yy * gw + xx
                for t in range(start[b], start[b + 1]):
                    k = items[t]
                    wx = xy[k, 0] - ex
                    wy = xy[k, 1] - ey
                    d2 = wx * wx + wy * wy
                    if d2 >= r2 or d2 >= bd:
                        continue
                    if use_dir and (wx * U[r, 0] + wy * U[r, 1] < -1.0 or abs(wx * U[r, 1] - wy * U[r, 0]) > lateral):
                        continue
                    bd = d2
                    best = k
        out[a] = best
    return out


@njit
def _k_cluster_hash(c, radius):
    """`_k_cluster` on a hashed bucket grid (cells radius wide, a table of ~2n chains instead of an array over
    the frame's cells, which are a few px wide): the same clusters and numbering."""
    n = c.shape[0]
    parent = np.arange(n)
    if n == 0:
        return parent
    x0 = c[:, 0].min()
    y0 = c[:, 1].min()
    size = 1
    while size < 2 * n:
        size *= 2
    mask = size - 1
    head = np.full(size, -1, np.int64)
    nxt = np.empty(n, np.int64)
    cx = np.empty(n, np.int64)
    cy = np.empty(n, np.int64)
    for i in range(n):
        cx[i] = int((c[i, 0] - x0) / radius)
        cy[i] = int((c[i, 1] - y0) / radius)
        hsh = (cx[i] * 73856093 + cy[i] * 19349663) & mask
        nxt[i] = head[hsh]
        head[hsh] = i
    r2 = radius * radius
    for i in range(n):
        for yy in range(cy[i] - 1, cy[i] + 2):
            for xx in range(cx[i] - 1, cx[i] + 2):
                j = head[(xx * 73856093 + yy * 19349663) & mask]
                while j >= 0:
                    if j > i and cx[j] == xx and cy[j] == yy:
                        dx = c[j, 0] - c[i, 0]
                        dy = c[j, 1] - c[i, 1]
                        if dx * dx + dy * dy < r2:
                            a = i
                            while parent[a] != a:
                                parent[a] = parent[parent[a]]
                                a = parent[a]
                            bb = j
                            while parent[bb] != bb:
                                parent[bb] = parent[parent[bb]]
                                bb = parent[bb]
                            if a != bb:
                                parent[max(a, bb)] = min(a, bb)
                    j = nxt[j]
    return _k_number(parent)


@njit
def _k_assoc_by_node(E, U, node_end, xy, reach, lateral):
    """`_k_associate` of every end without a node (node_end −1) turned around: each node looks for the ends
    within reach around it (a bucket grid of the ends, cells reach wide), an end keeps the nearest node ahead
    of it (along ≥ −1 px, within lateral of its line). −1 where none."""
    R = E.shape[0]
    K = xy.shape[0]
    best = np.full(R, -1, np.int64)
    if R == 0 or K == 0:
        return best
    bd = np.full(R, np.inf)
    cs = reach
    x0 = E[:, 0].min()
    y0 = E[:, 1].min()
    gw = int((E[:, 0].max() - x0) / cs) + 1
    gh = int((E[:, 1].max() - y0) / cs) + 1
    start = np.zeros(gw * gh + 1, np.int64)
    cellr = np.full(R, -1, np.int64)
    for r in range(R):
        if node_end[r] < 0:
            cellr[r] = int((E[r, 1] - y0) / cs) * gw + int((E[r, 0] - x0) / cs)
            start[cellr[r] + 1] += 1
    for b in range(gw * gh):
        start[b + 1] += start[b]
    fill = start[:-1].copy()
    items = np.empty(R, np.int64)
    for r in range(R):
        if cellr[r] >= 0:
            items[fill[cellr[r]]] = r
            fill[cellr[r]] += 1
    r2 = reach * reach
    for k in range(K):
        cx = int(math.floor((xy[k, 0] - x0) / cs))
        cy = int(math.floor((xy[k, 1] - y0) / cs))
        for yy in range(max(cy - 1, 0), min(cy + 2, gh)):
            for xx in range(max(cx - 1, 0), min(cx + 2, gw)):
                b = yy * gw + xx
                for t in range(start[b], start[b + 1]):
                    r = items[t]
                    wx = xy[k, 0] - E[r, 0]
                    wy = xy[k, 1] - E[r, 1]
                    d2 = wx * wx + wy * wy
                    if d2 >= r2 or d2 >= bd[r]:
                        continue
                    if wx * U[r, 0] + wy * U[r, 1] < -1.0 or abs(wx * U[r, 1] - wy * U[r, 0]) > lateral:
                        continue
                    bd[r] = d2
                    best[r] = k
    return best


@njit
def _k_front(q, fam, sid, piece, ts, tangent, index, seed_jid, n_p, anchor, min_samples, step_px, ring, trim_px, reach, sin_min):
    """Steps 0–1: the pieces' ends (`piece_ends`), the candidate pieces (≥ min_samples samples), their end rows
    (rows 0..nc−1 the first ends, nc..2nc−1 the last), the ends searched (unlabelled pieces' and, ring > 0, the
    ends within ring junction steps of one) and their crossings (`_k_end_pairs`). Returns cand, first, last,
    labelled, val, E, U, fe, the hit rows h and their crossings c (h empty when fewer than 3 ends are searched
    or hit: nothing to do)."""
    # the pieces' first and last trace positions; labelled and index from the first labelled sample (as
    # `piece_ends`, without reading every sample of the labelled pieces)
    first = np.full(n_p, -1, np.int64)
    last = np.full(n_p, -1, np.int64)
    for k in range(piece.shape[0]):
        p = piece[k]
        if first[p] < 0:
            first[p] = k
        last[p] = k
    labelled = np.zeros(n_p, np.bool_)
    val = np.full(n_p, np.nan)
    for p in range(n_p):
        for k in range(first[p], last[p] + 1):
            if math.isfinite(index[sid[k]]):
                labelled[p] = True
                val[p] = index[sid[k]]
                break
    nc = 0
    for p in range(n_p):
        if last[p] - first[p] + 1 >= min_samples:
            nc += 1
    cand = np.empty(nc, np.int64)
    m = 0
    for p in range(n_p):
        if last[p] - first[p] + 1 >= min_samples:
            cand[m] = p
            m += 1
    qt = np.empty((sid.shape[0], 2))  # the positions in trace order (the end lines read them in sequence)
    for j in range(sid.shape[0]):
        qt[j, 0] = q[sid[j], 0]
        qt[j, 1] = q[sid[j], 1]
    R = 2 * nc
    E = np.empty((R, 2))
    U = np.empty((R, 2))
    fe = np.empty(R, np.int64)
    ep = np.empty(R, np.int64)
    unl = np.empty(R, np.bool_)
    for r in range(R):
        # the end's sample and outward direction: the chord from the sample `anchor` places inside, or the
        # trace tangent on short chords (`piece_ends`)
        p = cand[r % nc]
        if r < nc:
            k = first[p]
            a = min(k + anchor, last[p])
            sgn = -1.0
        else:
            k = last[p]
            a = max(k - anchor, first[p])
            sgn = 1.0
        E[r, 0] = qt[k, 0]
        E[r, 1] = qt[k, 1]
        d0 = E[r, 0] - qt[a, 0]
        d1 = E[r, 1] - qt[a, 1]
        Ln = math.sqrt(d0 * d0 + d1 * d1)
        if Ln >= 1.5:
            U[r, 0] = d0 / Ln
            U[r, 1] = d1 / Ln
        else:
            U[r, 0] = sgn * tangent[k, 0]
            U[r, 1] = sgn * tangent[k, 1]
        ep[r] = k
        fe[r] = fam[sid[k]]
        unl[r] = not labelled[p]
    h = np.empty(0, np.int64)
    c = np.empty((0, 2))
    if nc == 0:
        return cand, first, last, labelled, val, E, U, fe, h, c
    if ring > 0:
        unl = _k_near_mask(E, unl, step_px, ring)
    ns = 0
    for r in range(R):
        if unl[r]:
            ns += 1
    if ns < 3:
        return cand, first, last, labelled, val, E, U, fe, h, c
    srch = np.empty(ns, np.int64)
    m = 0
    for r in range(R):
        if unl[r]:
            srch[m] = r
            m += 1
    part, cs = _k_end_pairs_f(E, U, ep, first, last, piece, ts, qt, trim_px, anchor, fe, srch, reach, sin_min)
    nh = 0
    for i in range(ns):
        if part[i] >= 0:
            nh += 1
    if nh < 3:
        return cand, first, last, labelled, val, E, U, fe, h, c
    h = np.empty(nh, np.int64)
    c = np.empty((nh, 2))
    m = 0
    for i in range(ns):
        if part[i] >= 0:
            h[m] = srch[i]
            c[m, 0] = cs[i, 0]
            c[m, 1] = cs[i, 1]
            m += 1
    return cand, first, last, labelled, val, E, U, fe, h, c


@njit
def _k_nodes(E, U, fe, h, c, merge_px, reach, lateral, continue_px, x_both, q, fam, x0, y0, cell, gw, gh, start, items, pos_of):
    """Steps 2–3: nodes (clusters of the crossings at their means), the ends without a crossing of their own
    associated by position, the X test (`_k_node_ends`, `_k_continues`). Returns the nodes xy (K, 2), each end
    row's node (−1: none or not an X), the number of ends associated (−1: no association step) and the number
    of nodes that are no crossing."""
    R = E.shape[0]
    nh = h.shape[0]
    node_of_hit = _k_cluster_hash(c, merge_px)
    K = 0
    for i in range(nh):
        K = max(K, node_of_hit[i] + 1)
    sx_ = np.zeros(K)
    sy_ = np.zeros(K)
    cnt = np.zeros(K)
    for i in range(nh):
        k = node_of_hit[i]
        cnt[k] += 1.0
        sx_[k] += c[i, 0]
        sy_[k] += c[i, 1]
    xy = np.empty((K, 2))
    for k in range(K):
        xy[k, 0] = sx_[k] / cnt[k]
        xy[k, 1] = sy_[k] / cnt[k]
    node_end = np.full(R, -1, np.int64)
    for i in range(nh):
        node_end[h[i]] = node_of_hit[i]
    n_assoc = -1
    if reach > 0:
        best = _k_assoc_by_node(E, U, node_end, xy, reach, lateral)
        n_free = 0
        n_assoc = 0
        for r in range(R):
            if node_end[r] < 0:
                n_free += 1
                node_end[r] = best[r]
                if best[r] >= 0:
                    n_assoc += 1
        if n_free == 0:
            n_assoc = -1
    has, sx, sy, ne, off_line = _k_node_ends(node_end, E, U, fe, xy, lateral)
    two = np.zeros((K, 2), np.bool_)
    through = np.zeros((K, 2), np.bool_)
    n_one = 0
    for k in range(K):
        for f in range(2):
            two[k, f] = ne[k, f] >= 2 and math.hypot(sx[k, f], sy[k, f]) <= ne[k, f] - 1.5
            through[k, f] = two[k, f]
    # the continuation test only where it decides: a node with both families, one of them two-sided, no end
    # line off it, and (x_both) a one-sided family (with x_both False a two-sided family is already through)
    ask = np.zeros((K, 2), np.bool_)
    for k in range(K):
        if x_both and has[k, 0] and has[k, 1] and (two[k, 0] or two[k, 1]) and not off_line[k]:
            for f in range(2):
                if not two[k, f]:
                    ask[k, f] = True
                    n_one += 1
    if continue_px > 0 and n_one > 0:
        pts = np.empty((n_one, 2))
        dn = np.empty((n_one, 2))
        fq = np.empty(n_one, np.int64)
        kq = np.empty(n_one, np.int64)
        m = 0
        for k in range(K):
            for f in range(2):
                if ask[k, f]:
                    nrm = max(math.hypot(sx[k, f], sy[k, f]), 1e-12)
                    pts[m, 0] = xy[k, 0]
                    pts[m, 1] = xy[k, 1]
                    dn[m, 0] = sx[k, f] / nrm
                    dn[m, 1] = sy[k, f] / nrm
                    fq[m] = f + 1
                    kq[m] = k
                    m += 1
        cont = _k_continues(pts, dn, fq, q, fam, continue_px, lateral, x0, y0, cell, gw, gh, start, items, pos_of)
        for m in range(n_one):
            through[kq[m], fq[m] - 1] = cont[m]
    x_node = np.empty(K, np.bool_)
    n_not = 0
    for k in range(K):
        thr = (through[k, 0] and through[k, 1]) if x_both else (through[k, 0] or through[k, 1])
        x_node[k] = has[k, 0] and has[k, 1] and thr and (two[k, 0] or two[k, 1]) and not off_line[k]
        if not x_node[k]:
            n_not += 1
    for r in range(R):
        if node_end[r] >= 0 and not x_node[node_end[r]]:
            node_end[r] = -1
    return xy, node_end, n_assoc, n_not


@njit
def _k_edge_inputs(node_end, nc, cand, first, fam, sid, xy):
    """Step 4's inputs to `_extract_kernels.edge_steps`: the pieces with a node at each end (their candidate
    numbers ed), their nodes, family, midpoint, node-to-node vector and length."""
    n = 0
    for i in range(nc):
        a = node_end[i]
        b = node_end[nc + i]
        if a >= 0 and b >= 0 and a != b:
            n += 1
    ed = np.empty(n, np.int64)
    a_j = np.empty(n, np.int64)
    b_j = np.empty(n, np.int64)
    fam_s = np.empty(n, np.int64)
    mid = np.empty((n, 2))
    dq = np.empty((n, 2))
    elen = np.empty(n)
    m = 0
    for i in range(nc):
        a = node_end[i]
        b = node_end[nc + i]
        if a >= 0 and b >= 0 and a != b:
            ed[m] = i
            a_j[m] = a
            b_j[m] = b
            fam_s[m] = fam[sid[first[cand[i]]]]
            dq[m, 0] = xy[b, 0] - xy[a, 0]
            dq[m, 1] = xy[b, 1] - xy[a, 1]
            mid[m, 0] = 0.5 * (xy[a, 0] + xy[b, 0])
            mid[m, 1] = 0.5 * (xy[a, 1] + xy[b, 1])
            elen[m] = math.hypot(dq[m, 0], dq[m, 1])
            m += 1
    return ed, a_j, b_j, fam_s, mid, dq, elen


@njit
def _k_use(n_nodes, edges, eseg, cand, labelled, min_component):
    """Step 5's choice: the nodes of the components that hold an unlabelled piece's edge and at least
    min_component nodes; returns them (sub, ascending), their new numbers (renum, −1: not used) and the edges
    kept (the rows of edges whose first node is used)."""
    cc = _k_components(n_nodes, edges)
    nC = 0
    for k in range(n_nodes):
        nC = max(nC, cc[k] + 1)
    want = np.zeros(nC, np.bool_)
    size = np.zeros(nC, np.int64)
    for k in range(n_nodes):
        size[cc[k]] += 1
    for t in range(edges.shape[0]):
        if not labelled[cand[eseg[t]]]:
            want[cc[edges[t, 0]]] = True
    renum = np.full(n_nodes, -1, np.int64)
    m = 0
    for k in range(n_nodes):
        if want[cc[k]] and size[cc[k]] >= min_component:
            renum[k] = m
            m += 1
    sub = np.empty(m, np.int64)
    for k in range(n_nodes):
        if renum[k] >= 0:
            sub[renum[k]] = k
    ne_ = 0
    for t in range(edges.shape[0]):
        if renum[edges[t, 0]] >= 0:
            ne_ += 1
    ek = np.empty(ne_, np.int64)
    m = 0
    for t in range(edges.shape[0]):
        if renum[edges[t, 0]] >= 0:
            ek[m] = t
            m += 1
    return sub, renum, ek


@njit
def _k_nearest_hash(P, rows, xy, radius):
    """For each point P[rows[a]] the nearest of the nodes xy closer than radius (−1: none), on a hashed bucket
    grid of the nodes (cells radius wide)."""
    K = xy.shape[0]
    out = np.full(rows.shape[0], -1, np.int64)
    if K == 0:
        return out
    size = 1
    while size < 2 * K:
        size *= 2
    mask = size - 1
    x0 = xy[:, 0].min()
    y0 = xy[:, 1].min()
    head = np.full(size, -1, np.int64)
    nxt = np.empty(K, np.int64)
    kcx = np.empty(K, np.int64)
    kcy = np.empty(K, np.int64)
    for k in range(K):
        kcx[k] = int(math.floor((xy[k, 0] - x0) / radius))
        kcy[k] = int(math.floor((xy[k, 1] - y0) / radius))
        hsh = (kcx[k] * 73856093 + kcy[k] * 19349663) & mask
        nxt[k] = head[hsh]
        head[hsh] = k
    r2 = radius * radius
    for a in range(rows.shape[0]):
        px = P[rows[a], 0]
        py = P[rows[a], 1]
        cx = int(math.floor((px - x0) / radius))
        cy = int(math.floor((py - y0) / radius))
        bd = np.inf
        best = -1
        for yy in range(cy - 1, cy + 2):
            for xx in range(cx - 1, cx + 2):
                k = head[(xx * 73856093 + yy * 19349663) & mask]
                while k >= 0:
                    if kcx[k] == xx and kcy[k] == yy:
                        wx = xy[k, 0] - px
                        wy = xy[k, 1] - py
                        d2 = wx * wx + wy * wy
                        if d2 < r2 and (d2 < bd or (d2 == bd and k < best)):
                            bd = d2
                            best = k
                    k = nxt[k]
        out[a] = best
    return out


@njit
def _k_anchors(L, comp, node_end, nc, cand, labelled, val, first, fam, sid, qj, jl, xy, merge_px):
    """Step 6: a node whose label disagrees with a labelled piece ending at it (its family's index) or with a
    labelled found junction within merge_px (qj, jl: the labelled found junctions) is a conflict; every node of
    a conflicting node's component is dropped. Returns ok_node (labelled and kept) and the number of components
    dropped."""
    K = L.shape[0]
    ok = np.empty(K, np.bool_)
    for k in range(K):
        ok[k] = L[k, 0] != UNLABELLED
    conflict = np.zeros(K, np.bool_)
    for r in range(node_end.shape[0]):
        nd = node_end[r]
        if nd < 0:
            continue
        p = cand[r % nc]
        if labelled[p] and ok[nd]:
            f = fam[sid[first[p]]] - 1
            if L[nd, f] != val[p]:
                conflict[nd] = True
    M = qj.shape[0]
    if M > 0:
        # only a found junction within merge_px of a labelled node can be in conflict (with its nearest node, when
        # that is labelled): those junctions from a hashed grid of the junctions around the labelled nodes, then
        # their nearest node of all (a hashed grid of the nodes)
        size = 1
        while size < 2 * M:
            size *= 2
        mask = size - 1
        x0 = qj[:, 0].min()
        y0 = qj[:, 1].min()
        head = np.full(size, -1, np.int64)
        nxt = np.empty(M, np.int64)
        jcx = np.empty(M, np.int64)
        jcy = np.empty(M, np.int64)
        for a in range(M):
            jcx[a] = int(math.floor((qj[a, 0] - x0) / merge_px))
            jcy[a] = int(math.floor((qj[a, 1] - y0) / merge_px))
            hsh = (jcx[a] * 73856093 + jcy[a] * 19349663) & mask
            nxt[a] = head[hsh]
            head[hsh] = a
        r2 = merge_px * merge_px
        near = np.zeros(M, np.bool_)
        n_near = 0
        for k in range(K):
            if not ok[k]:
                continue
            cx = int(math.floor((xy[k, 0] - x0) / merge_px))
            cy = int(math.floor((xy[k, 1] - y0) / merge_px))
            for yy in range(cy - 1, cy + 2):
                for xx in range(cx - 1, cx + 2):
                    a = head[(xx * 73856093 + yy * 19349663) & mask]
                    while a >= 0:
                        if jcx[a] == xx and jcy[a] == yy and not near[a]:
                            wx = xy[k, 0] - qj[a, 0]
                            wy = xy[k, 1] - qj[a, 1]
                            if wx * wx + wy * wy < r2:
                                near[a] = True
                                n_near += 1
                        a = nxt[a]
        if n_near > 0:
            rows = np.empty(n_near, np.int64)
            m = 0
            for a in range(M):
                if near[a]:
                    rows[m] = a
                    m += 1
            nn = _k_nearest_hash(qj, rows, xy, merge_px)
            for m in range(n_near):
                a = rows[m]
                nd = nn[m]
                if nd >= 0 and ok[nd] and (L[nd, 0] != jl[a, 0] or L[nd, 1] != jl[a, 1]):
                    conflict[nd] = True
    nC = 1
    for k in range(K):
        nC = max(nC, comp[k] + 2)
    bad = np.zeros(nC, np.bool_)  # comp + 1 (−1 counts as a value, as np.unique counts it)
    n_bad = 0
    for k in range(K):
        if conflict[k] and not bad[comp[k] + 1]:
            bad[comp[k] + 1] = True
            n_bad += 1
    if n_bad:
        for k in range(K):
            if bad[comp[k] + 1]:
                ok[k] = False
    return ok, n_bad


@njit
def _sign(x):
    if x > 0.0:
        return 1.0
    if x < 0.0:
        return -1.0
    return x  # 0 and NaN as np.sign


@njit
def _k_select(ok_node, L, ed, a_j, b_j, fam_s, cand, labelled, first, last, ts, q, sid, xy, trim_px):
    """Step 7's pieces: the unlabelled pieces between two kept nodes that agree on their index (their edge
    rows sel), and per piece the sums of the total-least-squares line through its samples beyond trim_px from
    its ends and its two nodes: mean (mx, my), sxx, syy, sxy."""
    ns = 0
    for t in range(ed.shape[0]):
        p = cand[ed[t]]
        f = fam_s[t] - 1
        if ok_node[a_j[t]] and ok_node[b_j[t]] and not labelled[p] and L[a_j[t], f] == L[b_j[t], f]:
            ns += 1
    sel = np.empty(ns, np.int64)
    m = 0
    for t in range(ed.shape[0]):
        p = cand[ed[t]]
        f = fam_s[t] - 1
        if ok_node[a_j[t]] and ok_node[b_j[t]] and not labelled[p] and L[a_j[t], f] == L[b_j[t], f]:
            sel[m] = t
            m += 1
    mom = np.empty((ns, 5))
    for i in range(ns):
        t = sel[i]
        p = cand[ed[t]]
        f0 = first[p]
        l0 = last[p]
        na0, na1 = xy[a_j[t], 0], xy[a_j[t], 1]
        nb0, nb1 = xy[b_j[t], 0], xy[b_j[t], 1]
        S0 = 0.0
        S1 = 0.0
        w = 0.0
        for j in range(f0, l0 + 1):
            if min(ts[j] - ts[f0], ts[l0] - ts[j]) >= trim_px:
                S0 += q[sid[j], 0]
                S1 += q[sid[j], 1]
                w += 1.0
        w += 2.0
        mx = (S0 + na0 + nb0) / w
        my = (S1 + na1 + nb1) / w
        sxx = 0.0
        syy = 0.0
        sxy = 0.0
        for j in range(f0, l0 + 1):
            if min(ts[j] - ts[f0], ts[l0] - ts[j]) >= trim_px:
                dxi = q[sid[j], 0] - mx
                dyi = q[sid[j], 1] - my
                sxx += dxi * dxi
                syy += dyi * dyi
                sxy += dxi * dyi
        mom[i, 0] = mx
        mom[i, 1] = my
        mom[i, 2] = sxx + (na0 - mx) * (na0 - mx) + (nb0 - mx) * (nb0 - mx)
        mom[i, 3] = syy + (na1 - my) * (na1 - my) + (nb1 - my) * (nb1 - my)
        mom[i, 4] = sxy + (na0 - mx) * (na1 - my) + (nb0 - mx) * (nb1 - my)
    return sel, mom


@njit
def _k_write(sel, mom, tdir, L, ed, a_j, b_j, fam_s, cand, first, last, ts, q, sid, xy, trim_px, lateral, move, q_out, index, seed_jid):
    """Step 7's writes: the selected pieces (`_k_select`) take their nodes' index; their end samples (within
    trim_px of an end) are moved onto the piece's line (through the mean mom[:, :2] along tdir, the fit's unit
    direction, NumPy's trigonometry) between the nodes' projections when within lateral of it (move; q_out in
    place); the other end samples stay unlabelled. index, seed_jid written in place. Returns pieces, samples
    labelled, samples moved (−1: no move step)."""
    ns = sel.shape[0]
    n_moved = 0
    n_pieces = 0
    n_samples = 0
    for i in range(ns):
        t = sel[i]
        p = cand[ed[t]]
        kk = L[a_j[t], fam_s[t] - 1]
        f0 = first[p]
        l0 = last[p]
        u0 = 0.0
        u1 = 0.0
        pa0 = 0.0
        pa1 = 0.0
        Lab = 0.0
        if move:
            na0, na1 = xy[a_j[t], 0], xy[a_j[t], 1]
            nb0, nb1 = xy[b_j[t], 0], xy[b_j[t], 1]
            mx = mom[i, 0]
            my = mom[i, 1]
            t0 = tdir[i, 0]
            t1 = tdir[i, 1]
            sg = _sign(t0 * (nb0 - na0) + t1 * (nb1 - na1))
            t0 *= sg
            t1 *= sg
            ua = (na0 - mx) * t0 + (na1 - my) * t1
            ub = (nb0 - mx) * t0 + (nb1 - my) * t1
            pa0 = mx + ua * t0
            pa1 = my + ua * t1
            d0 = (mx + ub * t0) - pa0
            d1 = (my + ub * t1) - pa1
            Lab = math.hypot(d0, d1)
            u0 = d0 / Lab
            u1 = d1 / Lab
        got = False
        for j in range(f0, l0 + 1):
            s = sid[j]
            keep = min(ts[j] - ts[f0], ts[l0] - ts[j]) >= trim_px
            if not keep and move:
                w0 = q[s, 0] - pa0
                w1 = q[s, 1] - pa1
                along = w0 * u0 + w1 * u1
                if abs(w0 * u1 - w1 * u0) <= lateral and along > 0 and along < Lab:
                    q_out[s, 0] = pa0 + along * u0
                    q_out[s, 1] = pa1 + along * u1
                    keep = True
                    n_moved += 1
            if keep:
                index[s] = kk
                seed_jid[s] = -1
                n_samples += 1
                got = True
        if got:
            n_pieces += 1
    return n_pieces, n_samples, (n_moved if move else -1)


def label_piece_junctions(
    q: np.ndarray,
    fam: np.ndarray,
    sid: np.ndarray,
    piece: np.ndarray,
    ts: np.ndarray,
    tangent: np.ndarray,
    index: np.ndarray,
    seed_jid: np.ndarray,
    *,
    model: RigModel,
    depth_range_mm: tuple[float, float],
    radius_px: float,
    grid: tuple,
    q_junction: np.ndarray,
    junction_labels: np.ndarray,
    trim_px: float = 0.0,
    merge_px: float | None = None,
    min_samples: int = 2,
    anchor: int = 3,
    reach_px: float = 0.0,
    lateral_px: float = 1.0,
    one_sided: bool = False,
    x_both: bool = True,
    move_ends: bool = True,
    fit_interior: bool = True,
    ring_cells: int = 1,
    continue_px: float | None = None,
    junction_nodes: bool = False,
    end_pairs: bool = True,
    q_out: np.ndarray | None = None,
    label_options=None,
    debug: dict | None = None,
) -> dict:
    """Label unlabelled pieces from junctions built at the crossings of pieces (module doc).

    q (P, 2) camera px, fam (P,) 1/2 of all samples; the traces as `labelling.label_samples` builds them: sid
    (n,) sample ids by piece and position, piece (n,) non-decreasing piece ids, ts (n,) position along the piece
    (px), tangent (n, 2) unit. index (P,) float (NaN: unlabelled), seed_jid (P,) int and q_out (P, 2) (the
    positions to triangulate; None: the end samples are not moved) are written in place (seed_jid −1: no
    found junction). radius_px: how far from a piece's end the crossing is searched when reach_px is 0; grid:
    the frame's bucket grid of the samples (`labelling._sample_grid`, cells ≥ radius_px). q_junction (M, 2),
    junction_labels (M, 2): the found junctions and their labels (anchors). trim_px: the pull of a crossing
    along a piece (`cross_trim_sigma`·σ). merge_px: crossing estimates this close are one node (default 0.25
    junction steps). min_samples: shorter pieces give no crossing estimates and no edges. anchor: the end
    lines' chord length in samples. reach_px: how far ahead of a piece's end its node may lie (half a
    crossing's gap; 0: only the end's own estimate); lateral_px: how far off the end's line (camera px).
    continue_px: how far past a node a one-sided family's line must show a trace sample (default reach_px).
    ring_cells: the labelled pieces whose ends are searched too lie within this many junction steps of an
    unlabelled piece's end. label_options: `labelling.LabelOptions` (default: min_component 3; the depth range
    is set from depth_range_mm).

    The method's options (the defaults) run compiled (`_k_front`, `_k_nodes`, `_k_edge_inputs`, `_k_use`,
    `_k_anchors`, `_k_write`: decision 0092, "Time"); the measurement switches (one_sided, x_both False is
    compiled too, move_ends False, fit_interior False, junction_nodes, end_pairs False) run
    `_label_piece_junctions_reference`, whose outputs the compiled path reproduces bit for bit. debug: filled
    with the nodes' positions `xy` and labels `labels` (UNLABELLED where none).
    Returns counts: nodes, edges, nodes used and labelled, ends associated by position, nodes that are no
    crossing, components rejected by an anchor, the sub-labeller's left-out reasons, pieces and samples
    labelled, end samples moved."""
    if one_sided or not move_ends or not fit_interior or junction_nodes or not end_pairs:
        return _label_piece_junctions_reference(
            q, fam, sid, piece, ts, tangent, index, seed_jid, model=model, depth_range_mm=depth_range_mm, radius_px=radius_px, grid=grid,
            q_junction=q_junction, junction_labels=junction_labels, trim_px=trim_px, merge_px=merge_px, min_samples=min_samples,
            anchor=anchor, reach_px=reach_px, lateral_px=lateral_px, one_sided=one_sided, x_both=x_both, move_ends=move_ends,
            fit_interior=fit_interior, ring_cells=ring_cells, continue_px=continue_px, junction_nodes=junction_nodes, end_pairs=end_pairs,
            q_out=q_out, label_options=label_options, debug=debug)
    from reconstruction.labelling import LabelOptions, label_epipolar

    stats = {"nodes": 0, "edges": 0, "nodes_labelled": 0, "components_anchor_conflict": 0, "pieces": 0, "samples": 0}
    n = len(piece)
    if n == 0:
        return stats
    n_p = int(piece[-1]) + 1
    if merge_px is None:
        merge_px = 0.25 * model.junction_step_cam_px
    # 1. crossings at the ends of unlabelled pieces and of the labelled ones around them
    cand, first, last, labelled, val, E, U, fe, h, c = _k_front(
        q, fam, sid, piece, ts, tangent, index, seed_jid, n_p, int(anchor), int(min_samples), float(model.junction_step_cam_px),
        int(ring_cells), float(trim_px), float(reach_px if reach_px > 0 else radius_px), _SIN_MIN_CROSSING)
    if len(h) == 0:
        return stats
    nc = len(cand)
    # 2–3. nodes, ends associated by position, only X's
    if continue_px is None:
        continue_px = reach_px
    xy, node_end, n_assoc, n_not = _k_nodes(E, U, fe, h, c, float(merge_px), float(reach_px), float(lateral_px), float(continue_px),
                                            bool(x_both), q, fam, *grid)
    n_nodes = len(xy)
    stats["nodes"] = n_nodes
    if n_assoc >= 0:
        stats["ends_associated"] = int(n_assoc)
    stats["nodes_not_crossing"] = int(n_not)
    # 4. edges: pieces with a node at both ends
    ed, a_j, b_j, fam_s, mid, dq, elen = _k_edge_inputs(node_end, nc, cand, first, fam, sid, xy)
    if len(ed) == 0:
        return stats
    edges, _, delta, eseg, _ = _ek.edge_steps(ed, a_j, b_j, fam_s, mid, dq, elen, model.J_proj_cam, float(model.cell_px),
                                             float(model.pattern.n1), float(model.pattern.n2), n_nodes)
    stats["edges"] = int(len(edges))
    if len(edges) == 0:
        return stats
    # 5. the default labeller on the components that hold an unlabelled piece between two of their nodes
    lo = label_options if label_options is not None else LabelOptions(min_component=3)
    lo = LabelOptions(**{**lo.__dict__, "depth_min_mm": float(depth_range_mm[0]), "depth_max_mm": float(depth_range_mm[1])})
    edges = np.ascontiguousarray(edges, np.int64)
    sub, renum, ek = _k_use(n_nodes, edges, np.ascontiguousarray(eseg, np.int64), cand, labelled, int(lo.min_component))
    stats["nodes_used"] = int(len(sub))
    if len(sub) == 0:
        return stats
    obs = SimpleNamespace(q_junction=xy[sub], edges=renum[edges[ek]], edge_delta=delta[ek])
    lab_sub = label_epipolar(obs, model, model.cam_normalised(xy[sub]), options=lo)
    L = np.full((n_nodes, 2), UNLABELLED, np.int64)
    L[sub] = lab_sub.labels
    comp = np.full(n_nodes, -1, np.int64)
    comp[sub] = lab_sub.component
    stats["left_out"] = {k: v for k, v in lab_sub.stats["junctions_left_out"].items() if v}
    if not (L[:, 0] != UNLABELLED).any():
        return stats
    # 6. anchors: labelled pieces ending at a node, labelled found junctions nearby
    jl = np.asarray(junction_labels, np.int64).reshape(-1, 2)
    lj = np.flatnonzero(jl[:, 0] != UNLABELLED)
    qj = np.ascontiguousarray(np.asarray(q_junction, np.float64).reshape(-1, 2)[lj])
    ok_node, n_bad = _k_anchors(L, comp, node_end, nc, cand, labelled, val, first, fam, sid, qj, np.ascontiguousarray(jl[lj]), xy,
                                float(merge_px))
    if n_bad:
        stats["components_anchor_conflict"] = int(n_bad)
    stats["nodes_labelled"] = int(ok_node.sum())
    if debug is not None:
        debug.update(xy=xy, labels=np.where(ok_node[:, None], L, UNLABELLED))
    # 7. the pieces between two labelled nodes that agree on their index
    sel, mom = _k_select(ok_node, L, ed, a_j, b_j, fam_s, cand, labelled, first, last, ts, q, sid, xy, float(trim_px))
    if len(sel) == 0:
        return stats
    # the fit's direction with NumPy's arctan2 (its SIMD version differs from the C library's in the last bit)
    ang = 0.5 * np.arctan2(2 * mom[:, 4], mom[:, 2] - mom[:, 3])
    tdir = np.stack([np.cos(ang), np.sin(ang)], axis=1)
    move = q_out is not None
    n_pc, n_s, n_mv = _k_write(sel, mom, tdir, L, ed, a_j, b_j, fam_s, cand, first, last, ts, q, sid, xy, float(trim_px),
                               float(lateral_px), move, q_out if move else np.empty((0, 2)), index, seed_jid)
    if n_mv >= 0:
        stats["samples_moved"] = int(n_mv)
    stats["pieces"] = int(n_pc)
    stats["samples"] = int(n_s)
    return stats
