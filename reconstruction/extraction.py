"""Grid extraction: sub-pixel line centres, the two line families, junctions and their connectivity.

One camera image in, a `GridObservation` out (camera pixels, (u, v), pixel (0, 0) = centre of the
top-left pixel). The method (docs/reconstruction.md):

1. Gaussian smoothing; candidates where the discrete Laplacian is clearly negative (a bright ridge).
2. At candidates, the Hessian's most negative eigenvector is the line normal n; Steger's sub-pixel
   offset t = −(∇I · n) / (nᵀ H n) moves the sample onto the ridge; pixels whose centre lies within
   half a pixel of the ridge are kept (one sample per pixel along the line). Isotropic spots (line
   crossings, blobs) are dropped by an anisotropy test.
3. Each sample's line direction is compared with the two families' directions predicted from the
   calibration (`RigModel.dir_cam`): the closer one names the family.
4. Junctions: where the (dilated) masks of both families meet. Around each, a straight line is fitted
   to each family's samples in an annulus, and the junction is the intersection of the two fits. A
   junction is kept only if both lines run *through* it (samples on both sides): T- and L-shapes are
   occlusion or shadow boundaries, or the pattern's rim, and would join unrelated surfaces.
5. Segments: samples outside every junction's disk, connected per family; a segment whose two ends touch
   two junctions and which is straight and passes through both junctions is an edge of the graph.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np
from scipy.spatial import cKDTree

from reconstruction.rigmodel import RigModel


@dataclass(frozen=True)
class ExtractOptions:
    """sigma_px: Gaussian smoothing (camera px) before the derivatives; None: from the line width the
        calibration predicts in the camera (`sigma_for`).
    threshold_sigma: a ridge must be this many noise standard deviations strong.
    min_relative_strength: and at least this fraction of the strongest ridges nearby (uneven albedo).
    anisotropy: the second eigenvalue may be at most this fraction of the first (rejects spots).
    family_margin: |cos| difference needed between the two predicted families.
    """

    sigma_px: float | None = None
    threshold_sigma: float = 5.0
    min_relative_strength: float = 0.15
    anisotropy: float = 0.5
    family_margin: float = 0.15
    max_segment_rms_px: float = 0.6
    max_junction_offset_px: float = 1.5
    debug: bool = False


@dataclass(frozen=True, eq=False)
class GridObservation:
    """What extraction found in one image.

    Samples (P): q (P, 2) sub-pixel line centres; family (P,) 1 = i-line, 2 = j-line; segment (P,) the
        segment id or −1; junction (P,) the junction whose disk holds the sample or −1; strength (P,).
    Junctions (M): q_junction (M, 2); junction_dir (M, 2, 2) fitted directions of the i- and j-line.
    Segments (S): segment_family (S,), segment_ends (S, 2) junction ids (−1 = none), segment_rms (S,)
        straight-line fit RMS (px), segment_centre (S, 2) and segment_dir (S, 2) of that fit.
    Edges (E): edges (E, 2) junction ids a → b, edge_family (E,), edge_delta (E, 2) the change of (i, j)
        from a to b (±1 in the index of the other family), edge_segment (E,).
    stats: counts and reasons.
    """

    q: np.ndarray
    family: np.ndarray
    segment: np.ndarray
    junction: np.ndarray
    strength: np.ndarray
    q_junction: np.ndarray
    junction_dir: np.ndarray
    segment_family: np.ndarray
    segment_ends: np.ndarray
    segment_rms: np.ndarray
    segment_centre: np.ndarray
    segment_dir: np.ndarray
    edges: np.ndarray
    edge_family: np.ndarray
    edge_delta: np.ndarray
    edge_segment: np.ndarray
    stats: dict


def to_grey_float(image: np.ndarray) -> np.ndarray:
    """(H, W) or (H, W, 3) uint8/uint16/float image -> (H, W) float32 on the 8-bit scale."""
    img = np.asarray(image)
    if img.ndim == 3:
        if img.shape[2] == 1:
            img = img[:, :, 0]
        else:
            img = img[:, :, :3].astype(np.float32) @ np.array([0.114, 0.587, 0.299], np.float32)  # BGR weights
    if img.dtype == np.uint16:
        return img.astype(np.float32) * np.float32(255.0 / 65535.0)
    return img.astype(np.float32, copy=False)


def image_noise_grey(img: np.ndarray) -> float:
    """Standard deviation (grey levels) of the sensor noise: the median absolute response to the 3×3
    operator [[1,−2,1],[−2,4,−2],[1,−2,1]] (which cancels planes and is 6σ for white noise; Immerkær 1996),
    over a subsample. The median keeps lines and edges from inflating it."""
    k = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32)
    r = cv2.filter2D(img[::2, ::2] if min(img.shape) > 400 else img, cv2.CV_32F, k)[1:-1, 1:-1]
    return float(np.median(np.abs(r))) / (0.6745 * 6.0)


@lru_cache(maxsize=16)
def _laplacian_noise_gain(sigma: float) -> float:
    """Std of the smoothed image's discrete Laplacian per unit std of white pixel noise."""
    n = int(np.ceil(4 * sigma)) * 2 + 9
    delta = np.zeros((n, n), np.float32)
    delta[n // 2, n // 2] = 1
    resp = cv2.Laplacian(cv2.GaussianBlur(delta, (0, 0), sigma), cv2.CV_32F, ksize=1)
    return float(np.sqrt((resp.astype(np.float64) ** 2).sum()))


def _ridge_samples(G: np.ndarray, options: ExtractOptions, sigma: float, noise_grey: float) -> dict:
    H, W = G.shape
    lap = cv2.Laplacian(G, cv2.CV_32F, ksize=1)
    # Noise of the Laplacian (and of the Hessian's eigenvalues, same order) from the sensor noise;
    # at least 0.5 grey level (quantisation).
    noise = max(noise_grey, 0.5) * _laplacian_noise_gain(round(sigma, 3))
    thr = options.threshold_sigma * noise
    lap[0, :] = 0
    lap[-1, :] = 0
    lap[:, 0] = 0
    lap[:, -1] = 0
    cand = lap < -0.5 * thr
    v, u = np.nonzero(cand)
    g = G
    c = g[v, u]
    r = g[v, u + 1]
    l_ = g[v, u - 1]
    d = g[v + 1, u]
    up = g[v - 1, u]
    gx = 0.5 * (r - l_)
    gy = 0.5 * (d - up)
    gxx = r - 2 * c + l_
    gyy = d - 2 * c + up
    gxy = 0.25 * (g[v + 1, u + 1] - g[v + 1, u - 1] - g[v - 1, u + 1] + g[v - 1, u - 1])
    half_tr = 0.5 * (gxx + gyy)
    disc = np.sqrt((0.5 * (gxx - gyy)) ** 2 + gxy * gxy)
    lam1 = half_tr - disc  # most negative
    lam2 = half_tr + disc
    # eigenvector of lam1: two algebraically equivalent forms, take the better-conditioned one
    ax, ay = gxy, lam1 - gxx
    bx, by = lam1 - gyy, gxy
    use_b = (bx * bx + by * by) > (ax * ax + ay * ay)
    nx = np.where(use_b, bx, ax)
    ny = np.where(use_b, by, ay)
    nn = np.sqrt(nx * nx + ny * ny)
    nn[nn == 0] = 1
    nx /= nn
    ny /= nn
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -(gx * nx + gy * ny) / lam1
    ox = t * nx
    oy = t * ny
    strength = -lam1
    keep = (
        (np.abs(ox) <= 0.5)
        & (np.abs(oy) <= 0.5)
        & (strength > thr)
        & (lam2 > -options.anisotropy * strength)
    )
    return {
        "u": u[keep],
        "v": v[keep],
        "q": np.column_stack([u[keep] + ox[keep], v[keep] + oy[keep]]).astype(np.float64),
        "n": np.column_stack([nx[keep], ny[keep]]).astype(np.float64),
        "strength": strength[keep].astype(np.float64),
        "noise": noise,
        "candidates": int(len(u)),
    }


def _line_fit_moments(groups: np.ndarray, q: np.ndarray, n_groups: int, weights: np.ndarray | None = None):
    """Per-group total-least-squares line: centroid (G, 2), unit direction (G, 2), RMS distance (G,), count (G,)."""
    w = np.ones(len(q)) if weights is None else weights
    cnt = np.bincount(groups, weights=w, minlength=n_groups)
    num = np.bincount(groups, minlength=n_groups)
    safe = np.where(cnt > 0, cnt, 1)
    mx = np.bincount(groups, weights=w * q[:, 0], minlength=n_groups) / safe
    my = np.bincount(groups, weights=w * q[:, 1], minlength=n_groups) / safe
    dx = q[:, 0] - mx[groups]
    dy = q[:, 1] - my[groups]
    sxx = np.bincount(groups, weights=w * dx * dx, minlength=n_groups) / safe
    syy = np.bincount(groups, weights=w * dy * dy, minlength=n_groups) / safe
    sxy = np.bincount(groups, weights=w * dx * dy, minlength=n_groups) / safe
    theta = 0.5 * np.arctan2(2 * sxy, sxx - syy)
    direction = np.column_stack([np.cos(theta), np.sin(theta)])
    half_tr = 0.5 * (sxx + syy)
    disc = np.sqrt((0.5 * (sxx - syy)) ** 2 + sxy * sxy)
    rms = np.sqrt(np.maximum(half_tr - disc, 0))
    return np.column_stack([mx, my]), direction, rms, num


def sigma_for(model: RigModel, options: ExtractOptions) -> float:
    """The smoothing scale: given, or 0.4 × the predicted line width in the camera (at least 1 px).

    A bright bar of width w smoothed by σ ≥ w/(2√3) has a single ridge at its centre (Steger 1998)."""
    if options.sigma_px is not None:
        return float(options.sigma_px)
    return float(np.clip(0.4 * model.line_width_cam_px, 1.0, 8.0))


def extract_grid(image: np.ndarray, model: RigModel, *, options: ExtractOptions = ExtractOptions()) -> GridObservation:
    """Find line samples, families, junctions and the segment graph in one camera image (see module doc)."""
    sigma = sigma_for(model, options)
    grey = to_grey_float(image)
    noise_grey = image_noise_grey(grey)
    G = cv2.GaussianBlur(grey, (0, 0), sigma)
    H, W = G.shape
    rs = _ridge_samples(G, options, sigma, noise_grey)
    q, nrm, strength = rs["q"], rs["n"], rs["strength"]
    u, v = rs["u"], rs["v"]
    stats: dict = {"ridge_candidates": rs["candidates"], "noise_laplacian": rs["noise"], "noise_grey": noise_grey, "sigma_px": sigma}

    # Uneven albedo: also demand a fraction of the locally strongest ridge.
    if len(q) and options.min_relative_strength > 0:
        simg = np.zeros((H, W), np.float32)
        simg[v, u] = strength
        k = 31
        local_max = cv2.dilate(simg, cv2.getStructuringElement(cv2.MORPH_RECT, (k, k)))
        ok = strength >= options.min_relative_strength * local_max[v, u]
        q, nrm, strength, u, v = q[ok], nrm[ok], strength[ok], u[ok], v[ok]

    # Families from the predicted directions.
    dirs, _ = model.lookup(q)
    d_line = np.column_stack([-nrm[:, 1], nrm[:, 0]])
    c1 = np.abs(np.einsum("ij,ij->i", d_line, dirs[:, 0]))
    c2 = np.abs(np.einsum("ij,ij->i", d_line, dirs[:, 1]))
    fam = np.where(c1 >= c2, 1, 2).astype(np.int8)
    ok = np.abs(c1 - c2) >= options.family_margin
    q, nrm, strength, u, v, fam = q[ok], nrm[ok], strength[ok], u[ok], v[ok], fam[ok]
    stats["samples"] = int(len(q))

    # Junction candidates: both families' masks, dilated, overlap.
    m1 = np.zeros((H, W), np.uint8)
    m2 = np.zeros((H, W), np.uint8)
    m1[v[fam == 1], u[fam == 1]] = 1
    m2[v[fam == 2], u[fam == 2]] = 1
    # The ridges of both families stop within about the smoothing scale of a crossing: bridge that gap.
    kr = int(np.ceil(max(2.0, 1.6 * sigma)))
    ker = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * kr + 1, 2 * kr + 1))
    both = cv2.bitwise_and(cv2.dilate(m1, ker), cv2.dilate(m2, ker))
    nb, blob_lab, blob_stats, blob_c = cv2.connectedComponentsWithStats(both, connectivity=8, ltype=cv2.CV_32S)
    cen = blob_c[1:].astype(np.float64)
    stats["junction_candidates"] = int(nb - 1)

    empty = _empty_observation(q, fam, strength, stats)
    if nb <= 1:
        return empty

    # Disk radius from the junction spacing the calibration predicts; the core (biased by the crossing
    # itself) from the smoothing scale.
    step = model.junction_step_cam_px
    R = float(np.clip(0.4 * step, 3.0, 60.0))
    r0 = float(min(max(1.5, 1.6 * sigma + 0.5), 0.6 * R))
    # Non-maximum suppression: one candidate per crossing (largest blob wins).
    if len(cen) >= 2:
        area = blob_stats[1:, cv2.CC_STAT_AREA]
        order_c = np.argsort(-area, kind="stable")
        tree_c = cKDTree(cen)
        alive = np.ones(len(cen), bool)
        for k in order_c.tolist():
            if alive[k]:
                for o in tree_c.query_ball_point(cen[k], r=R):
                    if o != k:
                        alive[o] = False
        cen = cen[alive]
        stats["junction_candidates"] = int(len(cen))
    stats["junction_radius_px"] = R
    stats["junction_core_px"] = r0

    # Junction id image: each candidate's disk (radius R) carries its id + 1.
    # (dilate single centroid pixels, not the blobs: a blob's own extent would widen the disk)
    lab16 = np.zeros((H, W), np.float32)
    ci = np.clip(np.rint(cen).astype(np.intp), 0, [W - 1, H - 1])
    lab16[ci[:, 1], ci[:, 0]] = np.arange(1, len(cen) + 1, dtype=np.float32)
    rk = int(np.ceil(R))
    disk = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * rk + 1, 2 * rk + 1))
    jimg = cv2.dilate(lab16, disk)
    jid = jimg[v, u].astype(np.int64) - 1  # −1: outside every disk
    dist_c = np.full(len(q), np.inf)
    inj = jid >= 0
    dist_c[inj] = np.linalg.norm(q[inj] - cen[jid[inj]], axis=1)
    inj &= dist_c <= R + 1.0

    # Line fits per (junction, family) in the annulus r0 < d <= R.
    nj = len(cen)
    ann = inj & (dist_c > r0)
    fits = {}
    for f in (1, 2):
        sel = ann & (fam == f)
        grp = jid[sel]
        cen_f, dir_f, rms_f, cnt_f = _line_fit_moments(grp, q[sel], nj)
        # Through test: samples on both sides of the centre along the line.
        s = np.einsum("ij,ij->i", q[sel] - cen[grp], dir_f[grp])
        smin = np.full(nj, np.inf)
        smax = np.full(nj, -np.inf)
        np.minimum.at(smin, grp, s)
        np.maximum.at(smax, grp, s)
        fits[f] = (cen_f, dir_f, rms_f, cnt_f, smin, smax)
    side = 0.5 * (r0 + R) * 0.6
    valid = np.ones(nj, bool)
    reasons = {"too_few_samples": 0, "not_through": 0, "parallel": 0, "off_centre": 0}
    for f in (1, 2):
        cen_f, dir_f, rms_f, cnt_f, smin, smax = fits[f]
        few = cnt_f < 3
        if options.debug:
            stats[f"debug_fit{f}"] = (cnt_f, smin, smax, rms_f)
        reasons["too_few_samples"] += int((valid & few).sum())
        valid &= ~few
        nt = ~((smin < -side) & (smax > side))
        reasons["not_through"] += int((valid & nt).sum())
        valid &= ~nt
    # Intersection of the two fitted lines: c1 + a·d1 = c2 + b·d2.
    c1_, d1_ = fits[1][0], fits[1][1]
    c2_, d2_ = fits[2][0], fits[2][1]
    cross = d1_[:, 0] * d2_[:, 1] - d1_[:, 1] * d2_[:, 0]
    par = np.abs(cross) < 0.2
    reasons["parallel"] += int((valid & par).sum())
    valid &= ~par
    with np.errstate(divide="ignore", invalid="ignore"):
        diff = c2_ - c1_
        a = (diff[:, 0] * d2_[:, 1] - diff[:, 1] * d2_[:, 0]) / cross
        qj = c1_ + a[:, None] * d1_
    off = np.linalg.norm(qj - cen, axis=1) > max(options.max_junction_offset_px, 0.35 * R)
    off |= ~np.isfinite(qj).all(axis=1)
    reasons["off_centre"] += int((valid & off).sum())
    valid &= ~off
    stats["junctions_rejected"] = reasons
    if options.debug:
        stats["debug_candidates"] = cen
        stats["debug_valid"] = valid

    # Renumber valid junctions 0..M-1.
    new_id = np.full(nj, -1, np.int64)
    new_id[valid] = np.arange(int(valid.sum()))
    q_junction = qj[valid]
    junction_dir = np.stack([d1_[valid], d2_[valid]], axis=1)
    M = len(q_junction)
    stats["junctions"] = M

    sample_junction = np.where(inj, new_id[np.where(jid >= 0, jid, 0)], -1)
    sample_junction[~inj] = -1

    # Segments: samples outside all disks, connected per family.
    outside = ~inj
    seg = np.full(len(q), -1, np.int64)
    seg_family = []
    seg_offset = 0
    for f in (1, 2):
        sel = outside & (fam == f)
        mask = np.zeros((H, W), np.uint8)
        mask[v[sel], u[sel]] = 1
        ns, slab = cv2.connectedComponents(mask, connectivity=8, ltype=cv2.CV_32S)
        seg[sel] = slab[v[sel], u[sel]] - 1 + seg_offset
        seg_family.append(np.full(ns - 1, f, np.int8))
        seg_offset += ns - 1
    seg_family = np.concatenate(seg_family) if seg_family else np.zeros(0, np.int8)
    S = seg_offset
    has_seg = seg >= 0
    _, seg_dir, seg_rms, seg_cnt = _line_fit_moments(seg[has_seg], q[has_seg], S)

    # Segment direction: mean of the samples' line directions (doubled angles; robust for short segments).
    seg_cen = np.zeros((S, 2))
    segment_ends = np.full((S, 2), -1, np.int64)
    stats["segments"] = int(S)
    if has_seg.any():
        sg = seg[has_seg]
        cnt = np.bincount(sg, minlength=S).astype(np.float64)
        cnt[cnt == 0] = 1
        seg_cen[:, 0] = np.bincount(sg, weights=q[has_seg, 0], minlength=S) / cnt
        seg_cen[:, 1] = np.bincount(sg, weights=q[has_seg, 1], minlength=S) / cnt
        ang2 = 2 * np.arctan2(nrm[has_seg, 0], -nrm[has_seg, 1])  # direction (−ny, nx)
        c2m = np.bincount(sg, weights=np.cos(ang2), minlength=S)
        s2m = np.bincount(sg, weights=np.sin(ang2), minlength=S)
        th = 0.5 * np.arctan2(s2m, c2m)
        seg_dir = np.column_stack([np.cos(th), np.sin(th)])
        # Extremes along the direction; each end's junction is the candidate about R beyond it.
        sproj = np.einsum("ij,ij->i", q[has_seg] - seg_cen[sg], seg_dir[sg])
        smin = np.full(S, np.inf)
        smax = np.full(S, -np.inf)
        np.minimum.at(smin, sg, sproj)
        np.maximum.at(smax, sg, sproj)
        tree = cKDTree(cen)
        for k, (sv, sgn) in enumerate(((smin, -1.0), (smax, 1.0))):
            probe = seg_cen + (sv + sgn * R)[:, None] * seg_dir
            dist, near = tree.query(probe, k=1, distance_upper_bound=0.6 * R + 1.0)
            hit = np.isfinite(dist)
            segment_ends[hit, k] = new_id[near[hit]]
    stats["segments_branching"] = 0

    # Edges: two ends, straight, passing through both junctions.
    cand = (segment_ends[:, 0] >= 0) & (segment_ends[:, 1] >= 0) & (segment_ends[:, 0] != segment_ends[:, 1])
    # Straightness: the samples must lie on the chord between the two junctions (short segments, whose own
    # fit is poorly conditioned, are judged by the chord too).
    qa = np.full((S, 2), np.nan)
    qb = np.full((S, 2), np.nan)
    qa[cand] = q_junction[segment_ends[cand, 0]]
    qb[cand] = q_junction[segment_ends[cand, 1]]
    chord = qb - qa
    clen = np.linalg.norm(chord, axis=1)
    cn = np.column_stack([-chord[:, 1], chord[:, 0]]) / np.where(clen > 0, clen, 1)[:, None]
    sh = has_seg & cand[np.maximum(seg, 0)]
    dist_ch = np.abs(np.einsum("ij,ij->i", q[sh] - qa[seg[sh]], cn[seg[sh]]))
    n_sh = np.bincount(seg[sh], minlength=S)
    rms_ch = np.sqrt(np.bincount(seg[sh], weights=dist_ch**2, minlength=S) / np.maximum(n_sh, 1))
    tol = options.max_segment_rms_px
    straight = cand & (rms_ch <= tol) & (n_sh >= 1)
    stats["segments_crooked"] = int((cand & ~straight).sum())
    sid = np.nonzero(straight)[0]
    a_j = segment_ends[sid, 0]
    b_j = segment_ends[sid, 1]
    fam_s = seg_family[sid]
    # Index change along the edge, from the predicted camera->projector Jacobian.
    mid = 0.5 * (q_junction[a_j] + q_junction[b_j])
    _, Jpc = model.lookup(mid)
    dq_proj = np.einsum("nij,nj->ni", Jpc, q_junction[b_j] - q_junction[a_j])
    n_other = np.where(fam_s == 1, model.pattern.n2, model.pattern.n1)
    s_other = np.sign(dq_proj[:, 1] - n_other * dq_proj[:, 0]).astype(np.int64)
    delta = np.zeros((len(sid), 2), np.int64)
    delta[:, 0] = np.where(fam_s == 2, s_other, 0)  # along a j-line, i changes
    delta[:, 1] = np.where(fam_s == 1, s_other, 0)  # along an i-line, j changes
    good = s_other != 0
    edges = np.column_stack([a_j, b_j])[good]
    stats["edges"] = int(good.sum())

    return GridObservation(
        q=q,
        family=fam,
        segment=seg,
        junction=sample_junction,
        strength=strength,
        q_junction=q_junction,
        junction_dir=junction_dir,
        segment_family=seg_family,
        segment_ends=segment_ends,
        segment_rms=seg_rms,
        segment_centre=seg_cen,
        segment_dir=seg_dir,
        edges=edges,
        edge_family=fam_s[good],
        edge_delta=delta[good],
        edge_segment=sid[good],
        stats=stats,
    )


def _empty_observation(q, fam, strength, stats) -> GridObservation:
    stats = {**stats, "junctions": 0, "segments": 0, "edges": 0}
    return GridObservation(
        q=q,
        family=fam,
        segment=np.full(len(q), -1, np.int64),
        junction=np.full(len(q), -1, np.int64),
        strength=strength,
        q_junction=np.zeros((0, 2)),
        junction_dir=np.zeros((0, 2, 2)),
        segment_family=np.zeros(0, np.int8),
        segment_ends=np.zeros((0, 2), np.int64),
        segment_rms=np.zeros(0),
        segment_centre=np.zeros((0, 2)),
        segment_dir=np.zeros((0, 2)),
        edges=np.zeros((0, 2), np.int64),
        edge_family=np.zeros(0, np.int8),
        edge_delta=np.zeros((0, 2), np.int64),
        edge_segment=np.zeros(0, np.int64),
        stats=stats,
    )
