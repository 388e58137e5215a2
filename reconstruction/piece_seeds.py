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
from reconstruction._label_kernels import _as_int64, crossing_hits_traces
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


@njit
def _k_round_ends(q, sid, piece, tangent, index, seed_jid, fam, n_p, anchor, min_samples):
    """A round's start (decision 0096): `piece_ends`, the unlabelled pieces with at least min_samples samples
    (cand (nc,), increasing), their two ends' rows (cand, then cand + n_p) gathered: E, U (2nc, 2), fe (2nc,)
    int64 the ends' family, and end_pos (2n_p,). Formerly flatnonzero, concatenate and four gathers."""
    e, u, end_pos, labelled, _, _ = piece_ends(q, sid, piece, tangent, index, seed_jid, n_p, anchor)
    nc = 0
    for p in range(n_p):
        nc += (not labelled[p]) and (end_pos[n_p + p] - end_pos[p] + 1 >= min_samples)
    cand = np.empty(nc, np.intp)
    i = 0
    for p in range(n_p):
        if (not labelled[p]) and (end_pos[n_p + p] - end_pos[p] + 1 >= min_samples):
            cand[i] = p
            i += 1
    E = np.empty((2 * nc, 2))
    U = np.empty((2 * nc, 2))
    fe = np.empty(2 * nc, np.int64)
    for r in range(2 * nc):
        row = cand[r] if r < nc else cand[r - nc] + n_p
        E[r, 0] = e[row, 0]
        E[r, 1] = e[row, 1]
        U[r, 0] = u[row, 0]
        U[r, 1] = u[row, 1]
        fe[r] = fam[sid[end_pos[row]]]
    return cand, E, U, fe, end_pos


@njit
def _k_near_hits(o, c, fe, index, sid):
    """The ends with a labelled crossing (h: o ≥ 0), their crossing c[h], the other family 3 − fe[h] and the
    labelled sample's line m (int64, as NumPy's cast)."""
    R = o.shape[0]
    nh = 0
    for r in range(R):
        nh += o[r] >= 0
    h = np.empty(nh, np.intp)
    ch = np.empty((nh, 2))
    fo = np.empty(nh, np.int64)
    m = np.empty(nh, np.int64)
    i = 0
    for r in range(R):
        if o[r] < 0:
            continue
        h[i] = r
        ch[i, 0] = c[r, 0]
        ch[i, 1] = c[r, 1]
        fo[i] = 3 - fe[r]
        m[i] = _as_int64(index[sid[o[r]]])
        i += 1
    return h, ch, fo, m


@njit
def _k_one_sided(o, h, m, kk, res, z, tol, z_lo, z_hi, nc, E, U, fe):
    """Step 1's verdicts: an end passes when its crossing's residual ≤ tol and depth lies in [z_lo, z_hi]; the
    pieces with exactly one passing end whose other end has no labelled crossing (sel, increasing), their near
    and far end rows, the near end's line k, the near end's line m_end, and the far ends' E, U, fe gathered."""
    ok = np.zeros(2 * nc, np.bool_)
    k_end = np.full(2 * nc, np.iinfo(np.int64).min, np.int64)
    m_end = np.zeros(2 * nc, np.int64)
    for i in range(h.shape[0]):
        r = h[i]
        ok[r] = (res[i] <= tol) and (z[i] >= z_lo) and (z[i] <= z_hi)
        k_end[r] = kk[i]
        m_end[r] = m[i]
    ns = 0
    for p in range(nc):
        a_ok, b_ok = ok[p], ok[p + nc]
        ns += (a_ok and o[p + nc] < 0) or (b_ok and o[p] < 0)
    sel = np.empty(ns, np.intp)
    near = np.empty(ns, np.intp)
    far = np.empty(ns, np.intp)
    k = np.empty(ns, np.int64)
    mn = np.empty(ns, np.int64)
    Ef = np.empty((ns, 2))
    Uf = np.empty((ns, 2))
    ff = np.empty(ns, np.int64)
    i = 0
    for p in range(nc):
        a_ok, b_ok = ok[p], ok[p + nc]
        if not ((a_ok and o[p + nc] < 0) or (b_ok and o[p] < 0)):
            continue
        sel[i] = p
        near[i] = p if a_ok else p + nc
        far[i] = p + nc if a_ok else p
        k[i] = k_end[near[i]]
        mn[i] = m_end[near[i]]
        Ef[i, 0] = E[far[i], 0]
        Ef[i, 1] = E[far[i], 1]
        Uf[i, 0] = U[far[i], 0]
        Uf[i, 1] = U[far[i], 1]
        ff[i] = fe[far[i]]
        i += 1
    return sel, near, far, k, mn, Ef, Uf, ff


@njit
def _k_far_hits(o2, far, cand, n_p, nc, end_pos):
    """The far ends with a crossing (g, int64), their trace positions (end_pos of the far end's row), the
    partner's trace position o2[g] (int64) and the number without one."""
    ng = 0
    for r in range(o2.shape[0]):
        ng += o2[r] >= 0
    g = np.empty(ng, np.int64)
    pf = np.empty(ng, np.int64)
    og = np.empty(ng, np.int64)
    i = 0
    for r in range(o2.shape[0]):
        if o2[r] < 0:
            continue
        g[i] = r
        fr = far[r]
        row = cand[fr] if fr < nc else cand[fr - nc] + n_p
        pf[i] = end_pos[row]
        og[i] = o2[r]
        i += 1
    return g, pf, og, o2.shape[0] - ng


@njit
def _k_far_gather(g, c2, ff, k):
    """c2[g], ff[g], k[g] for step 2's check."""
    n = g.shape[0]
    cg = np.empty((n, 2))
    fg = np.empty(n, np.int64)
    kg = np.empty(n, np.int64)
    for i in range(n):
        cg[i, 0] = c2[g[i], 0]
        cg[i, 1] = c2[g[i], 1]
        fg[i] = ff[g[i]]
        kg[i] = k[g[i]]
    return cg, fg, kg


@njit
def _k_confirmed(g, res2, z2, m2, mn, tol, z_lo, z_hi, ns, confirm_far, sel, near, k, cand, first, last, q, sid, fam):
    """Step 2's verdicts (good: the far crossing within tol of line m ± 1 inside the depth range; every piece when
    not confirm_far), the number rejected, and step 3's inputs: the kept pieces' trace positions pos (one
    block per piece, first to last), their owner (the kept piece's rank), the samples' q and family, the line
    k[owner]; and per kept piece its near end's row and its line."""
    good = np.zeros(ns, np.bool_)
    if not confirm_far:
        good[:] = True
    n_rej = 0
    if confirm_far:
        for i in range(g.shape[0]):
            r = g[i]
            gd = (res2[i] <= tol) and (z2[i] >= z_lo) and (z2[i] <= z_hi) and (abs(m2[i] - mn[r]) == 1)
            good[r] = gd
            n_rej += not gd
    nk = 0
    tot = 0
    for r in range(ns):
        if good[r]:
            p = cand[sel[r]]
            tot += last[p] - first[p] + 1
            nk += 1
    pos = np.empty(tot, np.int64)
    owner = np.empty(tot, np.int64)
    qs = np.empty((tot, 2))
    fs = np.empty(tot, np.int64)
    ks = np.empty(tot, np.int64)
    near_k = np.empty(nk, np.intp)
    k_k = np.empty(nk, np.int64)
    p_k = np.empty(nk, np.intp)
    j = 0
    w = 0
    for r in range(ns):
        if not good[r]:
            continue
        p = cand[sel[r]]
        near_k[j] = near[r]
        k_k[j] = k[r]
        p_k[j] = p
        for x in range(first[p], last[p] + 1):
            pos[w] = x
            owner[w] = j
            s = sid[x]
            qs[w, 0] = q[s, 0]
            qs[w, 1] = q[s, 1]
            fs[w] = fam[s]
            ks[w] = k[r]
            w += 1
        j += 1
    return n_rej, pos, owner, qs, fs, ks, near_k, k_k, p_k


@njit
def _k_write_pieces(pos, owner, zs, z_lo, z_hi, near_k, k_k, p_k, o, first, last, ts, sid, trim_px, index, seed_jid):
    """Step 3: a kept piece whose samples all lie inside [z_lo, z_hi] on its sheet takes line k and its near
    crossing's junction, except within trim_px of its ends (index, seed_jid written in place). Returns the
    pieces and samples written."""
    nk = near_k.shape[0]
    all_in = np.ones(nk, np.bool_)
    for w in range(pos.shape[0]):
        if not ((zs[w] >= z_lo) and (zs[w] <= z_hi)):
            all_in[owner[w]] = False
    jv = np.empty(nk, np.int64)  # the near crossings' junctions, read before any write (as the former gather)
    for j in range(nk):
        jv[j] = seed_jid[sid[o[near_k[j]]]]
    wrote = np.zeros(nk, np.bool_)
    n_s = 0
    for w in range(pos.shape[0]):
        j = owner[w]
        if not all_in[j]:
            continue
        p = p_k[j]
        x = pos[w]
        f0 = first[p]
        l0 = last[p]
        if min(ts[x] - ts[f0], ts[l0] - ts[x]) >= trim_px:
            s = sid[x]
            index[s] = k_k[j]
            seed_jid[s] = jv[j]
            wrote[j] = True
            n_s += 1
    n_p = 0
    for j in range(nk):
        n_p += wrote[j]
    return n_p, n_s


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
    tol = float(tol_px)
    # Each step's NumPy masks, gathers and scatters are compiled passes between the crossing searches and the
    # light-sheet checks (decision 0096: the same values in the same order).
    for _ in range(rounds):
        cand, E, U, fe, end_pos = _k_round_ends(q, sid, piece, tangent, index, seed_jid, fam, n_p, int(anchor), int(min_samples))
        first, last = end_pos[:n_p], end_pos[n_p:]
        nc = len(cand)
        if nc == 0:
            break
        # 1. each end's crossing with the nearest labelled sample of the other family, checked on its sheet m
        o, c = crossing_hits_traces(E, U, np.ones(2 * nc), fe, q, sid, tangent, fam, index, True, float(radius_px),
                                    _SIN_MIN_CROSSING, *grid)
        h, ch, fo, m = _k_near_hits(o, c, fe, index, sid)
        if len(h) == 0:
            break
        _, z, kk, res = model.sheet_check(ch, fo, m)
        # exactly one end checked; the other end has no labelled crossing at all
        sel, near, far, k, m_near, E_far, U_far, fe_far = _k_one_sided(o, h, m, kk, res, z, tol, z_lo, z_hi, nc, E, U, fe)
        ns = len(sel)
        if ns == 0:
            break
        # 2. the far end's crossing with any sample of the other family, checked on sheet k: the next line
        o2, c2 = crossing_hits_traces(E_far, U_far, np.ones(ns), fe_far, q, sid, tangent, fam, index, False, float(radius_px),
                                      _SIN_MIN_CROSSING, *grid)
        g, p_far, o_partner, n_missing = _k_far_hits(o2, far, cand, n_p, nc, end_pos)
        stats["far_missing"] += int(n_missing)
        res2 = z2 = m2 = np.zeros(0)
        if len(g) and confirm_far:
            if refine:
                _k_refine(p_far, o_partner, g, c2, first, last, piece, ts, q, sid, float(trim_px), int(anchor))
            c_g, f_g, k_g = _k_far_gather(g, c2, fe_far, k)
            _, z2, m2, res2 = model.sheet_check(c_g, f_g, k_g)
        elif confirm_far:
            g = np.zeros(0, np.int64)
        n_rej, pos, owner, q_pos, f_pos, k_pos, near_k, k_k, p_k = _k_confirmed(
            g, res2, z2, np.asarray(m2, np.int64), m_near, tol, z_lo, z_hi, ns, bool(confirm_far), sel, near, k, cand, first, last, q, sid, fam)
        stats["far_rejected"] += int(n_rej)
        if len(near_k) == 0:
            break
        # 3. the piece's samples inside the working volume on sheet k (their depth alone: `sheet_depth`, equal to
        # `sheet_check`'s to the bit, decision 0094); written, leaving out the samples within trim_px of the ends
        zs = model.sheet_depth(q_pos, f_pos, k_pos)
        n_pieces, n_samples = _k_write_pieces(pos, owner, zs, z_lo, z_hi, near_k, k_k, p_k, o, first, last, ts, sid,
                                              float(trim_px), index, seed_jid)
        if n_samples == 0:
            break
        stats["pieces"] += int(n_pieces)
        stats["samples"] += int(n_samples)
    return stats
