"""Label unlabelled trace pieces whose line the working volume alone names (decision 0128).

A line sample's camera ray crosses the working volume (camera-frame depth z in [depth_min_mm, depth_max_mm])
in a segment; in the projector that segment is a stretch of the sample's epipolar line, and the lines of the
sample's family that this stretch crosses are the only lines the sample can lie on (the light sheet of any
other line meets the ray outside the working volume). On rigs whose light planes cut the working volume in a
short image band (the paper's placements: a depth range of ±7 % at 2.8 m and a coarse grid), that stretch is
about one line spacing long, so a piece of one line (all its samples on one light sheet) is often left with one
admissible index: the intersection over the piece's samples of their admissible intervals.

The rule, for every trace piece without a labelled sample and with at least `min_samples` samples:

1. Each sample's stretch: its camera ray at z = depth_min_mm and z = depth_max_mm, projected into the projector
   (with its distortion), and the family's fractional line coordinate at both ends (`RigModel.line_offsets_px`,
   extrapolated beyond the pattern). Widened by `tol_px` projector px on either end (in the family's
   across-line units; the label stage passes 3 × the epipolar noise floor): the sample's position noise and the
   calibration's epipolar error.
2. The piece's admissible indices: the integers inside the intersection of its samples' widened stretches and
   inside the pattern. Exactly one, k, is required; none or several: the piece stays unlabelled.
3. The family: read as lines of the other family, the piece's stretches share no index. A piece of the other
   family's line (given this family by mistake where the families' image directions come close) would be
   labelled with a line it is not on; it drifts by one line of this family per junction step along itself, so a
   long one fails step 2, but short ones pass it (two on converged-1280 did, decision 0128): any piece that could
   be the other family's line inside the volume is left alone.
4. Every sample on sheet k (`RigModel.sheet_depth`, the triangulation's own sheet) inside [depth_min_mm,
   depth_max_mm] (the widening of step 1 may admit a sheet that puts some samples just outside).
5. (`label_pieces`) The samples farther than `trim_px` from both ends of the piece take k.

Why this is safe where one-sided evidence is not (decisions 0049, 0089, 0093): no neighbour is involved; the
only assumption is the working volume itself, which the labeller already relies on (offsets outside it are
discarded) and the triangulation enforces (points outside it are dropped). A sample's true sheet puts it at its
true depth, inside the working volume, so the true index is always admissible, and when it is the only one it
is the right one — provided the piece is one line's samples of the family it was given (step 3). A piece joining
two lines is cut by the trace's own tests (lateral jump, turn, ridge step). A lit surface outside the working
volume breaks the assumption: its pieces can take a wrong line (the component labeller relies on the volume too).
"""

from __future__ import annotations

import math

import numpy as np

from reconstruction._jit import njit
from reconstruction.rigmodel import RigModel


def index_stretch(model: RigModel, q_cam: np.ndarray, family: np.ndarray, depth_range_mm: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """The family's fractional line coordinate (index units, extrapolated beyond the pattern) where each camera
    pixel's ray enters and leaves the working volume: (lo, hi) (N,) each, lo <= hi; NaN where the ray does not
    reach the projector's image plane in front of it."""
    q = np.asarray(q_cam, np.float64).reshape(-1, 2)
    fam = np.asarray(family).reshape(-1)
    n = len(q)
    if n == 0:
        return np.zeros(0), np.zeros(0)
    procam = model.procam
    xy = model.cam_normalised(q)
    d = np.column_stack([xy, np.ones(n)]) @ procam.R_proj_cam.T  # ray directions in the projector frame, camera z = 1
    t = procam.t_proj_cam
    pat = model.pattern
    out = []
    for z in depth_range_mm:
        p = t[None, :] + float(z) * d
        uv = procam.projector.project(p)
        x = uv[:, 0] - pat.centre_px[0]
        y = uv[:, 1] - pat.centre_px[1]
        c = np.full(n, np.nan)
        for f, nf in ((1, pat.n1), (2, pat.n2)):
            sel = fam == f
            if sel.any():
                c[sel] = _fractional(y[sel] - nf * x[sel], model.line_offsets_px[f - 1], model.index_min)
        out.append(c)
    return np.fmin(out[0], out[1]), np.fmax(out[0], out[1])


def _fractional(c: np.ndarray, offs: np.ndarray, index_min: int) -> np.ndarray:
    """Fractional index of offsets c among the lines at offs (increasing), extrapolated linearly beyond the ends."""
    idx = np.arange(len(offs), dtype=np.float64) + index_min
    k = np.interp(c, offs, idx)
    lo = c < offs[0]
    hi = c > offs[-1]
    k[lo] = idx[0] + (c[lo] - offs[0]) / (offs[1] - offs[0])
    k[hi] = idx[-1] + (c[hi] - offs[-1]) / (offs[-1] - offs[-2])
    return k


@njit
def _k_open_positions(sid, piece, index, n_p, min_samples):
    """Trace positions (ascending) of the pieces without a labelled sample (finite index) of at least min_samples."""
    n = sid.shape[0]
    size = np.zeros(n_p, np.int64)
    lab = np.zeros(n_p, np.bool_)
    for a in range(n):
        size[piece[a]] += 1
        if not lab[piece[a]] and math.isfinite(index[sid[a]]):  # a labelled piece's index is not read again (decision 0150)
            lab[piece[a]] = True
    m = 0
    for a in range(n):
        if not lab[piece[a]] and size[piece[a]] >= min_samples:
            m += 1
    out = np.empty(m, np.int64)
    m = 0
    for a in range(n):
        if not lab[piece[a]] and size[piece[a]] >= min_samples:
            out[m] = a
            m += 1
    return out


@njit(inline="always")
def _fractional_k_from(c, offs, index_min, h):
    """`_fractional` for one offset c among offs (increasing), its segment found by the bisection when h < 0, else
    (offs strictly increasing) by a walk from segment h (the previous sample's: a piece's samples lie close
    together): (the value, the segment for the next call). With strictly increasing offs the bisection's segment is
    the one lo <= L − 2 with offs[lo] <= c and (lo = L − 2 or c < offs[lo + 1]): unique, so the walk finds the same
    one and the same value bit for bit (decision 0163)."""
    L = offs.shape[0]
    if c < offs[0]:
        return index_min + (c - offs[0]) / (offs[1] - offs[0]), h
    if c > offs[L - 1]:
        return index_min + L - 1 + (c - offs[L - 1]) / (offs[L - 1] - offs[L - 2]), h
    if h < 0:  # no segment yet (a piece's first sample, or no walk): the bisection
        lo = 0
        hi = L - 1
        while hi - lo > 1:
            mid = (lo + hi) // 2
            if offs[mid] <= c:
                lo = mid
            else:
                hi = mid
    else:
        lo = min(h, L - 2)
        while lo > 0 and offs[lo] > c:
            lo -= 1
        while lo < L - 2 and offs[lo + 1] <= c:
            lo += 1
    d = offs[lo + 1] - offs[lo]
    return index_min + lo + ((c - offs[lo]) / d if d > 0 else 0.0), lo


@njit
def _fractional_k(c, offs, index_min):
    """`_fractional` for one offset c among offs (increasing): `_fractional_k_from`'s bisection."""
    return _fractional_k_from(c, offs, index_min, -1)[0]


@njit(inline="always")
def _sheet_offset(ax, ay, az, fam, t, z, Kp, dist, has_dist, cu, cv, nn):
    """The family's line offset Y − n·X (projector px, the pattern's frame) of the point t + z·(ax, ay, az)
    (projector frame; (ax, ay, az) = R·(x, y, 1), the camera ray's direction) seen by the projector; NaN behind it."""
    px = t[0] + z * ax
    py = t[1] + z * ay
    pz = t[2] + z * az
    if not pz > 0:
        return np.nan
    u = px / pz
    v = py / pz
    if has_dist:
        r2 = u * u + v * v
        radial = 1 + r2 * (dist[0] + r2 * (dist[1] + r2 * dist[4]))
        ud = u * radial + 2 * dist[2] * u * v + dist[3] * (r2 + 2 * u * u)
        vd = v * radial + dist[2] * (r2 + 2 * v * v) + 2 * dist[3] * u * v
        u, v = ud, vd
    X = Kp[0, 0] * u + Kp[0, 1] * v + Kp[0, 2] - cu
    Y = Kp[1, 1] * v + Kp[1, 2] - cv
    return Y - nn[fam - 1] * X


@njit
def _k_stretch_at(ax, ay, az, fam, t, z, Kp, dist, has_dist, cu, cv, nn, offs, index_min):
    """The family's fractional line coordinate of the point t + z·(ax, ay, az) (projector frame; (ax, ay, az) =
    R·(x, y, 1), the camera ray's direction) seen by the projector (NaN behind it)."""
    c = _sheet_offset(ax, ay, az, fam, t, z, Kp, dist, has_dist, cu, cv, nn)
    if c != c:
        return np.nan
    return _fractional_k(c, offs[fam - 1], index_min)


@njit
def _k_stretch_one(x, y, fam, R, t, z, Kp, dist, has_dist, cu, cv, nn, offs, index_min):
    """The family's fractional line coordinate of camera point (x, y, 1)·z (normalised, camera frame) seen by the
    projector (NaN behind it)."""
    ax = R[0, 0] * x + R[0, 1] * y + R[0, 2]
    ay = R[1, 0] * x + R[1, 1] * y + R[1, 2]
    az = R[2, 0] * x + R[2, 1] * y + R[2, 2]
    return _k_stretch_at(ax, ay, az, fam, t, z, Kp, dist, has_dist, cu, cv, nn, offs, index_min)


@njit
def _k_stretch_pair(x, y, fam, R, t, z0, z1, Kp, dist, has_dist, cu, cv, nn, offs, index_min):
    """(`_k_stretch_one` at z0, `_k_stretch_one` at z1) in one call: the ray's direction R·(x, y, 1) is computed
    once for both depths, and both go through `_k_stretch_at` as `_k_stretch_one` does, so both are the same bit for
    bit; ~40 % less time than two calls (decision 0159)."""
    ax = R[0, 0] * x + R[0, 1] * y + R[0, 2]
    ay = R[1, 0] * x + R[1, 1] * y + R[1, 2]
    az = R[2, 0] * x + R[2, 1] * y + R[2, 2]
    return (_k_stretch_at(ax, ay, az, fam, t, z0, Kp, dist, has_dist, cu, cv, nn, offs, index_min),
            _k_stretch_at(ax, ay, az, fam, t, z1, Kp, dist, has_dist, cu, cv, nn, offs, index_min))


@njit
def _k_stretches_meet(xy, a, b, f, R, t, z0, z1, Kp, dist, has_dist, cu, cv, nn, offs, index_min, tol_f):
    """The intersection (lo, hi) in index units of family f's stretches (widened by tol_f) of positions a … b − 1;
    lo = inf when a ray misses the projector. Stops as soon as no integer is left in it."""
    lo = -np.inf
    hi = np.inf
    for s in range(a, b):
        c0, c1 = _k_stretch_pair(xy[s, 0], xy[s, 1], f, R, t, z0, z1, Kp, dist, has_dist, cu, cv, nn, offs, index_min)
        if not (math.isfinite(c0) and math.isfinite(c1)):
            return np.inf, hi
        lo = max(lo, min(c0, c1) - tol_f)
        hi = min(hi, max(c0, c1) + tol_f)
        if np.ceil(lo) > np.floor(hi):
            break
    return lo, hi


@njit(inline="always")
def _k_stretch_at_from(ax, ay, az, fam, t, z, Kp, dist, has_dist, cu, cv, nn, offs, index_min, h):
    """`_k_stretch_at` with `_fractional_k_from`'s walk from segment h (offs strictly increasing): (the same value,
    the segment)."""
    c = _sheet_offset(ax, ay, az, fam, t, z, Kp, dist, has_dist, cu, cv, nn)
    if c != c:
        return np.nan, h
    return _fractional_k_from(c, offs[fam - 1], index_min, h)


@njit
def _k_stretches_meet_walk(xy, a, b, f, R, t, z0, z1, Kp, dist, has_dist, cu, cv, nn, offs, index_min, tol_f):
    """`_k_stretches_meet` for line offsets offs strictly increasing in each family: each sample's two ends find
    their segment of offs by a walk from the previous sample's (`_fractional_k_from`), not by bisection. The same
    (lo, hi) bit for bit; ~half the time on the bench rigs (decision 0163)."""
    lo = -np.inf
    hi = np.inf
    h0 = -1  # each depth's segment of the previous sample (−1: none yet, found by bisection)
    h1 = -1
    for s in range(a, b):
        x = xy[s, 0]
        y = xy[s, 1]
        ax = R[0, 0] * x + R[0, 1] * y + R[0, 2]
        ay = R[1, 0] * x + R[1, 1] * y + R[1, 2]
        az = R[2, 0] * x + R[2, 1] * y + R[2, 2]
        c0, h0 = _k_stretch_at_from(ax, ay, az, f, t, z0, Kp, dist, has_dist, cu, cv, nn, offs, index_min, h0)
        c1, h1 = _k_stretch_at_from(ax, ay, az, f, t, z1, Kp, dist, has_dist, cu, cv, nn, offs, index_min, h1)
        if not (math.isfinite(c0) and math.isfinite(c1)):
            return np.inf, hi
        lo = max(lo, min(c0, c1) - tol_f)
        hi = min(hi, max(c0, c1) + tol_f)
        if np.ceil(lo) > np.floor(hi):
            break
    return lo, hi


@njit
def _k_offsets_strict(offs):
    """True when every row of offs (families × lines, at least 2 lines) increases strictly."""
    if offs.shape[1] < 2:
        return False
    for f in range(offs.shape[0]):
        for i in range(1, offs.shape[1]):
            if not offs[f, i] > offs[f, i - 1]:
                return False
    return True


@njit
def _k_meet(walk, xy, a, b, f, R, t, z0, z1, Kp, dist, has_dist, cu, cv, nn, offs, index_min, tol_f):
    """`_k_stretches_meet_walk` when walk (offs strictly increasing), else `_k_stretches_meet`."""
    if walk:
        return _k_stretches_meet_walk(xy, a, b, f, R, t, z0, z1, Kp, dist, has_dist, cu, cv, nn, offs, index_min, tol_f)
    return _k_stretches_meet(xy, a, b, f, R, t, z0, z1, Kp, dist, has_dist, cu, cv, nn, offs, index_min, tol_f)


@njit
def _k_piece_candidates(xy, fam, pid, R, t, z0, z1, Kp, dist, has_dist, cu, cv, nn, offs, index_min, index_max, tol, other_family,
                        walk_segments=True):
    """Per piece (pid (m,) non-decreasing ids of the positions, xy (m, 2) their normalised camera coordinates, fam
    (m,) their family): the single index inside the intersection of the widened stretches (tol (2,) per family,
    index units), or index_min − 1 (none or several; or, with other_family, the other family's stretches share
    an index too). Returns (piece ids (K,), index (K,)) of the pieces with one. walk_segments: the stretches by
    `_k_stretches_meet_walk` when the offsets increase strictly (the same values; False: `_k_stretches_meet`)."""
    m = xy.shape[0]
    n_out = 0
    ids = np.empty(m, np.int64)
    ks = np.empty(m, np.int64)
    walk = walk_segments and _k_offsets_strict(offs)  # the segment walk needs strictly increasing offsets (decision 0163)
    a = 0
    while a < m:
        b = a
        while b < m and pid[b] == pid[a]:
            b += 1
        f = fam[a]
        g = 3 - f
        lo_f, hi_f = _k_meet(walk, xy, a, b, f, R, t, z0, z1, Kp, dist, has_dist, cu, cv, nn, offs, index_min, tol[f - 1])
        k_lo = max(np.ceil(lo_f), index_min)
        k_hi = min(np.floor(hi_f), index_max)
        ok = k_lo == k_hi
        if ok and other_family:
            lo_g, hi_g = _k_meet(walk, xy, a, b, g, R, t, z0, z1, Kp, dist, has_dist, cu, cv, nn, offs, index_min, tol[g - 1])
            if max(np.ceil(lo_g), index_min) <= min(np.floor(hi_g), index_max):
                ok = False
        if ok:
            ids[n_out] = pid[a]
            ks[n_out] = np.int64(k_lo)
            n_out += 1
        a = b
    return ids[:n_out], ks[:n_out]


def piece_indices(model: RigModel, q: np.ndarray, fam: np.ndarray, sid: np.ndarray, piece: np.ndarray, index: np.ndarray,
                  depth_range_mm: tuple[float, float], *, tol_px: float = 0.3, min_samples: int = 4, other_family: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """The pieces the working volume labels (module doc): (piece ids (K,), their index (K,)). Pieces: `piece` (n,)
    non-decreasing ids 0, 1, … of the trace positions, `sid` (n,) their sample ids; fam (P,) the samples' families;
    index (P,) their labels so far (NaN: none). tol_px: the widening of each stretch, projector px. Steps 1–3 in
    one compiled pass over the open pieces' samples (`_k_piece_candidates`), step 4 with `RigModel.sheet_depth`;
    projectors with more than 5 distortion coefficients take `piece_indices_numpy`."""
    n = len(sid)
    none = (np.zeros(0, np.intp), np.zeros(0, np.intp))
    if n == 0:
        return none
    proj = model.procam.projector
    if proj.dist.size > 5:
        return piece_indices_numpy(model, q, fam, sid, piece, index, depth_range_mm, tol_px=tol_px, min_samples=min_samples,
                                   other_family=other_family)
    sid = np.asarray(sid, np.int64)
    piece = np.asarray(piece, np.int64)
    pos = _k_open_positions(sid, piece, np.asarray(index), int(piece[-1]) + 1, int(min_samples))
    if len(pos) == 0:
        return none
    s = sid[pos]
    f = np.asarray(fam)[s].astype(np.int64)
    xy = np.ascontiguousarray(model.cam_normalised(q[s]), np.float64)
    pat = model.pattern
    dist = np.zeros(5)
    dist[: min(5, proj.dist.size)] = np.asarray(proj.dist, np.float64).ravel()[:5]
    tol = tol_px / np.asarray(model.line_spacing_perp_px, np.float64)
    ids, k = _k_piece_candidates(xy, f, piece[pos], np.ascontiguousarray(model.procam.R_proj_cam, np.float64),
                                 np.ascontiguousarray(model.procam.t_proj_cam, np.float64), float(depth_range_mm[0]),
                                 float(depth_range_mm[1]), np.ascontiguousarray(proj.K, np.float64), dist, bool(proj.has_distortion),
                                 float(pat.centre_px[0]), float(pat.centre_px[1]), np.array([pat.n1, pat.n2], np.float64),
                                 np.ascontiguousarray(model.line_offsets_px, np.float64), int(model.index_min), int(model.index_max),
                                 tol, bool(other_family))
    if len(ids) == 0:
        return none
    return _inside_volume(model, q, fam, sid, piece, ids, k, depth_range_mm)


def _inside_volume(model, q, fam, sid, piece, ids, k, depth_range_mm):
    """Step 4: the pieces ids (with indices k) every sample of which lies inside the volume on its sheet k."""
    n_p = int(piece[-1]) + 1
    k_of = np.full(n_p, model.index_min - 1, np.intp)
    k_of[ids] = k
    sel = np.flatnonzero(k_of[piece] >= model.index_min)
    ss = sid[sel]
    z = model.sheet_depth(q[ss], np.asarray(fam)[ss], k_of[piece[sel]])
    out = ~((z >= depth_range_mm[0]) & (z <= depth_range_mm[1]))
    bad = np.zeros(n_p, bool)
    bad[piece[sel][out]] = True
    ok = ids[~bad[ids]]
    return ok.astype(np.intp), k_of[ok]


def piece_indices_numpy(model: RigModel, q: np.ndarray, fam: np.ndarray, sid: np.ndarray, piece: np.ndarray, index: np.ndarray,
                  depth_range_mm: tuple[float, float], *, tol_px: float = 0.3, min_samples: int = 4, other_family: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """`piece_indices` in NumPy (the reference the compiled path reproduces; projectors with more than 5 distortion
    coefficients). The pieces the working volume labels: (piece ids (K,), their index (K,)). Pieces: `piece` (n,)
    non-decreasing ids 0, 1, … of the trace positions, `sid` (n,) their sample ids; fam (P,) the samples' families;
    index (P,) their labels so far (NaN: none). tol_px: the widening of each stretch, projector px."""
    n = len(sid)
    none = (np.zeros(0, np.intp), np.zeros(0, np.intp))
    if n == 0:
        return none
    n_p = int(piece[-1]) + 1
    size = np.bincount(piece, minlength=n_p)
    n_lab = np.bincount(piece, weights=np.isfinite(index[sid]), minlength=n_p)
    open_ = (n_lab == 0) & (size >= min_samples)
    pos = np.flatnonzero(open_[piece])
    if len(pos) == 0:
        return none
    s = sid[pos]
    f = np.asarray(fam)[s].astype(np.intp)
    lo, hi = index_stretch(model, q[s], f, depth_range_mm)
    tol = tol_px / np.asarray(model.line_spacing_perp_px)[f - 1]
    lo = np.where(np.isfinite(lo), lo - tol, np.inf)
    hi = np.where(np.isfinite(hi), hi + tol, -np.inf)
    # per piece: the intersection of its samples' stretches (a sample without one empties it)
    pid = piece[pos]
    starts = np.flatnonzero(np.r_[True, pid[1:] != pid[:-1]])
    ids = pid[starts]
    k_lo = np.maximum(np.ceil(np.maximum.reduceat(lo, starts)), model.index_min)
    k_hi = np.minimum(np.floor(np.minimum.reduceat(hi, starts)), model.index_max)
    one = k_lo == k_hi
    if not one.any():
        return none
    k_of = np.full(n_p, model.index_min - 1, np.intp)
    k_of[ids[one]] = k_lo[one].astype(np.intp)
    if other_family:
        # 3. the family: as lines of the other family the piece's stretches share no index either
        g = 3 - f
        lo_g, hi_g = index_stretch(model, q[s], g, depth_range_mm)
        tol_g = tol_px / np.asarray(model.line_spacing_perp_px)[g - 1]
        lo_g = np.where(np.isfinite(lo_g), lo_g - tol_g, np.inf)
        hi_g = np.where(np.isfinite(hi_g), hi_g + tol_g, -np.inf)
        g_lo = np.maximum(np.ceil(np.maximum.reduceat(lo_g, starts)), model.index_min)
        g_hi = np.minimum(np.floor(np.minimum.reduceat(hi_g, starts)), model.index_max)
        one &= g_lo > g_hi
        if not one.any():
            return none
    # 4. every sample of the piece on sheet k inside the working volume
    sel = np.flatnonzero(k_of[pid] >= model.index_min)
    z = model.sheet_depth(q[s[sel]], f[sel], k_of[pid[sel]])
    out = ~((z >= depth_range_mm[0]) & (z <= depth_range_mm[1]))
    bad = np.zeros(n_p, bool)
    bad[pid[sel][out]] = True
    ok = ids[one][~bad[ids[one]]]
    return ok.astype(np.intp), k_of[ok]


def label_pieces(model: RigModel, q: np.ndarray, fam: np.ndarray, sid: np.ndarray, piece: np.ndarray, ts: np.ndarray,
                 index: np.ndarray, depth_range_mm: tuple[float, float], *, tol_px: float = 0.3, min_samples: int = 4,
                 trim_px: float = 0.0, other_family: bool = True) -> int:
    """`piece_indices`, then the samples of those pieces farther than trim_px (camera px, along the trace: ts (n,)
    the trace positions' coordinate along their piece) from both ends of their piece take its index (in place);
    returns the number of samples labelled. The ends are left out because the ridge is pulled there: by the
    crossing's light at a crossing, by the occluder where a silhouette or shadow cuts the line (decision 0059)."""
    ids, k = piece_indices(model, q, fam, sid, piece, index, depth_range_mm, tol_px=tol_px, min_samples=min_samples,
                           other_family=other_family)
    if len(ids) == 0:
        return 0
    n_p = int(piece[-1]) + 1
    k_of = np.full(n_p, np.nan)
    k_of[ids] = k
    v = k_of[piece]
    m = np.isfinite(v)
    if trim_px > 0:
        t_min = np.full(n_p, np.inf)
        t_max = np.full(n_p, -np.inf)
        np.minimum.at(t_min, piece[m], ts[m])
        np.maximum.at(t_max, piece[m], ts[m])
        m &= (ts - t_min[piece] > trim_px) & (t_max[piece] - ts > trim_px)
    index[sid[m]] = v[m]
    return int(m.sum())
