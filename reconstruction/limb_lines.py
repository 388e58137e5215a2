"""Label trace pieces beside a labelled line of their family, confirmed at both crossings (decision 0103).

Where a curved surface turns away towards its limb (the cylinder and sphere of the converged rigs), the grid
compresses in the image across the lines that run along the limb: neighbouring lines of that family come within
a few smoothing scales of one another, and the other family's short stretches between them lie entirely in the
crossings' mixing zones (`labelling.label_samples` step 1). What is left there are the along-limb family's
pieces, each one cell long between two crossings, with no labelled sample of the other family near them: the
crossing checks of steps 6 and 9b, the piece junctions of 9c (no piece of the other family to cross) and the
surface labels of 9d (the labelled surface lies on one side only) do not reach them.

A piece P of family f is labelled here from two independent directions:

1. **Across: its neighbour line.** The nearest trace sample of family f beside P's middle sample (within
   `across_px` across P's line, within P's half length along it, on each side) belongs to a labelled line k_n.
   P is then line k_n + 1 or k_n − 1 (lines of one family do not cross; which of the two depends on the side
   and the rig): two candidates, not the whole pattern.
2. **Along: both crossings on P's own sheet.** P's two ends face the next pieces of its line across the gaps
   that the crossings' mixing zones cut (a facing sample of family f ahead of the end on its tangent, within
   `reach_px` and `lateral_px`, and a sample of the other family within `cross_px` of the gap's middle: a
   crossing, not a silhouette or a shadow). The mixing zone is cut around the other line on both sides of it,
   so the crossing is the gap's middle. On light sheet k each crossing's ray must land within `tol_px`
   projector px of a line m of the other family inside the depth range, and the two crossings on consecutive
   lines (|m_b − m_a| = 1: a piece spans one cell). A candidate k is accepted only when it is the only one
   that passes (both candidates passing is ambiguous: left out).
3. **Working volume.** Every sample of P on sheet k lies inside the depth range.

The samples within `trim_px` of P's ends are left out (the crossings' light pulls the ridge there; the gap
filling and the crossing fill put points there where the line is labelled on both sides). Repeated for `rounds`
rounds: pieces labelled in one round are the neighbour lines of the next (the band is a few lines wide).

Kernels: per round one compiled pass finds the candidates (bucket grid of the frame's valid samples,
`labelling._sample_grid`), `RigModel.sheet_check` checks the crossings, `RigModel.sheet_depth` the samples.
"""

from __future__ import annotations

import math

import numpy as np

from reconstruction._continuation_kernels import piece_ends
from reconstruction._jit import njit
from reconstruction.rigmodel import RigModel

# a line may turn by up to 12° across a crossing's gap (the continuation's limit, decision 0072): the facing
# sample may lie this share of its distance ahead off the end's tangent, on top of lateral_px
_BEND = float(np.sin(np.deg2rad(12.0)))
_NONE = np.iinfo(np.int64).min  # no line (indices are negative too)


@njit
def _cells(x, y, r, x0, y0, cell, gw, gh):
    """The cell range (cx0, cx1, cy0, cy1) inclusive that a disk of radius r around (x, y) touches."""
    cx0 = max(0, int(math.floor((x - r - x0) / cell)))
    cx1 = min(gw - 1, int(math.floor((x + r - x0) / cell)))
    cy0 = max(0, int(math.floor((y - r - y0) / cell)))
    cy1 = min(gh - 1, int(math.floor((y + r - y0) / cell)))
    return cx0, cx1, cy0, cy1


@njit
def _k_candidates(q, fam, sid, piece, val, e, u, end_pos, labelled, n_p, min_samples, reach, lateral, cross_r,
                  across_r, x0, y0, cell, gw, gh, start, items, pos_of):
    """Per unlabelled piece of at least min_samples samples: its two crossings (gap middles, step 2) and the
    candidate lines from its labelled neighbour lines (step 1; val (n_p,): each piece's line, NaN: none). Returns the pieces (nc,), the crossings
    c (nc, 2, 2), the candidates kc (nc, 4) int64 (padding: the first candidate repeated), the piece's family and
    per piece (n_p,) why it was left out: 1 no facing piece at an end, 2 no sample of the other family in a gap,
    3 no neighbour line, 4 no labelled neighbour line (0: a candidate, or not tried)."""
    nc = 0
    for p in range(n_p):
        nc += (not labelled[p]) and (end_pos[n_p + p] - end_pos[p] + 1 >= min_samples)
    cand = np.empty(nc, np.intp)
    cr = np.empty((nc, 2, 2))
    kc = np.empty((nc, 4), np.int64)
    fp = np.empty(nc, np.int64)
    why = np.zeros(n_p, np.int8)  # 1 no facing piece at an end, 2 no crossing in a gap, 3 no neighbour line, 4 none labelled
    n_out = 0
    for p in range(n_p):
        a, b = end_pos[p], end_pos[n_p + p]
        if labelled[p] or b - a + 1 < min_samples:
            continue
        f = fam[sid[a]]
        ok = True
        # 2. the crossing at each end: the gap's middle to the facing sample of the same family ahead
        for side in range(2):
            r = side * n_p + p
            ex, ey, ux, uy = e[r, 0], e[r, 1], u[r, 0], u[r, 1]
            best = reach + 1.0
            bx = 0.0
            by = 0.0
            cx0, cx1, cy0, cy1 = _cells(ex + 0.5 * reach * ux, ey + 0.5 * reach * uy, 0.5 * reach + lateral + _BEND * reach, x0, y0, cell, gw, gh)
            for cy in range(cy0, cy1 + 1):
                for cx in range(cx0, cx1 + 1):
                    c = cy * gw + cx
                    for it in range(start[c], start[c + 1]):
                        s = items[it]
                        k = pos_of[s]
                        if k < 0 or fam[s] != f or piece[k] == p:
                            continue
                        dx, dy = q[s, 0] - ex, q[s, 1] - ey
                        al = dx * ux + dy * uy
                        ac = abs(dx * uy - dy * ux)
                        if al > 0.0 and al <= reach and ac <= lateral + _BEND * al and al < best:
                            best = al
                            bx, by = q[s, 0], q[s, 1]
            if best > reach:
                ok = False
                why[p] = 1
                break
            mx, my = 0.5 * (ex + bx), 0.5 * (ey + by)
            # a crossing: a sample of the other family near the gap's middle
            hit = False
            cx0, cx1, cy0, cy1 = _cells(mx, my, cross_r, x0, y0, cell, gw, gh)
            for cy in range(cy0, cy1 + 1):
                for cx in range(cx0, cx1 + 1):
                    c = cy * gw + cx
                    for it in range(start[c], start[c + 1]):
                        s = items[it]
                        if fam[s] != 3 - f:
                            continue
                        if (q[s, 0] - mx) ** 2 + (q[s, 1] - my) ** 2 <= cross_r * cross_r:
                            hit = True
                            break
                    if hit:
                        break
                if hit:
                    break
            if not hit:
                ok = False
                why[p] = 2
                break
            cr[n_out, side, 0] = mx
            cr[n_out, side, 1] = my
        if not ok:
            continue
        # 1. the neighbour lines: the nearest sample of family f across the middle sample, on each side
        mid = (a + b) // 2
        sm = sid[mid]
        qx, qy = q[sm, 0], q[sm, 1]
        tx, ty = e[n_p + p, 0] - e[p, 0], e[n_p + p, 1] - e[p, 1]
        half = 0.5 * math.hypot(tx, ty)
        if half <= 0.0:
            continue
        tx /= 2.0 * half
        ty /= 2.0 * half
        nearest = np.full(2, across_r + 1.0)
        nk = np.full(2, -1, np.intp)
        cx0, cx1, cy0, cy1 = _cells(qx, qy, across_r + half, x0, y0, cell, gw, gh)
        for cy in range(cy0, cy1 + 1):
            for cx in range(cx0, cx1 + 1):
                c = cy * gw + cx
                for it in range(start[c], start[c + 1]):
                    s = items[it]
                    k = pos_of[s]
                    if k < 0 or fam[s] != f or piece[k] == p:
                        continue
                    dx, dy = q[s, 0] - qx, q[s, 1] - qy
                    al = dx * tx + dy * ty
                    ac = dx * ty - dy * tx
                    if abs(al) > half or abs(ac) < 1.0:
                        continue
                    sd = 0 if ac < 0 else 1
                    if abs(ac) < nearest[sd]:
                        nearest[sd] = abs(ac)
                        nk[sd] = s
        n_k = 0
        why[p] = 3 if (nk[0] < 0 and nk[1] < 0) else 4
        for sd in range(2):
            if nk[sd] < 0 or nearest[sd] > across_r:
                continue
            kv = val[piece[pos_of[nk[sd]]]]  # the neighbour's piece's line (its trimmed ends carry none)
            if math.isfinite(kv):
                kn = int(kv)
                kc[n_out, n_k] = kn - 1
                kc[n_out, n_k + 1] = kn + 1
                n_k += 2
        if n_k == 0:
            continue
        why[p] = 0
        for j in range(n_k, 4):
            kc[n_out, j] = kc[n_out, 0]
        cand[n_out] = p
        fp[n_out] = f
        n_out += 1
    return cand[:n_out], cr[:n_out], kc[:n_out], fp[:n_out], why


@njit
def _k_verdicts(kc, m, res, z, tol, z_lo, z_hi):
    """Step 2's verdict per piece: the one candidate line whose two crossings land within tol of consecutive
    lines of the other family inside [z_lo, z_hi]; _NONE where none or more than one (distinct) pass.
    m, res, z: (nc, 4, 2) per candidate and crossing."""
    nc = kc.shape[0]
    out = np.full(nc, _NONE, np.int64)
    amb = 0
    for i in range(nc):
        got = False
        k_ok = 0
        many = False
        for j in range(4):
            good = abs(m[i, j, 1] - m[i, j, 0]) == 1
            for s in range(2):
                good = good and res[i, j, s] <= tol and z[i, j, s] >= z_lo and z[i, j, s] <= z_hi
            if good:
                if got and kc[i, j] != k_ok:
                    many = True
                got = True
                k_ok = kc[i, j]
        if got and not many:
            out[i] = k_ok
        amb += many
    return out, amb


@njit
def _k_gather(cand, k_of, end_pos, n_p, sid, q, fam):
    """The accepted pieces' samples: trace positions, owner rank, q, family, line."""
    tot = 0
    for i in range(cand.shape[0]):
        if k_of[i] != _NONE:
            p = cand[i]
            tot += end_pos[n_p + p] - end_pos[p] + 1
    pos = np.empty(tot, np.int64)
    owner = np.empty(tot, np.int64)
    qs = np.empty((tot, 2))
    fs = np.empty(tot, np.int64)
    ks = np.empty(tot, np.int64)
    w = 0
    for i in range(cand.shape[0]):
        if k_of[i] == _NONE:
            continue
        p = cand[i]
        for x in range(end_pos[p], end_pos[n_p + p] + 1):
            s = sid[x]
            pos[w] = x
            owner[w] = i
            qs[w, 0] = q[s, 0]
            qs[w, 1] = q[s, 1]
            fs[w] = fam[s]
            ks[w] = k_of[i]
            w += 1
    return pos, owner, qs, fs, ks


@njit
def _k_write(pos, owner, zs, z_lo, z_hi, k_of, cand, end_pos, n_p, ts, sid, trim_px, index):
    """Step 3 and the write: an accepted piece whose samples all lie in [z_lo, z_hi] on its sheet takes line
    k, except within trim_px of its ends. Returns pieces and samples written."""
    nc = k_of.shape[0]
    all_in = np.ones(nc, np.bool_)
    for w in range(pos.shape[0]):
        if not (zs[w] >= z_lo and zs[w] <= z_hi):
            all_in[owner[w]] = False
    wrote = np.zeros(nc, np.bool_)
    n_s = 0
    for w in range(pos.shape[0]):
        i = owner[w]
        if not all_in[i]:
            continue
        p = cand[i]
        x = pos[w]
        a, b = end_pos[p], end_pos[n_p + p]
        if min(ts[x] - ts[a], ts[b] - ts[x]) >= trim_px:
            index[sid[x]] = k_of[i]
            wrote[i] = True
            n_s += 1
    return int(wrote.sum()), n_s


def label_beside_lines(
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
    grid: tuple,
    sigma_px: float,
    reach_px: float,
    across_px: float,
    mix_sigma: float = 2.0,
    trim_px: float = 0.0,
    tol_px: float = 1.0,
    lateral_px: float = 1.0,
    min_samples: int = 4,
    anchor: int = 3,
    rounds: int = 8,
) -> dict:
    """Label unlabelled pieces beside a labelled line of their family whose two crossings confirm the line on
    its own light sheet (module doc).

    q (P, 2) camera px, fam (P,) 1/2; the traces as `labelling.label_samples` builds them: sid (n,) sample ids by
    piece and position, piece (n,) non-decreasing, ts (n,) position along the piece (px), tangent (n, 2).
    index (P,) float (NaN: unlabelled) is written in place. grid: the frame's bucket grid of the valid samples
    (`labelling._sample_grid`). sigma_px: extraction's smoothing; a crossing needs a sample of the other family
    within mix_sigma·σ of the gap's middle. reach_px: the longest crossing gap (camera px); across_px: how far
    across its line a piece's neighbour line may lie (camera px); tol_px: projector px. Returns counts: pieces
    and samples labelled, pieces left out as ambiguous."""
    stats = {"pieces": 0, "samples": 0, "ambiguous": 0}
    n = len(piece)
    if n == 0:
        return stats
    n_p = int(piece[-1]) + 1
    z_lo, z_hi = float(depth_range_mm[0]), float(depth_range_mm[1])
    x0, y0, cell, gw, gh, start, items, pos_of = grid
    start = start[: gw * gh + 1]
    for _ in range(rounds):
        e, u, end_pos, labelled, val, _ = piece_ends(q, sid, piece, tangent, index, seed_jid, n_p, int(anchor))
        cand, cr, kc, fp, why = _k_candidates(q, fam, sid, piece, val, e, u, end_pos, labelled, n_p, int(min_samples),
                                         float(reach_px), float(lateral_px), float(mix_sigma * sigma_px), float(across_px),
                                         x0, y0, cell, gw, gh, start, items, pos_of)
        nc = len(cand)
        if "left_out" not in stats:  # the first round's reasons
            stats["left_out"] = dict(zip(("no_facing_piece", "no_crossing", "no_neighbour", "neighbour_unlabelled"),
                                         (int(c) for c in np.bincount(why, minlength=5)[1:])))
        if nc == 0:
            break
        cq = np.broadcast_to(cr[:, None, :, :], (nc, 4, 2, 2)).reshape(-1, 2)
        cf = np.repeat(fp, 8)
        ck = np.repeat(kc.reshape(-1), 2)
        _, z, m, res = model.sheet_check(cq, cf, ck)
        k_of, n_amb = _k_verdicts(kc, np.asarray(m, np.int64).reshape(nc, 4, 2), np.asarray(res).reshape(nc, 4, 2),
                                  np.asarray(z).reshape(nc, 4, 2), float(tol_px), z_lo, z_hi)
        stats["ambiguous"] += int(n_amb)
        pos, owner, qs, fs, ks = _k_gather(cand, k_of, end_pos, n_p, sid, q, fam)
        if len(pos) == 0:
            break
        zs = model.sheet_depth(qs, fs, ks)
        n_pieces, n_samples = _k_write(pos, owner, zs, z_lo, z_hi, k_of, cand, end_pos, n_p, ts, sid, float(trim_px), index)
        if n_samples == 0:
            break
        stats["pieces"] += int(n_pieces)
        stats["samples"] += int(n_samples)
    return stats
