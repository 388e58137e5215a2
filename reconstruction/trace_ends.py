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
"""

from __future__ import annotations

import math

import numpy as np

from reconstruction._jit import njit


@njit
def seeded_far_ends(sid, piece, seed, index, unlabelled, q, tangent, fam):
    """The ends of seeded trace pieces beyond their seeds.

    Trace positions in order (sid (n,) sample ids, piece (n,) non-decreasing); seed (P,) the junction index
    of seed samples (unlabelled elsewhere); index (P,) float: the samples' line index. For every piece whose
    seeds all carry one value and whose end lies past its outermost seed: the end sample's position e (E, 2),
    its tangent te (E, 2), sign (E,) (−1 first end, +1 last end), family fe (E,), the piece's index k (E,),
    and the trace positions lo, hi (E,) of the stretch between the seed and that end (inclusive)."""
    n = sid.shape[0]
    ne = 0
    # pass 1 counts, pass 2 writes
    e = np.empty((0, 2))
    te = np.empty((0, 2))
    sign = np.empty(0)
    fe = np.empty(0, np.int64)
    kk = np.empty(0, np.int64)
    lo = np.empty(0, np.intp)
    hi = np.empty(0, np.intp)
    for rnd in range(2):
        if rnd == 1:
            e = np.empty((ne, 2))
            te = np.empty((ne, 2))
            sign = np.empty(ne)
            fe = np.empty(ne, np.int64)
            kk = np.empty(ne, np.int64)
            lo = np.empty(ne, np.intp)
            hi = np.empty(ne, np.intp)
        c = 0
        a = 0
        while a < n:
            b = a
            while b + 1 < n and piece[b + 1] == piece[a]:
                b += 1
            fs = -1
            ls = -1
            v = unlabelled
            one = True
            for k in range(a, b + 1):
                s = seed[sid[k]]
                if s != unlabelled:
                    if fs < 0:
                        fs = k
                        v = s
                    elif s != v:
                        one = False
                    ls = k
            if fs >= 0 and one:
                for side in range(2):
                    if side == 0:
                        if fs == a:
                            continue
                        k_end, k_lo, k_hi = a, a, fs - 1
                    else:
                        if ls == b:
                            continue
                        k_end, k_lo, k_hi = b, ls + 1, b
                    x = index[sid[k_end]]
                    if not math.isfinite(x):
                        continue
                    if rnd == 1:
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
        ne = c
    return e, te, sign, fe, kk, lo, hi


@njit
def unlabel_stretches(cut, lo, hi, sid, index, seed_jid):
    """index = NaN and seed_jid = −1 for the samples at trace positions lo[r]..hi[r] of the rows r with
    cut[r]. Returns how many samples lost their label."""
    m = 0
    for r in range(cut.shape[0]):
        if not cut[r]:
            continue
        for k in range(lo[r], hi[r] + 1):
            s = sid[k]
            if math.isfinite(index[s]):
                index[s] = np.nan
                seed_jid[s] = -1
                m += 1
    return m


def cut_far_ends(q, fam, sid, piece, tangent, seed, index, seed_jid, model, depth_range_mm, radius_px: float,
                 tol_px: float, grid: tuple, unlabelled: int) -> int:
    """Take the label off the stretch of a seeded piece between its outermost seed and an end whose crossing
    with a labelled line of the other family names another line of the piece's family (module doc).

    q (P, 2) camera px; fam (P,); sid, piece, tangent: the traces (positions in order); seed (P,) the
    seeds' index; index (P,) float and seed_jid (P,), modified in place. radius_px: how far from the end the
    crossing's other line may be (camera px); tol_px: the crossing's largest distance from a line centre
    (projector px); grid: `labelling._sample_grid` of the valid samples, cells at least radius_px wide.
    Returns the number of samples that lost their label."""
    from reconstruction import _label_kernels as _k

    e, te, sign, fe, kk, lo, hi = seeded_far_ends(sid, piece, seed, index, unlabelled, q, tangent, fam)
    if len(e) == 0:
        return 0
    _, bk = _k.crossing_nearest(e, fe, q, fam, index, True, float(radius_px), *grid)
    o, c = _k.crossing_test(e, te, sign, bk, q, sid, tangent, float(radius_px), float(np.sin(np.deg2rad(20))))
    sel = np.flatnonzero(o >= 0)
    if len(sel) == 0:
        return 0
    m = index[sid[o[sel]]].astype(np.int64)
    _, z, k_other, res = model.sheet_check(c[sel], 3 - fe[sel], m)  # light sheet m: the line of family fe it names
    cut = np.zeros(len(e), np.bool_)
    cut[sel] = (res <= tol_px) & (z >= depth_range_mm[0]) & (z <= depth_range_mm[1]) & (k_other != kk[sel])
    if not cut.any():
        return 0
    return int(unlabel_stretches(cut, lo, hi, sid, index, seed_jid))
