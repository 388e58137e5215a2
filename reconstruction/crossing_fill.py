"""Points through the crossings of labelled lines (decision 0086).

Where two lines cross, extraction leaves a gap in each: the crossing's core has no ridge samples (both
Hessian eigenvalues are negative there) and the label stage drops the samples of the mixing zone around it
unless a labelled junction or two facing pieces of one index hold them (docs/reconstruction.md, "Line
samples: which line", steps 1 and 6). When σ is large against the junction step (the paper rigs, lines
~12 camera px wide) these gaps are a large share of every line.

`fill_crossings` adds points in such a gap when the line is labelled with the same index k on both sides
of it and the two sides are one line on one surface:

1. The labelled samples of each line (family f, index k) are ordered along the family's mean direction;
   two consecutive ones farther apart than `min_gap_cells` sampling steps and at most the longest gap a
   crossing leaves (`continuation.crossing_gap_px` plus one step) open a gap.
2. Each side's `anchor` samples nearest the gap (consecutive, each step at most 2 cells) are fitted with a
   straight line. The two tangents must agree within `max_turn_deg` and meet at the gap's middle within
   `lateral_px` (per sampling step): along one light sheet the image position across the line is a
   function of depth, so a line that continues on another surface is offset sideways (the
   depth-continuity test of the traces and of the continuation, decisions 0045, 0072).
3. The gap must hold a crossing on that surface: a labelled junction with index k on this family, on the
   fitted curve; or a straight run of the other family's samples through the gap whose intersection with
   the curve, triangulated on light sheet k, lands within `residual_px` projector px of a line of the
   other family, inside the depth range (the crossing check of step 6, decision 0052). A gap at a
   silhouette or a shadow has no such crossing and stays empty.
4. Points are placed one sampling step apart on the blend of the two tangents (weight moving linearly
   from one side to the other: the straight chord for a straight line, the low-order curve for a gently
   bending one). Each point is then, like every line sample, the camera ray ∩ light sheet k.

The paper labeller's output is left alone (the pipeline calls this only for the default labeller).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from reconstruction.continuation import crossing_gap_px
from reconstruction.rigmodel import UNLABELLED, RigModel


@dataclass(frozen=True)
class CrossingFillOptions:
    """enabled: add the points (else nothing is added). min_gap_cells: a gap between consecutive labelled
    samples of one line is at least this many sampling steps. anchor: samples fitted on each side.
    max_turn_deg: the two sides' directions may differ by at most this. lateral_px: the two tangents must
    meet at the gap's middle within this (camera px per sampling step). residual_px: the crossing,
    triangulated on the line's light sheet, must lie this close to a line of the other family (projector
    px). mix_sigma, trim_sigma, min_angle_deg: the longest gap a crossing leaves (as the label stage's
    TraceOptions: mixing zone, trims, crossings down to this angle)."""

    enabled: bool = True
    min_gap_cells: float = 1.6
    anchor: int = 4
    max_turn_deg: float = 12.0
    lateral_px: float = 0.5
    residual_px: float = 1.0
    mix_sigma: float = 2.0
    trim_sigma: float = 1.0
    min_angle_deg: float = 45.0


@dataclass(frozen=True, eq=False)
class CrossingPoints:
    """The added samples: q (N, 2) camera px, family (N,) 1 or 2, index (N,) float line index, junction
    (N,) int (the junction whose index the gap's first side took, −1 where none); stats: counts."""

    q: np.ndarray
    family: np.ndarray
    index: np.ndarray
    junction: np.ndarray
    stats: dict


def _empty(stats: dict) -> CrossingPoints:
    return CrossingPoints(np.zeros((0, 2)), np.zeros(0, np.intp), np.zeros(0), np.zeros(0, np.int64), stats)


def fill_crossings(
    q: np.ndarray,
    family: np.ndarray,
    index: np.ndarray,
    junction: np.ndarray,
    *,
    q_samples: np.ndarray,
    family_samples: np.ndarray,
    q_junction: np.ndarray,
    junction_labels: np.ndarray,
    model: RigModel,
    sigma_px: float,
    cell_px: float,
    depth_range_mm: tuple[float, float],
    options: CrossingFillOptions = CrossingFillOptions(),
) -> CrossingPoints:
    """Points in the crossings' gaps of lines labelled with one index on both sides (module doc).

    q (P, 2), family (P,), index (P,) (NaN: unlabelled), junction (P,): the label stage's samples
    (`SampleLabels.q`, the observation's family, `SampleLabels.index`, `.junction`). q_samples (S, 2),
    family_samples (S,): every extracted sample (the other family's run through a gap). q_junction (M, 2),
    junction_labels (M, 2) (UNLABELLED where none). sigma_px: the extraction's smoothing; cell_px: its
    sampling step (1, or 2 on a half-resolution image). Camera px throughout."""
    stats = {"crossing_gaps": 0, "crossing_gaps_filled": 0, "samples_crossing_filled": 0}
    if not options.enabled:
        return _empty(stats)
    q = np.asarray(q, np.float64).reshape(-1, 2)
    fam = np.asarray(family).astype(np.intp).reshape(-1)
    idx = np.asarray(index, np.float64).reshape(-1)
    ok = np.isfinite(idx) & np.isfinite(q).all(axis=1) & ((fam == 1) | (fam == 2))
    sel = np.flatnonzero(ok)
    if len(sel) < 2 * options.anchor + 2:
        return _empty(stats)
    ql, fl, kl = q[sel], fam[sel], idx[sel].astype(np.int64)
    jl = np.asarray(junction, np.int64).reshape(-1)[sel]
    # 1. order each line's labelled samples along its family's direction (the rig's prediction)
    t = np.empty(len(sel))
    for f in (1, 2):
        m = fl == f
        t[m] = ql[m] @ _family_direction(model, f)
    order = np.lexsort((t, kl, fl))
    ql, fl, kl, jl, t = ql[order], fl[order], kl[order], jl[order], t[order]
    same = (fl[1:] == fl[:-1]) & (kl[1:] == kl[:-1])
    step = np.hypot(*(ql[1:] - ql[:-1]).T)
    gap_max = cell_px + crossing_gap_px(sigma_px, mix_sigma=options.mix_sigma, trim_sigma=options.trim_sigma,
                                        min_angle_deg=options.min_angle_deg)
    a = np.flatnonzero(same & (step > options.min_gap_cells * cell_px) & (step <= gap_max))
    stats["crossing_gaps"] = int(len(a))
    if len(a) == 0:
        return _empty(stats)
    n = len(ql)
    A = options.anchor
    # 2. each side's anchors: A consecutive samples of the same line, each step at most 2 cells
    offs_a = -np.arange(A)  # a, a-1, ...
    offs_b = 1 + np.arange(A)  # b = a+1, a+2, ...
    ia = a[:, None] + offs_a[None, :]
    ib = a[:, None] + offs_b[None, :]
    good = (ia[:, -1] >= 0) & (ib[:, -1] < n)
    a, ia, ib = a[good], ia[good], ib[good]
    if len(a) == 0:
        return _empty(stats)
    key_ok = np.ones(len(a), bool)
    for w in (ia, ib):
        key_ok &= ((fl[w] == fl[a][:, None]) & (kl[w] == kl[a][:, None])).all(axis=1)
        seg = np.hypot(*(ql[w[:, 1:]] - ql[w[:, :-1]]).transpose(2, 0, 1))
        key_ok &= (seg <= 2.0 * cell_px + 1e-9).all(axis=1)
    a, ia, ib = a[key_ok], ia[key_ok], ib[key_ok]
    if len(a) == 0:
        return _empty(stats)
    pa, pb = ql[a], ql[a + 1]
    chord = pb - pa
    L = np.hypot(chord[:, 0], chord[:, 1])
    u = chord / L[:, None]
    v = np.column_stack([-u[:, 1], u[:, 0]])
    # local coordinates (s along the chord from pa, r across)
    def local(w):
        d = ql[w] - pa[:, None, :]
        return np.einsum("gkc,gc->gk", d, u), np.einsum("gkc,gc->gk", d, v)

    sa, ra = local(ia)
    sb, rb = local(ib)
    ka, ca = _line_fit(sa, ra)  # r = ka*s + ca
    kb, cb = _line_fit(sb, rb)
    turn = np.abs(np.arctan(ka) - np.arctan(kb))
    s_mid = 0.5 * L
    lateral = np.abs((ka * s_mid + ca) - (kb * s_mid + cb))
    fit_ok = np.isfinite(ka) & np.isfinite(kb) & (turn <= np.deg2rad(options.max_turn_deg)) & (lateral <= options.lateral_px * cell_px)
    # the anchors must lie on their fits (straight runs; a ragged end is not a tangent)
    ra_res = np.abs(ra - (ka[:, None] * sa + ca[:, None])).max(axis=1)
    rb_res = np.abs(rb - (kb[:, None] * sb + cb[:, None])).max(axis=1)
    fit_ok &= (ra_res <= options.lateral_px * cell_px) & (rb_res <= options.lateral_px * cell_px)
    g = np.flatnonzero(fit_ok)
    if len(g) == 0:
        return _empty(stats)
    a, pa, u, v, L, ka, ca, kb, cb = a[g], pa[g], u[g], v[g], L[g], ka[g], ca[g], kb[g], cb[g]
    f_g, k_g = fl[a], kl[a]

    # 3. a crossing in the gap: a labelled junction of this line on the curve, or the other family's run
    crossing = np.zeros(len(a), bool)
    qj = np.asarray(q_junction, np.float64).reshape(-1, 2)
    lab = np.asarray(junction_labels, np.int64).reshape(-1, 2)
    labelled = np.flatnonzero(lab[:, 0] != UNLABELLED)
    if len(labelled):
        from scipy.spatial import cKDTree

        mid = np.array([curve_one(pa[gi], u[gi], v[gi], L[gi], ka[gi], ca[gi], kb[gi], cb[gi], 0.5 * L[gi]) for gi in range(len(a))])
        hits = cKDTree(qj[labelled]).query_ball_point(mid, r=0.5 * L + cell_px)
        for gi, hs in enumerate(hits):
            for h in hs:
                jj = labelled[h]
                if lab[jj, f_g[gi] - 1] != k_g[gi]:
                    continue
                s = float((qj[jj] - pa[gi]) @ u[gi])
                if not 0.0 < s < L[gi]:
                    continue
                on = curve_one(pa[gi], u[gi], v[gi], L[gi], ka[gi], ca[gi], kb[gi], cb[gi], s)
                if np.hypot(*(qj[jj] - on)) <= options.lateral_px * cell_px * 2.0:
                    crossing[gi] = True
                    break
    rest = np.flatnonzero(~crossing)
    if len(rest):
        crossing[rest] = _other_family_crossing(
            rest, pa, u, v, L, ka, ca, kb, cb, f_g, k_g, q_samples, family_samples, model, sigma_px, cell_px,
            depth_range_mm, options)
    stats["crossing_gaps_filled"] = int(crossing.sum())
    g = np.flatnonzero(crossing)
    if len(g) == 0:
        return _empty(stats)
    # 4. points one sampling step apart strictly inside the gap
    n_pts = np.maximum(np.ceil(L[g] / cell_px - 1e-9).astype(np.int64) - 1, 0)
    rep = np.repeat(np.arange(len(g)), n_pts)
    first = np.cumsum(n_pts) - n_pts
    step_no = np.arange(int(n_pts.sum())) - np.repeat(first, n_pts) + 1
    s = (step_no * (L[g] / (n_pts + 1))[rep])
    gg = g[rep]
    w = s / L[gg]
    r = (1.0 - w) * (ka[gg] * s + ca[gg]) + w * (kb[gg] * s + cb[gg])
    q_new = pa[gg] + s[:, None] * u[gg] + r[:, None] * v[gg]
    stats["samples_crossing_filled"] = int(len(q_new))
    return CrossingPoints(q_new, f_g[gg].astype(np.intp), k_g[gg].astype(np.float64), jl[a[gg]].astype(np.int64), stats)


def curve_one(pa, u, v, L, ka, ca, kb, cb, s: float) -> np.ndarray:
    """The gap's curve (module doc, step 4) at s (camera px along the chord from its first end)."""
    w = min(max(s / L, 0.0), 1.0)
    r = (1.0 - w) * (ka * s + ca) + w * (kb * s + cb)
    return pa + s * u + r * v


def _line_fit(s: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares r = k·s + c per row of s, r (G, K)."""
    sm = s.mean(axis=1)
    rm = r.mean(axis=1)
    ds = s - sm[:, None]
    sxx = (ds * ds).sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        k = (ds * (r - rm[:, None])).sum(axis=1) / sxx
    return k, rm - k * sm


def _family_direction(model: RigModel, family: int) -> np.ndarray:
    """A unit image direction of `family`'s lines for ordering samples along them: the principal axis of
    the rig's predicted directions over the camera (`RigModel.dir_cam`)."""
    d = np.asarray(model.dir_cam, np.float64)[..., family - 1, :].reshape(-1, 2)
    d = d[np.isfinite(d).all(axis=1)]
    w, V = np.linalg.eigh(d.T @ d)
    return V[:, 1]


def _other_family_crossing(rest, pa, u, v, L, ka, ca, kb, cb, f_g, k_g, q_samples, family_samples, model: RigModel,
                           sigma_px, cell_px, depth_range_mm, options: CrossingFillOptions) -> np.ndarray:
    """For gaps `rest`: whether the other family's samples run straight through the gap and cross the gap's
    curve at a point that, on light sheet k, lies within residual_px of a line of the other family inside
    the depth range (module doc, step 3)."""
    from scipy.spatial import cKDTree

    out = np.zeros(len(rest), bool)
    qs = np.asarray(q_samples, np.float64).reshape(-1, 2)
    fs = np.asarray(family_samples).reshape(-1)
    okq = np.isfinite(qs).all(axis=1)
    trees = {}
    for f in (1, 2):
        m = okq & (fs == f)
        trees[f] = (cKDTree(qs[m]), qs[m]) if m.any() else None
    c_q = np.full((len(rest), 2), np.nan)
    for n_, gi in enumerate(rest):
        other = 3 - int(f_g[gi])
        if trees[other] is None:
            continue
        tree, qo = trees[other]
        mid = curve_one(pa[gi], u[gi], v[gi], L[gi], ka[gi], ca[gi], kb[gi], cb[gi], 0.5 * L[gi])
        nb = tree.query_ball_point(mid, r=0.5 * L[gi] + sigma_px)
        if len(nb) < 4:
            continue
        P = qo[nb]
        c = P.mean(axis=0)
        d = P - c
        w, V = np.linalg.eigh(d.T @ d / len(P))
        if w[0] > (options.lateral_px * cell_px) ** 2:  # not one straight run
            continue
        e = V[:, 1]
        # intersection of the other family's run (c + μ e) with the gap's chord frame: solve for s where
        # the curve meets the run (two Newton steps from the chord's intersection)
        s = _intersect_s(c, e, pa[gi], u[gi], v[gi], L[gi], ka[gi], ca[gi], kb[gi], cb[gi])
        if s is None or not (0.0 < s < L[gi]):
            continue
        c_q[n_] = curve_one(pa[gi], u[gi], v[gi], L[gi], ka[gi], ca[gi], kb[gi], cb[gi], s)
    has = np.flatnonzero(np.isfinite(c_q[:, 0]))
    if len(has) == 0:
        return out
    gi = rest[has]
    _p, z, _k_other, dist = model.sheet_check(c_q[has], f_g[gi], k_g[gi])
    good = (dist <= options.residual_px) & (z >= depth_range_mm[0]) & (z <= depth_range_mm[1])
    out[has[good]] = True
    return out


def _intersect_s(c, e, pa, u, v, L, ka, ca, kb, cb) -> float | None:
    """s (along the chord) where the gap's curve meets the straight run c + μ·e, or None if parallel."""
    n = np.array([-e[1], e[0]])  # normal of the run
    s = 0.5 * L
    for _ in range(3):
        p = curve_one(pa, u, v, L, ka, ca, kb, cb, s)
        h = 1e-3
        dp = (curve_one(pa, u, v, L, ka, ca, kb, cb, s + h) - p) / h
        den = dp @ n
        if abs(den) < 1e-6:
            return None
        s = s - ((p - c) @ n) / den
    return float(s)
