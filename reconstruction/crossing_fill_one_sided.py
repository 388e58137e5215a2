"""Points from a labelled line's end up to the crossing that ended it (decision 0099).

Decision 0086 (`crossing_fill.fill_crossings`) places points through a crossing's gap when the line is
labelled with the same index k on both sides of it. Where the line's labelled samples stop at a crossing
and nothing of index k continues beyond it (the line ends there at a silhouette, a shadow, a grazing face,
or continues on a piece nobody labelled), the half-gap between the last labelled sample and the crossing's
centre is still line k on the same surface, provided the crossing is real and on that surface. Beyond the
crossing nothing is added: what happens there is not known from this side.

`fill_one_sided` adds those points:

1. The labelled samples of each line (family f, index k; with 0086's points, so that its filled gaps are no
   ends) are ordered along the family's direction (as 0086). A run ends where the next labelled sample of
   the same line is farther than `min_gap_cells` sampling steps, or there is none; both ends of every run
   are looked at.
2. The `anchor` samples nearest the end (consecutive in the order, same line, each step at most the longest
   gap a crossing leaves) are fitted with a straight line; they must lie on it within `lateral_px` per
   sampling step (0086's fit test). The end is extrapolated along the fit.
3. The end must be at a crossing on that surface, within the reach of its gap: the crossing's centre lies
   ahead of the end by at most (mix_sigma + trim_sigma)·σ / sin θ + one step (θ the crossing angle; the
   mixing zone and trims of the label stage, `continuation.crossing_gap_px`'s half), θ at least
   `min_angle_deg`. The crossing is either a labelled junction with index k on this family on the
   extrapolated line (within `lateral_px`), or a straight run of the other family's samples crossing it,
   found in a disc ahead of the end and re-centred on the crossing, whose crossing point, triangulated on
   light sheet k, lies within `residual_px` projector px of a line of the other family inside the depth
   range (`RigModel.sheet_check`, the crossing check of decision 0052) — and, when the other run's samples
   carry a label m, that line must be m (the crossing then checked on both light sheets). An end at a
   silhouette or a shadow has no such crossing; a T where line k stops at an occluder's rim fails the check
   because the rim's line is not on sheet k's surface.
4. Points one sampling step apart (evenly, the last at the crossing's centre) on the extrapolated line; each
   is, like every line sample, the camera ray ∩ light sheet k (`pipeline._k_frame_points`).

The paper labeller's output is left alone (the pipeline calls this only for the default labeller).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from reconstruction._jit import njit
from reconstruction.continuation import crossing_gap_px
from reconstruction.crossing_fill import (CrossingPoints, FillShared, _family_directions, _fit_across, _k_grids, _k_order, _other_run,
                                          _run_axis, _sorted_by_key, appended, grid_cell_px, order_with_appended)
from reconstruction.rigmodel import UNLABELLED, RigModel


@dataclass(frozen=True)
class OneSidedFillOptions:
    """enabled: add the points. min_gap_cells: a run ends where the next labelled sample of its line is
    farther than this many sampling steps. anchor: samples fitted at the end. lateral_px: the anchors lie on
    their fit, and a labelled junction on the extrapolation, within this (camera px per sampling step).
    residual_px: the crossing, triangulated on the line's light sheet, lies this close to a line of the other
    family (projector px). mix_sigma, trim_sigma, min_angle_deg: the crossing's reach, as the label stage's
    TraceOptions and decision 0086. other_label: when the other run's samples are labelled m, the sheet
    check must name m.
    unlabelled_run: accept the other family's run when none of its samples is labelled (its crossing then
    checked on sheet k only). through: the other family's run must have samples on both sides of the line
    (it runs through the crossing: not the corner where two lines end). beyond: no end whose image line
    continues beyond the crossing (labelled samples of its family within beyond_sigma·σ of the extrapolation,
    up to one reach past the crossing) with another index (a depth edge at the crossing) or with its own
    (a gap decision 0086 looked at and did not fill; off: measured, such gaps' sides are filled).
    pull_sigma: the fit's anchors start this many σ inside the end (the crossing pulls the last samples
    towards the other line; decision 0089's trim)."""

    enabled: bool = True
    min_gap_cells: float = 1.6
    anchor: int = 4
    lateral_px: float = 0.5
    residual_px: float = 1.0
    mix_sigma: float = 2.0
    trim_sigma: float = 1.0
    min_angle_deg: float = 45.0
    other_label: bool = True
    unlabelled_run: bool = True
    through: bool = True
    beyond: bool = True
    beyond_sigma: float = 2.0
    beyond_spacing: float = 0.5
    beyond_same: bool = False
    pull_sigma: float = 1.0


_EMPTY_STATS = ("ends", "ends_filled", "samples_one_sided_filled")


def _empty(stats: dict) -> CrossingPoints:
    return CrossingPoints(np.zeros((0, 2)), np.zeros(0, np.intp), np.zeros(0), np.zeros(0, np.int64), stats)


def fill_one_sided(
    q: np.ndarray,
    family: np.ndarray,
    index: np.ndarray,
    junction: np.ndarray,
    *,
    q_samples: np.ndarray,
    family_samples: np.ndarray,
    index_samples: np.ndarray,
    q_junction: np.ndarray,
    junction_labels: np.ndarray,
    model: RigModel,
    sigma_px: float,
    cell_px: float,
    depth_range_mm: tuple[float, float],
    options: OneSidedFillOptions = OneSidedFillOptions(),
    shared: FillShared | None = None,
) -> CrossingPoints:
    """Points from labelled lines' ends up to the crossing that ends them (module doc).

    q (P, 2), family (P,), index (P,) (NaN: unlabelled), junction (P,): the labelled samples (the label
    stage's, with decision 0086's points appended). q_samples (S, 2), family_samples (S,), index_samples
    (S,): every extracted sample and its label (NaN: none) (the other family's run at the crossing).
    q_junction (M, 2), junction_labels (M, 2) (UNLABELLED where none). sigma_px: the extraction's smoothing;
    cell_px: its sampling step. Camera px throughout. Returns the added samples (`CrossingPoints`, junction:
    that of the end sample); stats: ends looked at, filled, rejected by reason, samples added.
    shared: `fill_crossings`' work on this frame (`CrossingPoints.shared`; `with_one_sided` passes it when
    the inputs are the same objects): then q[:shared.n], family, index and q_samples, family_samples,
    q_junction, junction_labels must be those it was computed from, and when shared.order_all is given,
    q[shared.n:], family and index those of shared.points (`with_one_sided` sees to both). Its order is extended
    by the appended samples (shared.order_all, else `order_with_appended`) and its grids reused when the cell is
    equal; the outputs are those without it, bit for bit."""
    stats: dict = {"ends": 0, "ends_filled": 0, "samples_one_sided_filled": 0, "ends_rejected": {}}
    if not options.enabled:
        return _empty(stats)
    q = np.ascontiguousarray(q, np.float64).reshape(-1, 2)
    fam = np.ascontiguousarray(np.asarray(family).reshape(-1), np.intp)
    idx = np.ascontiguousarray(index, np.float64).reshape(-1)
    d1, d2 = _family_directions(model)
    if shared is not None and shared.n == len(q):
        order = shared.order  # nothing appended: the same arrays, the same order
    elif shared is not None and shared.order_all is not None and shared.n + len(shared.points[0]) == len(q):
        order = shared.order_all  # `fill_crossings`' own points appended: put in at their gaps (decision 0149)
    elif shared is not None and shared.n < len(q):
        order = order_with_appended(shared, q, fam, idx, d1, d2)
    else:
        sel, key = _k_order(q, fam, idx, d1, d2)
        order = _sorted_by_key(sel, key)
    if len(order) < options.anchor + 1:
        return _empty(stats)
    lab = np.ascontiguousarray(junction_labels, np.int64).reshape(-1, 2)
    qj = np.ascontiguousarray(q_junction, np.float64).reshape(-1, 2)
    gap_max = cell_px + crossing_gap_px(sigma_px, mix_sigma=options.mix_sigma, trim_sigma=options.trim_sigma,
                                        min_angle_deg=options.min_angle_deg)
    gcell = grid_cell_px(gap_max, sigma_px, cell_px)
    qs = np.ascontiguousarray(q_samples, np.float64).reshape(-1, 2)
    ks = np.ascontiguousarray(index_samples, np.float64).reshape(-1)
    if shared is not None and shared.grids is not None and shared.gcell == gcell:
        grids = shared.grids
    else:
        fs = np.ascontiguousarray(np.asarray(family_samples).reshape(-1), np.intp)
        grids = _k_grids(qj, lab, qs, fs, float(gcell))
    n_ends, ends, acc, c_q, m_other, why, why_run = _k_ends(
        q, fam, idx, order, qj, lab, qs, ks, *grids, float(gcell), float(cell_px), float(sigma_px),
        float(options.min_gap_cells * cell_px), float(gap_max), float((options.mix_sigma + options.trim_sigma) * sigma_px),
        int(options.anchor), float(math.sin(math.radians(options.min_angle_deg))), float(options.lateral_px * cell_px),
        bool(options.through), bool(options.beyond),
        float(max(options.beyond_sigma * sigma_px, options.beyond_spacing * model.junction_step_cam_px * math.sin(math.radians(options.min_angle_deg)))),
        bool(options.beyond_same), float(options.pull_sigma * sigma_px))
    stats["ends"] = int(n_ends)
    stats["ends_rejected"] = {"anchors": int(why[0]), "anchors_crooked": int(why[1]), "no_run": int(why[2]),
                              "beyond_reach": int(why[3]), "other_labels_disagree": int(why[4]),
                              "line_continues": int(why[5]), "sheet_check": 0}
    # the "no_run" ends by the disc test that failed: first disc (over the reach), then the re-centred one
    stats["no_run"] = {"few": int(why_run[0]), "not_straight": int(why_run[1]), "parallel": int(why_run[2]), "one_side": int(why_run[3]),
                       "centred_few": int(why_run[4]), "centred_not_straight": int(why_run[5]), "centred_parallel": int(why_run[6]),
                       "centred_one_side": int(why_run[7])}
    E = len(acc)
    stats["ends_at_junctions"] = int(acc.sum())
    if E == 0:
        return _empty(stats)
    chk = np.flatnonzero(~acc & np.isfinite(c_q[:, 0]))
    if len(chk):
        a_chk = ends[chk, 0].astype(np.intp)
        _p, z, k_other, dist = model.sheet_check(c_q[chk], fam[a_chk], idx[a_chk].astype(np.intp))
        ok = (dist <= options.residual_px) & (z >= depth_range_mm[0]) & (z <= depth_range_mm[1])
        m = m_other[chk]
        if not options.unlabelled_run:
            ok &= m != UNLABELLED
        if options.other_label:
            # the junction (k, m): the camera ray meets sheet k within residual_px of line m (the labelled
            # junctions' epipolar test, along line k)
            ok &= (m == UNLABELLED) | (k_other == m)
        acc[chk] = ok
        stats["ends_rejected"]["sheet_check"] = int(len(chk) - ok.sum())
    g = np.flatnonzero(acc)
    stats["ends_filled"] = int(len(g))
    if len(g) == 0:
        return _empty(stats)
    q_new, f_new, k_new, j_new = _k_points(fam, idx, np.ascontiguousarray(junction, np.int64).reshape(-1), ends, acc, float(cell_px))
    stats["samples_one_sided_filled"] = int(len(q_new))
    return CrossingPoints(q_new, f_new, k_new, j_new, stats)


@njit
def _k_points(fam, idx, junction, ends, acc, cell):
    """Step 4: per accepted end [sample, ox, oy, ux, uy, s_c], points at s = i·s_c/n, i = 1..n, n =
    max(round(s_c / cell), 1), on o + s·u."""
    E = ends.shape[0]
    total = 0
    for e in range(E):
        if acc[e]:
            total += max(int(round(ends[e, 5] / cell)), 1)
    q_new = np.empty((total, 2))
    f_new = np.empty(total, np.intp)
    k_new = np.empty(total)
    j_new = np.empty(total, np.int64)
    o = 0
    for e in range(E):
        if not acc[e]:
            continue
        a = int(ends[e, 0])
        sc = ends[e, 5]
        n = max(int(round(sc / cell)), 1)
        for i in range(1, n + 1):
            s = i * sc / n
            q_new[o, 0] = ends[e, 1] + s * ends[e, 3]
            q_new[o, 1] = ends[e, 2] + s * ends[e, 4]
            f_new[o] = fam[a]
            k_new[o] = idx[a]
            j_new[o] = junction[a]
            o += 1
    return q_new, f_new, k_new, j_new


@njit
def _run_crossing(ox, oy, ux, uy, mx, my, rad, f, qs, ks, x0, y0, gcell, gw, gh, start, mid, items, hits, lateral, through):
    """The other family's samples within rad of (mx, my): when at least 4 and one straight run (minor spread
    ≤ lateral), where its major axis crosses the line o + s·u: (s, sin θ, m) with m the run's label (the one
    index its labelled samples carry; UNLABELLED when none is labelled, −2**62 when they disagree); s NaN
    when there is no such run, and then the second value says why: 0 fewer than 4 samples, 1 not one
    straight run, 2 parallel to the line, 3 not on both sides of the line."""
    cnt, cxm, cym, cxx, cxy, cyy = _other_run(mx, my, rad, f, qs, x0, y0, gcell, gw, gh, start, mid, items, hits)
    if cnt < 4:
        return np.nan, 0.0, UNLABELLED_K
    lam_min, nx, ny = _run_axis(cxx, cxy, cyy)
    if lam_min > lateral * lateral:
        return np.nan, 1.0, UNLABELLED_K
    den = ux * nx + uy * ny  # sin θ up to sign
    if abs(den) < 1e-6:
        return np.nan, 2.0, UNLABELLED_K
    s = ((cxm - ox) * nx + (cym - oy) * ny) / den
    # the other line runs through the crossing: samples on both sides of the line o + s·u
    neg = 0
    pos = 0
    for h in range(cnt):
        i = hits[h]
        side = -(qs[i, 0] - ox) * uy + (qs[i, 1] - oy) * ux
        if side < 0.0:
            neg += 1
        else:
            pos += 1
    if through and (neg < 2 or pos < 2):
        return np.nan, 3.0, UNLABELLED_K
    m = UNLABELLED_K
    for h in range(cnt):
        k = ks[hits[h]]
        if np.isfinite(k):
            if m == UNLABELLED_K:
                m = int(k)
            elif m != int(k):
                m = CONFLICT_K
    return s, abs(den), m


UNLABELLED_K = UNLABELLED
CONFLICT_K = -(2 ** 62)


@njit
def _beyond(ox, oy, ux, uy, s_c, reach, width, f, k, qs, ks, x0, y0, gcell, gw, gh, start, mid, items, same):
    """The labelled samples (qs, labels ks, NaN: none; on `_family_grid`'s grid) of family f ahead of the crossing (s_c < s ≤ s_c + reach along o + s·u, within
    `width` of the line across it): 0 none, 1 some of another index than k (the image's line continues
    beyond the crossing with another index: a depth edge there), 2 only of index k (a gap decision 0086
    did not fill)."""
    mx = ox + (s_c + 0.5 * reach) * ux
    my = oy + (s_c + 0.5 * reach) * uy
    gx = int((mx - x0) / gcell)
    gy = int((my - y0) / gcell)
    # of the 3×3 cells around (mx, my)'s, only those the region's bounding box reaches (widened by 1e-6 px against
    # rounding; a cell index clamped as the grid clamps its samples'): the result does not depend on the order the
    # samples are read in, and no sample outside that box passes the test (decision 0149)
    xa = ox + s_c * ux
    xb = ox + (s_c + reach) * ux
    ya = oy + s_c * uy
    yb = oy + (s_c + reach) * uy
    wx = width * abs(uy) + 1e-6
    wy = width * abs(ux) + 1e-6
    cx_lo = max(gx - 1, min(max(int(math.floor((min(xa, xb) - wx - x0) / gcell)), 0), gw - 1))
    cx_hi = min(gx + 1, max(min(int(math.floor((max(xa, xb) + wx - x0) / gcell)), gw - 1), 0))
    cy_lo = max(gy - 1, min(max(int(math.floor((min(ya, yb) - wy - y0) / gcell)), 0), gh - 1))
    cy_hi = min(gy + 1, max(min(int(math.floor((max(ya, yb) + wy - y0) / gcell)), gh - 1), 0))
    out = 0
    for cy in range(cy_lo, cy_hi + 1):
        for cx in range(cx_lo, cx_hi + 1):
            c = cy * gw + cx
            t0 = start[c] if f == 1 else mid[c]
            t1 = mid[c] if f == 1 else start[c + 1]
            for t in range(t0, t1):
                i = items[t]
                if not np.isfinite(ks[i]):
                    continue
                ex = qs[i, 0] - ox
                ey = qs[i, 1] - oy
                s = ex * ux + ey * uy
                if s <= s_c or s > s_c + reach or abs(-ex * uy + ey * ux) > width:
                    continue
                if ks[i] != k:
                    return 1
                out = 2
    return out if same else 0


@njit
def _k_run_breaks(q, fam, idx, order, min_gap):
    """(n + 1,) bool: brk[p] where the runs of `order` break between its samples p − 1 and p (another line, or
    farther apart than min_gap), both ends of the order included. Also the border fill's (decision 0104)."""
    n = order.shape[0]
    brk = np.empty(n + 1, np.bool_)
    brk[0] = True
    brk[n] = True
    for p in range(1, n):
        a = order[p - 1]
        b = order[p]
        dx = q[b, 0] - q[a, 0]
        dy = q[b, 1] - q[a, 1]
        brk[p] = fam[b] != fam[a] or idx[b] != idx[a] or dx * dx + dy * dy > min_gap * min_gap
    return brk


@njit
def _k_ends(q, fam, idx, order, qj, lab, qs, ks, jx0, jy0, jgw, jgh, jstart, jitems, sx0, sy0, sgw, sgh, sstart, smid, sitems, gcell,
            cell, sigma, min_gap, gap_max, half_gap, anchor, sin_min, lateral, through, check_beyond, width, beyond_same, pull):
    """Steps 1–3 of the module doc. Returns the number of ends looked at, per end that passed the fit (E, 6)
    [end sample, ox, oy, ux, uy, s_c] (o the fit's point at the end sample, u the outward unit direction,
    s_c the crossing's centre along it), accepted (E,) (a labelled junction of this line ends it), c_q (E,
    2): the other family's crossing to check on light sheet k (NaN where none), m (E,): the other run's
    label (UNLABELLED: none), and the counts of ends rejected (5,): anchors missing or not one run, anchors
    off their line, no crossing run ahead, crossing beyond reach or too acute, the run's labels disagree, the
    line continues beyond with another index; and (8,) the no-run ends by `_run_crossing`'s reason, first
    disc (0–3) and re-centred disc (4–7). The labelled junctions' grid (jx0 … jitems) and the samples'
    (sx0 … sitems): `crossing_fill._k_grids` on cell gcell."""
    n = order.shape[0]
    # 1. the breaks between consecutive samples of the order (another line, or farther than min_gap)
    brk = _k_run_breaks(q, fam, idx, order, min_gap)
    # every end is a sample with a break on that side: 2·Σbrk − 2 of them (brk[0] and brk[n] serve one side
    # each), the rows' capacity (2·n before: ~1.7 MB filled per pitch 16 frame for a few hundred ends)
    cap = 0
    for p in range(n + 1):
        cap += brk[p]
    cap = max(2 * cap - 2, 0)
    ends = np.empty((cap, 6))
    acc = np.zeros(cap, np.bool_)
    c_q = np.full((cap, 2), np.nan)
    m_out = np.full(cap, UNLABELLED_K, np.int64)
    why = np.zeros(6, np.int64)
    why_run = np.zeros(8, np.int64)  # no run: the first disc's reason (0–3), the re-centred disc's (4–7)
    E = 0
    n_ends = 0
    hits = np.empty(sitems.shape[0], np.intp)
    fit_x = np.empty(anchor)
    fit_y = np.empty(anchor)
    for p in range(n):
        if not (brk[p] or brk[p + 1]):
            continue
        a = order[p]
        for side in range(2):
            step = 1 if side == 0 else -1  # 0: forward end (next sample beyond), 1: backward end
            if not brk[p + 1 - side]:
                continue  # not an end on this side
            nb = p + step
            n_ends += 1
            # 2. the anchors: `anchor` samples inward from the end, one run of this line, from the first one at
            # least `pull` from the end sample on (beyond the crossing's pull on the last samples)
            ok = True
            p1 = p
            while True:
                s0 = order[p1]
                ex = q[s0, 0] - q[a, 0]
                ey = q[s0, 1] - q[a, 1]
                if ex * ex + ey * ey >= pull * pull:
                    break
                nxt = p1 - step
                if nxt < 0 or nxt >= n:
                    ok = False
                    break
                s1 = order[nxt]
                if fam[s1] != fam[a] or idx[s1] != idx[a]:
                    ok = False
                    break
                fx = q[s1, 0] - q[s0, 0]
                fy = q[s1, 1] - q[s0, 1]
                if fx * fx + fy * fy > gap_max * gap_max:
                    ok = False
                    break
                p1 = nxt
            last = p1 - step * (anchor - 1)
            if not ok or last < 0 or last >= n:
                why[0] += 1
                continue
            for k in range(anchor - 1):
                s0 = order[p1 - step * k]
                s1 = order[p1 - step * (k + 1)]
                if fam[s1] != fam[a] or idx[s1] != idx[a]:
                    ok = False
                    break
                ex = q[s1, 0] - q[s0, 0]
                ey = q[s1, 1] - q[s0, 1]
                if ex * ex + ey * ey > gap_max * gap_max:
                    ok = False
                    break
            if not ok:
                why[0] += 1
                continue
            ai = order[last]
            ux0 = q[order[p1], 0] - q[ai, 0]
            uy0 = q[order[p1], 1] - q[ai, 1]
            l0 = math.sqrt(ux0 * ux0 + uy0 * uy0)
            if not l0 > 0.0:
                why[1] += 1
                continue
            ux0 /= l0
            uy0 /= l0
            for k in range(anchor):
                sid = order[p1 - step * k]
                fit_x[k] = q[sid, 0] - q[a, 0]
                fit_y[k] = q[sid, 1] - q[a, 1]
            kk, cc, status = _fit_across(fit_x, fit_y, anchor, ux0, uy0, lateral)  # step 11's fit
            if status != 0:
                why[1] += 1
                continue
            # the fitted line: o (at the end sample) + s·u, u outward
            nx0 = -uy0
            ny0 = ux0
            ox = q[a, 0] + cc * nx0
            oy = q[a, 1] + cc * ny0
            un = math.sqrt(1.0 + kk * kk)
            ux = (ux0 + kk * nx0) / un
            uy = (uy0 + kk * ny0) / un
            f = fam[a]
            kidx = int(idx[a])
            half_max = half_gap / sin_min + cell
            # the next labelled sample of this line ahead (if any) bounds the crossing
            s_next = np.inf
            if nb >= 0 and nb < n:
                b = order[nb]
                if fam[b] == fam[a] and idx[b] == idx[a]:
                    s_next = (q[b, 0] - ox) * ux + (q[b, 1] - oy) * uy
            # 3a. a labelled junction of this line ahead, on the extrapolation, within its reach
            gx = int((ox + 0.5 * half_max * ux - jx0) / gcell)
            gy = int((oy + 0.5 * half_max * uy - jy0) / gcell)
            best = np.inf
            for cy in range(max(gy - 1, 0), min(gy + 2, jgh)):
                for cx in range(max(gx - 1, 0), min(gx + 2, jgw)):
                    c = cy * jgw + cx
                    for t in range(jstart[c], jstart[c + 1]):
                        j = jitems[t]
                        if lab[j, f - 1] != kidx:
                            continue
                        ex = qj[j, 0] - ox
                        ey = qj[j, 1] - oy
                        s = ex * ux + ey * uy
                        if abs(-ex * uy + ey * ux) > lateral:
                            continue
                        if s > 0.0 and s <= half_max and s < best:
                            best = s
            if best < np.inf:
                bz = _beyond(ox, oy, ux, uy, best, half_max, width, f, kidx, qs, ks, sx0, sy0, gcell, sgw, sgh, sstart, smid, sitems, beyond_same) if check_beyond else 0
                if bz != 0:
                    why[5] += 1
                elif best < s_next:
                    ends[E, 0] = a
                    ends[E, 1] = ox
                    ends[E, 2] = oy
                    ends[E, 3] = ux
                    ends[E, 4] = uy
                    ends[E, 5] = best
                    acc[E] = True
                    E += 1
                else:
                    why[3] += 1
                continue
            # 3b. the other family's straight run ahead: a disc over the reach, then re-centred on the crossing
            r1 = 0.5 * half_max + sigma
            s, sin_t, m = _run_crossing(ox, oy, ux, uy, ox + 0.5 * half_max * ux, oy + 0.5 * half_max * uy, r1, f, qs, ks,
                                        sx0, sy0, gcell, sgw, sgh, sstart, smid, sitems, hits, lateral, through)
            if not np.isfinite(s):
                why[2] += 1
                why_run[int(sin_t)] += 1
                continue
            r2 = half_gap + sigma
            if s > 0.0 and s <= half_max:
                s, sin_t, m = _run_crossing(ox, oy, ux, uy, ox + s * ux, oy + s * uy, r2, f, qs, ks,
                                            sx0, sy0, gcell, sgw, sgh, sstart, smid, sitems, hits, lateral, through)
                if not np.isfinite(s):
                    why[2] += 1
                    why_run[4 + int(sin_t)] += 1
                    continue
            if not (s > 0.0 and sin_t >= sin_min and s <= half_gap / sin_t + cell and s < s_next):
                why[3] += 1
                continue
            if m == CONFLICT_K:
                why[4] += 1
                continue
            if check_beyond and _beyond(ox, oy, ux, uy, s, half_max, width, f, kidx, qs, ks, sx0, sy0, gcell, sgw, sgh, sstart, smid, sitems, beyond_same) != 0:
                why[5] += 1
                continue
            ends[E, 0] = a
            ends[E, 1] = ox
            ends[E, 2] = oy
            ends[E, 3] = ux
            ends[E, 4] = uy
            ends[E, 5] = s
            c_q[E, 0] = ox + s * ux
            c_q[E, 1] = oy + s * uy
            m_out[E] = m
            E += 1
    return n_ends, ends[:E], acc[:E], c_q[:E], m_out[:E], why, why_run


def with_one_sided(
    cp: CrossingPoints | None,
    q: np.ndarray,
    family: np.ndarray,
    index: np.ndarray,
    junction: np.ndarray,
    **kwargs,
) -> CrossingPoints:
    """Decision 0086's points `cp` (None: none) followed by `fill_one_sided`'s, computed over the label
    stage's samples (q, family, index, junction: `SampleLabels.q`, the observation's family, `.index`,
    `.junction`) with `cp`'s appended; stats: cp's, with "samples_one_sided_filled" and "one_sided" (the
    call's own counts). kwargs: `fill_one_sided`'s keywords except index_samples (the label stage's index)
    and shared: `cp.shared` (the order and grids `fill_crossings` built) is passed on when the arrays here
    are the very objects it was computed from; the result keeps `cp.shared` (for the border fill's boxes,
    decision 0149)."""
    fam = np.asarray(family).reshape(-1)
    sh = cp.shared if cp is not None else None
    same = (q, family, index, kwargs.get("q_samples"), kwargs.get("family_samples"), kwargs.get("q_junction"),
            kwargs.get("junction_labels"))
    if sh is not None and not all(a is b for a, b in zip(sh.inputs, same)):
        sh = None  # computed from other arrays: not reused
    if sh is not None and sh.order_all is not None and not all(a is b for a, b in zip(sh.points, (cp.q, cp.family, cp.index))):
        sh = replace(sh, order_all=None)  # other points than `fill_crossings`' own: their order is not known
    if cp is not None and len(cp.index):
        q_all = np.concatenate([np.asarray(q, np.float64).reshape(-1, 2), cp.q])
        f0 = sh.fam if sh is not None and sh.fam is not None else fam.astype(np.intp)  # the same values (decision 0149)
        f_all = np.concatenate([f0, cp.family.astype(np.intp, copy=False)])
        k_all = np.concatenate([np.asarray(index, np.float64), cp.index])
        j_all = np.concatenate([np.asarray(junction, np.int64), cp.junction])
    else:
        q_all, f_all, k_all, j_all = q, (sh.fam if sh is not None and sh.fam is not None else fam), index, junction
    op = fill_one_sided(q_all, f_all, k_all, j_all, index_samples=index, shared=sh, **kwargs)
    return appended(cp, op, "samples_one_sided_filled", "one_sided", cp.shared if cp is not None else None)
