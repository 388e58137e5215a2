"""Label trace pieces that one crossing with a labelled line names and the next crossing confirms (decision 0089).

`labelling.label_samples` labels a piece without a seed from the crossings at its ends only when *both* ends
cross labelled lines of the other family and name the same line (step 6, decision 0052): one-sided evidence
was removed because a piece seeded from one end ran on across a depth edge (decision 0049). Many pieces stay
unlabelled at the border of a labelled patch: one end crosses a labelled line m, the other end crosses a line
of the other family that is not labelled (yet). Here such a piece is labelled when that second crossing is
checked on the piece's own light sheet:

1. **Near end.** The crossing c₁ with the nearest labelled sample of the other family (line m; the search
   and the check of step 6: the intersection of the two tangents, triangulated on light sheet m, lands within
   `tol_px` projector px of line k of the piece's family, inside the depth range). A far end whose labelled
   crossing fails or names another line disqualifies the piece (that is step 6's disagreement).
2. **Far end.** The far end has no labelled sample of the other family within reach; its crossing c₂ with
   the nearest sample of the other family (any, labelled or not) is triangulated on light sheet k. Its
   projector point must lie within `tol_px` of line m ± 1 of the other family, inside the depth range. A piece
   is cut at every crossing (the mixing zone), so between its two crossings its line advances by exactly one
   line of the other family: the piece spans one cell of the pattern on sheet k. If the piece ran across a
   depth edge onto a line of another surface that continues it in the image (decision 0084's trap: along the
   camera plane the depth on sheet k stays continuous, so no test along the trace sees it), c₂ is a junction
   (k′, m′) of that surface; on sheet k its ray lands where the projector's epipolar line of c₂, which passes
   through (k′, m′), meets line k — on a line of the other family only where the epipolar direction runs
   through another junction, and on m ± 1 in particular only by a coincidence of the two depths. A far end
   without a crossing (a silhouette, a shadow, the pattern's edge) gives no confirmation and the piece stays
   unlabelled. The far crossing is the intersection of the two pieces' end lines beyond the crossing's pull
   (from the first sample `trim_px` inside each end, along the chord `anchor` samples further in), or of the
   tangents where a piece is too short for that.
3. **Working volume.** Every sample of the piece, triangulated on sheet k, lies inside the depth range.

The piece's samples within `trim_px` of its ends are left out (the crossings' light pulls the ridge there; the
gap filling of `label_samples` puts them on the line where the line is labelled on both sides). Repeated for
`rounds` rounds: newly labelled pieces are labelled lines for the next round's near ends.

All per-end work is vectorised over the pieces: the ends (`_continuation_kernels.piece_ends`), the crossing
searches (`_label_kernels.crossing_hits_traces` on the frame's bucket grid) and the light-sheet checks
(`RigModel.sheet_check`).
"""

from __future__ import annotations

import math

import numpy as np

from reconstruction._continuation_kernels import piece_ends
from reconstruction._jit import njit
from reconstruction._label_kernels import crossing_hits_traces
from reconstruction.rigmodel import RigModel

_SIN_MIN_CROSSING = float(np.sin(np.deg2rad(20.0)))  # the crossing searches' smallest crossing angle


@njit
def _k_end_line(p_end, first, last, piece, ts, q, sid, trim_px, anchor):
    """The line of a piece's end beyond the crossing's pull: the first sample at least trim_px (along the trace)
    inside from the end at trace position p_end, and the unit chord to it from the sample `anchor` places
    further in: (ok, x, y, ux, uy), ok False when the piece is too short."""
    p = piece[p_end]
    step = 1 if p_end == first[p] else -1
    stop = last[p] if step == 1 else first[p]
    t0 = ts[p_end]
    j = p_end
    while j != stop and abs(ts[j] - t0) < trim_px:
        j += step
    if abs(ts[j] - t0) < trim_px:
        return False, 0.0, 0.0, 0.0, 0.0
    j2 = j
    for _ in range(anchor):
        if j2 == stop:
            break
        j2 += step
    ax, ay = q[sid[j], 0], q[sid[j], 1]
    dx, dy = ax - q[sid[j2], 0], ay - q[sid[j2], 1]
    L = math.hypot(dx, dy)
    if L < 1.5:
        return False, 0.0, 0.0, 0.0, 0.0
    return True, ax, ay, dx / L, dy / L


@njit
def _k_refine(p_far, o_partner, rows, c, first, last, piece, ts, q, sid, trim_px, anchor):
    """The far crossings from both pieces' end lines beyond the crossing's pull (`_k_end_line`): for each far end
    p_far[r], the intersection of its piece's end line with that of the partner's piece (the piece of trace
    position o_partner[r]) at its end nearer the crossing, written to c[rows[r]] in place; c unchanged where
    either piece is too short or the lines are nearly parallel. tests/reconstruction/test_recon_piece_seeds.py
    compares it with the per-end Python code it replaced (last bits: Python's math.hypot is correctly rounded)."""
    for r in range(p_far.shape[0]):
        ok, ax, ay, ux, uy = _k_end_line(p_far[r], first, last, piece, ts, q, sid, trim_px, anchor)
        if not ok:
            continue
        i = rows[r]
        pp = piece[o_partner[r]]
        f, g = first[pp], last[pp]
        cx, cy = c[i, 0], c[i, 1]
        df = math.hypot(q[sid[f], 0] - cx, q[sid[f], 1] - cy)
        dg = math.hypot(q[sid[g], 0] - cx, q[sid[g], 1] - cy)
        ok2, bx, by, vx, vy = _k_end_line(f if df <= dg else g, first, last, piece, ts, q, sid, trim_px, anchor)
        if not ok2:
            continue
        den = ux * vy - uy * vx
        if abs(den) < _SIN_MIN_CROSSING:
            continue
        t = ((bx - ax) * vy - (by - ay) * vx) / den
        c[i, 0] = ax + t * ux
        c[i, 1] = ay + t * uy


def seed_one_sided(
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
    trim_px: float = 0.0,
    tol_px: float = 1.0,
    min_samples: int = 4,
    anchor: int = 3,
    rounds: int = 1,
    confirm_far: bool = True,
    refine: bool = True,
) -> dict:
    """Label unlabelled pieces whose crossing with a labelled line at one end names line k and whose crossing
    at the other end lands, on light sheet k, on the next line of the other family (module doc).

    q (P, 2) camera px, fam (P,) 1/2 of all samples; the traces as `labelling.label_samples` builds them: sid
    (n,) sample ids by piece and position, piece (n,) non-decreasing piece ids, ts (n,) position along the piece
    (px), tangent (n, 2) unit. index (P,) float (NaN: unlabelled) and seed_jid (P,) int are written in place
    (seed_jid: the junction of the labelled sample at the near end's crossing). radius_px: how far from a
    piece's end the crossings are searched (step 6's `cross_radius` junction steps); grid: the frame's bucket
    grid of the samples (`labelling._sample_grid`, cells ≥ radius_px). tol_px: projector px. Pieces shorter
    than min_samples are not tried. confirm_far=False skips step 2 (one-sided evidence alone, decision 0049's
    rule: for measurements only). refine=False takes the far crossing from the end tangents only (measurements).
    rounds: repetitions, newly labelled pieces serving as labelled lines. Returns counts: pieces and samples
    labelled, far ends rejected, far ends without a crossing."""
    stats = {"pieces": 0, "samples": 0, "far_rejected": 0, "far_missing": 0}
    n = len(piece)
    if n == 0:
        return stats
    n_p = int(piece[-1]) + 1
    z_lo, z_hi = float(depth_range_mm[0]), float(depth_range_mm[1])
    for _ in range(rounds):
        e, u, end_pos, labelled, _, _ = piece_ends(q, sid, piece, tangent, index, seed_jid, n_p, int(anchor))
        first, last = end_pos[:n_p], end_pos[n_p:]
        count = last - first + 1
        cand = np.flatnonzero(~labelled & (count >= min_samples))
        nc = len(cand)
        if nc == 0:
            break
        rows = np.concatenate((cand, cand + n_p))
        E = np.ascontiguousarray(e[rows])
        U = np.ascontiguousarray(u[rows])
        fe = fam[sid[end_pos[rows]]].astype(np.int64)
        # 1. each end's crossing with the nearest labelled sample of the other family, checked on its sheet m
        o, c = crossing_hits_traces(E, U, np.ones(2 * nc), fe, q, sid, tangent, fam, index, True, float(radius_px),
                                    _SIN_MIN_CROSSING, *grid)
        hit = o >= 0
        k_end = np.full(2 * nc, np.iinfo(np.int64).min, np.int64)
        m_end = np.zeros(2 * nc, np.int64)
        ok = np.zeros(2 * nc, bool)
        h = np.flatnonzero(hit)
        if len(h) == 0:
            break
        m = index[sid[o[h]]].astype(np.int64)
        _, z, kk, res = model.sheet_check(c[h], 3 - fe[h], m)
        ok[h] = (res <= tol_px) & (z >= z_lo) & (z <= z_hi)
        k_end[h] = kk
        m_end[h] = m
        # exactly one end checked; the other end has no labelled crossing at all
        a_ok, b_ok = ok[:nc], ok[nc:]
        a_hit, b_hit = hit[:nc], hit[nc:]
        one = (a_ok & ~b_hit) | (b_ok & ~a_hit)
        sel = np.flatnonzero(one)
        if len(sel) == 0:
            break
        near = np.where(a_ok[sel], sel, sel + nc)
        far = np.where(a_ok[sel], sel + nc, sel)
        k = k_end[near]
        # 2. the far end's crossing with any sample of the other family, checked on sheet k: the next line
        o2, c2 = crossing_hits_traces(np.ascontiguousarray(E[far]), np.ascontiguousarray(U[far]), np.ones(len(far)), fe[far], q, sid,
                                      tangent, fam, index, False, float(radius_px), _SIN_MIN_CROSSING, *grid)
        has2 = o2 >= 0
        stats["far_missing"] += int(np.sum(~has2))
        good = np.zeros(len(sel), bool) if confirm_far else np.ones(len(sel), bool)
        g = np.flatnonzero(has2)
        if len(g) and confirm_far:
            if refine:
                _k_refine(np.ascontiguousarray(end_pos[rows[far[g]]], np.int64), np.ascontiguousarray(o2[g], np.int64), g.astype(np.int64),
                          c2, first, last, piece, ts, q, sid, float(trim_px), int(anchor))
            _, z2, m2, res2 = model.sheet_check(c2[g], fe[far[g]], k[g])
            good[g] = (res2 <= tol_px) & (z2 >= z_lo) & (z2 <= z_hi) & (np.abs(m2 - m_end[near[g]]) == 1)
            stats["far_rejected"] += int(len(g) - good[g].sum())
        sel, near, k = sel[good], near[good], k[good]
        if len(sel) == 0:
            break
        # 3. the piece's samples inside the working volume on sheet k
        p_sel = cand[sel]
        lens = count[p_sel]
        pos = np.repeat(first[p_sel], lens) + (np.arange(lens.sum()) - np.repeat(np.cumsum(lens) - lens, lens))
        owner = np.repeat(np.arange(len(p_sel)), lens)
        _, zs, _, _ = model.sheet_check(q[sid[pos]], fam[sid[pos]], k[owner])
        inside = (zs >= z_lo) & (zs <= z_hi)
        all_in = np.bincount(owner, weights=~inside, minlength=len(p_sel)) == 0
        # write, leaving out the samples within trim_px of the piece's ends
        jv = seed_jid[sid[o[near]]]
        f0, l0 = first[p_sel][owner], last[p_sel][owner]
        keep = all_in[owner] & (np.minimum(ts[pos] - ts[f0], ts[l0] - ts[pos]) >= trim_px)
        w = pos[keep]
        if len(w) == 0:
            break
        index[sid[w]] = k[owner[keep]]
        seed_jid[sid[w]] = jv[owner[keep]]
        stats["pieces"] += int(np.unique(owner[keep]).size)
        stats["samples"] += int(len(w))
    return stats
