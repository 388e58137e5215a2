"""Points from a labelled line's end up to the image border (decision 0104).

On the paper presets (758×570, σ ≈ 5 px, extraction on the half-resolution path) the image holds a line
up to the border, but the smoothing's reflected border (cv2.BORDER_REFLECT) mirrors an oblique line into a
V, so within ~1–2 σ of the border the ridge is biased or rejected and the labelled runs stop short of it.
`fill_border` continues such a run straight to the border when the image says the line goes on:

1. The labelled samples of each line (family f, index k; the label stage's with the crossing fills' points,
   decisions 0086/0099, so that their filled gaps are no ends) are ordered along the family's direction
   (`crossing_fill`'s order). A run ends where the next labelled sample of its line is farther than
   `min_gap_cells` sampling steps, or there is none.
2. From the end inward, the samples nearer the border than `pull_sigma`·σ (the reflected border's pull)
   are skipped; the next `anchor` samples of the run are fitted with a straight line and must lie on it
   within `lateral_px` per sampling step (decision 0086's fit test).
3. The fit, from the end sample's foot on it outward, must leave the image box of pixel centres
   [0, W − 1] × [0, H − 1] (0.5 px inside the image's edge) within `reach_sigma`·σ + one sampling step of
   the outermost anchor: the extrapolation is never longer than the border band.
4. Evidence that the line goes on to the border, at every new point (one sampling step apart, evenly, the
   last on the box): the 3×3 box-filtered image across the line is a ridge (`labelling.profile_drop`'s
   test, decision 0050: drop ≤ `max_profile_drop`, the probes that leave the image left out) whose
   contrast is at least `contrast_frac` of the anchors' own; no labelled sample of the family lies ahead
   on the extension (the image's line continues there with another label: a depth edge; or with its own: a
   gap, the crossing fills' business); no extracted sample of the other family (labelled or not) within
   `other_width` line widths of the stretch from the outer anchor to the border (a crossing there is the
   crossing fills' business, and a line next to the anchors pulls the fit); on light sheet k every new
   point lies inside the depth range, and every new point and anchor farther than `cross_sigma`·σ + half a
   line width (camera px) from every line of the other family (no predicted crossing there,
   `RigModel.sheet_check`). One failing test rejects the whole end.
5. Each new point is, like every line sample, the camera ray ∩ light sheet k (`pipeline._k_frame_points`).

The paper labeller's output is left alone (the pipeline calls this only for the default labeller).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from reconstruction._jit import njit
from reconstruction.crossing_fill import CrossingPoints, _family_directions, _fit_across, _k_order, _sorted_by_key, appended
from reconstruction.crossing_fill_one_sided import _k_run_breaks
from reconstruction.rigmodel import RigModel


@dataclass(frozen=True)
class BorderFillOptions:
    """enabled: add the points. min_gap_cells: a run ends where the next labelled sample of its line is
    farther than this many sampling steps. pull_sigma: the anchors lie at least this many σ from the image
    border. anchor: samples fitted; lateral_px: they lie on their fit within this (camera px per sampling
    step). reach_sigma: the extrapolation from the outermost anchor to the border is at most this many σ
    plus one sampling step. max_profile_drop: the profile test at each new point (as
    `TraceOptions.max_profile_drop`); contrast_frac: each new point's ridge contrast is at least this share
    of the anchors' median. cross_sigma: on light sheet k each new point and each anchor is farther than this
    many σ plus half a line width from every line of the other family (camera px). other_width: no extracted
    sample of the other family within this many line widths of the stretch from the outer anchor to the
    border (0: the test off)."""

    enabled: bool = True
    min_gap_cells: float = 1.6
    pull_sigma: float = 2.0
    anchor: int = 5
    lateral_px: float = 0.5
    reach_sigma: float = 5.0
    max_profile_drop: float = 0.15
    contrast_frac: float = 0.5
    cross_sigma: float = 1.0
    other_width: float = 1.0


_REASONS = ("anchors", "anchors_crooked", "not_to_border", "too_far", "line_continues", "profile", "contrast", "other_family")


def _empty(stats: dict) -> CrossingPoints:
    return CrossingPoints(np.zeros((0, 2)), np.zeros(0, np.intp), np.zeros(0), np.zeros(0, np.int64), stats)


def _grey(image: np.ndarray) -> np.ndarray:
    """The frame as one grey channel, uint8 read as it is (the kernels read it bilinearly)."""
    img = np.asarray(image)
    if img.ndim == 3:
        from reconstruction.extraction import to_grey_float

        img = to_grey_float(img)
    if img.dtype not in (np.uint8, np.uint16, np.float32):
        img = img.astype(np.float32)
    return np.ascontiguousarray(img)


@njit
def _k_mark_lines(q, fam, idx, xmax, ymax, lim, kmin, mark):
    """Marks in mark (2, K) the lines (family − 1, index − kmin) of the labelled samples (finite index,
    family 1 or 2) within lim of the image box [0, xmax] × [0, ymax]."""
    nk = mark.shape[1]
    for i in range(q.shape[0]):
        k = idx[i]
        f = fam[i]
        if not np.isfinite(k) or (f != 1 and f != 2):
            continue
        if min(min(q[i, 0], xmax - q[i, 0]), min(q[i, 1], ymax - q[i, 1])) <= lim:
            ki = int(k) - kmin
            if ki >= 0 and ki < nk:
                mark[f - 1, ki] = True


@njit
def _k_mark_box(box, xmax, ymax, lim, mark):
    """`_k_mark_lines` from the lines' boxes (`FillShared.box`: `crossing_fill._k_gaps`' running boxes, equal to
    `crossing_fill._k_order_range_box`'s; same kmin and shape): a line
    has a sample within lim of the image box when its box does, min(smallest x, xmax − largest x, smallest y,
    ymax − largest y) ≤ lim, the least of its samples' distances (the subtraction is monotone in the position,
    so xmax − largest x is the least xmax − x bit for bit). Decision 0149."""
    for f in range(mark.shape[0]):
        for k in range(mark.shape[1]):
            if min(min(box[f, k, 0], xmax - box[f, k, 1]), min(box[f, k, 2], ymax - box[f, k, 3])) <= lim:
                mark[f, k] = True


@njit
def _k_select_lines(fam, idx, kmin, mark):
    """The ids of the labelled samples of the marked lines (`_k_mark_lines`)."""
    nk = mark.shape[1]
    out = np.empty(idx.shape[0], np.intp)
    c = 0
    for i in range(idx.shape[0]):
        k = idx[i]
        f = fam[i]
        if not np.isfinite(k) or (f != 1 and f != 2):
            continue
        ki = int(k) - kmin
        if ki >= 0 and ki < nk and mark[f - 1, ki]:
            out[c] = i
            c += 1
    return out[:c]


@njit
def _k_band(qs, xmax, ymax, lim):
    """The ids of the points qs within lim of the image box [0, xmax] × [0, ymax]."""
    out = np.empty(qs.shape[0], np.intp)
    m = 0
    for i in range(qs.shape[0]):
        if min(min(qs[i, 0], xmax - qs[i, 0]), min(qs[i, 1], ymax - qs[i, 1])) <= lim:
            out[m] = i
            m += 1
    return out[:m]


def fill_border(
    q: np.ndarray,
    family: np.ndarray,
    index: np.ndarray,
    junction: np.ndarray,
    *,
    image: np.ndarray,
    q_samples: np.ndarray,
    family_samples: np.ndarray,
    model: RigModel,
    sigma_px: float,
    cell_px: float,
    depth_range_mm: tuple[float, float],
    options: BorderFillOptions = BorderFillOptions(),
) -> CrossingPoints:
    """Points from labelled lines' ends up to the image border (module doc).

    q (P, 2), family (P,), index (P,) (NaN: unlabelled), junction (P,): the labelled samples (the label
    stage's, with the crossing fills' points appended), camera px. image (H, W) or (H, W, 3): the frame.
    q_samples (S, 2), family_samples (S,): every extracted sample (the other family's lines near the end).
    sigma_px: the extraction's smoothing; cell_px: its sampling step. Returns the added samples
    (`CrossingPoints`, junction: that of the end sample); stats: ends near the border looked at, filled,
    rejected by reason, samples added."""
    return _fill_parts(((q, family, index, junction),), image=image, q_samples=q_samples, family_samples=family_samples, model=model,
                       sigma_px=sigma_px, cell_px=cell_px, depth_range_mm=depth_range_mm, options=options)


def _fill_parts(parts, *, image, q_samples, family_samples, model, sigma_px, cell_px, depth_range_mm,
                options: BorderFillOptions = BorderFillOptions(), box: tuple | None = None) -> CrossingPoints:
    """`fill_border` over the labelled samples given in parts ((q, family, index, junction), ...), taken as
    one array in that order, without concatenating them: only the samples of the lines that come near the
    border are gathered. box: (the lines' boxes of parts[0], their first line index) (`FillShared.box`,
    `.box_kmin`), read instead of its samples to find the lines near the border (decision 0149)."""
    stats: dict = {"ends": 0, "ends_filled": 0, "samples_border_filled": 0, "ends_rejected": {}}
    if not options.enabled:
        return _empty(stats)
    H, W = np.shape(image)[:2]
    sigma = float(sigma_px)
    cell = float(cell_px)
    reach = options.reach_sigma * sigma + cell
    width = float(model.line_width_cam_px)
    # the labelled samples of the lines that come within reach (+ a line width) of the border: an end whose
    # extension reaches the border lies within reach of it, every labelled sample the line-continues test
    # may meet within reach + half a line width
    lim = float(reach + width)
    kmin = int(model.index_min)
    mark = np.zeros((2, int(model.index_max) - kmin + 1), np.bool_)
    arrs = []
    for i, (qp, fp, kp, jp) in enumerate(parts):
        qp = np.ascontiguousarray(qp, np.float64).reshape(-1, 2)
        fp = np.ascontiguousarray(np.asarray(fp).reshape(-1))
        kp = np.ascontiguousarray(kp, np.float64).reshape(-1)
        arrs.append((qp, fp, kp, jp))
        if i == 0 and box is not None and box[1] == kmin and box[0].shape[:2] == mark.shape:
            _k_mark_box(box[0], float(W - 1), float(H - 1), lim, mark)
        else:
            _k_mark_lines(qp, fp, kp, float(W - 1), float(H - 1), lim, kmin, mark)
    if not mark.any():
        return _empty(stats)
    sels = [_k_select_lines(fp, kp, kmin, mark) for _qp, fp, kp, _jp in arrs]
    q = np.concatenate([qp[s_] for (qp, _f, _k, _j), s_ in zip(arrs, sels)])
    fam = np.concatenate([fp[s_].astype(np.intp) for (_q, fp, _k, _j), s_ in zip(arrs, sels)])
    idx = np.concatenate([kp[s_] for (_q, _f, kp, _j), s_ in zip(arrs, sels)])
    junction = np.concatenate([np.asarray(jp).reshape(-1)[s_].astype(np.int64) for (_q, _f, _k, jp), s_ in zip(arrs, sels)])
    bd = np.minimum(np.minimum(q[:, 0], W - 1 - q[:, 0]), np.minimum(q[:, 1], H - 1 - q[:, 1]))
    near = np.flatnonzero(bd <= lim)
    d1, d2 = _family_directions(model)
    s_ord, key = _k_order(q, fam, idx, d1, d2)
    order = _sorted_by_key(s_ord, key)
    if len(order) < options.anchor + 1:
        return _empty(stats)
    qs = np.ascontiguousarray(q_samples, np.float64).reshape(-1, 2)
    fs = np.ascontiguousarray(np.asarray(family_samples).reshape(-1), np.intp)
    # the extracted samples the other-family test may meet (within 1.12 line widths of the stretch from the
    # outer anchor, which lies within reach of the border, to the border)
    nb = _k_band(qs, float(W - 1), float(H - 1), float(reach + 1.5 * width))
    n_ends, ends, anchors, why = _k_border_ends(
        q, fam, idx, np.ascontiguousarray(order, np.intp), near, qs, fs, nb, _grey(image), float(W - 1), float(H - 1), cell,
        float(options.min_gap_cells * cell), float(options.pull_sigma * sigma), int(options.anchor), float(options.lateral_px * cell),
        float(reach), width, float(options.max_profile_drop), float(options.contrast_frac), float(options.other_width * width))
    stats["ends"] = int(n_ends)
    stats["ends_rejected"] = {r: int(why[i]) for i, r in enumerate(_REASONS)}
    stats["ends_rejected"].update(depth_range=0, crossing=0)
    if len(ends) == 0:
        return _empty(stats)
    q_new, owner = _k_points(ends, cell)
    a = ends[owner, 0].astype(np.intp)
    E = len(ends)
    # 4. on light sheet k: the new points inside the depth range, and no line of the other family at them
    # nor at the anchors (a crossing there pulls the fit)
    anc = anchors.reshape(-1)
    q_chk = np.concatenate([q_new, q[anc]])
    own = np.concatenate([owner, np.repeat(np.arange(E), anchors.shape[1])])
    e0 = ends[own, 0].astype(np.intp)
    _p, z, _k_other, dist = model.sheet_check(q_chk, fam[e0], idx[e0].astype(np.intp))
    in_range = (z >= depth_range_mm[0]) & (z <= depth_range_mm[1])
    in_range[len(q_new):] = True
    clear = dist * model.cam_per_proj_px > options.cross_sigma * sigma + 0.5 * model.line_width_cam_px
    bad_range = np.bincount(own[~in_range], minlength=E) > 0
    bad_cross = np.bincount(own[in_range & ~clear], minlength=E) > 0
    stats["ends_rejected"]["depth_range"] = int(bad_range.sum())
    stats["ends_rejected"]["crossing"] = int((bad_cross & ~bad_range).sum())
    keep = ~(bad_range | bad_cross)
    stats["ends_filled"] = int(keep.sum())
    m = keep[owner]
    if not m.any():
        return _empty(stats)
    a = a[m]
    stats["samples_border_filled"] = int(m.sum())
    return CrossingPoints(q_new[m], fam[a], idx[a], junction[a], stats)


@njit
def _k_points(ends, cell):
    """Per end [sample, ox, oy, ux, uy, L]: points at s = i·L/n, i = 1..n, n = max(round(L / cell), 1), on
    o + s·u; and the end each belongs to."""
    E = ends.shape[0]
    total = 0
    for e in range(E):
        total += max(int(round(ends[e, 5] / cell)), 1)
    q_new = np.empty((total, 2))
    owner = np.empty(total, np.intp)
    o = 0
    for e in range(E):
        L = ends[e, 5]
        n = max(int(round(L / cell)), 1)
        for i in range(1, n + 1):
            s = i * L / n
            q_new[o, 0] = ends[e, 1] + s * ends[e, 3]
            q_new[o, 1] = ends[e, 2] + s * ends[e, 4]
            owner[o] = e
            o += 1
    return q_new, owner


@njit
def _bilinear(img, x, y):
    """img at (x, y) (pixel centres at integers), bilinear, coordinates clamped to the image."""
    H, W = img.shape
    x = min(max(x, 0.0), W - 1.0)
    y = min(max(y, 0.0), H - 1.0)
    x0 = min(int(x), W - 2) if W > 1 else 0
    y0 = min(int(y), H - 2) if H > 1 else 0
    fx = x - x0
    fy = y - y0
    x1 = min(x0 + 1, W - 1)
    y1 = min(y0 + 1, H - 1)
    return ((1 - fy) * ((1 - fx) * img[y0, x0] + fx * img[y0, x1]) + fy * ((1 - fx) * img[y1, x0] + fx * img[y1, x1]))


@njit
def _box(img, x, y):
    """The 3×3 box-filtered image at (x, y): the mean of bilinear reads one pixel apart."""
    acc = 0.0
    for dy in (-1.0, 0.0, 1.0):
        for dx in (-1.0, 0.0, 1.0):
            acc += _bilinear(img, x + dx, y + dy)
    return acc / 9.0


@njit
def _profile(img, x, y, nx, ny, w, xmax, ymax):
    """`labelling.profile_drop` at (x, y) across the normal (nx, ny) on the box-filtered image, probes
    outside the box [0, xmax] × [0, ymax] left out: (drop, contrast = inner − outer); contrast −1 when
    no outer probe lies inside."""
    inner = -1e30
    for d in (0.0, -0.25, 0.25, -0.5, 0.5):
        px = x + d * w * nx
        py = y + d * w * ny
        if px < 0.0 or px > xmax or py < 0.0 or py > ymax:
            continue
        inner = max(inner, _box(img, px, py))
    outer = 1e30
    for d in (-1.0, 1.0):
        px = x + d * w * nx
        py = y + d * w * ny
        if px < 0.0 or px > xmax or py < 0.0 or py > ymax:
            continue
        outer = min(outer, _box(img, px, py))
    if outer > 1e29 or inner < -1e29:
        return 1e30, -1.0
    c = _box(img, x, y)
    return (inner - c) / max(inner - outer, 1.0), inner - outer


@njit
def _exit(ox, oy, ux, uy, xmax, ymax):
    """Distance along o + s·u (s > 0) to where the ray leaves the box [0, xmax] × [0, ymax]."""
    s = np.inf
    if ux > 1e-12:
        s = min(s, (xmax - ox) / ux)
    elif ux < -1e-12:
        s = min(s, -ox / ux)
    if uy > 1e-12:
        s = min(s, (ymax - oy) / uy)
    elif uy < -1e-12:
        s = min(s, -oy / uy)
    return s


@njit
def _k_border_ends(q, fam, idx, order, ahead, qs, fs, band, img, xmax, ymax, cell, min_gap, pull, anchor, lateral, reach, width, max_drop,
                   contrast_frac, other_w):
    """Steps 1–4 (image part) of the module doc. Returns the number of ends near the border looked at, per
    accepted end (E, 6) [end sample, ox, oy, ux, uy, L] (o the end sample's foot on the fit, u outward, L
    to the box), and the counts of ends rejected by reason (`_REASONS`)."""
    n = order.shape[0]
    cap = 2 * ahead.shape[0]  # every end lies within reach of the border: one of the `ahead` samples
    ends = np.empty((cap, 6))
    anchors = np.empty((cap, anchor), np.intp)
    ids = np.empty(anchor, np.intp)
    why = np.zeros(8, np.int64)
    E = 0
    n_ends = 0
    near_lim = reach
    brk = _k_run_breaks(q, fam, idx, order, min_gap)  # the runs' ends, as the one-sided fill's
    xs = np.empty(anchor)
    ys = np.empty(anchor)
    fit_x = np.empty(anchor)
    fit_y = np.empty(anchor)
    for p in range(n):
        for side in range(2):
            step = 1 if side == 0 else -1  # 0: the run's forward end, 1: its backward end
            if not brk[p + 1 - side]:
                continue
            a = order[p]
            bd = min(min(q[a, 0], xmax - q[a, 0]), min(q[a, 1], ymax - q[a, 1]))
            if bd > near_lim:
                continue
            n_ends += 1
            # 2. inward from the end: skip the samples within the border's pull, then `anchor` samples of the run
            p1 = p
            ok = True
            cnt = 0
            while cnt < anchor:
                s0 = order[p1]
                b0 = min(min(q[s0, 0], xmax - q[s0, 0]), min(q[s0, 1], ymax - q[s0, 1]))
                if b0 >= pull:
                    ids[cnt] = s0
                    xs[cnt] = q[s0, 0]
                    ys[cnt] = q[s0, 1]
                    cnt += 1
                elif cnt > 0:
                    ok = False  # the run comes back into the pull: not one straight run to the border
                    break
                if cnt == anchor:
                    break
                if brk[p1] if step == 1 else brk[p1 + 1]:
                    ok = False  # the run ends before `anchor` samples beyond the pull
                    break
                p1 -= step
            if not ok:
                why[0] += 1
                continue
            # the fit: u0 from the inner to the outer anchor, residuals across it regressed on the position along it
            ux0 = xs[0] - xs[anchor - 1]
            uy0 = ys[0] - ys[anchor - 1]
            l0 = math.sqrt(ux0 * ux0 + uy0 * uy0)
            if not l0 > 0.0:
                why[1] += 1
                continue
            ux0 /= l0
            uy0 /= l0
            for k in range(anchor):
                fit_x[k] = xs[k] - xs[0]
                fit_y[k] = ys[k] - ys[0]
            kk, cc, status = _fit_across(fit_x, fit_y, anchor, ux0, uy0, lateral)  # step 11's fit
            if status != 0:
                why[1] += 1
                continue
            un = math.sqrt(1.0 + kk * kk)
            nx0 = -uy0
            ny0 = ux0
            ux = (ux0 + kk * nx0) / un
            uy = (uy0 + kk * ny0) / un
            # a point of the fit: the outer anchor's foot; then the end sample's foot o
            fx = xs[0] + cc * nx0  # position 0 along u0 is the outer anchor
            fy = ys[0] + cc * ny0
            s_end = (q[a, 0] - fx) * ux + (q[a, 1] - fy) * uy
            if s_end < 0.0:
                s_end = 0.0  # the end lies within the anchors (it is the outer anchor)
            ox = fx + s_end * ux
            oy = fy + s_end * uy
            # 3. the extension to the box of pixel centres, within reach of the outer anchor
            if ox < 0.0 or ox > xmax or oy < 0.0 or oy > ymax:
                why[2] += 1
                continue
            L = _exit(ox, oy, ux, uy, xmax, ymax)
            if not L > 0.5 * cell:
                why[2] += 1
                continue
            if s_end + L > reach:
                why[3] += 1
                continue
            # 4. no labelled sample of the family ahead on the extension (within half a line width of it)
            cont = False
            for t in range(ahead.shape[0]):
                i = ahead[t]
                if fam[i] != fam[a]:
                    continue
                ex = q[i, 0] - ox
                ey = q[i, 1] - oy
                s = ex * ux + ey * uy
                if s > 0.5 * cell and s <= L + 0.5 * cell and abs(-ex * uy + ey * ux) <= 0.5 * width:
                    cont = True
                    break
            if cont:
                why[4] += 1
                continue
            # no sample of the other family (labelled or not) near the line from the outer anchor to the border:
            # a crossing there (the crossing fills' business) or a line that pulls the anchors
            for t in range(band.shape[0]):
                i = band[t]
                if fs[i] == fam[a]:
                    continue
                ex = qs[i, 0] - ox
                ey = qs[i, 1] - oy
                s = ex * ux + ey * uy
                if s >= -s_end - 0.5 * width and s <= L + 0.5 * width and abs(-ex * uy + ey * ux) <= other_w:
                    cont = True
                    break
            if cont:
                why[7] += 1
                continue
            # the image: a ridge at every new point, with at least contrast_frac of the anchors' contrast
            cs = np.empty(anchor)
            for k in range(anchor):
                _d, cs[k] = _profile(img, xs[k], ys[k], -uy, ux, width, xmax, ymax)
            c_run = np.median(cs)
            m = max(int(round(L / cell)), 1)
            bad = 0
            for i in range(1, m + 1):
                s = i * L / m
                d, c = _profile(img, ox + s * ux, oy + s * uy, -uy, ux, width, xmax, ymax)
                if d > max_drop:
                    bad = 1
                    break
                if c < contrast_frac * c_run:
                    bad = 2
                    break
            if bad:
                why[4 + bad] += 1
                continue
            ends[E, 0] = a
            ends[E, 1] = ox
            ends[E, 2] = oy
            ends[E, 3] = ux
            ends[E, 4] = uy
            ends[E, 5] = L
            anchors[E] = ids
            E += 1
    return n_ends, ends[:E], anchors[:E], why


def with_border(
    cp: CrossingPoints | None,
    q: np.ndarray,
    family: np.ndarray,
    index: np.ndarray,
    junction: np.ndarray,
    **kwargs,
) -> CrossingPoints:
    """The crossing fills' points `cp` (None: none) followed by `fill_border`'s, computed over the label
    stage's samples (q, family, index, junction: `SampleLabels.q`, the observation's family, `.index`,
    `.junction`) with `cp`'s appended; stats: cp's, with "samples_border_filled" and "border" (the call's
    own counts). kwargs: `fill_border`'s keywords. When q, family and index are the arrays `fill_crossings`
    ran on (`cp.shared`), the lines' boxes it made on them (`FillShared.box`) stand for their samples in the
    test "which lines come near the border" (decision 0149)."""
    parts = [(q, family, index, junction)]
    if cp is not None and len(cp.index):
        parts.append((cp.q, cp.family, cp.index, cp.junction))
    sh = cp.shared if cp is not None else None
    box = None
    if sh is not None and sh.box is not None and all(a is b for a, b in zip(sh.inputs[:3], (q, family, index))):
        box = (sh.box, sh.box_kmin)
    bp = _fill_parts(tuple(parts), box=box, **kwargs)
    return appended(cp, bp, "samples_border_filled", "border", cp.shared if cp is not None else None)
