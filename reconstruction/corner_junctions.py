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


@njit(error_model="numpy")
def _solve3(a, b):
    """The 3×3 system a·x = b by Cramer's rule (a (3, 3), b (3,)); NaN when singular."""
    det = (a[0, 0] * (a[1, 1] * a[2, 2] - a[1, 2] * a[2, 1]) - a[0, 1] * (a[1, 0] * a[2, 2] - a[1, 2] * a[2, 0])
           + a[0, 2] * (a[1, 0] * a[2, 1] - a[1, 1] * a[2, 0]))
    x = np.full(3, np.nan)
    if abs(det) < 1e-12:
        return x
    for c in range(3):
        m = a.copy()
        for r in range(3):
            m[r, c] = b[r]
        x[c] = (m[0, 0] * (m[1, 1] * m[2, 2] - m[1, 2] * m[2, 1]) - m[0, 1] * (m[1, 0] * m[2, 2] - m[1, 2] * m[2, 0])
                + m[0, 2] * (m[1, 0] * m[2, 1] - m[1, 1] * m[2, 0])) / det
    return x


@njit(error_model="numpy")
def curved_crossings(valid, arm_of, fam, qx, qy, nx, ny, cen, dr, cnt, n_neg, n_pos, par, offc, sx, sy,
                     rms_tol, jump_tol, sin_turn, off_tol):
    """X's whose arms are curved (a curved surface): the candidates the arm tests rejected although both lines
    run through (samples on both sides), not parallel and on the candidate, refitted with a parabola per
    family in the frame of its straight fit (offset w = a + b·s + c·s² along s; one pass dropping samples
    farther than max(1, 3·RMS)). Kept where both parabolas are straight enough (RMS ≤ rms_tol), show no
    sideways jump (mean residuals on the two sides within jump_tol) and no turn of the samples' own
    directions against the parabola's tangent (mean |sin| ≤ sin_turn), and their intersection (Newton from
    the straight fits' one) is within off_tol of the candidate (sx, sy).

    arm_of (P,) the candidate each sample is an arm of (−1 none); fam (P,) 1/2; qx, qy, nx, ny float32 the
    samples and their normals; cen, dr (2·ns, 2), cnt, n_neg, n_pos (2·ns,): `junction_fits`' output.
    Returns curved (ns,) bool, qj (ns, 2) the intersection and tangents (ns, 2, 2) the unit tangents of the
    i- and j-parabola there (NaN where not curved)."""
    ns = len(valid)
    G = 2 * ns
    curved = np.zeros(ns, np.bool_)
    qj = np.full((ns, 2), np.nan)
    tang = np.full((ns, 2, 2), np.nan)
    want = np.zeros(ns, np.bool_)
    for k in range(ns):
        a = 2 * k
        b = a + 1
        want[k] = ((not valid[k]) and (not par[k]) and (not offc[k]) and cnt[a] >= 5 and cnt[b] >= 5
                   and n_neg[a] >= 1 and n_pos[a] >= 1 and n_neg[b] >= 1 and n_pos[b] >= 1)
    # the arm samples of the wanted candidates, grouped per (candidate, family) (counting sort)
    P = len(arm_of)
    start = np.zeros(G + 1, np.int64)
    for i in range(P):
        c = arm_of[i]
        if c >= 0 and want[c]:
            start[2 * c + fam[i]] += 1
    for g in range(G):
        start[g + 1] += start[g]
    fill = start[:-1].copy()
    order = np.empty(start[G], np.int64)
    for i in range(P):
        c = arm_of[i]
        if c >= 0 and want[c]:
            g = 2 * c + fam[i] - 1
            order[fill[g]] = i
            fill[g] += 1
    coef = np.zeros((G, 3))
    ok = np.zeros(G, np.bool_)
    for k in range(ns):
        if not want[k]:
            continue
        good = True
        for g in (2 * k, 2 * k + 1):
            cx, cy, dx, dy = cen[g, 0], cen[g, 1], dr[g, 0], dr[g, 1]
            keep_lim = np.inf
            x = np.full(3, np.nan)
            rms = np.inf
            for it in range(2):
                A = np.zeros((3, 3))
                B = np.zeros(3)
                n = 0
                for t in range(start[g], start[g + 1]):
                    i = order[t]
                    px = np.float64(qx[i]) - cx
                    py = np.float64(qy[i]) - cy
                    s = px * dx + py * dy
                    w = px * dy - py * dx
                    if it == 1 and abs(w - (x[0] + x[1] * s + x[2] * s * s)) > keep_lim:
                        continue
                    v0, v1, v2 = 1.0, s, s * s
                    A[0, 0] += v0 * v0
                    A[0, 1] += v0 * v1
                    A[0, 2] += v0 * v2
                    A[1, 1] += v1 * v1
                    A[1, 2] += v1 * v2
                    A[2, 2] += v2 * v2
                    B[0] += w * v0
                    B[1] += w * v1
                    B[2] += w * v2
                    n += 1
                A[1, 0] = A[0, 1]
                A[2, 0] = A[0, 2]
                A[2, 1] = A[1, 2]
                if n < 5:
                    x = np.full(3, np.nan)
                    break
                x = _solve3(A, B)
                if not np.isfinite(x[0]):
                    break
                ss = 0.0
                for t in range(start[g], start[g + 1]):
                    i = order[t]
                    px = np.float64(qx[i]) - cx
                    py = np.float64(qy[i]) - cy
                    s = px * dx + py * dy
                    r = (px * dy - py * dx) - (x[0] + x[1] * s + x[2] * s * s)
                    if it == 1 and abs(r) > keep_lim:
                        continue
                    ss += r * r
                rms = math.sqrt(ss / n)
                keep_lim = max(1.0, 3.0 * rms)
            if not (np.isfinite(x[0]) and rms <= rms_tol):
                good = False
                break
            coef[g, 0] = x[0]
            coef[g, 1] = x[1]
            coef[g, 2] = x[2]
        if not good:
            continue
        # the intersection of the two parabolas: p_g(s) = c_g + s·d_g + w_g(s)·n_g, n_g = (d_y, −d_x)
        ga = 2 * k
        gb = ga + 1
        c_ = dr[ga, 0] * dr[gb, 1] - dr[ga, 1] * dr[gb, 0]
        ex = cen[gb, 0] - cen[ga, 0]
        ey = cen[gb, 1] - cen[ga, 1]
        s_a = (ex * dr[gb, 1] - ey * dr[gb, 0]) / c_
        s_b = (ex * dr[ga, 1] - ey * dr[ga, 0]) / c_
        for it in range(20):
            wa = coef[ga, 0] + coef[ga, 1] * s_a + coef[ga, 2] * s_a * s_a
            wb = coef[gb, 0] + coef[gb, 1] * s_b + coef[gb, 2] * s_b * s_b
            fx = (cen[ga, 0] + s_a * dr[ga, 0] + wa * dr[ga, 1]) - (cen[gb, 0] + s_b * dr[gb, 0] + wb * dr[gb, 1])
            fy = (cen[ga, 1] + s_a * dr[ga, 1] - wa * dr[ga, 0]) - (cen[gb, 1] + s_b * dr[gb, 1] - wb * dr[gb, 0])
            da = coef[ga, 1] + 2 * coef[ga, 2] * s_a
            db = coef[gb, 1] + 2 * coef[gb, 2] * s_b
            j00 = dr[ga, 0] + da * dr[ga, 1]
            j10 = dr[ga, 1] - da * dr[ga, 0]
            j01 = -(dr[gb, 0] + db * dr[gb, 1])
            j11 = -(dr[gb, 1] - db * dr[gb, 0])
            det = j00 * j11 - j01 * j10
            if abs(det) < 1e-12:
                s_a = np.nan
                break
            ua = (fx * j11 - fy * j01) / det
            ub = (j00 * fy - j10 * fx) / det
            s_a -= ua
            s_b -= ub
            if abs(ua) + abs(ub) < 1e-9:
                break
        if not np.isfinite(s_a):
            continue
        wa = coef[ga, 0] + coef[ga, 1] * s_a + coef[ga, 2] * s_a * s_a
        px = cen[ga, 0] + s_a * dr[ga, 0] + wa * dr[ga, 1]
        py = cen[ga, 1] + s_a * dr[ga, 1] - wa * dr[ga, 0]
        if not (np.isfinite(px) and np.isfinite(py)) or math.hypot(px - sx[k], py - sy[k]) > off_tol:
            continue
        # no sideways jump (mean residuals on the two sides of the intersection) and no turn against the tangent
        good = True
        for g, s0 in ((ga, s_a), (gb, s_b)):
            cx, cy, dx, dy = cen[g, 0], cen[g, 1], dr[g, 0], dr[g, 1]
            sn = 0.0
            nn = 0
            sp = 0.0
            np_ = 0
            ssin = 0.0
            m = 0
            for t in range(start[g], start[g + 1]):
                i = order[t]
                ux = np.float64(qx[i]) - cx
                uy = np.float64(qy[i]) - cy
                s = ux * dx + uy * dy
                r = (ux * dy - uy * dx) - (coef[g, 0] + coef[g, 1] * s + coef[g, 2] * s * s)
                if abs(r) > max(1.0, 3.0 * rms_tol):
                    continue
                if s < s0 - 0.5:
                    sn += r
                    nn += 1
                elif s > s0 + 0.5:
                    sp += r
                    np_ += 1
                dw = coef[g, 1] + 2 * coef[g, 2] * s
                tx = dx + dw * dy
                ty = dy - dw * dx
                tl = math.hypot(tx, ty)
                ssin += abs(np.float64(nx[i]) * tx / tl + np.float64(ny[i]) * ty / tl)
                m += 1
            if nn == 0 or np_ == 0 or m == 0:
                good = False
                break
            if abs(sn / nn - sp / np_) > jump_tol or ssin / m > sin_turn:
                good = False
                break
        if not good:
            continue
        curved[k] = True
        qj[k, 0] = px
        qj[k, 1] = py
        for f, (g, s0) in enumerate(((ga, s_a), (gb, s_b))):
            dw = coef[g, 1] + 2 * coef[g, 2] * s0
            tx = dr[g, 0] + dw * dr[g, 1]
            ty = dr[g, 1] - dw * dr[g, 0]
            tl = math.hypot(tx, ty)
            tang[k, f, 0] = tx / tl
            tang[k, f, 1] = ty / tl
    return curved, qj, tang
