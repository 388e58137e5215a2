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
   across-line units): the sample's position noise and the calibration's epipolar error.
2. The piece's admissible indices: the integers inside the intersection of its samples' widened stretches and
   inside the pattern. Exactly one, k, is required; none or several: the piece stays unlabelled.
3. Away from both ends of the intersection by its own noise: the piece's samples also lie on sheet k inside
   the working volume (`RigModel.sheet_depth`, the triangulation's own sheet): every sample's depth inside
   [depth_min_mm, depth_max_mm].

Why this is safe where one-sided evidence is not (decisions 0049, 0089, 0093): no neighbour is involved; the
only assumption is the working volume itself, which the labeller already relies on (offsets outside it are
discarded) and the triangulation enforces (points outside it are dropped). A sample's true sheet puts it at its
true depth, inside the working volume, so the true index is always admissible, and when it is the only one it
is the right one — provided the piece is one line's samples of the family it was given. A piece of the other
family (given this family by mistake) drifts by one line per junction step along itself: its stretches do not
share an integer once it is longer than the stretch (step 2 then finds none). A piece joining two lines is cut
by the trace's own tests (lateral jump, turn, ridge step).
"""

from __future__ import annotations

import numpy as np

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


def piece_indices(model: RigModel, q: np.ndarray, fam: np.ndarray, sid: np.ndarray, piece: np.ndarray, index: np.ndarray,
                  depth_range_mm: tuple[float, float], *, tol_px: float = 0.3, min_samples: int = 4, other_family: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """The pieces the working volume labels (module doc): (piece ids (K,), their index (K,)). Pieces: `piece` (n,)
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
        # 4. the family: as lines of the other family the piece's stretches share no index either
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
    # 3. every sample of the piece on sheet k inside the working volume
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
