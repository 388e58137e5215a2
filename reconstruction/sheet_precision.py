"""Line-sample points whose light sheet runs nearly along the epipolar lines are left out (decision 0131).

A line sample's point is its camera ray cut with the light sheet of its line. Its depth is where the ray's
epipolar line (in the projector image) crosses the pattern line. When the two run at an angle θ, a sample that
lies δ projector px across its line (its position noise, or the calibration's epipolar error) moves that crossing
by δ / sin θ along the epipolar line, and the point along its camera ray by

    σ_z = δ · G / sin θ,      G = |dλ / dq_proj|: mm along the camera ray per projector px along the epipolar line.

A junction is the crossing of two lines: its depth does not depend on one line's angle. On the unseen seeds 116
and 126 (rigs warned ill-posed) one family's lines run within a few degrees of the epipolar lines (sin θ
0.001–0.08): their labels are right, but their points' median error is 60–70 times the other family's, and they
are nearly all of the points more than 1 % off.

`imprecise_samples` predicts σ_z / |p| for every sample point with δ = max(σ̂, σ0): σ̂ the robust scale of the
frame's labelled junctions' epipolar residuals (their position noise in projector px), σ0 the labeller's
`noise_floor_px` (the epipolar error the calibration may leave, decision 0110; `rig` sets it from the
calibration). A point whose predicted error exceeds `max_error_pct` of its distance is left out.

Decision 0151: a sample's own sideways offset from its line's local fit (the straight fit of its segment, or of
its junction's arm, that extraction made), converted to projector px across its line (`across_line_scale`),
takes δ's place where it is larger (`own_offsets_px`): the samples near a crossing are pulled sideways by the
other line's profile by more than the frame's noise (unseen seed 148: 0.1–0.25 px, against a robust scatter of
0.03 px), a bias that no per-frame scale shows but each such sample's residual does.

The projector is taken as a pinhole for the angle and the gain (its distortion changes both by a few per cent at
most); the epipole is K·t in homogeneous coordinates, so a camera displaced sideways (epipole at infinity) needs
no special case.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from reconstruction._jit import njit


@dataclass(frozen=True)
class SheetPrecisionOptions:
    """enabled: leave out line-sample points whose predicted depth error, max(σ̂, noise floor)·G / sin θ (module
    doc), exceeds max_error_pct of their distance from the projector. max_error_pct: half of the 1 % that counts a
    point as wrong (the issue's p99 target): a point one predicted σ off from it still stays under 1 %. own_offset
    (decision 0151): a sample's δ is the larger of the frame's and its own sideways offset from its line's local
    fit (`own_offsets_px`), so a sample measurably pulled off its line is judged at that offset."""

    enabled: bool = True
    max_error_pct: float = 0.5
    own_offset: bool = True  # decision 0151: δ per sample = max(frame δ, its own offset from its line's local fit)

    def __post_init__(self) -> None:
        if not self.max_error_pct > 0:
            raise ValueError(f"SheetPrecisionOptions.max_error_pct = {self.max_error_pct}: must be > 0")


def predicted_error(K_proj: np.ndarray, t_proj_cam: np.ndarray, slope: np.ndarray, p: np.ndarray, delta_px: float) -> np.ndarray:
    """The predicted relative depth error (fraction) of sample points p (N, 3) (projector frame, mm) on lines of
    slope `slope` (N,) (projector image: y = slope·x + c) with δ = delta_px across their line (module doc).
    K_proj (3, 3) the projector's intrinsics, t_proj_cam (3,) the camera centre (mm). inf where the line runs
    exactly along the epipolar line."""
    p = np.asarray(p, np.float64)
    z = p[:, 2]
    x = p[:, 0] / z
    y = p[:, 1] / z
    fx, skew, cx, fy, cy = K_proj[0, 0], K_proj[0, 1], K_proj[0, 2], K_proj[1, 1], K_proj[1, 2]
    u = fx * x + skew * y + cx
    v = fy * y + cy
    e = K_proj @ np.asarray(t_proj_cam, np.float64)  # the epipole (homogeneous)
    # the epipolar line's direction at (u, v): towards the epipole (e_xy − q·e_z; a direction when e_z = 0)
    du = e[0] - u * e[2]
    dv = e[1] - v * e[2]
    nd = np.hypot(du, dv)
    s = np.asarray(slope, np.float64)
    sin_t = np.abs(du * s - dv) / (nd * np.hypot(1.0, s))
    # G: the camera ray through p, d unit; dq/dλ of its projection (projector px per mm along the ray)
    d = p - np.asarray(t_proj_cam, np.float64)
    d /= np.linalg.norm(d, axis=1)[:, None]
    gx = (d[:, 0] - x * d[:, 2]) / z
    gy = (d[:, 1] - y * d[:, 2]) / z
    g_u = fx * gx + skew * gy
    g_v = fy * gy
    with np.errstate(divide="ignore", invalid="ignore"):
        return delta_px / (np.hypot(g_u, g_v) * sin_t * np.linalg.norm(p, axis=1))


def frame_noise_px(junction_residual: np.ndarray, floor_px: float, *, min_junctions: int = 20) -> float:
    """δ of `predicted_error`: max(1.4826·median |r|, floor_px) over the labelled junctions' epipolar residuals
    (projector px, NaN where none); floor_px alone with fewer than min_junctions of them."""
    r = np.abs(np.asarray(junction_residual, np.float64))
    r = r[np.isfinite(r)]
    if len(r) < min_junctions:
        return float(floor_px)
    return max(1.4826 * float(np.median(r)), float(floor_px))


@njit
def _k_imprecise(K, t, n1, n2, p, family, delta_px, limit, out, src, n_obs, q, ofam, segment, seg_centre, seg_dir, junction,
                 q_junction, junction_dir, scale1, scale2, own_cap):
    """`predicted_error` > limit (fraction) for every row of p (N, 3) with family > 0 (slope n1 for 1, n2 for 2);
    writes out (N,) bool, returns how many are flagged. The same quantities compared squared and multiplied out
    (no square root or division but x/z, y/z): err ≤ limit ⟺ δ²·|e_dir|²·(1 + s²)·z²·|d|² ≤
    limit²·|g|²·(e_dir × line)²·|p|², with d = p − t not normalised and g its projection's derivative times z·|d|. A
    line exactly along the epipolar line (err = inf), and anything not finite, is flagged.

    Decision 0151 (src (N,) not empty): a row that δ does not flag is judged again at its sample's own offset
    (as `_k_own_offsets` for sample src[a]; the arguments from q on are `_own_args`'), at most own_cap, where an offset of
    own_cap would flag it (elsewhere its own offset cannot: the gathers are skipped)."""
    fx, skew, cx, fy, cy = K[0, 0], K[0, 1], K[0, 2], K[1, 1], K[1, 2]
    t0, t1, t2 = t[0], t[1], t[2]
    e0 = K[0, 0] * t0 + K[0, 1] * t1 + K[0, 2] * t2
    e1 = K[1, 0] * t0 + K[1, 1] * t1 + K[1, 2] * t2
    e2 = K[2, 0] * t0 + K[2, 1] * t1 + K[2, 2] * t2
    h1 = 1.0 + n1 * n1
    h2 = 1.0 + n2 * n2
    d2l = delta_px * delta_px
    has_own = src.shape[0] > 0
    cap2 = own_cap * own_cap
    l2 = limit * limit
    n_bad = 0
    for a in range(p.shape[0]):
        f = family[a]
        if f <= 0:
            out[a] = False
            continue
        s = n1 if f == 1 else n2
        hs = h1 if f == 1 else h2
        px = float(p[a, 0])
        py = float(p[a, 1])
        pz = float(p[a, 2])
        x = px / pz
        y = py / pz
        u = fx * x + skew * y + cx
        v = fy * y + cy
        du = e0 - u * e2
        dv = e1 - v * e2
        c = du * s - dv
        d0 = px - t0
        d1 = py - t1
        d2 = pz - t2
        gx = d0 - x * d2
        gy = d1 - y * d2
        g_u = fx * gx + skew * gy
        g_v = fy * gy
        lhs1 = (du * du + dv * dv) * hs * (pz * pz) * (d0 * d0 + d1 * d1 + d2 * d2)  # at δ = 1 px
        rhs = l2 * (g_u * g_u + g_v * g_v) * (c * c) * (px * px + py * py + pz * pz)
        bad = not (d2l * lhs1 <= rhs)
        if not bad and has_own and cap2 * lhs1 > rhs:
            # decision 0151: the sample's own offset from its line's local fit (as `_k_own_offsets`), at most own_cap
            # (compared squared: bad ⟺ min(x², cap²·|e|²)·lhs1 > rhs·|e|², x the cross product with the fit's direction e
            # times the scale)
            n = src[a]
            if 0 <= n < n_obs:
                sg = segment[n]
                if sg >= 0:
                    ox = seg_centre[sg, 0]
                    oy = seg_centre[sg, 1]
                    ex = seg_dir[sg, 0]
                    ey = seg_dir[sg, 1]
                else:
                    j = junction[n]
                    if j >= 0:
                        ox = q_junction[j, 0]
                        oy = q_junction[j, 1]
                        ex = junction_dir[j, f - 1, 0]  # the row's family is its sample's
                        ey = junction_dir[j, f - 1, 1]
                    else:
                        ox = oy = ex = ey = 0.0
                ne2 = ex * ex + ey * ey
                x = ((q[n, 0] - ox) * ey - (q[n, 1] - oy) * ex) * (scale1 if f == 1 else scale2)
                bad = min(x * x, cap2 * ne2) * lhs1 > rhs * ne2  # False where there is no fit (ne2 = 0) or x is NaN
        out[a] = bad
        n_bad += bad
    return n_bad


def imprecise_samples(K_proj: np.ndarray, t_proj_cam: np.ndarray, n1: float, n2: float, p: np.ndarray, family: np.ndarray,
                      delta_px: float, options: SheetPrecisionOptions, own: tuple | None = None) -> np.ndarray:
    """(N,) bool: the sample points p (N, 3) of family (N,) (1: i-lines, slope n1; 2: j-lines, slope n2; 0, a
    junction, is never flagged) whose `predicted_error` exceeds options.max_error_pct % (compiled, `_k_imprecise`).
    own (decision 0151; None: none): (src, q, obs, scale, cap_px) — a row's δ is max(delta_px, min(its sample's
    `own_offsets_px`, cap_px)), src (N,) each row's sample."""
    fam = np.ascontiguousarray(family)
    out = np.zeros(len(fam), np.bool_)
    if len(fam) == 0 or not options.enabled:
        return out
    _k_imprecise(np.ascontiguousarray(K_proj, np.float64), np.ascontiguousarray(t_proj_cam, np.float64), float(n1), float(n2),
                 np.ascontiguousarray(p), fam, float(delta_px), float(options.max_error_pct) / 100.0, out,
                 *_NO_OWN if own is None else (np.ascontiguousarray(own[0], np.int64), *_own_args(own[1], own[2], own[3]), float(own[4])))
    return out


_NO_OWN = (np.zeros(0, np.int64), 0, np.zeros((1, 2)), np.zeros(1, np.int8), np.zeros(1, np.int64), np.zeros((1, 2)), np.zeros((1, 2)),
           np.zeros(1, np.int64), np.zeros((1, 2)), np.zeros((1, 2, 2)), 1.0, 1.0, 0.0)


@njit
def _k_across_scale(q_junction, junction_dir, labels, edges, edge_family, edge_delta, offsets, index_min, h1, h2, unlabelled,
                    min_edges):
    """`across_line_scale` (2,): for each edge along a line of family g between junctions on neighbouring lines of the
    other family f (both labelled), the spacing of those two f-lines across them in the projector, |c_b − c_a| /
    sqrt(1 + n_f²), over the edge's distance across the f-line in the camera, |(q_b − q_a) × t_f| (t_f the fitted
    f-line direction at a); the median per family, NaN with fewer than min_edges edges."""
    E = edges.shape[0]
    L = offsets.shape[1]
    out = np.full(2, np.nan)
    ratio = np.empty(E)
    for f in (1, 2):
        h = h1 if f == 1 else h2
        m = 0
        for e in range(E):
            if edge_family[e] == f or abs(edge_delta[e, f - 1]) != 1:
                continue
            a = edges[e, 0]
            b = edges[e, 1]
            la = labels[a, f - 1]
            lb = labels[b, f - 1]
            if la == unlabelled or lb == unlabelled:
                continue
            ia = la - index_min
            ib = lb - index_min
            if ia < 0 or ib < 0 or ia >= L or ib >= L:
                continue
            tx = junction_dir[a, f - 1, 0]
            ty = junction_dir[a, f - 1, 1]
            nt = np.sqrt(tx * tx + ty * ty)
            cam = abs((q_junction[b, 0] - q_junction[a, 0]) * ty - (q_junction[b, 1] - q_junction[a, 1]) * tx)
            if not (nt > 0 and cam > 0):
                continue
            ratio[m] = abs(offsets[f - 1, ib] - offsets[f - 1, ia]) / h / (cam / nt)
            m += 1
        if m >= min_edges:
            out[f - 1] = np.median(ratio[:m])
    return out


def across_line_scale(obs, labels: np.ndarray, line_offsets_px: np.ndarray, index_min: int, n1: float, n2: float,
                      unlabelled: int, *, min_edges: int = 10) -> np.ndarray:
    """(2,) projector px across a line of family 1 / 2 per camera px across it, this frame's median over its
    labelled edges (`_k_across_scale`); NaN for a family with fewer than min_edges such edges."""
    if len(obs.edges) == 0 or obs.junction_dir is None or len(obs.junction_dir) == 0:
        return np.full(2, np.nan)
    return _k_across_scale(np.ascontiguousarray(obs.q_junction, np.float64), np.ascontiguousarray(obs.junction_dir, np.float64),
                           np.ascontiguousarray(labels), np.ascontiguousarray(obs.edges), np.ascontiguousarray(obs.edge_family),
                           np.ascontiguousarray(obs.edge_delta), np.ascontiguousarray(line_offsets_px, np.float64), int(index_min),
                           float(np.hypot(1.0, n1)), float(np.hypot(1.0, n2)), int(unlabelled), int(min_edges))


@njit
def _k_own_offsets(src, n_obs, q, family, segment, seg_centre, seg_dir, junction, q_junction, junction_dir, scale1, scale2, out):
    """`own_offsets_px`' kernel: row a's sample n = src[a] (the same arithmetic as in `_k_imprecise`, written out in
    both: a compiled helper with these many array arguments cost ten times the loop itself)."""
    for a in range(src.shape[0]):
        out[a] = 0.0
        n = src[a]
        if n < 0 or n >= n_obs:
            continue
        f = family[n]
        if f != 1 and f != 2:
            continue
        sg = segment[n]
        if sg >= 0:
            cx = seg_centre[sg, 0]
            cy = seg_centre[sg, 1]
            tx = seg_dir[sg, 0]
            ty = seg_dir[sg, 1]
        else:
            j = junction[n]
            if j < 0:
                continue
            cx = q_junction[j, 0]
            cy = q_junction[j, 1]
            tx = junction_dir[j, f - 1, 0]
            ty = junction_dir[j, f - 1, 1]
        nt = np.sqrt(tx * tx + ty * ty)
        if not nt > 0:
            continue
        v = abs((q[n, 0] - cx) * ty - (q[n, 1] - cy) * tx) / nt * (scale1 if f == 1 else scale2)
        if v == v:
            out[a] = v


def _own_args(q: np.ndarray, obs, scale: np.ndarray) -> tuple:
    """The observation's arrays `_k_own_offsets` reads (contiguous; placeholders where obs has no junctions)."""
    jd = obs.junction_dir if obs.junction_dir is not None and len(obs.junction_dir) else np.zeros((1, 2, 2))
    qj = obs.q_junction if len(obs.q_junction) else np.zeros((1, 2))
    return (len(obs.q), np.ascontiguousarray(q, np.float64), np.ascontiguousarray(obs.family), np.ascontiguousarray(obs.segment),
            np.ascontiguousarray(obs.segment_centre, np.float64), np.ascontiguousarray(obs.segment_dir, np.float64),
            np.ascontiguousarray(obs.junction), np.ascontiguousarray(qj, np.float64), np.ascontiguousarray(jd, np.float64),
            float(scale[0]), float(scale[1]))


def own_offsets_px(src: np.ndarray, q: np.ndarray, obs, scale: np.ndarray) -> np.ndarray:
    """(N,) projector px: for each row, its sample n = src[row] of the observation obs (q (≥ P, 2) the positions
    triangulated, `SampleLabels.q`), the distance of q[n] from its line's local fit in the camera — its segment's
    straight fit (obs.segment_centre / segment_dir) or, for a sample a junction's arm holds, that arm's fitted line
    through the junction (obs.q_junction / junction_dir) — times scale[family − 1] (`across_line_scale`). 0 where
    there is none (src < 0 or ≥ P: a junction, a crossing point; no segment nor junction; scale NaN).
    `imprecise_samples` computes the same inside its pass, for the rows where it can matter."""
    src = np.ascontiguousarray(src, np.int64)
    out = np.zeros(len(src))
    if len(src):
        _k_own_offsets(src, *_own_args(q, obs, scale), out)
    return out
