"""Points through the crossings of labelled lines (decision 0086).

Where two lines cross, extraction leaves a gap in each: the crossing's core has no ridge samples (both
Hessian eigenvalues are negative there) and the label stage drops the samples of the mixing zone around it
unless a labelled junction or two facing pieces of one index hold them (docs/reconstruction.md, "Line
samples: which line", steps 1 and 6). When σ is large against the junction step (the paper rigs, lines
~12 camera px wide) these gaps are a large share of every line.

`fill_crossings` adds points in such a gap when the line is labelled with the same index k on both sides
of it and the two sides are one line on one surface:

1. The labelled samples of each line (family f, index k) are ordered along the family's direction (the
   principal axis of the rig's predicted directions); two consecutive ones farther apart than
   `min_gap_cells` sampling steps and at most the longest gap a crossing leaves
   (`continuation.crossing_gap_px` plus one step) open a gap.
2. Each side's `anchor` samples nearest the gap (same line, each step at most that longest gap: a side may
   span a neighbouring small gap) are fitted with a straight line; they must lie on it within `lateral_px`
   (per sampling step). The two tangents must agree within `max_turn_deg` and meet at the gap's middle
   within `lateral_px`: along one light sheet the image position across the line is a function of depth,
   so a line that continues on another surface is offset sideways (the depth-continuity test of the
   traces and of the continuation, decisions 0045, 0072).
3. The gap must hold a crossing on that surface: a labelled junction with index k on this family, on the
   gap's curve (within `lateral_px`), inside the gap or no farther from its nearer end than that
   crossing's mixing zone and trim reach along the line, (mix_sigma + trim_sigma)·σ / sin θ (θ from the
   junction's fitted directions); or a straight run of the other family's samples through the gap whose
   intersection with the curve, triangulated on light sheet k, lands within `residual_px` projector px of
   a line of the other family, inside the depth range (the crossing check of step 6, decision 0052). A gap
   at a silhouette or a shadow has no such crossing and stays empty.
4. Points are placed one sampling step apart on the blend of the two tangents (weight moving linearly
   from one side to the other: the straight chord for a straight line, the low-order curve for a gently
   bending one). Each point is then, like every line sample, the camera ray ∩ light sheet k.

The paper labeller's output is left alone (the pipeline calls this only for the default labeller).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from reconstruction._jit import njit
from reconstruction._label_kernels import sample_grid
from reconstruction.continuation import crossing_gap_px
from reconstruction.rigmodel import UNLABELLED, RigModel

_NO_TRACE = np.zeros(0, np.intp)  # sample_grid's trace positions are not needed here


@dataclass(frozen=True)
class CrossingFillOptions:
    """enabled: add the points (else nothing is added). min_gap_cells: a gap between consecutive labelled
    samples of one line is at least this many sampling steps. anchor: samples fitted on each side.
    max_turn_deg: the two sides' directions may differ by at most this. lateral_px: the two tangents must
    meet at the gap's middle within this, and each side's anchors lie on their line within this (camera px
    per sampling step). residual_px: the crossing, triangulated on the line's light sheet, must lie this
    close to a line of the other family (projector px). mix_sigma, trim_sigma, min_angle_deg: the longest
    gap a crossing leaves (as the label stage's TraceOptions: mixing zone, trims, crossings down to this
    angle in the image). require_crossing: off fills every gap that passes the tangent tests (for tests: a
    line that continues collinearly on another surface passes them; only the crossing check sees it)."""

    enabled: bool = True
    min_gap_cells: float = 1.6
    anchor: int = 4
    max_turn_deg: float = 12.0
    lateral_px: float = 0.5
    residual_px: float = 1.0
    mix_sigma: float = 2.0
    trim_sigma: float = 1.0
    min_angle_deg: float = 45.0
    require_crossing: bool = True


@dataclass(frozen=True, eq=False)
class CrossingPoints:
    """The added samples: q (N, 2) camera px, family (N,) 1 or 2, index (N,) float line index, junction
    (N,) int (the junction whose index the gap's first side took, −1 where none); stats: counts."""

    q: np.ndarray
    family: np.ndarray
    index: np.ndarray
    junction: np.ndarray
    stats: dict
    shared: FillShared | None = None


@dataclass(frozen=True, eq=False)
class FillShared:
    """What `fill_crossings` computed that decision 0099's one-sided fill needs again on the same frame:
    `inputs`, the arrays it was called with (q, family, index, q_samples, family_samples, q_junction,
    junction_labels; reused only for these very objects, unchanged), n = len(q); order: the labelled samples
    of q in order along their lines (`_k_order`, `_sorted_by_key`), key: their keys in that order, key_range:
    (smallest, largest line index, largest |position|) (`_k_order_range`); gcell: the bucket grids' cell
    (camera px); grids: `_k_grids`' output on that cell (None when `fill_crossings` stopped before building
    them). order_all: the order of q followed by the points `fill_crossings` returned (`points`: the very
    arrays q, family, index of its `CrossingPoints`), those points put in at their gaps (`_k_insert_order`,
    decision 0149): `order_with_appended`'s result for them, without its sort and merge; None where that
    insertion is not exact (the one-sided fill then calls `order_with_appended`). box: the lines' boxes of q
    (`_k_gaps`' running boxes on the model's index range, for the border fill's test "which lines come near the
    border"; None when a labelled sample's position is not finite: the border fill then walks the samples);
    box_kmin: the line index of its first column (the model's index_min). fam: the family of q as np.intp (the
    one-sided fill's, decision 0149)."""

    inputs: tuple
    n: int
    order: np.ndarray
    key: np.ndarray
    key_range: np.ndarray
    gcell: float
    grids: tuple | None
    order_all: np.ndarray | None = None
    points: tuple = ()
    box: np.ndarray | None = None
    box_kmin: int = 0
    fam: np.ndarray | None = None


def _empty(stats: dict, shared: FillShared | None = None) -> CrossingPoints:
    return CrossingPoints(np.zeros((0, 2)), np.zeros(0, np.intp), np.zeros(0), np.zeros(0, np.int64), stats, shared)


def grid_cell_px(gap_max: float, sigma_px: float, cell_px: float) -> float:
    """The bucket grids' cell of the crossing searches (camera px): the longest gap a crossing leaves, at
    least 4σ and two sampling steps (a search reads the 3×3 cells around a point)."""
    return max(gap_max, 4.0 * sigma_px, 2.0 * cell_px)


def _gap_max_px(sigma_px: float, cell_px: float, options: CrossingFillOptions) -> float:
    """The longest crossing gap `fill_crossings` bridges (camera px)."""
    return cell_px + crossing_gap_px(sigma_px, mix_sigma=options.mix_sigma, trim_sigma=options.trim_sigma,
                                     min_angle_deg=options.min_angle_deg)


def fill_grid_cell_px(sigma_px: float, cell_px: float, options: CrossingFillOptions) -> float:
    """`fill_crossings`' bucket-grid cell (camera px) for these options (`grid_cell_px` of the longest gap)."""
    return grid_cell_px(_gap_max_px(sigma_px, cell_px, options), sigma_px, cell_px)


def family_grid(q_samples: np.ndarray, family_samples: np.ndarray, cell_px: float) -> tuple:
    """Every extracted sample's bucket grid by family (`_family_grid`: x0, y0, gw, gh, start, mid, items) on
    cells cell_px wide. Needs no label: the pipeline builds it in the extraction stage and hands it to
    `fill_crossings` (`grids`; decision 0115)."""
    qs = np.ascontiguousarray(q_samples, np.float64).reshape(-1, 2)
    fs = np.ascontiguousarray(np.asarray(family_samples).reshape(-1), np.intp)
    return _family_grid(qs, fs, float(cell_px))


def fill_crossings(
    q: np.ndarray,
    family: np.ndarray,
    index: np.ndarray,
    junction: np.ndarray,
    *,
    q_samples: np.ndarray,
    family_samples: np.ndarray,
    q_junction: np.ndarray,
    junction_dir: np.ndarray,
    junction_labels: np.ndarray,
    model: RigModel,
    sigma_px: float,
    cell_px: float,
    depth_range_mm: tuple[float, float],
    options: CrossingFillOptions = CrossingFillOptions(),
    grids: dict | None = None,
) -> CrossingPoints:
    """Points in the crossings' gaps of lines labelled with one index on both sides (module doc).

    q (P, 2), family (P,), index (P,) (NaN: unlabelled), junction (P,): the label stage's samples
    (`SampleLabels.q`, the observation's family, `SampleLabels.index`, `.junction`). q_samples (S, 2),
    family_samples (S,): every extracted sample (the other family's run through a gap). q_junction (M, 2),
    junction_dir (M, 2, 2) (the fitted i- and j-line directions), junction_labels (M, 2) (UNLABELLED where
    none). sigma_px: the extraction's smoothing; cell_px: its
    sampling step (1, or 2 on a half-resolution image). Camera px throughout. Compiled (`_k_gaps`). grids:
    bucket grids built before the labels (`labelling.SamplePrep.grids`): the one under ("family", cell), cell
    `fill_grid_cell_px(sigma_px, cell_px, options)`, must be `family_grid(q_samples, family_samples, cell)`
    and is used instead of building it again (decision 0115)."""
    stats = {"crossing_gaps": 0, "crossing_gaps_filled": 0, "samples_crossing_filled": 0, "crossing_gaps_rejected": {}}
    if not options.enabled:
        return _empty(stats)
    inputs = (q, family, index, q_samples, family_samples, q_junction, junction_labels)
    q = np.ascontiguousarray(q, np.float64).reshape(-1, 2)
    fam = np.ascontiguousarray(np.asarray(family).reshape(-1), np.intp)
    idx = np.ascontiguousarray(index, np.float64).reshape(-1)
    # 1. each line's labelled samples in order along its family's direction (the rig's prediction)
    d1, d2 = _family_directions(model)
    kb = int(model.index_min)
    sel, key, key_range, _box, odd = _k_order_range_box(q, fam, idx, d1, d2, kb, 0)
    order, key_sorted = _sorted_with_keys(sel, key)
    gap_max = _gap_max_px(sigma_px, cell_px, options)
    gcell = grid_cell_px(gap_max, sigma_px, cell_px)
    if len(order) < 2 * options.anchor + 2:
        return _empty(stats, FillShared(inputs, len(q), order, key_sorted, key_range, gcell, None, fam=fam))
    lab = np.ascontiguousarray(junction_labels, np.int64).reshape(-1, 2)
    qj = np.ascontiguousarray(q_junction, np.float64).reshape(-1, 2)
    jdir = np.ascontiguousarray(junction_dir, np.float64).reshape(-1, 2, 2)
    qs = np.ascontiguousarray(q_samples, np.float64).reshape(-1, 2)
    fs = fam if family_samples is family else np.ascontiguousarray(np.asarray(family_samples).reshape(-1), np.intp)
    fgrid = None if grids is None else grids.get(("family", float(gcell)))
    if fgrid is None:
        grids = _k_grids(qj, lab, qs, fs, float(gcell))
    else:
        grids = _k_junction_grid(qj, lab, float(gcell)) + tuple(fgrid)
    n_gaps, gaps, acc, c_q, why, gp, box = _k_gaps(
        q, fam, idx, order, qj, jdir, lab, qs, *grids, float(gcell), float(cell_px), float(sigma_px),
        float(options.min_gap_cells * cell_px), float(gap_max), float((options.mix_sigma + options.trim_sigma) * sigma_px),
        int(options.anchor), float(np.deg2rad(options.max_turn_deg)),
        float(options.lateral_px * cell_px), kb, int(model.index_max) - kb + 1)
    shared = FillShared(inputs, len(q), order, key_sorted, key_range, gcell, grids, box=box if odd == 0 else None, box_kmin=kb, fam=fam)
    stats["crossing_gaps"] = int(n_gaps)
    stats["crossing_gaps_rejected"] = {"anchors_missing": int(why[0]), "anchors_broken": int(why[1]), "anchors_crooked": int(why[2]),
                                       "turn": int(why[3]), "lateral": int(why[4]), "no_crossing": 0}
    G = len(acc)
    if G == 0:
        return _empty(stats, shared)
    # 3. (second half) the other family's crossings, on light sheet k
    chk = np.flatnonzero(~acc & np.isfinite(c_q[:, 0]))
    if len(chk):
        a_chk = gaps[chk, 0].astype(np.intp)
        _p, z, _k_other, dist = model.sheet_check(c_q[chk], fam[a_chk], idx[a_chk].astype(np.intp))
        acc[chk] = (dist <= options.residual_px) & (z >= depth_range_mm[0]) & (z <= depth_range_mm[1])
    if not options.require_crossing:
        acc[:] = True
    g = np.flatnonzero(acc)
    stats["crossing_gaps_filled"] = int(len(g))
    stats["crossing_gaps_rejected"]["no_crossing"] = int(G - len(g))
    if len(g) == 0:
        return _empty(stats, shared)
    # 4. points one sampling step apart strictly inside the gap, on the blend of the two tangents
    q_new, f_new, k_new, j_new = _k_points(q, fam, idx, np.ascontiguousarray(junction, np.int64).reshape(-1), gaps, acc, float(cell_px))
    stats["samples_crossing_filled"] = int(len(q_new))
    # the order of q and these points, for the one-sided fill (decision 0149): each gap's points put in after its
    # first sample, checked against the keys
    order_all, ok = _k_insert_order(order, key_sorted, key_range, gp, gaps, acc, float(cell_px), q_new, f_new, k_new, len(q), d1, d2)
    shared = replace(shared, order_all=order_all if ok else None, points=(q_new, f_new, k_new))
    return CrossingPoints(q_new, f_new, k_new, j_new, stats, shared)


@njit
def _k_insert_order(order, key, key_range, gp, gaps, acc, cell, q_new, f_new, k_new, n0, d1, d2):
    """`order_with_appended` for the points `_k_points` made (q_new, f_new, k_new; ids from n0 on) without a sort:
    each accepted gap's points (in `_k_points`' order) go after the gap's first sample, order[gp[g]]. Returns that
    order and ok: True when every point takes part in the order and lies inside key_range (`_k_appended_keys`'
    test) and the keys of the result (the old ones `key`, the new ones by `_order_key`) increase strictly. Then it
    is the one order by key, the merge `order_with_appended` returns; else (ok False) the caller sorts."""
    kmin = key_range[0]
    kmax = key_range[1]
    tmax = key_range[2]
    span = 2.0 * (tmax + 1.0)
    n = order.shape[0]
    m = q_new.shape[0]
    out = np.empty(n + m, np.intp)
    # the old keys increase strictly (one tight pass); then between two gaps the old order is copied as it is and
    # only the keys around each gap's points are compared
    for p in range(1, n):
        if not key[p] > key[p - 1]:
            return out, False
    o = 0
    p = 0
    j = 0
    for g in range(gaps.shape[0]):
        if not acc[g]:
            continue
        n_pts = _n_gap_points(gaps[g, 3], cell)
        if n_pts == 0:
            continue
        pg = gp[g]
        if pg < p or pg >= n:
            return out, False
        c = pg + 1 - p
        out[o:o + c] = order[p:pg + 1]
        o += c
        p = pg + 1
        last = key[pg]
        for _ in range(n_pts):
            if j >= m:
                return out, False
            f = f_new[j]
            k = k_new[j]
            if not ((f == 1 or f == 2) and np.isfinite(k) and np.isfinite(q_new[j, 0]) and np.isfinite(q_new[j, 1])):
                return out, False
            if f == 1:
                t = q_new[j, 0] * d1[0] + q_new[j, 1] * d1[1]
            else:
                t = q_new[j, 0] * d2[0] + q_new[j, 1] * d2[1]
            if k < kmin or k > kmax or abs(t) > tmax:
                return out, False
            kj = _order_key(f, k, t, kmin, kmax, span)
            if not kj > last:
                return out, False
            last = kj
            out[o] = n0 + j
            o += 1
            j += 1
        if p < n and not key[p] > last:
            return out, False
    out[o:] = order[p:]
    return out, j == m


@njit(inline="always")
def _n_gap_points(L, cell):
    """The points `_k_points` puts in a gap of length L: one sampling step apart, strictly inside."""
    return max(int(math.ceil(L / cell - 1e-9)) - 1, 0)


@njit
def _k_grids(qj, lab, qs, fs, gcell):
    """The two bucket grids of the crossing searches (decisions 0086, 0099), cell gcell: the labelled
    junctions' (`sample_grid` of qj where lab[:, 0] is not UNLABELLED: x0, y0, gw, gh, start, items) and
    every extracted sample's, split by family (`_family_grid`: x0, y0, gw, gh, start, mid, items)."""
    jkeep = np.empty(qj.shape[0], np.bool_)
    for j in range(qj.shape[0]):
        jkeep[j] = lab[j, 0] != UNLABELLED
    jx0, jy0, jgw, jgh, jstart, jitems, _ = sample_grid(qj, jkeep, _NO_TRACE, gcell)
    sx0, sy0, sgw, sgh, sstart, smid, sitems = _family_grid(qs, fs, gcell)
    return jx0, jy0, jgw, jgh, jstart, jitems, sx0, sy0, sgw, sgh, sstart, smid, sitems


@njit
def _k_junction_grid(qj, lab, gcell):
    """`_k_grids`' first grid alone (the labelled junctions': x0, y0, gw, gh, start, items)."""
    jkeep = np.empty(qj.shape[0], np.bool_)
    for j in range(qj.shape[0]):
        jkeep[j] = lab[j, 0] != UNLABELLED
    jx0, jy0, jgw, jgh, jstart, jitems, _ = sample_grid(qj, jkeep, _NO_TRACE, gcell)
    return jx0, jy0, jgw, jgh, jstart, jitems


def _family_directions(model: RigModel) -> tuple[np.ndarray, np.ndarray]:
    """Unit image directions of the two families' lines for ordering samples along them: the principal
    axes of the rig's predicted directions over the camera (`RigModel.dir_cam`); once per rig."""
    key = id(model.dir_cam)
    hit = _DIRS.get(key)
    if hit is not None and hit[0] is model.dir_cam:
        return hit[1], hit[2]
    out = []
    for f in (1, 2):
        d = np.asarray(model.dir_cam, np.float64)[..., f - 1, :].reshape(-1, 2)
        d = d[np.isfinite(d).all(axis=1)]
        _w, V = np.linalg.eigh(d.T @ d)
        out.append(V[:, 1])
    if len(_DIRS) > 32:
        _DIRS.clear()
    _DIRS[key] = (model.dir_cam, out[0], out[1])
    return out[0], out[1]


_DIRS: dict = {}


@njit
def _k_order(q, fam, idx, d1, d2):
    """The labelled samples (finite index and position, family 1 or 2) and their sort key: family, line index
    and position along the family's direction (d1, d2) as one float, line-major (indices are integers and
    the positions span less than `span`). NumPy's argsort of the key is faster than numba's."""
    sel, key, _r = _k_order_range(q, fam, idx, d1, d2)
    return sel, key


@njit
def _k_order_range(q, fam, idx, d1, d2):
    """`_k_order`'s sel and key, and the key's range (3,): the smallest and largest line index and the
    largest |position| (an appended sample inside it gets its key from the same formula: `_k_appended_keys`)."""
    sel, key, rng, _box, _odd = _k_order_range_box(q, fam, idx, d1, d2, 0, 0)
    return sel, key, rng


@njit
def _k_order_range_box(q, fam, idx, d1, d2, box_kmin, box_nk):
    """`_k_order_range`, and in the same pass each line's box (decision 0149, for the border fill's
    `_k_mark_box`): box (2, box_nk, 4) [smallest x, largest x, smallest y, largest y] of the samples in the
    order of line (family f, index k) at box[f − 1, int(k) − box_kmin] (±inf where none; `fill_crossings` takes
    them from `_k_gaps`, box_nk 0 here); odd: the number of labelled samples (family 1 or 2, finite index) the
    order and the box leave out (a position not finite), which `border_fill._k_mark_lines` would look at."""
    n = q.shape[0]
    sel = np.empty(n, np.intp)
    m = 0
    kmin = np.inf
    kmax = -np.inf
    tmax = 0.0
    t = np.empty(n)
    box = np.empty((2, box_nk, 4))
    for f in range(2):
        for k in range(box_nk):
            box[f, k, 0] = np.inf
            box[f, k, 1] = -np.inf
            box[f, k, 2] = np.inf
            box[f, k, 3] = -np.inf
    odd = 0
    for i in range(n):
        if (fam[i] == 1 or fam[i] == 2) and np.isfinite(idx[i]):
            x = q[i, 0]
            y = q[i, 1]
            if not (np.isfinite(x) and np.isfinite(y)):
                odd += 1
            elif box_nk > 0:
                ki = int(idx[i]) - box_kmin
                if ki >= 0 and ki < box_nk:
                    f = fam[i] - 1
                    box[f, ki, 0] = min(box[f, ki, 0], x)
                    box[f, ki, 1] = max(box[f, ki, 1], x)
                    box[f, ki, 2] = min(box[f, ki, 2], y)
                    box[f, ki, 3] = max(box[f, ki, 3], y)
        if (fam[i] == 1 or fam[i] == 2) and np.isfinite(idx[i]) and np.isfinite(q[i, 0]) and np.isfinite(q[i, 1]):
            sel[m] = i
            if fam[i] == 1:
                t[m] = q[i, 0] * d1[0] + q[i, 1] * d1[1]
            else:
                t[m] = q[i, 0] * d2[0] + q[i, 1] * d2[1]
            kmin = min(kmin, idx[i])
            kmax = max(kmax, idx[i])
            tmax = max(tmax, abs(t[m]))
            m += 1
    span = 2.0 * (tmax + 1.0)
    key = np.empty(m)
    for p in range(m):
        i = sel[p]
        key[p] = _order_key(fam[i], idx[i], t[p], kmin, kmax, span)
    rng = np.empty(3)
    rng[0] = kmin
    rng[1] = kmax
    rng[2] = tmax
    return sel[:m], key, rng, box, odd


@njit(inline="always")
def _order_key(f, k, t, kmin, kmax, span):
    """The sort key of a sample of family f, index k, position t (`_k_order`)."""
    return (f * (kmax - kmin + 2.0) + (k - kmin)) * span + t


def order_with_appended(shared: FillShared, q: np.ndarray, fam: np.ndarray, idx: np.ndarray,
                        d1: np.ndarray, d2: np.ndarray) -> np.ndarray:
    """`_sorted_by_key(*_k_order(q, fam, idx, d1, d2))` when q[:n], fam[:n], idx[:n] (n = shared.n) are the
    arrays `shared.order` was computed from and the samples from n on were appended, by sorting only the
    appended ones and merging them into shared.order in O(P) (`_k_merge`). Exact: when the appended samples
    leave the key's range (line indices, largest |position|) as it was, every key is the one the full sort
    computes, the old ones' are shared.key; when all keys are distinct the order by key is unique, so the
    merge gives the full sort's order. Else (the range grows, or two keys are equal and the argsort's tie
    order decides) the full sort."""
    app, app_key, ok = _k_appended_keys(shared.key_range, int(shared.n), q, fam, idx, d1, d2)
    if ok:
        app, app_key = _sorted_with_keys(app, app_key)
        merged, ok = _k_merge(shared.order, shared.key, app, app_key)
        if ok:
            return merged
    sel, key = _k_order(q, fam, idx, d1, d2)
    return _sorted_by_key(sel, key)


@njit
def _k_appended_keys(key_range, n0, q, fam, idx, d1, d2):
    """The appended samples (ids ≥ n0) that take part in the order (as `_k_order_range`) and their keys with
    the old set's range key_range = (kmin, kmax, tmax); ok False when one lies outside that range (the full
    sort's keys would differ)."""
    kmin = key_range[0]
    kmax = key_range[1]
    tmax = key_range[2]
    span = 2.0 * (tmax + 1.0)
    N = q.shape[0]
    app = np.empty(max(N - n0, 0), np.intp)
    app_key = np.empty(max(N - n0, 0))
    m = 0
    for i in range(n0, N):
        if (fam[i] == 1 or fam[i] == 2) and np.isfinite(idx[i]) and np.isfinite(q[i, 0]) and np.isfinite(q[i, 1]):
            if fam[i] == 1:
                t = q[i, 0] * d1[0] + q[i, 1] * d1[1]
            else:
                t = q[i, 0] * d2[0] + q[i, 1] * d2[1]
            if idx[i] < kmin or idx[i] > kmax or abs(t) > tmax:
                return app[:0], app_key[:0], False
            app[m] = i
            app_key[m] = _order_key(fam[i], idx[i], t, kmin, kmax, span)
            m += 1
    return app[:m], app_key[:m], True


@njit
def _k_merge(order0, key0, order1, key1):
    """Two orders with their keys (each non-decreasing) merged by key; ok False unless the merged keys
    increase strictly (then the merge is the one order by key)."""
    n0 = order0.shape[0]
    n1 = order1.shape[0]
    out = np.empty(n0 + n1, np.intp)
    i = 0
    j = 0
    last = -np.inf
    for t in range(n0 + n1):
        if j >= n1 or (i < n0 and key0[i] < key1[j]):
            s = order0[i]
            k = key0[i]
            i += 1
        else:
            s = order1[j]
            k = key1[j]
            j += 1
        if not k > last:
            return out, False
        last = k
        out[t] = s
    return out, True


def _sorted_by_key(sel: np.ndarray, key: np.ndarray) -> np.ndarray:
    """sel[np.argsort(key)], by a sort of integers instead of an argsort (decision 0090: NumPy's sort; since decision
    0127 `_k_sort_u64`, a bucket sort in numba). Each key is mapped to an unsigned integer of the same order, its
    lowest b bits replaced by its position (b bits hold len(key) − 1); when the remaining high bits differ between
    every two neighbours of the sorted list, the keys are distinct and that is the one order by key, the
    argsort's; else (keys within ~2^b ulp of each other, or a key ≤ 0) the argsort itself."""
    return _sorted_with_keys(sel, key)[0]


def _sorted_with_keys(sel: np.ndarray, key: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`_sorted_by_key`'s order and the keys in that order."""
    n = len(key)
    if n >= 2:
        # `_k_pack`, the sort of the packed integers and `_k_unpack_keys` in one call; the sort is `_k_sort_u64`'s
        # (decision 0127: NumPy's np.sort of them took ~0.9 ms for 28 000 keys here)
        order, ok, key_sorted = _k_sorted_keys(np.ascontiguousarray(sel, np.intp), np.ascontiguousarray(key, np.float64),
                                               int(n - 1).bit_length())
        if ok:
            return order, key_sorted
    o = np.argsort(key)
    return sel[o], key[o]


@njit
def _k_sorted_keys(sel, key, b):
    """`_k_unpack_keys(np.sort(packed), sel, key, b)` for `_k_pack(key, b)`'s packed integers, with `_k_sort_u64` as
    the sort: the same order, ok and keys (ok False also when `_k_pack`'s is)."""
    packed, ok = _k_pack(key, b)
    if not ok:
        return np.empty(0, np.intp), False, np.empty(0)
    return _k_unpack_keys(_k_sort_u64(packed), sel, key, b)


@njit
def _k_sort_u64(v):
    """np.sort(v) for unsigned integers (decision 0127): a counting sort on the values' leading bits into about two
    buckets per value (each bucket a contiguous range of values, the buckets in increasing order; the keys of
    `_k_order` cluster by line, so most buckets stay empty), then each bucket sorted on its own: an insertion sort
    up to 32 values, numba's np.sort above. A sorted array of integers is unique, so it is np.sort's whatever either
    algorithm does with equal values."""
    n = v.shape[0]
    out = np.empty(n, np.uint64)
    if n == 0:
        return out
    lo = v[0]
    hi = v[0]
    for i in range(n):
        x = v[i]
        if x < lo:
            lo = x
        if x > hi:
            hi = x
    nbits = 2
    while (1 << nbits) <= n:
        nbits += 1
    sb = 0  # bits of hi − lo
    s = hi - lo
    while s > 0:
        sb += 1
        s >>= np.uint64(1)
    shift = np.uint64(sb - nbits if sb > nbits else 0)
    nb = int((hi - lo) >> shift) + 1  # at most 2^nbits ≤ 2n
    start = np.zeros(nb + 1, np.intp)
    for i in range(n):
        start[int((v[i] - lo) >> shift) + 1] += 1
    for k in range(nb):
        start[k + 1] += start[k]
    fill = start[:nb].copy()
    for i in range(n):
        k = int((v[i] - lo) >> shift)
        out[fill[k]] = v[i]
        fill[k] += 1
    for k in range(nb):
        a = start[k]
        e = start[k + 1]
        if e - a <= 1:
            continue
        if e - a > 32:
            out[a:e] = np.sort(out[a:e])
            continue
        for i in range(a + 1, e):
            x = out[i]
            j = i - 1
            while j >= a and out[j] > x:
                out[j + 1] = out[j]
                j -= 1
            out[j + 1] = x
    return out


@njit
def _k_pack(key, b):
    """`_sorted_by_key`'s integers: the key's bits (positive floats order as their bit patterns) with the lowest
    b replaced by the position; ok False when a key is not a positive finite number."""
    n = key.shape[0]
    out = np.empty(n, np.uint64)
    bits = key.view(np.uint64)
    hi_mask = ~((np.uint64(1) << np.uint64(b)) - np.uint64(1))
    ok = True
    for i in range(n):
        if not (key[i] > 0.0 and key[i] < np.inf):
            ok = False
        out[i] = (bits[i] & hi_mask) | np.uint64(i)
    return out, ok


@njit
def _k_unpack(srt, sel, b):
    """The positions of the sorted integers (their lowest b bits) as sample ids sel[...]; ok False when two
    neighbours share their high bits (keys too close to tell apart at this precision)."""
    n = srt.shape[0]
    low = (np.uint64(1) << np.uint64(b)) - np.uint64(1)
    order = np.empty(n, np.intp)
    ok = True
    for i in range(n):
        order[i] = sel[np.intp(srt[i] & low)]
        if i > 0 and (srt[i] >> np.uint64(b)) == (srt[i - 1] >> np.uint64(b)):
            ok = False
    return order, ok


@njit
def _k_unpack_keys(srt, sel, key, b):
    """`_k_unpack`, also returning the keys in that order."""
    n = srt.shape[0]
    low = (np.uint64(1) << np.uint64(b)) - np.uint64(1)
    order = np.empty(n, np.intp)
    key_sorted = np.empty(n)
    ok = True
    for i in range(n):
        pos = np.intp(srt[i] & low)
        order[i] = sel[pos]
        key_sorted[i] = key[pos]
        if i > 0 and (srt[i] >> np.uint64(b)) == (srt[i - 1] >> np.uint64(b)):
            ok = False
    return order, ok, key_sorted


def appended(cp: CrossingPoints | None, new: CrossingPoints, count_key: str, stats_key: str,
             shared: FillShared | None = None) -> CrossingPoints:
    """The points `cp` (None: none) followed by a later fill's `new` ones (decisions 0099, 0104): stats are cp's,
    with new.stats[count_key] under count_key and all of new.stats under stats_key; `shared` is kept with them."""
    stats = dict(cp.stats) if cp is not None else {"samples_crossing_filled": 0}
    stats[count_key] = new.stats[count_key]
    stats[stats_key] = new.stats
    if cp is None or len(cp.index) == 0:
        return CrossingPoints(new.q, new.family, new.index, new.junction, stats, shared)
    if (len(new.index) == 0 and len(new.q) == 0 and len(new.family) == 0 and len(new.junction) == 0
            and all(np.result_type(a, b) == a.dtype for a, b in ((cp.q, new.q), (cp.index, new.index), (cp.junction, new.junction)))):
        # nothing new: cp's own arrays (the concatenation would copy them, same values and dtypes; decision 0149)
        return CrossingPoints(cp.q, cp.family, cp.index, cp.junction, stats, shared)
    return CrossingPoints(np.concatenate([cp.q, new.q]), np.concatenate([cp.family, new.family.astype(cp.family.dtype)]),
                          np.concatenate([cp.index, new.index]), np.concatenate([cp.junction, new.junction]), stats, shared)


@njit
def _fit_across(ex, ey, n, ux, uy, lateral):
    """The straight-line fit of the fills' anchors (steps 11–13): n points given by their offsets (ex, ey) from a
    common origin, in the frame of the unit direction u: the across offset r = −ex·uy + ey·ux regressed on the
    along offset s = ex·ux + ey·uy, r ≈ k·s + c. Returns (k, c, status): 0 fitted and every point within lateral
    of the line, 1 degenerate (every s alike), 2 a point farther than lateral from it."""
    sm = 0.0
    rm = 0.0
    for k in range(n):
        sm += ex[k] * ux + ey[k] * uy
        rm += -ex[k] * uy + ey[k] * ux
    sm /= n
    rm /= n
    sxx = 0.0
    sxr = 0.0
    for k in range(n):
        ds = ex[k] * ux + ey[k] * uy - sm
        sxx += ds * ds
        sxr += ds * (-ex[k] * uy + ey[k] * ux - rm)
    if not sxx > 0.0:
        return 0.0, 0.0, 1
    kk = sxr / sxx
    cc = rm - kk * sm
    for k in range(n):
        if abs(-ex[k] * uy + ey[k] * ux - (kk * (ex[k] * ux + ey[k] * uy) + cc)) > lateral:
            return kk, cc, 2
    return kk, cc, 0


@njit
def _k_points(q, fam, idx, junction, gaps, acc, cell):
    """Step 4: points one sampling step apart strictly inside each accepted gap, on the blend of its two
    tangents: q (N, 2), family (N,), index (N,), junction (N,) (that of the gap's first sample)."""
    G = gaps.shape[0]
    total = 0
    for g in range(G):
        if acc[g]:
            total += _n_gap_points(gaps[g, 3], cell)
    q_new = np.empty((total, 2))
    f_new = np.empty(total, np.intp)
    k_new = np.empty(total)
    j_new = np.empty(total, np.int64)
    o = 0
    for g in range(G):
        if not acc[g]:
            continue
        a = int(gaps[g, 0])
        ux = gaps[g, 1]
        uy = gaps[g, 2]
        L = gaps[g, 3]
        n_pts = _n_gap_points(L, cell)
        for k in range(1, n_pts + 1):
            s = k * (L / (n_pts + 1))
            r = _curve_r(s, L, gaps[g, 4], gaps[g, 5], gaps[g, 6], gaps[g, 7])
            q_new[o, 0] = q[a, 0] + s * ux - r * uy
            q_new[o, 1] = q[a, 1] + s * uy + r * ux
            f_new[o] = fam[a]
            k_new[o] = idx[a]
            j_new[o] = junction[a]
            o += 1
    return q_new, f_new, k_new, j_new


@njit
def _curve_r(s, L, ka, ca, kb, cb):
    """The gap's curve across its chord at s along it: the two sides' tangents blended linearly."""
    w = min(max(s / L, 0.0), 1.0)
    return (1.0 - w) * (ka * s + ca) + w * (kb * s + cb)


@njit
def _k_gaps(q, fam, idx, order, qj, jdir, lab, qs, jx0, jy0, jgw, jgh, jstart, jitems, sx0, sy0, sgw, sgh, sstart, smid, sitems,
            gcell, cell, sigma, min_gap, gap_max, half_gap, anchor, max_turn, lateral, box_kmin, box_nk):
    """Steps 1–3 of the module doc over the ordered labelled samples `order`: the gaps between consecutive
    samples of one line, the two sides' tangent fits and tests, and the crossing in the gap. Returns the
    number of gaps, per gap that passed the tangent tests (G, 8) [first sample id, u (2), L, ka, ca, kb,
    cb] (u the chord's direction from the first sample, L its length, r = k·s + c each side's tangent
    across the chord), accepted (G,) bool (a labelled junction of this line names the gap), c_q (G, 2):
    where the other family's straight run crosses the curve (NaN where none), to be checked on the light
    sheet, the counts of gaps rejected (5,): anchors missing, broken, crooked, turn, lateral, per gap its
    position in order (G,), that of its first sample (decision 0149's insertion), and the lines' boxes of the
    ordered samples (2, box_nk, 4), as `_k_order_range_box`'s, kept as running extremes along each line's run of
    the order (decision 0149: the border fill's lines near the border). The
    labelled junctions' grid (jx0 … jitems) and the samples' (sx0 … sitems): `_k_grids` on cell gcell."""
    n = order.shape[0]
    cap = max(n - 1, 1)  # at most one gap per consecutive pair
    gaps = np.empty((cap, 8))
    why = np.zeros(6, np.int64)  # gaps rejected: anchors out of range, anchors not one run, anchors off their line, turn, lateral
    acc = np.empty(cap, np.bool_)  # each row written when it is made (below), not filled ahead
    c_q = np.empty((cap, 2))
    gp = np.empty(cap, np.intp)  # each gap's position in order (its first sample's)
    box = np.empty((2, box_nk, 4))
    for bf in range(2):
        for bk in range(box_nk):
            box[bf, bk, 0] = np.inf
            box[bf, bk, 1] = -np.inf
            box[bf, bk, 2] = np.inf
            box[bf, bk, 3] = -np.inf
    rx0 = np.inf
    rx1 = -np.inf
    ry0 = np.inf
    ry1 = -np.inf
    G = 0
    n_gaps = 0
    hits = np.empty(sitems.shape[0], np.intp)  # the other family's samples in the disc, in search order
    fit_x = np.empty(anchor)
    fit_y = np.empty(anchor)
    for p in range(n - 1):
        a = order[p]
        b = order[p + 1]
        rx0 = min(rx0, q[a, 0])
        rx1 = max(rx1, q[a, 0])
        ry0 = min(ry0, q[a, 1])
        ry1 = max(ry1, q[a, 1])
        if fam[a] != fam[b] or idx[a] != idx[b]:
            _box_flush(box, fam[a], idx[a], box_kmin, rx0, rx1, ry0, ry1)
            rx0 = np.inf
            rx1 = -np.inf
            ry0 = np.inf
            ry1 = -np.inf
            continue
        dx = q[b, 0] - q[a, 0]
        dy = q[b, 1] - q[a, 1]
        L = math.sqrt(dx * dx + dy * dy)
        if not (L > min_gap and L <= gap_max):
            continue
        n_gaps += 1
        if p - anchor + 1 < 0 or p + anchor >= n:
            why[0] += 1
            continue
        # 2. the anchors: consecutive samples of the same line, steps of at most 2 cells
        ok = True
        for k in range(1, anchor):
            for (s0, s1) in ((order[p - k + 1], order[p - k]), (order[p + k], order[p + k + 1])):
                if fam[s1] != fam[a] or idx[s1] != idx[a]:
                    ok = False
                ex = q[s1, 0] - q[s0, 0]
                ey = q[s1, 1] - q[s0, 1]
                if ex * ex + ey * ey > gap_max * gap_max:
                    ok = False
        if not ok:
            why[1] += 1
            continue
        ux = dx / L
        uy = dy / L
        ka = 0.0
        ca = 0.0
        kb = 0.0
        cb = 0.0
        for side in range(2):
            for k in range(anchor):
                sid = order[p - k] if side == 0 else order[p + 1 + k]
                fit_x[k] = q[sid, 0] - q[a, 0]
                fit_y[k] = q[sid, 1] - q[a, 1]
            kk, cc, status = _fit_across(fit_x, fit_y, anchor, ux, uy, lateral)
            if status != 0:
                ok = False
                break
            if side == 0:
                ka = kk
                ca = cc
            else:
                kb = kk
                cb = cc
        if not ok:
            why[2] += 1
            continue
        if abs(math.atan(ka) - math.atan(kb)) > max_turn:
            why[3] += 1
            continue
        sm = 0.5 * L
        if abs((ka * sm + ca) - (kb * sm + cb)) > lateral:
            why[4] += 1
            continue
        gaps[G, 0] = a
        gp[G] = p
        gaps[G, 1] = ux
        gaps[G, 2] = uy
        gaps[G, 3] = L
        gaps[G, 4] = ka
        gaps[G, 5] = ca
        gaps[G, 6] = kb
        gaps[G, 7] = cb
        acc[G] = False
        c_q[G, 0] = np.nan
        c_q[G, 1] = np.nan
        rmid = _curve_r(sm, L, ka, ca, kb, cb)
        mx = q[a, 0] + sm * ux - rmid * uy
        my = q[a, 1] + sm * uy + rmid * ux
        f = fam[a]
        kidx = int(idx[a])
        # 3. a labelled junction of this line in the gap, on the curve
        gx = int((mx - jx0) / gcell)
        gy = int((my - jy0) / gcell)
        found = False
        for cy in range(max(gy - 1, 0), min(gy + 2, jgh)):
            for cx in range(max(gx - 1, 0), min(gx + 2, jgw)):
                c = cy * jgw + cx
                for t in range(jstart[c], jstart[c + 1]):
                    j = jitems[t]
                    if lab[j, f - 1] != kidx:
                        continue
                    # the gap lies in this crossing's own gap: the junction is in it, or no farther from
                    # its nearer end than the crossing's mixing zone and trim reach along the line,
                    # half_gap/sin θ (θ the crossing's angle); on the curve (beyond the gap's ends: on that
                    # side's tangent)
                    ex = qj[j, 0] - q[a, 0]
                    ey = qj[j, 1] - q[a, 1]
                    s = ex * ux + ey * uy
                    if abs(-ex * uy + ey * ux - _curve_r(s, L, ka, ca, kb, cb)) > lateral:
                        continue
                    sin_t = abs(jdir[j, 0, 0] * jdir[j, 1, 1] - jdir[j, 0, 1] * jdir[j, 1, 0])
                    reach = half_gap / max(sin_t, 1e-3)
                    if s >= -reach and s <= L + reach:
                        found = True
        if found:
            acc[G] = True
            G += 1
            continue
        # else: the other family's samples within L/2 + σ of the gap's middle, one straight run
        rad = 0.5 * L + sigma
        cnt, cxm, cym, cxx, cxy, cyy = _other_run(mx, my, rad, f, qs, sx0, sy0, gcell, sgw, sgh, sstart, smid, sitems, hits)
        if cnt >= 4:
            lam_min, nx, ny = _run_axis(cxx, cxy, cyy)
            if lam_min <= lateral * lateral:
                # Newton on s: (curve(s) − c)·n = 0
                s = sm
                good = True
                for _ in range(4):
                    r = _curve_r(s, L, ka, ca, kb, cb)
                    px = q[a, 0] + s * ux - r * uy
                    py = q[a, 1] + s * uy + r * ux
                    h = 1e-4 * max(L, 1.0)
                    r2 = _curve_r(s + h, L, ka, ca, kb, cb)
                    dpx = (ux - (r2 - r) / h * uy)
                    dpy = (uy + (r2 - r) / h * ux)
                    den = dpx * nx + dpy * ny
                    if abs(den) < 1e-6:
                        good = False
                        break
                    s = s - ((px - cxm) * nx + (py - cym) * ny) / den
                if good and s > 0.0 and s < L:
                    r = _curve_r(s, L, ka, ca, kb, cb)
                    c_q[G, 0] = q[a, 0] + s * ux - r * uy
                    c_q[G, 1] = q[a, 1] + s * uy + r * ux
        G += 1
    if n > 0:
        a = order[n - 1]
        _box_flush(box, fam[a], idx[a], box_kmin, min(rx0, q[a, 0]), max(rx1, q[a, 0]), min(ry0, q[a, 1]), max(ry1, q[a, 1]))
    return n_gaps, gaps[:G], acc[:G], c_q[:G], why, gp[:G], box


@njit(inline="always")
def _box_flush(box, f, k, box_kmin, x0, x1, y0, y1):
    """A line's run's extremes into its box (`_k_gaps`)."""
    ki = int(k) - box_kmin
    if ki >= 0 and ki < box.shape[1]:
        box[f - 1, ki, 0] = min(box[f - 1, ki, 0], x0)
        box[f - 1, ki, 1] = max(box[f - 1, ki, 1], x1)
        box[f - 1, ki, 2] = min(box[f - 1, ki, 2], y0)
        box[f - 1, ki, 3] = max(box[f - 1, ki, 3], y1)


@njit
def _family_grid(qs, fs, cell):
    """The bucket grid of `_label_kernels.sample_grid` over the samples of family 1 or 2 with a finite
    position (the same origin, cells and clamping), each cell's items split by family: x0, y0, gw, gh,
    start (gw·gh + 1,), mid (gw·gh,), items; cell c holds family 1 in items[start[c]:mid[c]] and family 2 in
    items[mid[c]:start[c + 1]], each in increasing sample id (the order of sample_grid's cell without the
    other family)."""
    P = qs.shape[0]
    x0 = np.inf
    y0 = np.inf
    x1 = -np.inf
    y1 = -np.inf
    nv = 0
    for s in range(P):
        if (fs[s] == 1 or fs[s] == 2) and np.isfinite(qs[s, 0]) and np.isfinite(qs[s, 1]):
            x0 = min(x0, qs[s, 0])
            y0 = min(y0, qs[s, 1])
            x1 = max(x1, qs[s, 0])
            y1 = max(y1, qs[s, 1])
            nv += 1
    if nv == 0:
        x0 = 0.0
        y0 = 0.0
        x1 = 0.0
        y1 = 0.0
    gw = int((x1 - x0) / cell) + 1
    gh = int((y1 - y0) / cell) + 1
    nc = gw * gh
    key = np.empty(P, np.intp)
    n1 = np.zeros(nc, np.intp)
    start = np.zeros(nc + 1, np.intp)
    for s in range(P):
        if (fs[s] == 1 or fs[s] == 2) and np.isfinite(qs[s, 0]) and np.isfinite(qs[s, 1]):
            cx = min(max(int(math.floor((qs[s, 0] - x0) / cell)), 0), gw - 1)
            cy = min(max(int(math.floor((qs[s, 1] - y0) / cell)), 0), gh - 1)
            c = cy * gw + cx
            key[s] = c
            start[c + 1] += 1
            if fs[s] == 1:
                n1[c] += 1
        else:
            key[s] = -1
    for c in range(nc):
        start[c + 1] += start[c]
    fill1 = np.empty(nc, np.intp)
    mid = np.empty(nc, np.intp)
    for c in range(nc):
        fill1[c] = start[c]
        mid[c] = start[c] + n1[c]
    fill2 = mid.copy()
    items = np.empty(nv, np.intp)
    for s in range(P):
        c = key[s]
        if c >= 0:
            if fs[s] == 1:
                items[fill1[c]] = s
                fill1[c] += 1
            else:
                items[fill2[c]] = s
                fill2[c] += 1
    return x0, y0, gw, gh, start, mid, items


@njit
def _run_axis(cxx, cxy, cyy):
    """A run's covariance (xx, xy, yy) → (its smaller eigenvalue, the unit normal (nx, ny) of its major axis)."""
    tr = 0.5 * (cxx + cyy)
    det = math.sqrt(max(0.25 * (cxx - cyy) ** 2 + cxy * cxy, 0.0))
    lam_max = tr + det
    if abs(cxy) > 1e-12:
        ex = lam_max - cyy
        ey = cxy
    elif cxx >= cyy:
        ex = 1.0
        ey = 0.0
    else:
        ex = 0.0
        ey = 1.0
    en = math.sqrt(ex * ex + ey * ey)
    return tr - det, -ey / en, ex / en


@njit
def _other_run(mx, my, rad, f, qs, x0, y0, cell, gw, gh, start, mid, items, hits):
    """`_k_gaps`' step 3 search: the samples of family 3 − f (f ∈ {1, 2}) within rad of (mx, my) on the
    grid of `_family_grid`: their number, mean (x, y) and covariance (xx, xy, yy) (divided by the
    number; only computed from 4 samples on). The sums add the samples in the order of the 3×3 cells
    around (mx, my)'s cell of the grid of both families (rows, then columns, then sample id), as a
    search of that grid that skips family f does; only the cells the disc's bounding box reaches (widened
    by 1e-6 px against rounding) and only the family's part of each are read. hits: scratch (≥ the number
    of items), the found samples in order."""
    gx = int((mx - x0) / cell)
    gy = int((my - y0) / cell)
    cx_lo = max(gx - 1, 0, int(math.floor((mx - rad - 1e-6 - x0) / cell)))
    cx_hi = min(gx + 1, gw - 1, int(math.floor((mx + rad + 1e-6 - x0) / cell)))
    cy_lo = max(gy - 1, 0, int(math.floor((my - rad - 1e-6 - y0) / cell)))
    cy_hi = min(gy + 1, gh - 1, int(math.floor((my + rad + 1e-6 - y0) / cell)))
    cnt = 0
    sx = 0.0
    sy = 0.0
    for cy in range(cy_lo, cy_hi + 1):
        for cx in range(cx_lo, cx_hi + 1):
            c = cy * gw + cx
            t0 = mid[c] if f == 1 else start[c]
            t1 = start[c + 1] if f == 1 else mid[c]
            for t in range(t0, t1):
                i = items[t]
                ex = qs[i, 0] - mx
                ey = qs[i, 1] - my
                if ex * ex + ey * ey <= rad * rad:
                    hits[cnt] = i
                    cnt += 1
                    sx += qs[i, 0]
                    sy += qs[i, 1]
    if cnt < 4:
        return cnt, 0.0, 0.0, 0.0, 0.0, 0.0
    cxm = sx / cnt
    cym = sy / cnt
    cxx = 0.0
    cxy = 0.0
    cyy = 0.0
    for h in range(cnt):
        i = hits[h]
        ex = qs[i, 0] - cxm
        ey = qs[i, 1] - cym
        cxx += ex * ex
        cxy += ex * ey
        cyy += ey * ey
    return cnt, cxm, cym, cxx / cnt, cxy / cnt, cyy / cnt
