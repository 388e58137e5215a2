"""Label unlabelled trace pieces from the labelled surface around them (decision 0093).

A labelled sample of line k has a depth: its camera ray on light sheet k. Around an unlabelled piece, the
labelled samples within about one junction step give the local surface; on a smooth surface the piece's index
follows from it: its samples' rays meet that surface at projector positions on one line k of its family.

Evidence from one side only is not enough (across a depth edge the neighbours are another surface, and a
periodic grid lets a wrong k fit by chance; decisions 0049, 0089). Confirming the prediction at the piece's
crossings (the crossing on the epipolar line of the predicted junction, on both light sheets) was measured
and does not work on these rigs: the crossings of short unlabelled pieces are located to 1–5 projector px on
the sensitive sheet, and the partner-sheet check alone let a piece 8 lines off through (decision 0093). So the
surface must hold on *both sides* of the piece: a piece is labelled only where it lies inside the labelled
surface around it and one plane fits that surface far better than one sheet step:

1. **Neighbourhood.** The labelled samples (either family) in the cells of the frame's bucket grid
   (`labelling._sample_grid`) that the square of half side `fit_radius_px` + the piece's half extent around
   the piece's centre touches.
2. **Support on both sides.** At least `min_neighbours` of them, spread in two directions (the smaller
   principal spread at least `min_spread` of that half side: one line's samples leave the plane open), and the
   piece's centre within `max_offset` standard deviations (Mahalanobis, in the neighbours' own covariance)
   of their centroid: neighbours around the piece, not on one side of it (for a uniformly labelled half disc
   the offset of the disc's centre is 1.6). Camera px only, from per-cell sums: no depth is computed for
   pieces that fail here.
3. **Local surface.** The neighbours, triangulated on their own sheets (camera-frame depth z), are fitted by a
   plane in the camera frame: 1/z = a·x + b·y + c in normalised camera coordinates (exact for a plane, least
   squares). Its RMS relative depth residual (of (1/z − fit)·z) must be at most `max_fit_lines` of the
   relative depth step between neighbouring light sheets on the piece's middle ray (|z(k+1) − z(k)| / z(k)):
   neighbours from two surfaces, or a fold, do not fit one plane.
4. **Prediction.** Each sample's ray meets the plane; its projector point lies within `max_pred_lines` line
   spacings (the family's smallest) of one line k of the piece's family, the same k for every sample; and the
   predicted position, in sheet steps from sheet k, drifts along the piece by at most `max_pred_lines` per
   junction step of the piece's length (a line keeps its index along itself; a piece of the other family's
   line, given this family by mistake, drifts by a whole line per junction step).
5. **Working volume.** Every sample of the piece, triangulated on sheet k, lies inside the depth range.

Pieces of at least `min_samples` samples are tried. The samples within `trim_px` of a piece's ends are left
out (the crossing's light pulls the ridge there; the gap filling puts them back where the line is labelled on
both sides) and take the junction of the labelled neighbour nearest the piece's centre. Repeated for `rounds`
rounds: newly labelled pieces are neighbours in the next (only pieces whose cells changed are looked at
again). The depths of the labelled samples are computed once per sample and only for pieces with support.
"""

from __future__ import annotations

import math

import numpy as np

from reconstruction._jit import njit
from reconstruction._label_kernels import project_nearest_line as _k_project_nearest_line
from reconstruction.continuation import project_nearest_line
from reconstruction.geometry import depth_cam
from reconstruction.rigmodel import RigModel, _k_cam_bilinear, _k_light_sheets



@njit
def _k_open_pieces(sid, piece, index, q, n_p, min_samples):
    """The trace pieces (piece (n,) non-decreasing ids, sid (n,) their sample ids in order): first and last
    trace position of each (n_p,), and the pieces without a labelled sample (finite index) of at least
    min_samples samples: their ids, the mean of their samples (camera px) and their half extent (the largest
    distance of a sample from that mean)."""
    n = sid.shape[0]
    first = np.full(n_p, -1, np.intp)
    last = np.full(n_p, -1, np.intp)
    lab = np.zeros(n_p, np.bool_)
    for k in range(n):
        p = piece[k]
        if first[p] < 0:
            first[p] = k
        last[p] = k
        if not lab[p] and math.isfinite(index[sid[k]]):  # a labelled piece's index is not read past its first label
            lab[p] = True
    m = 0
    for p in range(n_p):
        if not lab[p] and last[p] - first[p] + 1 >= min_samples:
            m += 1
    cand = np.empty(m, np.intp)
    cen = np.empty((m, 2))
    ext = np.zeros(m)
    r = 0
    for p in range(n_p):
        if lab[p] or last[p] - first[p] + 1 < min_samples:
            continue
        sx = 0.0
        sy = 0.0
        for k in range(first[p], last[p] + 1):
            sx += q[sid[k], 0]
            sy += q[sid[k], 1]
        c = last[p] - first[p] + 1
        cx = sx / c
        cy = sy / c
        e = 0.0
        for k in range(first[p], last[p] + 1):
            d = math.hypot(q[sid[k], 0] - cx, q[sid[k], 1] - cy)
            if d > e:
                e = d
        cand[r] = p
        cen[r, 0] = cx
        cen[r, 1] = cy
        ext[r] = e
        r += 1
    return first, last, cand, cen, ext


@njit
def _k_cell_box(cx, cy, R, x0, y0, cell, gw, gh):
    """The grid cells (inclusive ranges gx0..gx1, gy0..gy1) that the square of half side R around (cx, cy)
    touches: a piece's neighbourhood."""
    gx0 = max(int(math.floor((cx - R - x0) / cell)), 0)
    gx1 = min(int(math.floor((cx + R - x0) / cell)), gw - 1)
    gy0 = max(int(math.floor((cy - R - y0) / cell)), 0)
    gy1 = min(int(math.floor((cy + R - y0) / cell)), gh - 1)
    return gx0, gx1, gy0, gy1


@njit
def _k_cell_sums(q, index, cen, rad, x0, y0, cell, gw, gh, start, items):
    """Per grid cell of the neighbourhoods of the centres cen (n, 2) (half sides rad, `_k_cell_box`), over its
    labelled samples (finite index): count, Σx, Σy, Σx², Σxy, Σy² (camera px). Returns slot (gw·gh,), the row
    of a cell in sums (−1: in no neighbourhood, never read), and sums (m, 6) (decision 0097: a frame-wide
    (gw·gh, 6) table was ~0.7 MB to clear per call)."""
    G = gw * gh
    slot = np.full(G, -1, np.int64)
    for r in range(cen.shape[0]):
        gx0, gx1, gy0, gy1 = _k_cell_box(cen[r, 0], cen[r, 1], rad[r], x0, y0, cell, gw, gh)
        for yy in range(gy0, gy1 + 1):
            for xx in range(gx0, gx1 + 1):
                slot[yy * gw + xx] = 0
    m = 0
    for b in range(G):
        if slot[b] == 0:
            slot[b] = m + 1  # (1-based while counting)
            m += 1
    out = np.zeros((m, 6))
    for b in range(G):
        sl = slot[b] - 1
        slot[b] = sl
        if sl < 0:
            continue
        for t in range(start[b], start[b + 1]):
            s = items[t]
            if math.isfinite(index[s]):
                x = q[s, 0]
                y = q[s, 1]
                out[sl, 0] += 1.0
                out[sl, 1] += x
                out[sl, 2] += y
                out[sl, 3] += x * x
                out[sl, 4] += x * y
                out[sl, 5] += y * y
    return slot, out


@njit
def _k_support(cen, rad, slot, sums, dirty, x0, y0, cell, gw, gh):
    """Per piece centre cen[r]: its neighbourhood's labelled samples (the grid cells the square of half side
    rad[r] touches, from the per-cell sums of `_k_cell_sums`, slot and sums; every such cell has a slot):
    their count, the smaller principal spread (camera px, square root of the smaller eigenvalue of their
    covariance) and offset2, the Mahalanobis form
    of the centre against their centroid in that covariance (inf when singular or fewer than 3). Centres
    whose cells include none marked in dirty (gw·gh, bool: where labels changed since the last call) are
    skipped (count 0)."""
    n = cen.shape[0]
    cnt = np.zeros(n, np.int64)
    spread = np.zeros(n)
    offset2 = np.full(n, np.inf)
    for r in range(n):
        cx = cen[r, 0]
        cy = cen[r, 1]
        gx0, gx1, gy0, gy1 = _k_cell_box(cx, cy, rad[r], x0, y0, cell, gw, gh)
        changed = False
        m = sx = sy = sxx = sxy = syy = 0.0
        for yy in range(gy0, gy1 + 1):
            for xx in range(gx0, gx1 + 1):
                b = yy * gw + xx
                changed |= dirty[b]
                sl = slot[b]
                m += sums[sl, 0]
                sx += sums[sl, 1]
                sy += sums[sl, 2]
                sxx += sums[sl, 3]
                sxy += sums[sl, 4]
                syy += sums[sl, 5]
        if not changed:
            continue
        cnt[r] = int(m)
        if m < 3.0:
            continue
        mx = sx / m
        my = sy / m
        cxx = max(sxx / m - mx * mx, 0.0)
        cxy = sxy / m - mx * my
        cyy = max(syy / m - my * my, 0.0)
        tr = 0.5 * (cxx + cyy)
        disc = math.sqrt(max(0.25 * (cxx - cyy) ** 2 + cxy * cxy, 0.0))
        spread[r] = math.sqrt(max(tr - disc, 0.0))
        dc = cxx * cyy - cxy * cxy
        if dc > 0.0:
            dx = mx - cx
            dy = my - cy
            offset2[r] = (cyy * dx * dx - 2.0 * cxy * dx * dy + cxx * dy * dy) / dc
    return cnt, spread, offset2


@njit
def _k_supported(open_c, cen_all, rad_all, slot, sums, dirty, x0, y0, cell, gw, gh, min_neighbours, min_spread, max_offset2):
    """One round's step 2 over the open candidates (open_c (m,) bool over cen_all (m, 2), rad_all (m,)):
    `_k_support`, then the candidates with at least min_neighbours neighbours, a smaller principal spread of at
    least min_spread·rad and offset2 ≤ max_offset2. Returns the number of open candidates and the supported
    ones (indices into cen_all, ascending)."""
    m = open_c.shape[0]
    n_open = 0
    for i in range(m):
        if open_c[i]:
            n_open += 1
    oc = np.empty(n_open, np.int64)
    cen = np.empty((n_open, 2))
    rad = np.empty(n_open)
    j = 0
    for i in range(m):
        if open_c[i]:
            oc[j] = i
            cen[j, 0] = cen_all[i, 0]
            cen[j, 1] = cen_all[i, 1]
            rad[j] = rad_all[i]
            j += 1
    if n_open == 0:
        return 0, oc
    cnt, spread, offset2 = _k_support(cen, rad, slot, sums, dirty, x0, y0, cell, gw, gh)
    ns = 0
    for j in range(n_open):
        if cnt[j] >= min_neighbours and spread[j] >= min_spread * rad[j] and offset2[j] <= max_offset2:
            ns += 1
    sup = np.empty(ns, np.int64)
    k = 0
    for j in range(n_open):
        if cnt[j] >= min_neighbours and spread[j] >= min_spread * rad[j] and offset2[j] <= max_offset2:
            sup[k] = oc[j]
            k += 1
    return n_open, sup


@njit
def _k_needed(cen, rad, index, w, seen, x0, y0, cell, gw, gh, start, items):
    """The labelled samples (finite index[s]) in the neighbourhood of any centre cen[r] (the cells
    `_k_support` sums) whose depth is not known yet (w[s] NaN), each once: their ids, in the order found.
    seen (P,) bool is scratch, marked for the returned ids (and left marked)."""
    out = np.empty(items.shape[0], np.intp)
    m = 0
    # a cell is read at its first visit only: nothing it could add later is unseen then (index and w do not change
    # here), so the ids and their order are those of reading it at every visit (decision 0124)
    visited = np.zeros(gw * gh, np.bool_)
    for r in range(cen.shape[0]):
        gx0, gx1, gy0, gy1 = _k_cell_box(cen[r, 0], cen[r, 1], rad[r], x0, y0, cell, gw, gh)
        for yy in range(gy0, gy1 + 1):
            for xx in range(gx0, gx1 + 1):
                b = yy * gw + xx
                if visited[b]:
                    continue
                visited[b] = True
                for t in range(start[b], start[b + 1]):
                    s = items[t]
                    if seen[s] or not math.isfinite(index[s]) or math.isfinite(w[s]):
                        continue
                    seen[s] = True
                    out[m] = s
                    m += 1
    return out[:m]


@njit
def _k_cam_xy(q, tab, inv_step, K_cam, xy, inside):
    """`RigModel.cam_normalised` of pixels q (N, 2) into xy (N, 2): the camera table (`_k_cam_bilinear`; inside
    (N,) False where a pixel lies outside it), or with an empty table (a camera without distortion) the pinhole
    inverse with K_cam, the operations of `Intrinsics.pixels_to_normalised` (decision 0094)."""
    if tab.shape[0] > 0:
        _k_cam_bilinear(q, tab, inv_step, xy, inside)
        return
    for n in range(q.shape[0]):
        y = (q[n, 1] - K_cam[1, 2]) / K_cam[1, 1]
        xy[n, 0] = (q[n, 0] - K_cam[0, 2] - K_cam[0, 1] * y) / K_cam[0, 0]
        xy[n, 1] = y
        inside[n] = True


@njit
def _k_needed_points(cen, rad, index, w, seen, x0, y0, cell, gw, gh, start, items, q, fam, xy_lab, tab, inv_step, K_cam, R, t,
                     index_min, nodes, iterations, end_n, end_t, chord_n, chord_t, K_proj, dist, centre, n_other, offsets,
                     inv_dx, guess):
    """`_k_needed`, then those samples' light-sheet points in one call (decision 0094): their normalised camera
    coordinates from the camera table (`RigModel.cam_normalised`'s `_k_cam_bilinear`), written to xy_lab (read
    only where w becomes finite), and their points p (m, 3) on their own sheets (`RigModel.intersect_light_sheets`'
    `_k_light_sheets`). Returns (ids, p, True), or (ids, empty, False) when a sample lies outside the table
    (the caller then takes the NumPy path for these ids)."""
    todo = _k_needed(cen, rad, index, w, seen, x0, y0, cell, gw, gh, start, items)
    m = todo.shape[0]
    qq = np.empty((m, 2))
    fam_t = np.empty(m, np.intp)
    idx_t = np.empty(m, np.intp)
    for r in range(m):
        s = todo[r]
        qq[r, 0] = q[s, 0]
        qq[r, 1] = q[s, 1]
        fam_t[r] = fam[s]
        idx_t[r] = np.int64(index[s])
    xy = np.empty((m, 2))
    inside = np.empty(m, np.bool_)
    _k_cam_xy(qq, tab, inv_step, K_cam, xy, inside)
    for r in range(m):
        if not inside[r]:
            return todo, np.empty((0, 3)), False
    p = np.empty((m, 3))
    if m:
        _k_light_sheets(xy, fam_t, idx_t, R, t, index_min, nodes, iterations, end_n, end_t, chord_n, chord_t, K_proj, dist,
                        centre, n_other, offsets, inv_dx, guess, p, np.empty(m))
    for r in range(m):
        xy_lab[todo[r], 0] = xy[r, 0]
        xy_lab[todo[r], 1] = xy[r, 1]
    return todo, p, True


@njit
def _k_fit_planes(cen, rad, q, xy, w, index, x0, y0, cell, gw, gh, start, items):
    """Per centre r: the least-squares plane w = c + a·u + b·v of the labelled samples in its neighbourhood
    (the cells `_k_support` sums; w = 1/z camera-frame depth, (u, v) = (x − xr, y − yr) normalised camera
    coordinates from the first such sample's (xr, yr)), in one pass: the normal equations and the sums that
    give the relative residual Σ((w − fit)/w)² = m − 2·Σfit/w + Σfit²/w² without a second pass. Returns coef
    (n, 5) = (a, b, c, xr, yr) (NaN where singular or fewer than 3 samples with a depth), the RMS relative
    residual, and near: the neighbour nearest the centre (sample id, −1: none)."""
    n = cen.shape[0]
    coef = np.full((n, 5), np.nan)
    rms = np.full(n, np.inf)
    near = np.full(n, -1, np.int64)
    for r in range(n):
        cx = cen[r, 0]
        cy = cen[r, 1]
        gx0, gx1, gy0, gy1 = _k_cell_box(cx, cy, rad[r], x0, y0, cell, gw, gh)
        m = 0
        dn = np.inf
        xr = yr = 0.0
        su = sv = suu = suv = svv = sw = suw = svw = 0.0
        i1 = iu = iv = j1 = ju = jv = juu = juv = jvv = 0.0  # Σ(1, u, v)/w and Σ(1, u, v, u², uv, v²)/w²
        for yy in range(gy0, gy1 + 1):
            for xx in range(gx0, gx1 + 1):
                b = yy * gw + xx
                for t in range(start[b], start[b + 1]):
                    s = items[t]
                    ws = w[s]
                    if not (math.isfinite(index[s]) and math.isfinite(ws)):
                        continue
                    d2 = (q[s, 0] - cx) ** 2 + (q[s, 1] - cy) ** 2
                    if d2 < dn:
                        dn = d2
                        near[r] = s
                    if m == 0:
                        xr = xy[s, 0]
                        yr = xy[s, 1]
                    m += 1
                    u = xy[s, 0] - xr
                    v = xy[s, 1] - yr
                    su += u
                    sv += v
                    suu += u * u
                    suv += u * v
                    svv += v * v
                    sw += ws
                    suw += u * ws
                    svw += v * ws
                    g = 1.0 / ws
                    i1 += g
                    iu += u * g
                    iv += v * g
                    g2 = g * g
                    j1 += g2
                    ju += u * g2
                    jv += v * g2
                    juu += u * u * g2
                    juv += u * v * g2
                    jvv += v * v * g2
        if m < 3:
            continue
        # [suu suv su; suv svv sv; su sv m] (a b c)ᵀ = (suw svw sw)ᵀ, centred: subtract the means
        fm = float(m)
        cuu = suu - su * su / fm
        cuv = suv - su * sv / fm
        cvv = svv - sv * sv / fm
        cuw = suw - su * sw / fm
        cvw = svw - sv * sw / fm
        det = cuu * cvv - cuv * cuv
        if not det > 0.0:
            continue
        a = (cuw * cvv - cvw * cuv) / det
        bb = (cvw * cuu - cuw * cuv) / det
        c = (sw - a * su - bb * sv) / fm
        coef[r, 0] = a
        coef[r, 1] = bb
        coef[r, 2] = c
        coef[r, 3] = xr
        coef[r, 4] = yr
        f_w = c * i1 + a * iu + bb * iv
        f2_w2 = c * c * j1 + a * a * juu + bb * bb * jvv + 2.0 * (c * a * ju + c * bb * jv + a * bb * juv)
        rms[r] = math.sqrt(max(fm - 2.0 * f_w + f2_w2, 0.0) / fm)
    return coef, rms, near


@njit
def _k_predict(coef, lens, xy, R, t):
    """The predicted points: sample r of fitted piece i (lens (m,) samples each, in order) meets the plane of
    coef[i] (`_k_fit_planes`) along its ray (normalised camera coordinates xy[r]): its camera-frame depth zp
    (NaN behind the camera) and projector-frame point p (N, 3) (the origin where none)."""
    N = xy.shape[0]
    zp = np.full(N, np.nan)
    p = np.zeros((N, 3))
    r = 0
    for i in range(lens.shape[0]):
        a, b, c, xr, yr = coef[i, 0], coef[i, 1], coef[i, 2], coef[i, 3], coef[i, 4]
        for _ in range(lens[i]):
            x = xy[r, 0]
            y = xy[r, 1]
            wv = c + a * (x - xr) + b * (y - yr)
            if wv > 0.0:
                z = 1.0 / wv
                zp[r] = z
                for d in range(3):
                    p[r, d] = R[d, 0] * x * z + R[d, 1] * y * z + R[d, 2] * z + t[d]
            r += 1
    return zp, p


@njit
def _k_piece_index(lens, kk, dist, fam_s, spacing, max_pred_lines):
    """Per fitted piece (lens (m,) samples each, in order): the line k its samples' predicted points are
    nearest to (kk, dist (N,) projector px from `project_nearest_line`), and whether every sample names the
    same k within max_pred_lines line spacings (spacing (2,) projector px per family; fam_s (N,) 1/2); the
    middle sample's position."""
    m = lens.shape[0]
    k = np.zeros(m, np.int64)
    ok = np.zeros(m, np.bool_)
    mid = np.zeros(m, np.intp)
    r = 0
    for i in range(m):
        k[i] = kk[r]
        good = True
        for j in range(r, r + lens[i]):
            if kk[j] != k[i] or not dist[j] / spacing[fam_s[j] - 1] <= max_pred_lines:
                good = False
        ok[i] = good
        mid[i] = r + lens[i] // 2
        r += lens[i]
    return k, ok, mid


@njit
def _k_accept(lens, ok, zp, zs, z1, mid, rms, length, step_px, max_fit_lines, max_pred_lines, z_lo, z_hi, ts_s, trim_px):
    """Per fitted piece whose prediction named one line (ok): the fit against the depth step between sheets k
    and k + 1 on the middle ray (rms ≤ max_fit_lines·|z1 − z0|/z0, z0 = zs[mid]), the prediction's drift along
    the piece in sheet steps (range of (zp − zs)/step ≤ max_pred_lines per junction step step_px of the
    piece's length), every sample's depth zs on sheet k inside [z_lo, z_hi]. Returns the accepted pieces
    (bool (m,)) and the samples to write (bool (N,): of accepted pieces, at least trim_px from the piece's
    ends along ts_s)."""
    m = lens.shape[0]
    acc = np.zeros(m, np.bool_)
    write = np.zeros(zs.shape[0], np.bool_)
    r = 0
    for i in range(m):
        n = lens[i]
        if ok[i]:
            z0 = zs[mid[i]]
            step = abs(z1[i] - z0)
            good = rms[i] <= max_fit_lines * step / z0
            lo = np.inf
            hi = -np.inf
            for j in range(r, r + n):
                if not (zs[j] >= z_lo and zs[j] <= z_hi):
                    good = False
                if math.isfinite(zp[j]):
                    o = (zp[j] - zs[j]) / max(step, 1e-9)
                    lo = min(lo, o)
                    hi = max(hi, o)
            if hi >= lo and (hi - lo) * (step_px / length[i]) > max_pred_lines:
                good = False
            if good:
                acc[i] = True
                t0 = ts_s[r]
                t1 = ts_s[r + n - 1]
                for j in range(r, r + n):
                    if min(ts_s[j] - t0, t1 - ts_s[j]) >= trim_px:
                        write[j] = True
        r += n
    return acc, write


@njit
def _k_predict_sheets(fr, cand, count, first, last, sid, q, fam, ts, coef, rms, spacing, max_pred_lines, tab, inv_step, K_cam, R,
                      t, index_min, nodes, iterations, end_n, end_t, chord_n, chord_t, K_proj, dist, centre, n_other, offsets,
                      inv_dx, guess, K_nl, dist_nl, distorted, cu, cv, n12, offs, hyp, indices):
    """Steps 3–5 of a round for the fitted pieces cand[fr] up to the sheet points (decision 0094), the same
    operations as the NumPy path of `label_from_surface`: their samples (trace positions pos, ids s_all),
    normalised camera coordinates (`_k_cam_xy`), `_k_predict`, the nearest line of their family
    (`_label_kernels.project_nearest_line`), `_k_piece_index`, and the points out (N + m, 3) of the samples on
    sheet k and of the middle samples on k + 1 (`RigModel.intersect_light_sheets`' kernel). Returns (lens, pos,
    s_all, k, ok, mid, zp, out, rms, length, ts_s, True) with `_k_accept`'s per-piece inputs, or False last
    when a sample lies outside the camera table (the caller takes the NumPy path)."""
    m = fr.shape[0]
    lens = np.empty(m, np.int64)
    N = 0
    for i in range(m):
        lens[i] = count[cand[fr[i]]]
        N += lens[i]
    pos = np.empty(N, np.int64)
    s_all = np.empty(N, np.int64)
    qq = np.empty((N, 2))
    f_s = np.empty(N, np.int64)
    r = 0
    for i in range(m):
        f0 = first[cand[fr[i]]]
        for j in range(lens[i]):
            pos[r] = f0 + j
            s = sid[f0 + j]
            s_all[r] = s
            qq[r, 0] = q[s, 0]
            qq[r, 1] = q[s, 1]
            f_s[r] = fam[s]
            r += 1
    xy = np.empty((N, 2))
    inside = np.empty(N, np.bool_)
    _k_cam_xy(qq, tab, inv_step, K_cam, xy, inside)
    rr = np.empty(m)
    length = np.empty(m)
    ts_s = np.empty(N)
    for n in range(N):
        if not inside[n]:
            e = np.zeros(0, np.int64)
            return lens, pos, s_all, e, np.zeros(0, np.bool_), np.zeros(0, np.intp), np.empty(0), np.empty((0, 3)), rr, length, ts_s, False
    cf = np.empty((m, 5))
    for i in range(m):
        for c in range(5):
            cf[i, c] = coef[fr[i], c]
        rr[i] = rms[fr[i]]
        pc = cand[fr[i]]
        length[i] = max(ts[last[pc]] - ts[first[pc]], 1.0)
    zp, p_pred = _k_predict(cf, lens, xy, R, t)
    kk, dd = _k_project_nearest_line(p_pred, f_s, K_nl, dist_nl, distorted, cu, cv, n12, offs, hyp, indices)
    k, ok, mid = _k_piece_index(lens, kk, dd, f_s, spacing, max_pred_lines)
    # the samples on sheet k and each piece's middle sample on sheet k + 1
    M = N + m
    xy2 = np.empty((M, 2))
    fam2 = np.empty(M, np.intp)
    idx2 = np.empty(M, np.intp)
    r = 0
    for i in range(m):
        for j in range(lens[i]):
            xy2[r, 0] = xy[r, 0]
            xy2[r, 1] = xy[r, 1]
            fam2[r] = f_s[r]
            idx2[r] = k[i]
            r += 1
    for i in range(m):
        xy2[N + i, 0] = xy[mid[i], 0]
        xy2[N + i, 1] = xy[mid[i], 1]
        fam2[N + i] = f_s[mid[i]]
        idx2[N + i] = k[i] + 1
    out = np.empty((M, 3))
    if M:
        _k_light_sheets(xy2, fam2, idx2, R, t, index_min, nodes, iterations, end_n, end_t, chord_n, chord_t, K_proj, dist,
                        centre, n_other, offsets, inv_dx, guess, out, np.empty(M))
    for n in range(N):
        ts_s[n] = ts[pos[n]]
    return lens, pos, s_all, k, ok, mid, zp, out, rr, length, ts_s, True


@njit
def _k_predict_accept(fr, cand, count, first, last, sid, q, fam, ts, coef, rms, spacing, max_pred_lines, step_px, max_fit_lines,
                      z_lo, z_hi, trim_px, tab, inv_step, K_cam, R, t, index_min, nodes, iterations, end_n, end_t, chord_n,
                      chord_t, K_proj, dist, centre, n_other, offsets, inv_dx, guess, K_nl, dist_nl, distorted, cu, cv, n12,
                      offs, hyp, indices):
    """`_k_predict_sheets`, the depths z = R[:, 2]·(p − t) as `RigModel.sheet_depth`'s kernel path computes them
    (the camera-table rigs), and `_k_accept`, in one call. Returns (lens, pos, s_all, k, acc, write, True), or
    False last as `_k_predict_sheets`."""
    lens, pos, s_all, k, ok, mid, zp, out, rr, length, ts_s, good = _k_predict_sheets(
        fr, cand, count, first, last, sid, q, fam, ts, coef, rms, spacing, max_pred_lines, tab, inv_step, K_cam, R, t, index_min,
        nodes, iterations, end_n, end_t, chord_n, chord_t, K_proj, dist, centre, n_other, offsets, inv_dx, guess, K_nl, dist_nl,
        distorted, cu, cv, n12, offs, hyp, indices)
    if not good:
        return lens, pos, s_all, k, np.zeros(0, np.bool_), np.zeros(0, np.bool_), False
    N = s_all.shape[0]
    m = lens.shape[0]
    r02, r12, r22 = R[0, 2], R[1, 2], R[2, 2]
    t0, t1, t2 = t[0], t[1], t[2]
    zs = np.empty(N)
    z1 = np.empty(m)
    for n in range(N + m):
        z = (out[n, 0] - t0) * r02 + (out[n, 1] - t1) * r12 + (out[n, 2] - t2) * r22
        if n < N:
            zs[n] = z
        else:
            z1[n - N] = z
    acc, write = _k_accept(lens, ok, zp, zs, z1, mid, rr, length, step_px, max_fit_lines, max_pred_lines, z_lo, z_hi, ts_s, trim_px)
    return lens, pos, s_all, k, acc, write, True


@njit
def _k_write(lens, write, k, near, s_all, q, index, seed_jid, slot, sums, dirty, x0, y0, cell, gw, gh):
    """Writes the accepted samples (write (N,), in the order of s_all, lens (m,) per piece): index k of their
    piece, seed_jid of its nearest labelled neighbour near[i]; marks their grid cells in dirty (cleared first)
    and adds them to the per-cell sums (`_k_cell_sums`: slot, sums; a cell without a slot is never read).
    Returns the pieces written (bool (m,)) and the number of samples."""
    dirty[:] = False
    m = lens.shape[0]
    done = np.zeros(m, np.bool_)
    nw = 0
    r = 0
    for i in range(m):
        for j in range(r, r + lens[i]):
            if not write[j]:
                continue
            s = s_all[j]
            index[s] = k[i]
            seed_jid[s] = seed_jid[near[i]]
            x = q[s, 0]
            y = q[s, 1]
            gx = min(max(int(math.floor((x - x0) / cell)), 0), gw - 1)
            gy = min(max(int(math.floor((y - y0) / cell)), 0), gh - 1)
            b = gy * gw + gx
            dirty[b] = True
            sl = slot[b]
            if sl >= 0:
                sums[sl, 0] += 1.0
                sums[sl, 1] += x
                sums[sl, 2] += y
                sums[sl, 3] += x * x
                sums[sl, 4] += x * y
                sums[sl, 5] += y * y
            done[i] = True
            nw += 1
        r += lens[i]
    return done, nw


def label_from_surface(
    q: np.ndarray,
    fam: np.ndarray,
    sid: np.ndarray,
    piece: np.ndarray,
    ts: np.ndarray,
    index: np.ndarray,
    seed_jid: np.ndarray,
    *,
    model: RigModel,
    depth_range_mm: tuple[float, float],
    grid: tuple,
    fit_radius_px: float,
    trim_px: float = 0.0,
    min_samples: int = 4,
    rounds: int = 3,
    min_neighbours: int = 8,
    min_spread: float = 0.15,
    max_offset: float = 1.0,
    max_fit_lines: float = 0.1,
    max_pred_lines: float = 0.25,
    compiled: bool = True,
) -> dict:
    """Label unlabelled pieces that lie inside a labelled, locally plane surface which predicts their index
    (module doc).

    q (P, 2) camera px, fam (P,) 1/2 of all samples; the traces as `labelling.label_samples` builds them: sid
    (n,) sample ids by piece and position, piece (n,) non-decreasing piece ids, ts (n,) position along the
    piece (px). index (P,) float (NaN: unlabelled) and seed_jid (P,) int are written in place (seed_jid: that
    of the labelled neighbour nearest the piece's centre). grid: the frame's bucket grid of the valid samples
    (`labelling._sample_grid`, any cell size; its first seven entries are read). fit_radius_px: the
    neighbourhood's reach beyond the piece's half extent (camera px, about one junction step). max_offset:
    standard deviations (the square root of the Mahalanobis form). Returns counts: pieces and samples
    labelled, pieces tried (summed over the rounds), pieces with a plane fit and with a prediction. compiled False:
    the NumPy path for the neighbours' depths and the prediction even where the compiled calls apply
    (`_k_needed_points`, `_k_predict_accept`, `_k_predict_sheets`: decision 0094), the reference they reproduce
    bit for bit (tested)."""
    stats = {"pieces": 0, "samples": 0, "tried": 0, "fitted": 0, "predicted": 0}
    n = len(piece)
    if n == 0:
        return stats
    n_p = int(piece[-1]) + 1
    first, last, cand_all, cen_all, ext_all = _k_open_pieces(sid, piece, index, q, n_p, int(min_samples))
    if len(cand_all) == 0:
        return stats
    z_lo, z_hi = float(depth_range_mm[0]), float(depth_range_mm[1])
    # each family's smallest line spacing, perpendicular to its lines (projector px)
    spacing = model.line_spacing_perp_px
    R = model.procam.R_proj_cam
    t = model.procam.t_proj_cam
    w_lab = np.full(len(q), np.nan)  # 1/z of the labelled samples, computed once per sample
    xy_lab = np.empty((len(q), 2))  # read only where w_lab is finite
    # the labelled samples' points in one compiled call where the model's kernels apply (as `RigModel.sheet_check`)
    # (a camera table, or a camera without distortion: the pinhole inverse; the projector's OpenCV 5-coefficient model)
    cam_tab = model.cam_xy_table
    pinhole = cam_tab is None and not model.procam.camera.has_distortion
    fast = compiled and (cam_tab is not None or pinhole) and model.procam.projector.dist.size <= 5
    if pinhole:
        cam_tab = np.zeros((0, 0, 2))
    inv_step = 1.0 / model.cam_table_px
    K_cam = np.ascontiguousarray(model.procam.camera.K, np.float64)
    fixed = model._sheet_check_args  # (built once per rig; its entry 6 is the projector's undistortion iterations)
    iters = fixed[6] if fixed is not None else (1 if model.procam.projector.has_distortion else 0)
    seen = np.zeros(len(q), np.bool_)  # samples whose depth was computed (or missed the sheet)
    count = last - first + 1
    rad_all = ext_all + float(fit_radius_px)
    open_c = np.ones(len(cand_all), bool)
    x0, y0, cell, gw, gh, start, items = grid[:7]
    dirty = np.ones(gw * gh, np.bool_)  # the cells where labels changed: all at first
    slot, sums = _k_cell_sums(q, index, cen_all, rad_all, x0, y0, cell, gw, gh, start, items)  # per cell, its labelled samples
    for _ in range(rounds):
        # 2. support on both sides (camera px only, before any depth is computed)
        n_open, sup = _k_supported(open_c, cen_all, rad_all, slot, sums, dirty, x0, y0, cell, gw, gh, int(min_neighbours),
                                   float(min_spread), float(max_offset * max_offset))
        if n_open == 0:
            break
        stats["tried"] += int(n_open)
        if len(sup) == 0:
            break
        cand, cen, rad = cand_all[sup], cen_all[sup], rad_all[sup]
        # 1. the local surface, from the depths of the labelled samples around (each computed once)
        if fast:
            todo, p_t, inside = _k_needed_points(cen, rad, index, w_lab, seen, *grid[:7], q, fam, xy_lab, cam_tab, inv_step, K_cam,
                                                 R, t, model.index_min, model.sheet_nodes, iters, *model._sheet_kernel_tables)
        else:
            todo, p_t, inside = _k_needed(cen, rad, index, w_lab, seen, *grid[:7]), None, False
        if len(todo):
            if not inside:
                xy_t = model.cam_normalised(q[todo])
                p_t = model.intersect_light_sheets(xy_t, fam[todo], index[todo].astype(np.int64))
            z = (p_t - t) @ R[:, 2]  # camera-frame depth
            ok = z > 0  # (NaN where the ray misses the sheet)
            w_lab[todo[ok]] = 1.0 / z[ok]
            if not inside:
                xy_lab[todo[ok]] = xy_t[ok]
        coef, rms, near = _k_fit_planes(cen, rad, q, xy_lab, w_lab, index, *grid[:7])
        fr = np.flatnonzero(np.isfinite(coef[:, 0]))
        stats["fitted"] += len(fr)
        if len(fr) == 0:
            break
        # 4. the prediction at every sample of those pieces
        done_k = False
        if fast and not pinhole:
            lens, pos, s_all, k, acc, write, done_k = _k_predict_accept(
                fr, cand, count, first, last, sid, q, fam, ts, coef, rms, spacing, float(max_pred_lines),
                float(model.junction_step_cam_px), float(max_fit_lines), z_lo, z_hi, float(trim_px), cam_tab, inv_step, K_cam, R, t,
                model.index_min, model.sheet_nodes, iters, *model._sheet_kernel_tables, *model.nearest_line_tables)
        elif fast:
            # the pinhole camera: `sheet_check`'s NumPy path took these depths with `geometry.depth_cam`
            lens, pos, s_all, k, ok, mid, zp, out, rr, length, ts_s, done_k = _k_predict_sheets(
                fr, cand, count, first, last, sid, q, fam, ts, coef, rms, spacing, float(max_pred_lines), cam_tab, inv_step, K_cam,
                R, t, model.index_min, model.sheet_nodes, iters, *model._sheet_kernel_tables, *model.nearest_line_tables)
            zz = depth_cam(model.procam, out)
            acc, write = _k_accept(lens, ok, zp, zz[: len(s_all)], zz[len(s_all):], mid, rr, length, float(model.junction_step_cam_px),
                                   float(max_fit_lines), float(max_pred_lines), z_lo, z_hi, ts_s, float(trim_px))
        if not done_k:
            pc = cand[fr]
            lens = count[pc]
            pos = np.repeat(first[pc] - np.cumsum(lens) + lens, lens) + np.arange(lens.sum())
            s_all = sid[pos]
            q_s = q[s_all]
            xy_s = model.cam_normalised(q_s)
            zp, p_pred = _k_predict(coef[fr], lens, xy_s, R, t)
            f_s = fam[s_all].astype(np.int64)
            kk, dist = project_nearest_line(model, f_s, p_pred)
            k, ok, mid = _k_piece_index(lens, kk, dist, f_s, spacing, float(max_pred_lines))
            # 3. and 5. the samples on sheet k and each piece's middle sample on sheet k + 1 (one call): the fit
            # against the depth step, the drift along the piece, the working volume (the depths only: decision 0094)
            zz = model.sheet_depth(np.concatenate((q_s, q_s[mid])), np.concatenate((f_s, f_s[mid])),
                                   np.concatenate((np.repeat(k, lens), k + 1)), xy_cam=np.concatenate((xy_s, xy_s[mid])))
            acc, write = _k_accept(lens, ok, zp, zz[: len(s_all)], zz[len(s_all):], mid, rms[fr],
                                   np.maximum(ts[last[pc]] - ts[first[pc]], 1.0), float(model.junction_step_cam_px),
                                   float(max_fit_lines), float(max_pred_lines), z_lo, z_hi, ts[pos], float(trim_px))
        stats["predicted"] += int(acc.sum())
        done, nw = _k_write(lens, write, k, near[fr], s_all, q, index, seed_jid, slot, sums, dirty, x0, y0, cell, gw, gh)
        if nw == 0:
            break
        open_c[sup[fr[done]]] = False
        stats["pieces"] += int(done.sum())
        stats["samples"] += int(nw)
    return stats
