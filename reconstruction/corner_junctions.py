"""Corner junctions: T-shaped crossings kept as junctions of the graph (an option, off by default: decision 0102).

Extraction keeps a crossing candidate only where both lines run through it (samples of each family on
both sides, decision 0041). A T — one family through, the other ending at it — is left out because it
may be a silhouette or a shadow edge. On the paper presets (junction step ~60 camera px, σ ≈ 5 px) every
missing junction costs whole line pieces, and most missed visible junctions there are L's and T's.

`corner_candidates` picks the candidates the arm tests rejected only because one family does not run through
(each family ≥ 3 arm samples, straight fits, no sideways jump, not parallel, the fitted intersection on the
candidate: its position is the intersection of the two fitted lines, well defined with a stem on one side);
`dark_beyond` keeps those whose stem's missing side is dark (a shadow edge or the pattern's rim, not an
occluding edge with the front surface lit beyond); `corner_kinds` says which family runs through.
`ExtractOptions.corner_junctions` keeps them as junctions of the graph.

Measured in decision 0102: the corners' labels are almost all right, but the samples they seed are not
(the through line at a silhouette continues as another surface's line; an occlusion T's stem inherits the
near surface's index: one-sided evidence), so the option adds points more than 1 % off on five of the eight
bench scenes and is off by default. L shapes (no family through) are never corners: on paper-orthogonal
they mislabel whole pieces (148 points more than 1 % off).

Everything here works in extraction's working pixels (half resolution on the wide-line path).
"""

from __future__ import annotations

import math

import numpy as np

from reconstruction._jit import njit


@njit(error_model="numpy")
def corner_candidates(valid, cnt, n_neg, n_pos, rms, jump, par, offc, qj, rms_tol):
    """The candidates that the arm tests rejected only because one family does not run through.

    valid (ns,) bool: the arm tests' verdict (`_extract_kernels.junction_verdicts`); cnt, n_neg, n_pos, rms
    (2·ns,) per candidate and family (rows 2·k + family − 1, `junction_fits`): arm samples, inliers before and
    after the candidate along the fit, RMS distance from the fit (working px); jump, par, offc (ns,) bool:
    a sideways jump or a turn of the samples against the fit, the two fits parallel, the intersection off the
    candidate; qj (ns, 2): the intersection; rms_tol: the straightness limit (working px).

    Returns corner (ns,) bool: not valid, each family ≥ 3 arm samples with samples on at least one side, one
    family with samples on both sides (a T, not an L), both fits straight, no jump, not parallel, the
    intersection finite and on the candidate."""
    ns = len(valid)
    corner = np.zeros(ns, np.bool_)
    for k in range(ns):
        if valid[k] or jump[k] or par[k] or offc[k]:
            continue
        a = 2 * k
        b = a + 1
        if cnt[a] < 3 or cnt[b] < 3:
            continue
        if rms[a] > rms_tol or rms[b] > rms_tol:
            continue
        side_a = (n_neg[a] >= 1) or (n_pos[a] >= 1)
        side_b = (n_neg[b] >= 1) or (n_pos[b] >= 1)
        thr_a = (n_neg[a] >= 1) and (n_pos[a] >= 1)
        thr_b = (n_neg[b] >= 1) and (n_pos[b] >= 1)
        if not (side_a and side_b and (thr_a or thr_b)):
            continue
        if not (math.isfinite(qj[k, 0]) and math.isfinite(qj[k, 1])):
            continue
        corner[k] = True
    return corner


@njit
def corner_kinds(corner, n_neg, n_pos, new_id, M):
    """(M,) int8 for the kept junctions (new_id (ns + 1,) candidate → kept id, −1 dropped): 0 a junction both
    lines run through, 1 a corner whose i-line runs through (the j-line ends at it), 2 one whose j-line does."""
    kind = np.zeros(M, np.int8)
    for k in range(len(corner)):
        j = new_id[k]
        if corner[k] and j >= 0:
            a = 2 * k
            kind[j] = 1 if (n_neg[a] >= 1 and n_pos[a] >= 1) else 2
    return kind


@njit(error_model="numpy")
def dark_beyond(corner, qj, dr, n_neg, n_pos, qx, qy, r_in, r_out, half_width, max_samples):
    """Keep only the corners whose stem's missing side is dark: no more than `max_samples` line samples (either
    family; qx, qy float32 working px) lie beyond the through line on the side where the stem would go on,
    from r_in to r_out along the stem's fitted direction and within half_width across it. A shadow edge or
    the pattern's rim leaves that side dark; an occluding edge leaves the surface in front there, lit with
    its own lines (decision 0102). dr (2·ns, 2) the fits' directions; n_neg, n_pos (2·ns,) the inlier
    counts before and after the candidate along them. Modifies `corner` in place; returns how many it drops."""
    ns = len(corner)
    P = len(qx)
    if P == 0:
        return 0
    # a bucket grid of the samples, cells of r_out (counting sort)
    lox = np.float64(qx[0])
    loy = np.float64(qy[0])
    hix = lox
    hiy = loy
    for i in range(P):
        lox = min(lox, np.float64(qx[i]))
        loy = min(loy, np.float64(qy[i]))
        hix = max(hix, np.float64(qx[i]))
        hiy = max(hiy, np.float64(qy[i]))
    cs = max(r_out, 1.0)
    gw = int((hix - lox) / cs) + 1
    gh = int((hiy - loy) / cs) + 1
    start = np.zeros(gw * gh + 1, np.int64)
    cell = np.empty(P, np.int64)
    for i in range(P):
        c = int((np.float64(qy[i]) - loy) / cs) * gw + int((np.float64(qx[i]) - lox) / cs)
        cell[i] = c
        start[c + 1] += 1
    for c in range(gw * gh):
        start[c + 1] += start[c]
    fill = start[:-1].copy()
    order = np.empty(P, np.int64)
    for i in range(P):
        order[fill[cell[i]]] = i
        fill[cell[i]] += 1
    dropped = 0
    for k in range(ns):
        if not corner[k]:
            continue
        a = 2 * k
        g = a if not (n_neg[a] >= 1 and n_pos[a] >= 1) else a + 1  # the stem's fit
        sgn = -1.0 if n_pos[g] >= 1 else 1.0  # the stem's samples are on the + side: the missing side is −
        ux = sgn * dr[g, 0]
        uy = sgn * dr[g, 1]
        cx = int((qj[k, 0] - lox) / cs)
        cy = int((qj[k, 1] - loy) / cs)
        count = 0
        for yy in range(max(cy - 1, 0), min(cy + 2, gh)):
            for xx in range(max(cx - 1, 0), min(cx + 2, gw)):
                c = yy * gw + xx
                for t in range(start[c], start[c + 1]):
                    i = order[t]
                    dx = np.float64(qx[i]) - qj[k, 0]
                    dy = np.float64(qy[i]) - qj[k, 1]
                    s = dx * ux + dy * uy
                    w = abs(dx * uy - dy * ux)
                    if s >= r_in and s <= r_out and w <= half_width:
                        count += 1
        if count > max_samples:
            corner[k] = False
            dropped += 1
    return dropped
