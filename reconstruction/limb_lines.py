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
   `across_px` across P's line, within half of P's length and half of `across_px` along it), on each side,
   belongs to a labelled line k_n. P is then line k_n + 1 or k_n − 1 (lines of one family do not cross; which
   of the two depends on the side and the rig): two candidates, not the whole pattern.
2. **Along: both crossings on P's own sheet.** P's two ends face the next pieces of its line across the gaps
   that the crossings' mixing zones cut (a facing sample of family f ahead of the end, within `reach_px` and
   `lateral_px` + sin 12° of the distance off the end's tangent, and a sample of the other family within
   mix_sigma·σ of the gap's middle: a crossing, not a silhouette or a shadow). The mixing zone is cut around
   the other line on both sides of it, so the crossing is the gap's middle. A candidate k scores the larger of
   its two crossings' residuals on light sheet k where both land inside the depth range on consecutive lines
   m, m ± 1 of the other family (a piece spans one cell). The better candidate must score within `tol_px`
   projector px and the other at least `margin`·`tol_px` (else ambiguous: left out). Near a limb a wrong sheet
   moves the crossings by only ~1.2–1.7 projector px per line (decision 0103), so the crossings alone do not
   tell adjacent lines apart; they choose between the two lines beside the neighbour, two sheets apart. Every
   labelled neighbour line must be next to k, and each neighbour sample, on its own sheet, must lie inside the
   depth range nearest to m or m ± 1 (the same cell on both lines: a neighbour two lines away, the adjacent
   line missing, fails here).
3. **Working volume.** Every sample of P on sheet k lies inside the depth range.

A wrongly labelled neighbour line is carried to P (its offset fits P's crossings as well): this step grows a
mislabelled patch by the pieces beside it, as every step that spreads labels does (decision 0103).

The samples within `trim_px` of P's ends are left out (the crossings' light pulls the ridge there; the gap
filling and the crossing fill put points there where the line is labelled on both sides). Repeated for `rounds`
rounds: pieces labelled in one round are the neighbour lines of the next (the band is a few lines wide).

After the rounds (decision 0106, `ends`): an end of a piece labelled here whose facing piece is still unlabelled
gets no gap filling, so its trimmed samples take P's line where the line continues across that crossing on P's
sheet (the gap's middle within `tol_px` of a line m of the other family, the facing sample nearest to m − 1, m or
m + 1, both inside the depth range), each of them within `lateral_px` of the line through the first labelled
sample inside the end (`_k_end_rows`, `RigModel.sheet_check`, `_k_write_ends`). Where the facing piece carries a
line, the trim stands (the fillings' case, or a conflict).

Kernels: every round in one compiled call (`_k_all`, decision 0103's "speed, round 2"): the pieces' ends and
labels (`_k_pieces`), then per round steps 1 and 2's geometry on the frame's bucket grid split by family
(`labelling._sample_grid`) over the pieces that can still become candidates (`_k_live_round`: each piece's
neighbour samples searched once, its crossings once; after the first round only pieces whose search reaches a
newly labelled sample, and a candidate's verdict again only when its neighbour lines changed), the crossings
and neighbours on their sheets (`rigmodel._k_sheet_check`), `_verdicts`, step 3 (`rigmodel._k_sheet_depth`)
and `_k_write`. Where the rig has no camera table or a pixel lies outside it, `RigModel`'s NumPy path gives the
sheets: `_by_rounds` then runs the rounds one by one (`_k_round`, `RigModel.sheet_check`, `_k_verdicts`,
`RigModel.sheet_depth`, `_k_write`), with the same labels. `_k_all` calls kernels of `rigmodel`: after
changing one of them, clear the numba caches (decision 0095).
"""

from __future__ import annotations

import math

import numpy as np

from reconstruction._jit import njit
from reconstruction.rigmodel import RigModel, _k_sheet_check, _k_sheet_depth

# a line may turn by up to 12° across a crossing's gap (the continuation's limit, decision 0072): the facing
# sample may lie this share of its distance ahead off the end's tangent, on top of lateral_px
_BEND = float(np.sin(np.deg2rad(12.0)))
_NONE = np.iinfo(np.int64).min  # no line (indices are negative too)
_SPAN = 1  # the lines tried: the neighbour's line ± 1 (the neighbour's own line is checked, never chosen: no ranking)
_LINES = 2 * _SPAN + 1
_ROWS = 2 * _LINES + 2  # sheet-check rows per candidate piece: each line's two crossings, each side's neighbour sample


@njit
def _cells(x, y, r, x0, y0, cell, gw, gh):
    """The cell range (cx0, cx1, cy0, cy1) inclusive that a disk of radius r around (x, y) touches."""
    cx0 = max(0, int(math.floor((x - r - x0) / cell)))
    cx1 = min(gw - 1, int(math.floor((x + r - x0) / cell)))
    cy0 = max(0, int(math.floor((y - r - y0) / cell)))
    cy1 = min(gh - 1, int(math.floor((y + r - y0) / cell)))
    return cx0, cx1, cy0, cy1


@njit
def _fam_items(c, f, start, ncell):
    """The item range of cell c holding family f (the grid's items split by family, `sample_grid_split`)."""
    mid = start[ncell + 1 + c]
    if f == 1:
        return start[c], mid
    return mid, start[c + 1]


@njit
def _k_pieces(sid, piece, index, n_p):
    """Per piece (n_p): its first and last trace positions (end_pos (2n_p,): first, then last), whether it is
    labelled and its line (val, NaN: none; the first labelled sample's), as `piece_ends` gives them without the
    ends' directions (computed here only for the pieces whose crossings are looked for)."""
    end_pos = np.full(2 * n_p, -1, np.intp)
    labelled = np.zeros(n_p, np.bool_)
    val = np.full(n_p, np.nan)
    n = sid.shape[0]
    k = 0
    while k < n:  # piece by piece (piece is non-decreasing); index is read up to the piece's first labelled sample
        p = piece[k]
        end_pos[p] = k
        while k < n and piece[k] == p:
            if not labelled[p]:
                v = index[sid[k]]
                if math.isfinite(v):
                    labelled[p] = True
                    val[p] = v
            k += 1
        end_pos[n_p + p] = k - 1
    return end_pos, labelled, val


@njit
def _end(p, side, n_p, end_pos, q, sid, tangent, anchor):
    """A piece end's position and outward unit direction, as `_continuation_kernels.piece_ends`: the chord from
    the sample `anchor` places inside, or the trace tangent where that chord is shorter than 1.5 px."""
    a, b = end_pos[p], end_pos[n_p + p]
    if side == 0:
        k = a
        j = min(a + anchor, b)
        sgn = -1.0
    else:
        k = b
        j = max(b - anchor, a)
        sgn = 1.0
    ex, ey = q[sid[k], 0], q[sid[k], 1]
    d0 = ex - q[sid[j], 0]
    d1 = ey - q[sid[j], 1]
    L = math.sqrt(d0 * d0 + d1 * d1)
    if L >= 1.5:
        return ex, ey, d0 / L, d1 / L
    return ex, ey, sgn * tangent[k, 0], sgn * tangent[k, 1]


@njit
def _facing(p, ex, ey, ux, uy, q, piece, f, reach, lateral, x0, y0, cell, gw, gh, start, items, pos_of):
    """The facing sample of piece p's end at (ex, ey) with outward direction (ux, uy): the nearest trace sample of
    family f on another piece ahead, within reach along and lateral + sin 12° of its distance across the end's
    tangent (the first sample of the next piece of the line); −1: none."""
    ncell = gw * gh
    best = reach + 1.0
    sb = -1
    cx0, cx1, cy0, cy1 = _cells(ex + 0.5 * reach * ux, ey + 0.5 * reach * uy, 0.5 * reach + lateral + _BEND * reach, x0, y0, cell, gw, gh)
    for cy in range(cy0, cy1 + 1):
        for cx in range(cx0, cx1 + 1):
            i0, i1 = _fam_items(cy * gw + cx, f, start, ncell)
            for it in range(i0, i1):
                s = items[it]
                k = pos_of[s]
                if k < 0 or piece[k] == p:
                    continue
                dx, dy = q[s, 0] - ex, q[s, 1] - ey
                al = dx * ux + dy * uy
                if al > 0.0 and al <= reach and al < best and abs(dx * uy - dy * ux) <= lateral + _BEND * al:
                    best = al
                    sb = s
    return sb


@njit
def _crossings(p, q, fam, sid, piece, tangent, end_pos, anchor, n_p, f, reach, lateral, cross_r, x0, y0, cell, gw, gh, start, items, pos_of, cr):
    """Step 2 for piece p (family f): its two gap middles into cr[p]; 0 when both are found, 1 when an end has
    no facing piece of its line within reach, 2 when a gap has no sample of the other family within cross_r
    of its middle."""
    ncell = gw * gh
    for side in range(2):
        ex, ey, ux, uy = _end(p, side, n_p, end_pos, q, sid, tangent, anchor)
        # the facing sample of the same family ahead: the first of the next piece of the line
        sb = _facing(p, ex, ey, ux, uy, q, piece, f, reach, lateral, x0, y0, cell, gw, gh, start, items, pos_of)
        if sb < 0:
            return 1
        mx, my = 0.5 * (ex + q[sb, 0]), 0.5 * (ey + q[sb, 1])
        # a crossing, not a silhouette or a shadow: a sample of the other family near the gap's middle
        hit = False
        cx0, cx1, cy0, cy1 = _cells(mx, my, cross_r, x0, y0, cell, gw, gh)
        for cy in range(cy0, cy1 + 1):
            for cx in range(cx0, cx1 + 1):
                i0, i1 = _fam_items(cy * gw + cx, 3 - f, start, ncell)
                for it in range(i0, i1):
                    s = items[it]
                    if (q[s, 0] - mx) ** 2 + (q[s, 1] - my) ** 2 <= cross_r * cross_r:
                        hit = True
                        break
                if hit:
                    break
            if hit:
                break
        if not hit:
            return 2
        cr[p, side, 0] = mx
        cr[p, side, 1] = my
    return 0


@njit
def _axis(a, b, sid, q, across_r):
    """A piece's search frame (trace positions a … b): its middle sample (qx, qy), the unit chord (tx, ty) from its
    first to its last sample and how far along it the search reaches (half the chord, at most across_r / 2: beside
    the piece's middle, not the whole length of a long piece). ok False for a piece of zero length."""
    sm = sid[(a + b) // 2]
    qx, qy = q[sm, 0], q[sm, 1]
    tx, ty = q[sid[b], 0] - q[sid[a], 0], q[sid[b], 1] - q[sid[a], 1]
    half = 0.5 * math.hypot(tx, ty)
    if half <= 0.0:
        return False, qx, qy, tx, ty, 0.0
    return True, qx, qy, tx / (2.0 * half), ty / (2.0 * half), min(half, 0.5 * across_r)


@njit
def _beside(p, f, qx, qy, tx, ty, reach_al, across_r, cx0, cx1, cy0, cy1, q, piece, pos_of, gw, gh, start, items):
    """The nearest trace sample of family f on another piece on each side of piece p's middle (qx, qy), within
    reach_al along its chord (tx, ty) and at least 1 px across, in cells cx0 … cx1, cy0 … cy1: (s0, near0) on the
    left, (s1, near1) on the right (−1 and across_r + 1 where none)."""
    ncell = gw * gh
    near0 = across_r + 1.0
    near1 = across_r + 1.0
    s0 = -1
    s1 = -1
    for cy in range(cy0, cy1 + 1):
        for cx in range(cx0, cx1 + 1):
            i0, i1 = _fam_items(cy * gw + cx, f, start, ncell)
            for it in range(i0, i1):  # the geometric tests first, then whether the sample is another piece's
                s = items[it]
                dx, dy = q[s, 0] - qx, q[s, 1] - qy
                if abs(dx * tx + dy * ty) > reach_al:
                    continue
                ac = dx * ty - dy * tx
                if ac <= -1.0:
                    if -ac < near0:
                        k = pos_of[s]
                        if k >= 0 and piece[k] != p:
                            near0 = -ac
                            s0 = s
                elif ac >= 1.0 and ac < near1:
                    k = pos_of[s]
                    if k >= 0 and piece[k] != p:
                        near1 = ac
                        s1 = s
    return s0, near0, s1, near1


@njit
def _k_round(q, fam, sid, piece, tangent, val, end_pos, labelled, why, cr, n_p, anchor, min_samples, reach, lateral, cross_r, across_r,
             dirty, first_round, x0, y0, cell, gw, gh, start, items, pos_of):
    """One round of steps 1 and 2 over the unlabelled pieces of at least min_samples samples. Step 1: the
    nearest trace sample of the piece's family across its middle sample on each side (within its half length
    and across_r / 2 along, across_r across); each side whose sample's piece is labelled (val (n_p,), NaN: none) proposes that
    line ± 1. Step 2 (`_crossings`) then, once per piece (kept in why and cr). After the first round only
    pieces whose search reaches a dirty cell (a sample labelled in the last round) are looked at again.

    why (n_p,) int8, updated in place: 6 not looked at yet, 5 not tried (labelled, or short), 1 no facing
    piece, 2 no crossing in a gap, 3 no neighbour line, 4 no labelled neighbour line, 0 a candidate.
    Returns the candidates (nc,), kc (nc, 3) int64: the centre line (side 0's neighbour line, else side 1's),
    then each side's neighbour line (_NONE: none), nb (nc, 2) each side's neighbour sample (the other side's
    where one side has none), and the rows of the sheet check, _ROWS per candidate piece:
    its two crossings on the sheets centre − 1, centre, centre + 1, then each side's neighbour sample on its own
    sheet (the other side's where one side has none): pixels (_ROWS·nc, 2), family and line (_ROWS·nc,)."""
    cand = np.empty(n_p, np.intp)
    kc = np.empty((n_p, 3), np.int64)  # the centre line, then each side's neighbour line (_NONE: none)
    nb = np.empty((n_p, 2), np.intp)  # each side's neighbour sample (the other side's where none)
    n_out = 0
    for p in range(n_p):
        if why[p] == 5 or why[p] == 1 or why[p] == 2:
            continue
        a, b = end_pos[p], end_pos[n_p + p]
        if why[p] == 6:
            if labelled[p] or b - a + 1 < min_samples:
                why[p] = 5
                continue
        elif labelled[p]:
            continue
        f = fam[sid[a]]
        ok, qx, qy, tx, ty, reach_al = _axis(a, b, sid, q, across_r)
        if not ok:
            why[p] = 5
            continue
        cx0, cx1, cy0, cy1 = _cells(qx, qy, math.hypot(across_r, reach_al), x0, y0, cell, gw, gh)
        if not first_round:
            seen = False
            for cy in range(cy0, cy1 + 1):
                for cx in range(cx0, cx1 + 1):
                    seen = seen or dirty[cy * gw + cx]
            if not seen:
                continue
        s0, near0, s1, near1 = _beside(p, f, qx, qy, tx, ty, reach_al, across_r, cx0, cx1, cy0, cy1, q, piece, pos_of, gw, gh, start,
                                       items)
        kn0 = _NONE
        kn1 = _NONE
        for sd in range(2):
            s = s0 if sd == 0 else s1
            if s < 0 or (near0 if sd == 0 else near1) > across_r:
                continue
            kv = val[piece[pos_of[s]]]  # the neighbour's piece's line (its trimmed ends carry none)
            if math.isfinite(kv):
                if sd == 0:
                    kn0 = int(kv)
                else:
                    kn1 = int(kv)
        if kn0 == _NONE and kn1 == _NONE:
            why[p] = 3 if (s0 < 0 and s1 < 0) else 4
            continue
        if why[p] != 0:  # the crossings, once per piece
            w = _crossings(p, q, fam, sid, piece, tangent, end_pos, anchor, n_p, f, reach, lateral, cross_r, x0, y0, cell, gw, gh, start, items, pos_of, cr)
            why[p] = w
            if w != 0:
                continue
        cand[n_out] = p
        kc[n_out, 0] = kn0 if kn0 != _NONE else kn1  # the centre of the lines tried
        kc[n_out, 1] = kn0
        kc[n_out, 2] = kn1
        nb[n_out, 0] = s0 if kn0 != _NONE else s1
        nb[n_out, 1] = s1 if kn1 != _NONE else s0
        n_out += 1
    cq = np.empty((_ROWS * n_out, 2))
    cf = np.empty(_ROWS * n_out, np.int64)
    ck = np.empty(_ROWS * n_out, np.int64)
    for i in range(n_out):
        p = cand[i]
        f = fam[sid[end_pos[p]]]
        for j in range(_LINES):
            r = _ROWS * i + 2 * j
            for sd in range(2):
                cq[r + sd, 0] = cr[p, sd, 0]
                cq[r + sd, 1] = cr[p, sd, 1]
                cf[r + sd] = f
                ck[r + sd] = kc[i, 0] - _SPAN + j
        for sd in range(2):  # the neighbour samples on their own sheets
            r = _ROWS * i + 2 * _LINES + sd
            s = nb[i, sd]
            cq[r, 0] = q[s, 0]
            cq[r, 1] = q[s, 1]
            cf[r] = f
            ck[r] = kc[i, 1 + sd] if kc[i, 1 + sd] != _NONE else kc[i, 0]
    return cand[:n_out], kc[:n_out], nb[:n_out], cq, cf, ck


@njit
def _k_verdicts(cand, kc, m, res, z, tol, margin, z_lo, z_hi, end_pos, n_p, sid, q, fam):
    """`_verdicts` on `_k_round`'s rows (_ROWS per candidate)."""
    return _verdicts(cand, kc, m, res, z, tol, margin, z_lo, z_hi, end_pos, n_p, sid, q, fam, _ROWS, np.empty(kc.shape[0], np.bool_))


@njit
def _verdicts(cand, kc, m, res, z, tol, margin, z_lo, z_hi, end_pos, n_p, sid, q, fam, rows, amb_of):
    """Step 2's verdict per candidate piece. A line's score is the larger of the piece's two crossings' residuals
    on its sheet where both land inside [z_lo, z_hi] on consecutive lines of the other family. Of the two lines
    beside the neighbour's line the better must score within tol and the other at least margin·tol (else
    ambiguous, counted: the two are two sheets apart, and where the other family's lines run nearly along the
    epipolar lines a wrong sheet moves the crossings little), and it must be next to every labelled
    neighbour line, whose sample, on its own sheet, lies in the depth range nearest to one of the two lines of
    the other family that the crossings name (the same cell on both lines). m, res, z: (_ROWS·nc,) in
    `_k_round`'s row order (rows = _ROWS), or without the rows of the neighbour's own line (rows = _ROWS − 2,
    `_k_live_round`: they are never read). Returns k_of (nc,) (_NONE: not accepted), the number ambiguous, and
    the accepted pieces' samples for step 3: trace positions, owner (candidate rank), q, family, line; amb_of
    (nc,) is set True where the candidate is ambiguous."""
    nc = kc.shape[0]
    k_of = np.full(nc, _NONE, np.int64)
    amb = 0
    tot = 0
    amb_of[:] = False
    for i in range(nc):
        # each line's score: the larger crossing residual, where both crossings lie in the depth range on
        # consecutive lines of the other family (otherwise the line is out: the depth range decides)
        best = np.inf
        second = np.inf
        j_ok = 0
        for j in range(_LINES):
            if j == _SPAN:  # the piece is not its neighbour's line
                continue
            r = rows * i + 2 * j - (2 if rows < _ROWS and j > _SPAN else 0)
            if abs(m[r + 1] - m[r]) != 1:  # the piece is not its neighbour's line
                continue
            if not (z[r] >= z_lo and z[r] <= z_hi and z[r + 1] >= z_lo and z[r + 1] <= z_hi):
                continue
            sc = max(res[r], res[r + 1])
            if sc < best:
                second = best
                best = sc
                j_ok = j
            elif sc < second:
                second = sc
        if best > tol:
            continue
        if second < margin * tol:  # a rival line nearly as good: ambiguous
            amb += 1
            amb_of[i] = True
            continue
        k = kc[i, 0] - _SPAN + j_ok
        r = rows * i + 2 * j_ok - (2 if rows < _ROWS and j_ok > _SPAN else 0)
        ok = True
        for sd in range(2):
            kn = kc[i, 1 + sd]
            if kn == _NONE:
                continue
            rn = rows * i + rows - 2 + sd
            ok = ok and abs(k - kn) == 1 and (m[rn] == m[r] or m[rn] == m[r + 1]) and z[rn] >= z_lo and z[rn] <= z_hi
        if ok:
            k_of[i] = k
            p = cand[i]
            tot += end_pos[n_p + p] - end_pos[p] + 1
    pos = np.empty(tot, np.int64)
    owner = np.empty(tot, np.int64)
    qs = np.empty((tot, 2))
    fs = np.empty(tot, np.int64)
    ks = np.empty(tot, np.int64)
    w = 0
    for i in range(nc):
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
    return k_of, amb, pos, owner, qs, fs, ks


@njit
def _k_write(pos, owner, zs, z_lo, z_hi, k_of, cand, nb, end_pos, n_p, ts, sid, trim_px, index, seed_jid, labelled, val, q, dirty,
             x0, y0, cell, gw, gh):
    """Step 3 and the write: an accepted piece whose samples all lie in [z_lo, z_hi] on its sheet takes line
    k, except within trim_px of its ends, with the junction of its (first) neighbour sample (seed_jid, as the
    surface labels of decision 0093 do); the piece is marked labelled (labelled, val) and the cells of its
    samples dirty (dirty cleared first). Returns pieces and samples written."""
    dirty[:] = False
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
            s = sid[x]
            index[s] = k_of[i]
            seed_jid[s] = seed_jid[nb[i, 0]]
            wrote[i] = True
            n_s += 1
            cx = min(gw - 1, max(0, int((q[s, 0] - x0) / cell)))
            cy = min(gh - 1, max(0, int((q[s, 1] - y0) / cell)))
            dirty[cy * gw + cx] = True
    n_w = 0
    for i in range(nc):
        if wrote[i]:
            labelled[cand[i]] = True
            val[cand[i]] = k_of[i]
            n_w += 1
    return n_w, n_s


@njit
def _k_live_round(q, fam, sid, piece, tangent, val, end_pos, labelled, why, cr, live, n_live, nbs, rect, seen_kn, seen_amb, n_p, anchor,
                  min_samples, reach, lateral, cross_r, across_r, dirty, first_round, x0, y0, cell, gw, gh, start, items, pos_of):
    """`_k_round` on the pieces that can still become candidates, with what does not change between rounds kept:
    live[:n_live] (ascending piece ids, compacted in place) are the pieces `_k_round` would look at again
    (why 6 before the first round; afterwards 0 or 4, unlabelled: a piece with no neighbour sample (3), no
    facing piece (1), no crossing (2) or labelled stays as it is); nbs (n_p, 2) each side's neighbour sample
    within across_r (−1: none) and rect (n_p, 4) the cell range of the search, both from the piece's first
    search (the samples and the grid do not change, only the lines of their pieces, val). Same verdicts (why),
    crossings (cr) and candidates as `_k_round`, in the same order, except a candidate whose neighbour lines
    are those of its last verdict (seen_kn (n_p, 2), _NONE + 1: none yet; the verdict depends on nothing else):
    left out, its verdict counted again when it was ambiguous (seen_amb). The rows leave out the neighbour's
    own line (_ROWS − 2 per candidate, `_verdicts`' compact layout: never read). Returns the candidates, kc,
    nb, the rows, the new n_live and the number of repeated ambiguous verdicts."""
    cand = np.empty(n_live, np.intp)
    kc = np.empty((n_live, 3), np.int64)
    nb = np.empty((n_live, 2), np.intp)
    n_out = 0
    w_live = 0
    n_amb = 0
    for li in range(n_live):
        p = live[li]
        if first_round:
            a, b = end_pos[p], end_pos[n_p + p]
            if labelled[p] or b - a + 1 < min_samples:
                why[p] = 5
                continue
            ok, qx, qy, tx, ty, reach_al = _axis(a, b, sid, q, across_r)
            if not ok:
                why[p] = 5
                continue
            cx0, cx1, cy0, cy1 = _cells(qx, qy, math.hypot(across_r, reach_al), x0, y0, cell, gw, gh)
            rect[p, 0] = cx0
            rect[p, 1] = cx1
            rect[p, 2] = cy0
            rect[p, 3] = cy1
            s0, near0, s1, near1 = _beside(p, fam[sid[a]], qx, qy, tx, ty, reach_al, across_r, cx0, cx1, cy0, cy1, q, piece, pos_of, gw, gh,
                                           start, items)
            if s0 < 0 and s1 < 0:  # no neighbour sample, now or later
                why[p] = 3
                continue
            nbs[p, 0] = s0 if near0 <= across_r else -1
            nbs[p, 1] = s1 if near1 <= across_r else -1
            seen_kn[p, 0] = _NONE + 1  # no verdict yet (a line index is never _NONE + 1)
            seen_kn[p, 1] = _NONE + 1
        else:
            if labelled[p]:
                continue  # labelled in the last round: done
            seen = False
            for cy in range(rect[p, 2], rect[p, 3] + 1):
                for cx in range(rect[p, 0], rect[p, 1] + 1):
                    if dirty[cy * gw + cx]:
                        seen = True
                        break
                if seen:
                    break
            if not seen:
                live[w_live] = p
                w_live += 1
                continue
        kn0 = _NONE
        kn1 = _NONE
        for sd in range(2):
            s = nbs[p, sd]
            if s < 0:
                continue
            kv = val[piece[pos_of[s]]]
            if math.isfinite(kv):
                if sd == 0:
                    kn0 = int(kv)
                else:
                    kn1 = int(kv)
        if kn0 == _NONE and kn1 == _NONE:
            why[p] = 4
            live[w_live] = p
            w_live += 1
            continue
        if why[p] != 0:  # the crossings, once per piece
            f = fam[sid[end_pos[p]]]
            w = _crossings(p, q, fam, sid, piece, tangent, end_pos, anchor, n_p, f, reach, lateral, cross_r, x0, y0, cell, gw, gh, start, items,
                           pos_of, cr)
            why[p] = w
            if w != 0:
                continue
        live[w_live] = p
        w_live += 1
        if seen_kn[p, 0] == kn0 and seen_kn[p, 1] == kn1:  # the same verdict as last time
            n_amb += seen_amb[p]
            continue
        cand[n_out] = p
        kc[n_out, 0] = kn0 if kn0 != _NONE else kn1
        kc[n_out, 1] = kn0
        kc[n_out, 2] = kn1
        nb[n_out, 0] = nbs[p, 0] if kn0 != _NONE else nbs[p, 1]
        nb[n_out, 1] = nbs[p, 1] if kn1 != _NONE else nbs[p, 0]
        n_out += 1
    rows = _ROWS - 2
    cq = np.empty((rows * n_out, 2))
    cf = np.empty(rows * n_out, np.intp)
    ck = np.empty(rows * n_out, np.intp)
    for i in range(n_out):
        p = cand[i]
        f = fam[sid[end_pos[p]]]
        r = rows * i
        for j in range(_LINES):
            if j == _SPAN:
                continue
            for sd in range(2):
                cq[r + sd, 0] = cr[p, sd, 0]
                cq[r + sd, 1] = cr[p, sd, 1]
                cf[r + sd] = f
                ck[r + sd] = kc[i, 0] - _SPAN + j
            r += 2
        for sd in range(2):
            s = nb[i, sd]
            cq[r + sd, 0] = q[s, 0]
            cq[r + sd, 1] = q[s, 1]
            cf[r + sd] = f
            ck[r + sd] = kc[i, 1 + sd] if kc[i, 1 + sd] != _NONE else kc[i, 0]
    return cand[:n_out], kc[:n_out], nb[:n_out], cq, cf, ck, w_live, n_amb


@njit
def _k_all(q, fam, sid, piece, ts, tangent, index, seed_jid, n_p, anchor, min_samples, reach, lateral, cross_r, across_r, tol, margin,
           z_lo, z_hi, trim_px, rounds, x0, y0, cell, gw, gh, start, items, pos_of,
           tab, inv_step, R, t, index_min, nodes, iterations, end_n, end_t, chord_n, chord_t, K_proj, dist, centre, n_other, offsets, inv_dx,
           guess, K_nl, dist_nl, distorted, cu, cv, n12, offs, hyp, indices):
    """Every round in one call (`_k_pieces`, `_k_live_round`, `_k_sheet_check`, `_k_verdicts`, `_k_sheet_depth`,
    `_k_write`): `RigModel.sheet_check` and `sheet_depth`'s compiled path with their fixed arguments (tab …
    indices: `RigModel._sheet_check_args`, one by one: numba types a tuple of arrays in Python, ~0.2 ms a
    call; the first 18 are `_k_sheet_depth`'s). Returns ok,
    pieces, samples, ambiguous and the first round's left-out counts (no facing piece, no crossing, no neighbour,
    neighbour unlabelled). ok False: a pixel lay outside the camera table (the NumPy path's case); index and
    seed_jid are then restored as they were and the caller runs the rounds again through `RigModel`."""
    end_pos, labelled, val = _k_pieces(sid, piece, index, n_p)
    why = np.full(n_p, 6, np.int8)
    live = np.empty(n_p, np.intp)  # the pieces `_k_round` would try: unlabelled, at least min_samples long
    n_live = 0
    for p in range(n_p):
        if labelled[p] or end_pos[n_p + p] - end_pos[p] + 1 < min_samples:
            why[p] = 5
        else:
            live[n_live] = p
            n_live += 1
    # per piece, written before read (the crossings once found, the rest at the piece's first search)
    cr = np.empty((n_p, 2, 2))
    nbs = np.empty((n_p, 2), np.intp)
    rect = np.empty((n_p, 4), np.intp)
    seen_kn = np.empty((n_p, 2), np.int64)
    seen_amb = np.empty(n_p, np.int64)
    dirty = np.zeros(gw * gh, np.bool_)
    amb_of = np.empty(n_live, np.bool_)
    log_s = np.empty(256, np.intp)  # the samples written and their junctions before: undone when not ok
    log_j = np.empty(256, seed_jid.dtype)
    log_x = np.empty(256, np.intp)  # their trace positions (the end pass's pieces this step labelled, decision 0163)
    n_log = 0
    n_pieces = 0
    n_samples = 0
    n_amb = 0
    left = np.zeros(4, np.int64)
    ok = True
    for r in range(rounds):
        cand, kc, nb, cq, cf, ck, n_live, amb_again = _k_live_round(q, fam, sid, piece, tangent, val, end_pos, labelled, why, cr, live, n_live,
                                                                    nbs, rect, seen_kn, seen_amb, n_p, anchor, min_samples, reach, lateral,
                                                                    cross_r, across_r, dirty, r == 0, x0, y0, cell, gw, gh, start, items, pos_of)
        n_amb += amb_again
        if r == 0:
            for p in range(n_p):
                if why[p] >= 1 and why[p] <= 4:
                    left[why[p] - 1] += 1
        nc = cand.shape[0]
        if nc == 0:
            break
        nr = cq.shape[0]
        p_tmp = np.empty((nr, 3))
        z = np.empty(nr)
        m, res = _k_sheet_check(cq, cf, ck, tab, inv_step, R, t, index_min, nodes, iterations, end_n, end_t, chord_n, chord_t, K_proj, dist,
                                centre, n_other, offsets, inv_dx, guess, K_nl, dist_nl, distorted, cu, cv, n12, offs, hyp, indices,
                                np.empty((nr, 2)), np.empty(nr, np.bool_), p_tmp, np.empty(nr), z)
        if m.shape[0] != nr:
            ok = False
            break
        k_of, amb, pos, owner, qs, fs, ks = _verdicts(cand, kc, m, res, z, tol, margin, z_lo, z_hi, end_pos, n_p, sid, q, fam, _ROWS - 2,
                                                      amb_of[:nc])
        n_amb += amb
        for i in range(nc):
            seen_kn[cand[i], 0] = kc[i, 1]
            seen_kn[cand[i], 1] = kc[i, 2]
            seen_amb[cand[i]] = amb_of[i]
        if pos.shape[0] == 0:
            break
        zs = np.empty(pos.shape[0])
        if not _k_sheet_depth(qs, fs.astype(np.intp), ks.astype(np.intp), tab, inv_step, R, t, index_min, nodes, iterations, end_n, end_t,
                              chord_n, chord_t, K_proj, dist, centre, n_other, offsets, inv_dx, guess, zs):
            ok = False
            break
        if n_log + pos.shape[0] > log_s.shape[0]:
            size = 2 * (n_log + pos.shape[0])
            grown_s = np.empty(size, np.intp)
            grown_j = np.empty(size, seed_jid.dtype)
            grown_x = np.empty(size, np.intp)
            grown_s[:n_log] = log_s[:n_log]
            grown_j[:n_log] = log_j[:n_log]
            grown_x[:n_log] = log_x[:n_log]
            log_s = grown_s
            log_j = grown_j
            log_x = grown_x
        for w in range(pos.shape[0]):  # the undo log: every sample an accepted piece may write
            s = sid[pos[w]]
            log_s[n_log] = s
            log_j[n_log] = seed_jid[s]
            log_x[n_log] = pos[w]
            n_log += 1
        npc, nsm = _k_write(pos, owner, zs, z_lo, z_hi, k_of, cand, nb, end_pos, n_p, ts, sid, trim_px, index, seed_jid, labelled, val, q,
                            dirty, x0, y0, cell, gw, gh)
        if nsm == 0:
            break
        n_pieces += npc
        n_samples += nsm
    if not ok:
        for i in range(n_log - 1, -1, -1):
            index[log_s[i]] = np.nan
            seed_jid[log_s[i]] = log_j[i]
    # with ok: end_pos, labelled and val are `_k_pieces` of the labels now (_k_write keeps labelled and val), and every
    # sample whose index the rounds changed is at one of the logged positions (what the undo above relies on):
    # `_k_end_rows_after` needs no pass over every trace position (decision 0163)
    return ok, n_pieces, n_samples, n_amb, left, end_pos, labelled, val, log_x[:n_log]


@njit
def _k_end_rows(q, fam, sid, piece, tangent, index, was_unlabelled, n_p, anchor, reach, lateral, x0, y0, cell, gw, gh, start, items, pos_of):
    """The ends of the pieces this step labelled (decision 0106) whose facing piece (`_facing`, as step 2 found
    it) is unlabelled after the rounds: where the facing piece carries the piece's line the gap fillings put
    points through the crossing (0103's trim stands), where it carries another line the end stays trimmed too.
    was_unlabelled (P,) bool: index was NaN before the step (the step labels only pieces without a label).
    Returns per end (ne,): piece, side, the first labelled trace position inside it (the samples before it are
    the trimmed ones), and the rows of the sheet check on the piece's sheet, 2 per end: the gap's middle, then
    the facing sample: pixels (2·ne, 2), family and line (2·ne,)."""
    end_pos, labelled, val = _k_pieces(sid, piece, index, n_p)
    n = sid.shape[0]
    mine = np.zeros(n_p, np.bool_)
    for x in range(n):
        s = sid[x]
        if was_unlabelled[s] and math.isfinite(index[s]):
            mine[piece[x]] = True
    return _k_end_rows_of(q, fam, sid, piece, tangent, index, mine, end_pos, labelled, val, n_p, anchor, reach, lateral, x0, y0, cell,
                          gw, gh, start, items, pos_of)


@njit
def _k_end_rows_after(q, fam, sid, piece, tangent, index, was_unlabelled, n_p, anchor, reach, lateral, x0, y0, cell, gw, gh, start, items,
                      pos_of, end_pos, labelled, val, log_x):
    """`_k_end_rows` right after `_k_all` (ok), from what it returns: its end_pos, labelled and val (the same as
    `_k_pieces` now), and the pieces this step labelled from its logged positions log_x alone (a sample outside them
    kept its label, so it has no label now that it lacked before). The same result; no pass over every trace
    position (decision 0163)."""
    mine = np.zeros(n_p, np.bool_)
    for i in range(log_x.shape[0]):
        x = log_x[i]
        s = sid[x]
        if was_unlabelled[s] and math.isfinite(index[s]):
            mine[piece[x]] = True
    return _k_end_rows_of(q, fam, sid, piece, tangent, index, mine, end_pos, labelled, val, n_p, anchor, reach, lateral, x0, y0, cell,
                          gw, gh, start, items, pos_of)


@njit
def _k_end_rows_of(q, fam, sid, piece, tangent, index, mine, end_pos, labelled, val, n_p, anchor, reach, lateral, x0, y0, cell, gw, gh,
                   start, items, pos_of):
    """`_k_end_rows`' rows for the pieces mine (n_p,) bool, the pieces' table (end_pos, labelled, val) given."""
    ends = np.empty((2 * n_p, 3), np.intp)
    rq = np.empty((4 * n_p, 2))
    rf = np.empty(4 * n_p, np.intp)
    rk = np.empty(4 * n_p, np.intp)
    ne = 0
    for p in range(n_p):
        if not mine[p]:
            continue
        a, b = end_pos[p], end_pos[n_p + p]
        f = fam[sid[a]]
        for side in range(2):
            ex, ey, ux, uy = _end(p, side, n_p, end_pos, q, sid, tangent, anchor)
            sb = _facing(p, ex, ey, ux, uy, q, piece, f, reach, lateral, x0, y0, cell, gw, gh, start, items, pos_of)
            if sb < 0 or labelled[piece[pos_of[sb]]]:
                continue
            x = a if side == 0 else b
            step = 1 if side == 0 else -1
            inner = x
            while inner >= a and inner <= b and not math.isfinite(index[sid[inner]]):
                inner += step
            if inner < a or inner > b or inner == x:
                continue
            ends[ne, 0] = p
            ends[ne, 1] = side
            ends[ne, 2] = inner
            rq[2 * ne, 0] = 0.5 * (ex + q[sb, 0])
            rq[2 * ne, 1] = 0.5 * (ey + q[sb, 1])
            rq[2 * ne + 1, 0] = q[sb, 0]
            rq[2 * ne + 1, 1] = q[sb, 1]
            for r in range(2):
                rf[2 * ne + r] = f
                rk[2 * ne + r] = int(val[p])
            ne += 1
    return ends[:ne], rq[: 2 * ne], rf[: 2 * ne], rk[: 2 * ne], end_pos, val


@njit
def _k_write_ends(ends, keep, end_pos, n_p, sid, index, seed_jid, val, q, anchor, lateral):
    """The trimmed samples of the kept ends (keep (ne,) bool) take their piece's line and the junction of the
    first labelled sample inside the end, from that sample outwards while each lies within lateral px of the
    line through it and the sample `anchor` further inside (a sample the crossing's light pulls off the line, or
    one past a silhouette, stops the end). Returns the samples written."""
    n_s = 0
    for e in range(ends.shape[0]):
        if not keep[e]:
            continue
        p, side, inner = ends[e, 0], ends[e, 1], ends[e, 2]
        a, b = end_pos[p], end_pos[n_p + p]
        step = 1 if side == 0 else -1
        far = min(max(inner + step * anchor, a), b)
        si, sf = sid[inner], sid[far]
        dx, dy = q[si, 0] - q[sf, 0], q[si, 1] - q[sf, 1]
        L = math.sqrt(dx * dx + dy * dy)
        if L < 1.0:
            continue
        dx /= L
        dy /= L
        jid = seed_jid[si]
        x = inner - step
        while x >= a and x <= b:  # the samples 0103's trim left out (all within trim_px of the end)
            s = sid[x]
            if abs((q[s, 0] - q[si, 0]) * dy - (q[s, 1] - q[si, 1]) * dx) > lateral:
                break
            index[s] = val[p]
            seed_jid[s] = jid
            n_s += 1
            x -= step
    return n_s


def _label_ends(q, fam, sid, piece, tangent, index, seed_jid, was_unlabelled, *, model, depth_range_mm, grid, reach_px, lateral_px, tol_px,
                anchor, after=None) -> int:
    """Decision 0106: the trimmed ends of the pieces this step labelled that face an unlabelled piece of their
    line (`_k_end_rows`) take the piece's line where the line continues across the crossing on the piece's
    sheet: the gap's middle lies within tol_px of a line m of the other family and the facing sample in the
    same or the next cell (its nearest line m − 1, m or m + 1), both inside the depth range (a facing piece on
    another surface, beyond a depth edge, lands elsewhere on this sheet); each sample on the piece's line within
    lateral_px (`_k_write_ends`). Returns the samples written."""
    n_p = int(piece[-1]) + 1
    x0, y0, cell, gw, gh, start, items, pos_of = grid
    if after is None:
        ends, rq, rf, rk, end_pos, val = _k_end_rows(q, fam, sid, piece, tangent, index, was_unlabelled, n_p, int(anchor), float(reach_px),
                                                     float(lateral_px), x0, y0, cell, gw, gh, start, items, pos_of)
    else:  # `_k_all`'s (end_pos, labelled, val, logged positions): the same rows (decision 0163)
        ends, rq, rf, rk, end_pos, val = _k_end_rows_after(q, fam, sid, piece, tangent, index, was_unlabelled, n_p, int(anchor),
                                                           float(reach_px), float(lateral_px), x0, y0, cell, gw, gh, start, items, pos_of,
                                                           *after)
    if len(ends) == 0:
        return 0
    _, z, m, res = model.sheet_check(rq, rf, rk)
    z = z.reshape(-1, 2)
    m = np.asarray(m, np.int64).reshape(-1, 2)
    inside = np.all((z >= depth_range_mm[0]) & (z <= depth_range_mm[1]), axis=1)
    keep = inside & (res[0::2] <= tol_px) & (np.abs(m[:, 1] - m[:, 0]) <= 1)
    return int(_k_write_ends(ends, keep, end_pos, n_p, sid, index, seed_jid, val, q, int(anchor), float(lateral_px)))


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
    margin: float = 2.0,
    lateral_px: float = 1.0,
    min_samples: int = 4,
    anchor: int = 3,
    rounds: int = 8,
    ends: bool = True,
    end_rows_from_rounds: bool = True,
) -> dict:
    """Label unlabelled pieces beside a labelled line of their family whose two crossings confirm the line on
    its own light sheet (module doc).

    q (P, 2) camera px, fam (P,) 1/2; the traces as `labelling.label_samples` builds them: sid (n,) sample ids by
    piece and position, piece (n,) non-decreasing, ts (n,) position along the piece (px), tangent (n, 2).
    index (P,) float (NaN: unlabelled) and seed_jid (P,) int (the junction of the piece's neighbour sample) are
    written in place. grid: the frame's bucket grid of the valid samples split by family
    (`labelling._sample_grid(..., fam)`; ValueError otherwise). sigma_px: extraction's smoothing; a crossing needs
    a sample of the other family within mix_sigma·σ of the gap's middle. reach_px: the longest crossing gap
    (camera px); across_px: how far across its line a piece's neighbour line may lie (camera px); tol_px:
    projector px; margin: the other candidate must miss by margin·tol_px; lateral_px: camera px; pieces shorter
    than min_samples are not tried; anchor: samples inside an end for its direction; rounds: at most this many
    (each round's labels are the next round's neighbours). Returns counts: pieces and samples labelled, pieces
    left out as ambiguous, and the first round's pieces left out by reason (`left_out`: no facing piece, no
    crossing in a gap, no neighbour line, no labelled neighbour line; the crossings are looked for only beside a
    labelled neighbour line). end_rows_from_rounds: decision 0106's end pass takes the pieces' table and the pieces
    this step labelled from the compiled rounds (`_k_end_rows_after`; the same result, decision 0163); False: it
    walks every trace position again (`_k_end_rows`)."""
    stats = {"pieces": 0, "samples": 0, "ambiguous": 0}
    n = len(piece)
    if n == 0:
        return stats
    n_p = int(piece[-1]) + 1
    z_lo, z_hi = float(depth_range_mm[0]), float(depth_range_mm[1])
    x0, y0, cell, gw, gh, start, items, pos_of = grid
    if len(start) != 2 * gw * gh + 1:
        raise ValueError("label_beside_lines needs the bucket grid split by family: build it with labelling._sample_grid(..., fam)")
    fixed = model._sheet_check_args
    was_unlabelled = np.isnan(index)
    if fixed is not None:
        ok, n_pieces, n_samples, n_amb, left, *after = _k_all(q, fam, sid, piece, ts, tangent, index, seed_jid, n_p, int(anchor), int(min_samples),
                                                      float(reach_px), float(lateral_px), float(mix_sigma * sigma_px), float(across_px),
                                                      float(tol_px), float(margin), z_lo, z_hi, float(trim_px), int(rounds),
                                                      x0, y0, cell, gw, gh, start, items, pos_of, *fixed)
        if ok:
            stats["pieces"] = int(n_pieces)
            stats["samples"] = int(n_samples)
            stats["ambiguous"] = int(n_amb)
            stats["left_out"] = dict(zip(("no_facing_piece", "no_crossing", "no_neighbour", "neighbour_unlabelled"), (int(c) for c in left)))
            _after_rounds(stats, q, fam, sid, piece, ts, tangent, index, seed_jid, was_unlabelled, model=model, depth_range_mm=depth_range_mm,
                          grid=grid, sigma_px=sigma_px, reach_px=reach_px, across_px=across_px, mix_sigma=mix_sigma, trim_px=trim_px,
                          tol_px=tol_px, margin=margin, lateral_px=lateral_px, min_samples=min_samples, anchor=anchor, ends=ends,
                          after=tuple(after) if end_rows_from_rounds else None)
            return stats
    # the NumPy path of RigModel (no camera table, or a pixel outside it): round by round
    return _by_rounds(q, fam, sid, piece, ts, tangent, index, seed_jid, model=model, depth_range_mm=depth_range_mm, grid=grid,
                      sigma_px=sigma_px, reach_px=reach_px, across_px=across_px, mix_sigma=mix_sigma, trim_px=trim_px, tol_px=tol_px,
                      margin=margin, lateral_px=lateral_px, min_samples=min_samples, anchor=anchor, rounds=rounds, ends=ends)


def _by_rounds(q, fam, sid, piece, ts, tangent, index, seed_jid, *, model, depth_range_mm, grid, sigma_px, reach_px, across_px, mix_sigma,
               trim_px, tol_px, margin, lateral_px, min_samples, anchor, rounds, ends=True) -> dict:
    """`label_beside_lines` round by round through `RigModel.sheet_check` and `sheet_depth` (their NumPy path
    where the camera table does not cover a pixel): `_k_round`, `_k_verdicts`, `_k_write` per round, every
    piece's search repeated where it reaches a dirty cell. The same labels and counts as `_k_all` (checked by
    test_recon_limb.py) at about 1.6–1.9× its time (decision 0103, speed, round 2)."""
    stats = {"pieces": 0, "samples": 0, "ambiguous": 0}
    n_p = int(piece[-1]) + 1
    z_lo, z_hi = float(depth_range_mm[0]), float(depth_range_mm[1])
    x0, y0, cell, gw, gh, start, items, pos_of = grid
    was_unlabelled = np.isnan(index)
    end_pos, labelled, val = _k_pieces(sid, piece, index, n_p)
    why = np.full(n_p, 6, np.int8)
    cr = np.zeros((n_p, 2, 2))
    dirty = np.zeros(gw * gh, np.bool_)
    for r in range(rounds):
        cand, kc, nb, cq, cf, ck = _k_round(q, fam, sid, piece, tangent, val, end_pos, labelled, why, cr, n_p, int(anchor), int(min_samples),
                                        float(reach_px), float(lateral_px), float(mix_sigma * sigma_px), float(across_px),
                                        dirty, r == 0, x0, y0, cell, gw, gh, start, items, pos_of)
        if r == 0:  # the first round's reasons
            stats["left_out"] = dict(zip(("no_facing_piece", "no_crossing", "no_neighbour", "neighbour_unlabelled"),
                                         (int(c) for c in np.bincount(why, minlength=7)[1:5])))
        if len(cand) == 0:
            break
        _, z, m, res = model.sheet_check(cq, cf, ck)
        k_of, n_amb, pos, owner, qs, fs, ks = _k_verdicts(cand, kc, np.asarray(m, np.int64), res, z, float(tol_px), float(margin), z_lo, z_hi,
                                                          end_pos, n_p, sid, q, fam)
        stats["ambiguous"] += int(n_amb)
        if len(pos) == 0:
            break
        zs = model.sheet_depth(qs, fs, ks)
        n_pieces, n_samples = _k_write(pos, owner, zs, z_lo, z_hi, k_of, cand, nb, end_pos, n_p, ts, sid, float(trim_px), index,
                                       seed_jid, labelled, val, q, dirty, x0, y0, cell, gw, gh)
        if n_samples == 0:
            break
        stats["pieces"] += int(n_pieces)
        stats["samples"] += int(n_samples)
    _after_rounds(stats, q, fam, sid, piece, ts, tangent, index, seed_jid, was_unlabelled, model=model, depth_range_mm=depth_range_mm, grid=grid,
                  sigma_px=sigma_px, reach_px=reach_px, across_px=across_px, mix_sigma=mix_sigma, trim_px=trim_px, tol_px=tol_px, margin=margin,
                  lateral_px=lateral_px, min_samples=min_samples, anchor=anchor, ends=ends)
    return stats


def _after_rounds(stats, q, fam, sid, piece, ts, tangent, index, seed_jid, was_unlabelled, *, model, depth_range_mm, grid, sigma_px, reach_px,
                  across_px, mix_sigma, trim_px, tol_px, margin, lateral_px, min_samples, anchor, ends, after=None) -> None:
    """Decision 0106's pass after the rounds, into stats: the trimmed ends facing an unlabelled piece (`_label_ends`,
    when ends)."""
    if ends and stats["samples"] == 0:
        # the rounds labelled nothing: no piece this step labelled, so no end to look at (`_k_end_rows` would return
        # none; decision 0145: most frames where this step labels nothing)
        stats["samples_ends"] = 0
    elif ends:
        stats["samples_ends"] = _label_ends(q, fam, sid, piece, tangent, index, seed_jid, was_unlabelled, model=model,
                                            depth_range_mm=depth_range_mm, grid=grid, reach_px=reach_px, lateral_px=lateral_px, tol_px=tol_px,
                                            anchor=anchor, after=after)
        stats["samples"] += stats["samples_ends"]
