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
   tangent on pieces too short for that), ahead of both ends, the nearest such one (`_k_end_pairs_f`).
2. **Nodes.** The estimates of one crossing (up to four: the two pieces of each line that end in its gap)
   closer than `merge_px` to one another are one node (single linkage, `_k_cluster_hash`); it sits at their mean.
   An end without an estimate of its own takes the nearest node ahead of it on its end line (within
   `reach_px`, half a crossing's gap, and `lateral_px` across it; `_k_assoc_by_node`).
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

Speed (decision 0092, "Time, round 2"): everything but `label_epipolar` and the fit's angle runs in six compiled
kernels (`_k_front`, `_k_nodes`, `_k_edge_inputs`, `_k_use`, `_k_anchors`, `_k_select`/`_k_write`) around
`_extract_kernels.edge_steps`. The first NumPy version, with decision 0092's measurement switches (`one_sided`,
`move_ends`, `fit_interior`, `junction_nodes`, `end_pairs`), lives in the tests since decision 0097
(`tests/reconstruction/_piece_junctions_reference.py`), as the reference the compiled path reproduces bit for bit.
"""

from __future__ import annotations

import math

from types import SimpleNamespace

import numpy as np

from reconstruction import _extract_kernels as _ek
from reconstruction._jit import njit
from reconstruction._label_kernels import _union_find_join, _union_find_root
from reconstruction.piece_seeds import _SIN_MIN_CROSSING
from reconstruction.rigmodel import UNLABELLED, RigModel

# the sub-labeller's options without label_options, per depth range (built once: ~15 µs a call; never mutated)
_DEFAULT_LO: dict = {}


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
        _union_find_join(parent, edges[k, 0], edges[k, 1])
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
    bucket grid (`_label_kernels.sample_grid`; with `sample_grid_split`'s layout, start of length 2·gw·gh + 1,
    only the query's family's part of each cell is read)."""
    n = pts.shape[0]
    out = np.zeros(n, np.bool_)
    ring = int(math.ceil(reach / cell))
    G = gw * gh
    split = start.shape[0] == 2 * G + 1
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
                t0 = start[b]
                t1 = start[b + 1]
                if split:
                    if fams[i] == 1:
                        t1 = start[G + 1 + b]
                    else:
                        t0 = start[G + 1 + b]
                for t in range(t0, t1):
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
def _k_leaves_frame(x, y, dx, dy, reach, fw, fh, margin):
    """Decision 0143: does the line from (x, y) along the unit direction (dx, dy) leave the frame (fw × fh camera
    px, less margin px at every side) within reach px? There its continuation cannot be seen: a node whose line
    runs out of the image a short way past it shows one side only without being a T. A point inside the margin band
    itself (or beyond the frame) is not judged: False (the ridges there are fitted against the frame's edge, a node
    there may be an extrapolation into it). fw ≤ 0: never."""
    if fw <= 0.0:
        return False
    if x < margin or y < margin or x > fw - 1.0 - margin or y > fh - 1.0 - margin:
        return False
    ex = x + reach * dx
    ey = y + reach * dy
    return ex < margin or ey < margin or ex > fw - 1.0 - margin or ey > fh - 1.0 - margin


@njit
def _k_end_pairs_f(E, U, pos, first, last, piece, ts, q, sid, trim_px, anchor, fe, rows, radius, sin_min):
    """The crossing at each end rows[i]: among the ends of the other family within radius of its end sample
    E (R, 2), the intersection of the two end lines that lies ahead of both ends (along their outward
    directions, from −1 px to radius) and nearest to this end; lines meeting at a sine below sin_min are
    skipped. An end's line lies beyond the crossing's pull (`piece_seeds._k_end_line` of trace position
    pos[r]: from the first sample trim_px inside the end, along the chord `anchor` samples further in), or is
    the end sample and its outward direction U where the piece is too short; computed when first needed.
    The ends are bucketed in one grid per family (cells radius wide); the end lines read q (P, 2) through
    sid. Returns the partner end (−1: none) and the crossing c (n, 2).
    (The reference's `_k_end_pairs`, one grid for both families, gives the same results: decision 0097.)"""
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
        xa = max(cx - 1, 0)
        xb = min(cx + 2, gw)
        for yy in range(max(cy - 1, 0), min(cy + 2, gh)):
            # a row's cells are consecutive buckets: one run, the same ends in the same order (decision 0157)
            for t in range(start[g0 + yy * gw + xa], start[g0 + yy * gw + xb] if xb > xa else start[g0 + yy * gw + xa]):
                    ddx = Ec[t, 0] - E[r, 0]
                    ddy = Ec[t, 1] - E[r, 1]
                    if ddx * ddx + ddy * ddy >= r2:
                        continue
                    o = items[t]
                    for zz in range(2):
                        z = r if zz == 0 else o
                        if not done[z]:
                            # `piece_seeds._k_end_line` written out (a call per end costs more than the line)
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
                                ax = q[sid[j], 0]
                                ay = q[sid[j], 1]
                                dx = ax - q[sid[j2], 0]
                                dy = ay - q[sid[j2], 1]
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


# ---- the steps' kernels (decision 0092, "Time"; the reference they reproduce: decision 0097) ----


@njit
def _k_cluster_hash(c, radius):
    """Single-linkage clusters of the points c (N, 2) closer than radius, numbered by their lowest member, on a
    hashed bucket grid (cells radius wide, a table of ~2n chains instead of an array over the frame's cells,
    which are a few px wide; union–find)."""
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
    """For every end without a node (node_end −1; position E[r], outward unit direction U[r]): the nearest node
    of xy (K, 2) within reach of the end, not behind it (along ≥ −1 px) and within lateral of its end line; −1
    where none. Each node looks for the ends within reach around it (a hashed bucket grid of the ends without
    a node, cells reach wide: a frame-wide grid of cells a few px wide was most of the time); an end sees the
    nodes in increasing order, as with the grid (decision 0097)."""
    R = E.shape[0]
    K = xy.shape[0]
    best = np.full(R, -1, np.int64)
    if R == 0 or K == 0:
        return best
    bd = np.full(R, np.inf)
    cs = reach
    x0 = E[:, 0].min()
    y0 = E[:, 1].min()
    nf = 0
    for r in range(R):
        if node_end[r] < 0:
            nf += 1
    size = 1
    while size < 2 * nf:
        size *= 2
    mask = size - 1
    head = np.full(size, -1, np.int64)
    nxt = np.empty(R, np.int64)
    ecx = np.empty(R, np.int64)
    ecy = np.empty(R, np.int64)
    for r in range(R):
        if node_end[r] < 0:
            ecx[r] = int((E[r, 0] - x0) / cs)
            ecy[r] = int((E[r, 1] - y0) / cs)
            hsh = (ecx[r] * 73856093 + ecy[r] * 19349663) & mask
            nxt[r] = head[hsh]
            head[hsh] = r
    r2 = reach * reach
    for k in range(K):
        cx = int(math.floor((xy[k, 0] - x0) / cs))
        cy = int(math.floor((xy[k, 1] - y0) / cs))
        for yy in range(cy - 1, cy + 2):
            for xx in range(cx - 1, cx + 2):
                r = head[(xx * 73856093 + yy * 19349663) & mask]
                while r >= 0:
                    if ecx[r] == xx and ecy[r] == yy:
                        wx = xy[k, 0] - E[r, 0]
                        wy = xy[k, 1] - E[r, 1]
                        d2 = wx * wx + wy * wy
                        if d2 < r2 and d2 < bd[r]:
                            if not (wx * U[r, 0] + wy * U[r, 1] < -1.0 or abs(wx * U[r, 1] - wy * U[r, 0]) > lateral):
                                bd[r] = d2
                                best[r] = k
                    r = nxt[r]
    return best


@njit
def _k_front(q, fam, sid, piece, ts, tangent, index, seed_jid, n_p, anchor, min_samples, step_px, ring, trim_px, reach, sin_min):
    """Steps 0–1: the pieces' ends (`piece_ends`), the candidate pieces (≥ min_samples samples), their end rows
    (rows 0..nc−1 the first ends, nc..2nc−1 the last), the ends searched (unlabelled pieces' and, ring > 0, the
    ends within ring junction steps of one) and their crossings (`_k_end_pairs_f`). Returns cand, first, last,
    labelled, val, E, U, fe, the hit rows h and their crossings c (h empty when fewer than 3 ends are searched
    or hit: nothing to do)."""
    # the pieces' first and last trace positions; labelled and index from the first labelled sample (as
    # `piece_ends`, without reading every sample of the labelled pieces)
    first = np.full(n_p, -1, np.int64)
    last = np.full(n_p, -1, np.int64)
    labelled = np.zeros(n_p, np.bool_)
    val = np.full(n_p, np.nan)
    for k in range(piece.shape[0]):  # one pass; a labelled piece's index is not read past its first labelled sample
        p = piece[k]
        if first[p] < 0:
            first[p] = k
        last[p] = k
        if not labelled[p]:
            v = index[sid[k]]
            if math.isfinite(v):
                labelled[p] = True
                val[p] = v
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
        E[r, 0] = q[sid[k], 0]
        E[r, 1] = q[sid[k], 1]
        d0 = E[r, 0] - q[sid[a], 0]
        d1 = E[r, 1] - q[sid[a], 1]
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
    part, cs = _k_end_pairs_f(E, U, ep, first, last, piece, ts, q, sid, trim_px, anchor, fe, srch, reach, sin_min)
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
def _k_nodes(E, U, fe, h, c, merge_px, reach, lateral, continue_px, x_both, q, fam, x0, y0, cell, gw, gh, start, items, pos_of,
             fw=0.0, fh=0.0, margin=0.0):
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
            if not two[k, f] and ne[k, f] == 1 and continue_px > 0:
                # decision 0143: one end, and its line leaves the frame within continue_px past the node: the far
                # side cannot be seen, the frame is no edge of the surface (fw 0: off)
                nrm = max(math.hypot(sx[k, f], sy[k, f]), 1e-12)
                two[k, f] = _k_leaves_frame(xy[k, 0], xy[k, 1], sx[k, f] / nrm, sy[k, f] / nrm, continue_px, fw, fh, margin)
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
    labelled found junction within merge_px (qj (M, 2), jl (M, 2): the found junctions and their labels; the
    unlabelled ones, jl UNLABELLED, are skipped) is a conflict; every node of
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
    M = 0
    x0 = np.inf
    y0 = np.inf
    for a in range(qj.shape[0]):
        if jl[a, 0] != UNLABELLED:
            M += 1
            x0 = min(x0, qj[a, 0])
            y0 = min(y0, qj[a, 1])
    if M > 0:
        # only a found junction within merge_px of a labelled node can be in conflict (with its nearest node, when
        # that is labelled): those junctions from a hashed grid of the junctions around the labelled nodes, then
        # their nearest node of all (a hashed grid of the nodes)
        size = 1
        while size < 2 * M:
            size *= 2
        mask = size - 1
        MA = qj.shape[0]
        head = np.full(size, -1, np.int64)
        nxt = np.empty(MA, np.int64)
        jcx = np.empty(MA, np.int64)
        jcy = np.empty(MA, np.int64)
        for a in range(MA):
            if jl[a, 0] == UNLABELLED:
                continue
            jcx[a] = int(math.floor((qj[a, 0] - x0) / merge_px))
            jcy[a] = int(math.floor((qj[a, 1] - y0) / merge_px))
            hsh = (jcx[a] * 73856093 + jcy[a] * 19349663) & mask
            nxt[a] = head[hsh]
            head[hsh] = a
        r2 = merge_px * merge_px
        near = np.zeros(MA, np.bool_)
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
            for a in range(MA):
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


@njit
def _k_short_pairs(sub, renum, ek, edges, xy, min_px, at_frame):
    """`_short_pairs_out`'s test, compiled: (m,) bool, the used nodes (sub (m,)) in components of exactly two (over
    the edges rows ek, node numbers renum) that are not at the frame or closer than min_px."""
    m = sub.shape[0]
    parent = np.arange(m)
    for t in ek:
        _union_find_join(parent, renum[edges[t, 0]], renum[edges[t, 1]])
    r = np.empty(m, np.int64)
    size = np.zeros(m, np.int64)
    first = np.full(m, -1, np.int64)
    second = np.full(m, -1, np.int64)
    for a in range(m):
        r[a] = _union_find_root(parent, a)
        size[r[a]] += 1
        if first[r[a]] < 0:
            first[r[a]] = a
        elif second[r[a]] < 0:
            second[r[a]] = a
    drop = np.zeros(m, np.bool_)
    for c in range(m):
        if size[c] == 2:
            a = first[c]
            b = second[c]
            na = sub[a]
            nb = sub[b]
            if not (at_frame[na] or at_frame[nb]) or math.hypot(xy[na, 0] - xy[nb, 0], xy[na, 1] - xy[nb, 1]) < min_px:
                drop[a] = True
                drop[b] = True
    return drop


def _short_pairs_out(sub: np.ndarray, renum: np.ndarray, ek: np.ndarray, edges: np.ndarray, xy: np.ndarray, min_px: float,
                     at_frame: np.ndarray):
    """Decision 0143: of the nodes used (sub, their new numbers renum, the edges between them ek, as `t_nodes.x_use`
    returns them), the components of exactly two nodes are kept only where one of them lies at the frame (at_frame
    (K,) bool, by node: the frame, not the surface, cut the component short) and the two lie min_px apart or more.
    Elsewhere a pair is left to the lone crossings (decision 0139), which label both lines at each node (on unseen
    seed 153 the pairs took pieces from 0139's nodes: coverage −0.36 points). Between two crossings closer than
    min_px the piece's samples all lie within the crossings' pull (the mixing zone and the trimmed ends): its edge
    names the line right, but the samples it writes are biased across the line, on a face whose lines run near the
    epipolar direction a depth error of percent (unseen seed 126: two points 1.3 and 1.6 % off). Returns sub,
    renum, ek."""
    drop = _k_short_pairs(sub, renum, ek, edges, xy, float(min_px), at_frame)
    if not drop.any():
        return sub, renum, ek
    keep_sub = sub[~drop]
    renum2 = np.full(len(renum), -1, np.int64)
    renum2[keep_sub] = np.arange(len(keep_sub))
    ek2 = ek[(renum2[edges[ek, 0]] >= 0) & (renum2[edges[ek, 1]] >= 0)]
    return keep_sub, renum2, ek2


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
    x_both: bool = True,
    ring_cells: int = 1,
    continue_px: float | None = None,
    q_out: np.ndarray | None = None,
    label_options=None,
    debug: dict | None = None,
    t_nodes: bool = False,
    t_ends: str = "refit",
    t_rule: str = "after",
    frame_through: bool = False,
    frame_margin_px: float = 0.0,
    pair_min_px: float = 0.0,
) -> dict:
    """Label unlabelled pieces from junctions built at the crossings of pieces (module doc).

    t_nodes: nodes with one family through (T's) join the graph too; the through line's pieces at a T are
    written only at the pattern's rim, their line fitted without the T node ("refit"; `reconstruction.t_nodes`,
    decision 0098; the compiled path only). Measurement switch t_ends: "drop" (the through line's samples within
    trim_px of a T stay unlabelled), "keep" (moved as at an X). t_rule: "after" (decision 0098, round 2: the
    components of the X nodes alone are labelled first, a T then takes the labels its labelled X neighbours
    agree on and joins nothing: `t_nodes.x_use`, `t_nodes.t_labels`), "graph" (round 1: the T's join the
    graph given to `label_epipolar`; a T at a silhouette can join two surfaces; a measurement switch), "rim"
    ("after", with the T's whose through piece is already labelled with the pattern's first or last index
    joining the graph as X's: `t_nodes.rim_ts`; a measurement switch).

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
    unlabelled piece's end. x_both (False: a node is a crossing when one family's line passes through it; a
    measurement switch). label_options: `labelling.LabelOptions` (default: min_component 3; the depth range
    is set from depth_range_mm).

    pair_min_px: with label_options' min_component 2, a component of two nodes is labelled only where one of them
    lies within continue_px of the frame (frame_through on) and the two lie at least this far apart (decision 0143:
    its one edge must hold samples beyond both crossings' pull).
    frame_through: a family with one end at a node whose line leaves the camera frame (less frame_margin_px) within
    continue_px past the node counts as running through it, in the X test and for the T's stems (decision 0143).

    Compiled (`_k_front`, `_k_nodes`, `_k_edge_inputs`, `_k_use`, `_k_anchors`, `_k_select`, `_k_write`: decision
    0092, "Time"); decision 0092's other measurement switches run only in the NumPy reference in the tests
    (decision 0097). debug: filled with the nodes' positions `xy` and labels `labels` (UNLABELLED where none).
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
    fw, fh = (float(model.procam.camera.width), float(model.procam.camera.height)) if frame_through else (0.0, 0.0)
    xy, node_end, n_assoc, n_not = _k_nodes(E, U, fe, h, c, float(merge_px), float(reach_px), float(lateral_px), float(continue_px),
                                            bool(x_both and not t_nodes), q, fam, *grid, fw, fh, float(frame_margin_px))
    if t_nodes:  # decision 0098: which family stops at each node
        from reconstruction.t_nodes import rim_ts, t_labels, t_node_stems, through_end_samples, through_kept, through_refit, x_use

        stem = t_node_stems(xy, node_end, E, U, fe, float(lateral_px), float(continue_px), q, fam, *grid, fw, fh, float(frame_margin_px))
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
    d_rng = (float(depth_range_mm[0]), float(depth_range_mm[1]))
    lo = _DEFAULT_LO.get(d_rng) if label_options is None else None
    if lo is None:
        lo = label_options if label_options is not None else LabelOptions(min_component=3)
        lo = LabelOptions(**{**lo.__dict__, "depth_min_mm": d_rng[0], "depth_max_mm": d_rng[1]})
        if label_options is None and len(_DEFAULT_LO) < 64:
            _DEFAULT_LO[d_rng] = lo
    edges = np.ascontiguousarray(edges, np.int64)
    t_after = t_nodes and t_rule in ("after", "rim")
    if t_after:  # decision 0098, round 2: the X nodes' components first, without the T's
        stem_g = stem
        if t_rule == "rim":  # the T's whose through piece is already labelled with the rim index join as X's
            rim = rim_ts(stem, node_end, nc, cand, labelled, val, first, fam, sid, int(model.index_min), int(model.index_max))
            stem_g = np.where(rim, -1, stem)
            stats["t_rim"] = int(rim.sum())
        sub, renum, ek = x_use(n_nodes, edges, np.ascontiguousarray(eseg, np.int64), cand, labelled, stem_g, int(lo.min_component))
    else:
        sub, renum, ek = _k_use(n_nodes, edges, np.ascontiguousarray(eseg, np.int64), cand, labelled, int(lo.min_component))
    if len(sub) and int(lo.min_component) <= 2:
        # decision 0143: a component of two nodes only where the frame cut it (a node within continue_px of the
        # frame's edge, less the margin) and its nodes lie pair_min_px apart
        if fw > 0:
            d_edge = np.minimum(np.minimum(xy[:, 0], xy[:, 1]), np.minimum(fw - 1.0 - xy[:, 0], fh - 1.0 - xy[:, 1])) - float(frame_margin_px)
            at_frame = d_edge <= float(continue_px)
        else:
            at_frame = np.zeros(n_nodes, bool)
        sub, renum, ek = _short_pairs_out(sub, renum, ek, edges, np.ascontiguousarray(xy, np.float64), float(pair_min_px), at_frame)
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
    if t_after:  # the T's take the labels their labelled X neighbours agree on
        n_t, n_t_bad = t_labels(L, comp, stem_g, edges, np.ascontiguousarray(delta, np.int64), UNLABELLED)
        stats["t_labelled"], stats["t_disagree"] = int(n_t), int(n_t_bad)
    if not (L[:, 0] != UNLABELLED).any():
        return stats
    # 6. anchors: labelled pieces ending at a node, labelled found junctions nearby
    jl = np.ascontiguousarray(np.asarray(junction_labels, np.int64).reshape(-1, 2))
    qj = np.ascontiguousarray(np.asarray(q_junction, np.float64).reshape(-1, 2))
    ok_node, n_bad = _k_anchors(L, comp, node_end, nc, cand, labelled, val, first, fam, sid, qj, jl, xy, float(merge_px))
    if n_bad:
        stats["components_anchor_conflict"] = int(n_bad)
    stats["nodes_labelled"] = int(ok_node.sum())
    if debug is not None:
        debug.update(xy=xy, labels=np.where(ok_node[:, None], L, UNLABELLED))
    # 7. the pieces between two labelled nodes that agree on their index
    sel, mom = _k_select(ok_node, L, ed, a_j, b_j, fam_s, cand, labelled, first, last, ts, q, sid, xy, float(trim_px))
    if t_nodes and len(sel):  # decision 0098: no half-hidden through line at a T off the pattern's rim
        keep = through_kept(sel, a_j, b_j, fam_s, stem, L, int(model.index_min), int(model.index_max))
        sel, mom = sel[keep], mom[keep]
        t_rows = np.zeros(len(sel), np.int64) if t_ends == "keep" else (
            through_refit(sel, mom, ed, a_j, b_j, fam_s, cand, first, last, ts, q, sid, xy, stem, float(trim_px), 2)
            if t_ends == "refit" else np.full(len(sel), 2, np.int64))
    if len(sel) == 0:
        return stats
    # the fit's direction with NumPy's arctan2 (its SIMD version differs from the C library's in the last bit)
    ang = 0.5 * np.arctan2(2 * mom[:, 4], mom[:, 2] - mom[:, 3])
    tdir = np.empty((len(ang), 2))
    np.cos(ang, out=tdir[:, 0])
    np.sin(ang, out=tdir[:, 1])
    move = q_out is not None
    if t_nodes:  # decision 0098: the through line's ends at a T not refitted stay as they were
        keep_s = through_end_samples(sel, ed, a_j, b_j, fam_s, cand, first, last, ts, sid, stem, float(trim_px), t_rows == 2)
        keep_v = (index[keep_s].copy(), seed_jid[keep_s].copy(), q_out[keep_s].copy() if move else None)
    n_pc, n_s, n_mv = _k_write(sel, mom, tdir, L, ed, a_j, b_j, fam_s, cand, first, last, ts, q, sid, xy, float(trim_px),
                               float(lateral_px), move, q_out if move else np.empty((0, 2)), index, seed_jid)
    if t_nodes and len(keep_s):
        n_s -= int(np.isfinite(index[keep_s]).sum() - np.isfinite(keep_v[0]).sum())
        index[keep_s], seed_jid[keep_s] = keep_v[0], keep_v[1]
        if move:
            q_out[keep_s] = keep_v[2]
    if n_mv >= 0:
        stats["samples_moved"] = int(n_mv)
    stats["pieces"] = int(n_pc)
    stats["samples"] = int(n_s)
    return stats
