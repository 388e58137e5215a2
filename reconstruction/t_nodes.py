"""Crossings with one family through: T nodes of decision 0092's node graph (decision 0098).

Decision 0092's X test keeps a node only where both families' lines run through it (pieces on both sides, or
a trace sample past it). With one family through (`x_both=False`) the nodes where the other family's line
stops join the graph too: the T's. Three kinds of T are seen in a camera image of the grid:

- the pattern's rim (decision 0041): the through line is the pattern's first or last line, the stems end
  there because no light lies beyond. The node is a true crossing and the through line is whole;
- a silhouette: the through line runs along an occluding edge that hides part of its profile, so its ridge
  (the sub-pixel centre) sits off the line's centre, towards the visible half. The node is a true crossing
  (its labels come out right) but every sample of the through line there is off by a share of a spacing
  (0.03 spacings, up to 0.78 % in depth, on paper-orthogonal);
- a shadow's or an occlusion's edge where the stem lies on one surface and the through line on another.

The stems' pieces at any T are whole lines on one surface and are labelled as at an X. The through line's
pieces between nodes of which one is a T are taken only where the T is the pattern's rim: the through line's
label (from the component's offset) is the pattern's first or last index, so no light lies beyond it and
nothing hides it. Elsewhere the T node serves the topology only (it joins the component and carries its
labels to the stems) and the half-hidden line it sits on stays unlabelled.

Round 2 (decision 0098, "Round 2"; `label_piece_junctions(t_rule="after")`, the default): the T's do not join
the graph given to the labeller. The components of the X nodes alone are labelled first (`x_use`, then
`labelling.label_epipolar` as in decision 0092); a T then takes the labels that all its labelled X neighbours
imply through their edges (`t_labels`), and stays unlabelled where they disagree. So a T never joins two
components and never brings an offset of its own: at a silhouette, where the stems' surface and the through
line's surface have index systems an arbitrary offset apart, the T can only carry the stems' own labels,
which the stem pieces' X ends already have. Round 1 (`t_rule="graph"`, the T's in the labeller's graph) is
kept as a measurement switch.

Kernels:
- `x_use`, `t_labels`: round 2 (above);
- `t_node_stems`: per node, the family whose line stops there (its stem), or −1 where both go through (an X
  by decision 0092's test: two-sided, or a trace sample past the node within continue_px);
- `through_kept`: which of step 7's selected pieces may be written.
"""

from __future__ import annotations

import math

import numpy as np

from reconstruction._jit import njit
from reconstruction._label_kernels import _union_find_join, _union_find_root
from reconstruction.piece_junctions import _k_continues, _k_leaves_frame, _k_node_ends


@njit
def t_node_stems(xy, node_end, E, U, fe, lateral, continue_px, q, fam, x0, y0, cell, gw, gh, start, items, pos_of, fw=0.0, fh=0.0, margin=0.0):
    """The stem of each node: 0 or 1 (family 1 or 2) where that family's line stops at the node, −1 where
    both families' lines go through it (or the node has no ends).

    xy (K, 2) the nodes, camera px; node_end (R,) each end row's node (−1: none), after the X test with one
    family through (`piece_junctions._k_nodes`, x_both False); E (R, 2), U (R, 2), fe (R,): the ends' samples,
    outward unit directions, families; lateral: how far off an end's line a node may be (px); continue_px: how
    far past the node a one-sided family's line must show a trace sample to go through
    (`piece_junctions._k_continues`); q, fam and the frame's bucket grid of the samples as `_k_nodes` takes
    them. A family goes through where its ends lie on both sides of the node (decision 0092's two-sided
    rule: ne ≥ 2 and |Σ outward| ≤ ne − 1.5) or its line shows a sample past the node, or (decision 0143; fw > 0) its
    one end's line leaves the frame fw × fh (less margin px) within continue_px past the node."""
    K = xy.shape[0]
    stem = np.full(K, -1, np.int64)
    has, sx, sy, ne, off = _k_node_ends(node_end, E, U, fe, xy, lateral)
    n_q = 0
    for k in range(K):
        if has[k, 0] and has[k, 1]:
            for f in range(2):
                if not (ne[k, f] >= 2 and math.hypot(sx[k, f], sy[k, f]) <= ne[k, f] - 1.5):
                    n_q += 1
    if n_q == 0:
        return stem
    pts = np.empty((n_q, 2))
    dn = np.empty((n_q, 2))
    fq = np.empty(n_q, np.int64)
    kq = np.empty(n_q, np.int64)
    m = 0
    for k in range(K):
        if has[k, 0] and has[k, 1]:
            for f in range(2):
                if not (ne[k, f] >= 2 and math.hypot(sx[k, f], sy[k, f]) <= ne[k, f] - 1.5):
                    nrm = max(math.hypot(sx[k, f], sy[k, f]), 1e-12)
                    pts[m, 0] = xy[k, 0]
                    pts[m, 1] = xy[k, 1]
                    dn[m, 0] = sx[k, f] / nrm
                    dn[m, 1] = sy[k, f] / nrm
                    fq[m] = f + 1
                    kq[m] = k
                    m += 1
    if continue_px > 0:
        cont = _k_continues(pts, dn, fq, q, fam, continue_px, lateral, x0, y0, cell, gw, gh, start, items, pos_of)
    else:
        cont = np.zeros(n_q, np.bool_)
    for m in range(n_q):
        if not cont[m] and not (ne[kq[m], fq[m] - 1] == 1 and _k_leaves_frame(pts[m, 0], pts[m, 1], dn[m, 0], dn[m, 1], continue_px, fw, fh, margin)):
            stem[kq[m]] = fq[m] - 1
    return stem


@njit
def through_kept(sel, ed_a, ed_b, fam_s, stem, L, index_min, index_max):
    """Which selected pieces (rows sel of step 7's edge arrays: end nodes ed_a, ed_b, family fam_s 1/2) may be
    written: not a piece of the through line at a T node (stem[node] the other family), unless the label L
    (K, 2) of that line there is the pattern's first or last index (index_min, index_max: the pattern's rim,
    whole and unhidden). Returns a bool mask over sel."""
    n = sel.shape[0]
    keep = np.ones(n, np.bool_)
    for i in range(n):
        t = sel[i]
        f = fam_s[t] - 1
        for nd in (ed_a[t], ed_b[t]):
            s = stem[nd]
            if s >= 0 and s != f:
                k = L[nd, f]
                if k != index_min and k != index_max:
                    keep[i] = False
    return keep


@njit
def _at_t(stem, nd, f):
    """Is node nd a T on a line of family f (0/1) going through it (its stem the other family)?"""
    return stem[nd] >= 0 and stem[nd] != f


@njit
def through_refit(sel, mom, ed, ed_a, ed_b, fam_s, cand, first, last, ts, q, sid, xy, stem, trim_px, min_inner):
    """Step 7's line fit again, for the selected pieces of a through line at a T, without the T node(s): the
    stem's light reaches the through line from one side only there, so the T node (the crossing of the end
    lines) is pulled across the through line towards the stem (decision 0098: about twice the X nodes'
    offset). The total-least-squares sums (mom rows: mean x, y, sxx, syy, sxy, as `piece_junctions._k_select`
    writes them) over the piece's samples beyond trim_px from its ends and its nodes (xy) that are not such a
    T, written in place where the piece has at least min_inner such samples. Returns per selected piece: 0 no
    T on its line, 1 refitted, 2 a T but too few samples (its samples near the T are then left unlabelled:
    `through_end_samples`)."""
    n = sel.shape[0]
    out = np.zeros(n, np.int64)
    for i in range(n):
        t = sel[i]
        f = fam_s[t] - 1
        ta = _at_t(stem, ed_a[t], f)
        tb = _at_t(stem, ed_b[t], f)
        if not (ta or tb):
            continue
        p = cand[ed[t]]
        f0 = first[p]
        l0 = last[p]
        S0 = 0.0
        S1 = 0.0
        w = 0.0
        for j in range(f0, l0 + 1):
            if min(ts[j] - ts[f0], ts[l0] - ts[j]) >= trim_px:
                S0 += q[sid[j], 0]
                S1 += q[sid[j], 1]
                w += 1.0
        if w < min_inner:
            out[i] = 2
            continue
        if not ta:
            S0 += xy[ed_a[t], 0]
            S1 += xy[ed_a[t], 1]
            w += 1.0
        if not tb:
            S0 += xy[ed_b[t], 0]
            S1 += xy[ed_b[t], 1]
            w += 1.0
        mx = S0 / w
        my = S1 / w
        sxx = 0.0
        syy = 0.0
        sxy = 0.0
        for j in range(f0, l0 + 1):
            if min(ts[j] - ts[f0], ts[l0] - ts[j]) >= trim_px:
                dx = q[sid[j], 0] - mx
                dy = q[sid[j], 1] - my
                sxx += dx * dx
                syy += dy * dy
                sxy += dx * dy
        for m in range(2):
            nd = ed_a[t] if m == 0 else ed_b[t]
            if (m == 0 and not ta) or (m == 1 and not tb):
                dx = xy[nd, 0] - mx
                dy = xy[nd, 1] - my
                sxx += dx * dx
                syy += dy * dy
                sxy += dx * dy
        mom[i, 0] = mx
        mom[i, 1] = my
        mom[i, 2] = sxx
        mom[i, 3] = syy
        mom[i, 4] = sxy
        out[i] = 1
    return out


@njit
def through_end_samples(sel, ed, ed_a, ed_b, fam_s, cand, first, last, ts, sid, stem, trim_px, rows):
    """The samples (ids) of the selected pieces' ends within trim_px of a T node on their through line (stem
    the other family): the stem's light reaches the through line from one side only there, so its ridge is
    pulled sideways towards the stem (at an X the crossing line's light lies on both sides). These are left
    unlabelled (step 7 would move them onto the piece's fitted line). ed: the edge rows' candidate pieces
    (cand[ed[t]] the piece), ed_a / ed_b their nodes at the piece's first / last sample; rows (bool over
    sel): the pieces to look at (the others' ends are moved as at an X, after `through_refit`)."""
    n = 0
    for i in range(sel.shape[0]):
        if not rows[i]:
            continue
        t = sel[i]
        f = fam_s[t] - 1
        p = cand[ed[t]]
        ta = _at_t(stem, ed_a[t], f)
        tb = _at_t(stem, ed_b[t], f)
        if ta or tb:
            for j in range(first[p], last[p] + 1):
                if (ta and ts[j] - ts[first[p]] < trim_px) or (tb and ts[last[p]] - ts[j] < trim_px):
                    n += 1
    out = np.empty(n, np.int64)
    m = 0
    for i in range(sel.shape[0]):
        if not rows[i]:
            continue
        t = sel[i]
        f = fam_s[t] - 1
        p = cand[ed[t]]
        ta = _at_t(stem, ed_a[t], f)
        tb = _at_t(stem, ed_b[t], f)
        if ta or tb:
            for j in range(first[p], last[p] + 1):
                if (ta and ts[j] - ts[first[p]] < trim_px) or (tb and ts[last[p]] - ts[j] < trim_px):
                    out[m] = sid[j]
                    m += 1
    return out


@njit
def x_use(n_nodes, edges, eseg, cand, labelled, stem, min_component):
    """Round 2 (T's after the X's): step 5's choice on the graph of the X nodes only (stem −1; the edges with
    both nodes X). A component of that graph is labelled when it has at least min_component nodes and an
    unlabelled piece's edge at one of its nodes (to an X or to a T: the stems the T's then carry). Returns
    as `piece_junctions._k_use`: the nodes used (sub, ascending), their new numbers (renum, −1: not used)
    and the rows of edges between two used nodes (ek)."""
    parent = np.arange(n_nodes)
    for t in range(edges.shape[0]):
        a = edges[t, 0]
        b = edges[t, 1]
        if stem[a] < 0 and stem[b] < 0:
            _union_find_join(parent, a, b)
    root = np.empty(n_nodes, np.int64)
    size = np.zeros(n_nodes, np.int64)
    for k in range(n_nodes):
        root[k] = _union_find_root(parent, k)
        if stem[k] < 0:
            size[root[k]] += 1
    want = np.zeros(n_nodes, np.bool_)
    for t in range(edges.shape[0]):
        if not labelled[cand[eseg[t]]]:
            for m in range(2):
                nd = edges[t, m]
                if stem[nd] < 0:
                    want[root[nd]] = True
    renum = np.full(n_nodes, -1, np.int64)
    m = 0
    for k in range(n_nodes):
        if stem[k] < 0 and want[root[k]] and size[root[k]] >= min_component:
            renum[k] = m
            m += 1
    sub = np.empty(m, np.int64)
    for k in range(n_nodes):
        if renum[k] >= 0:
            sub[renum[k]] = k
    ne_ = 0
    for t in range(edges.shape[0]):
        if renum[edges[t, 0]] >= 0 and renum[edges[t, 1]] >= 0:
            ne_ += 1
    ek = np.empty(ne_, np.int64)
    m = 0
    for t in range(edges.shape[0]):
        if renum[edges[t, 0]] >= 0 and renum[edges[t, 1]] >= 0:
            ek[m] = t
            m += 1
    return sub, renum, ek


@njit
def t_labels(L, comp, stem, edges, delta, unlabelled):
    """Round 2: the T nodes' labels from the labelled X nodes next to them, written in place into L (K, 2)
    and comp (K,). A T takes L[x] ± delta of every edge to a labelled X node x (edges (E, 2), L[b] = L[a] +
    delta[t]); it is labelled only where all of them agree (never a new offset: a T whose neighbours come
    from two components with different index systems stays unlabelled). Then every edge between two
    labelled T's must agree with its delta, else both stay unlabelled. Each labelled T gets a component of
    its own (an anchor conflict at a T drops the T, not the component it was labelled from). Returns the
    number of T's labelled and the number left out by a disagreement."""
    K = L.shape[0]
    n_imp = np.zeros(K, np.int64)
    bad = np.zeros(K, np.bool_)
    Li = np.zeros((K, 2), np.int64)
    for t in range(edges.shape[0]):
        for m in range(2):
            x = edges[t, m]
            y = edges[t, 1 - m]
            if stem[x] >= 0 or stem[y] < 0 or L[x, 0] == unlabelled:
                continue
            sgn = 1 if m == 0 else -1
            i = L[x, 0] + sgn * delta[t, 0]
            j = L[x, 1] + sgn * delta[t, 1]
            if n_imp[y] == 0:
                Li[y, 0] = i
                Li[y, 1] = j
            elif Li[y, 0] != i or Li[y, 1] != j:
                bad[y] = True
            n_imp[y] += 1
    ok = np.zeros(K, np.bool_)
    for k in range(K):
        ok[k] = stem[k] >= 0 and n_imp[k] > 0 and not bad[k]
    drop = np.zeros(K, np.bool_)
    for t in range(edges.shape[0]):
        a = edges[t, 0]
        b = edges[t, 1]
        if ok[a] and ok[b]:
            if Li[b, 0] - Li[a, 0] != delta[t, 0] or Li[b, 1] - Li[a, 1] != delta[t, 1]:
                drop[a] = True
                drop[b] = True
    c_next = 0
    for k in range(K):
        c_next = max(c_next, comp[k] + 1)
    n_ok = 0
    n_bad = 0
    for k in range(K):
        if stem[k] < 0 or n_imp[k] == 0:
            continue
        if ok[k] and not drop[k]:
            L[k, 0] = Li[k, 0]
            L[k, 1] = Li[k, 1]
            comp[k] = c_next
            c_next += 1
            n_ok += 1
        else:
            n_bad += 1
    return n_ok, n_bad


@njit
def rim_ts(stem, node_end, nc, cand, labelled, val, first, fam, sid, index_min, index_max):
    """Round 2, option "rim": the T's known to be at the pattern's rim before this step's labelling: a piece of
    the through family ending at the T is already labelled (found junctions, earlier steps: labelled, val)
    with the pattern's first or last index (index_min, index_max). node_end (R,) each end row's node (row r
    is an end of the piece cand[r % nc]). Returns a bool per node."""
    K = stem.shape[0]
    out = np.zeros(K, np.bool_)
    for r in range(node_end.shape[0]):
        nd = node_end[r]
        if nd < 0 or stem[nd] < 0:
            continue
        p = cand[r % nc]
        if not labelled[p]:
            continue
        f = fam[sid[first[p]]] - 1
        if f != stem[nd] and (val[p] == index_min or val[p] == index_max):
            out[nd] = True
    return out
