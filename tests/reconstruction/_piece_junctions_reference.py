"""The first NumPy implementation of decision 0092's piece junctions and the kernels only it uses, moved out of
`reconstruction.piece_junctions` (decision 0097): the reference the compiled path is tested against bit for bit
(`test_recon_piece_junctions.py`), and the home of the measurement switches decision 0092 reports (`one_sided`,
`move_ends=False`, `fit_interior=False`, `junction_nodes`, `end_pairs=False`; `x_both=False` is compiled too).

`_k_cluster` (single linkage on a bucket grid), `_k_associate` (the nearest node ahead of an end) and `_k_end_pairs`
(the crossings of end lines, one bucket grid for both families) are the first versions of the module's
`_k_cluster_hash`, `_k_assoc_by_node` and `_k_end_pairs_f`, which give the same results (tested)."""

from __future__ import annotations

import math

from types import SimpleNamespace

import numpy as np

from reconstruction import _extract_kernels as _ek
from reconstruction._continuation_kernels import piece_ends
from reconstruction._jit import njit
from reconstruction._label_kernels import _union_find_root, crossing_hits_traces
from reconstruction.piece_junctions import _k_components, _k_continues, _k_near_mask, _k_node_ends, _k_number
from reconstruction.piece_seeds import _SIN_MIN_CROSSING, _k_end_line, _k_refine
from reconstruction.rigmodel import UNLABELLED, RigModel


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
