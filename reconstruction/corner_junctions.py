"""Corner junctions: T-shaped crossings kept as junctions of the graph, their biased samples left out (decision 0102).

Extraction keeps a crossing candidate only where both lines run through it (samples of each family on
both sides, decision 0041). A T — one family through, the other ending at it — is left out because it
may be a silhouette or a shadow edge. On the paper presets (junction step ~60 camera px, σ ≈ 5 px) that
costs whole pieces: a piece between two crossings one of which is a T has one junction end at most,
so it joins no component of the graph and stays unlabelled ("no seed").

Measured (decision 0102): at the T's that the arm tests reject and that are otherwise straight junctions
(each family ≥ 3 arm samples, straight fits, no sideways jump, not parallel, the fitted intersection on the
candidate), the label the epipolar labeller gives is right; what goes wrong when they are simply kept is the
position of the samples next to them: the through line's ridge is pulled by the stem's light (or half hidden
by the occluding edge) and the stem's end is pulled by the through line, within about one core radius plus
one smoothing scale. So a corner junction

1. joins the graph like any junction (its position: the intersection of the two families' fitted lines,
   which is well defined with a stem on one side only), and so carries the component's labels to the
   pieces that end at it, and
2. gives up its samples within `r_bias` (the core plus one smoothing scale, the radius extraction already
   uses around rejected candidates): they belong neither to it nor to a segment, exactly as around a
   rejected candidate.

L shapes (no family through) are not corners: measured on paper-orthogonal, keeping them mislabels whole
pieces (148 points more than 1 % off).

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
