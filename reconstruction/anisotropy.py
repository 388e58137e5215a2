"""Junction spacing along each line family, as the calibration predicts it (decision 0077).

`RigModel.junction_step_cam_px` is ONE typical spacing for the whole image (the shorter of the two families'
at the working depth). Where the grid is anisotropic in the image (oblique views: the paper's orthogonal rig
sees crossings ~40 px apart along the i-lines and ~100 px along the j-lines) the arms of a junction sized from
that one step reach into the neighbouring crossing along the dense family, whose light pulls the ridge
sideways there: the arm's straight-line fit turns and the junction is rejected as crooked. This module gives
the spacing along each family at each camera position from the model's coarse Jacobian table, so that the
arms can follow it.

Along an i-line (y = n1·x + c in the projector) the j-lines cross every Δx = p2 / |n2 − n1| (p2: the
spacing of the j-lines' offsets), i.e. at projector displacements Δx·(1, n1); in the camera that is
J_cam_proj(q)·(1, n1)·Δx (camera px), with J_cam_proj the inverse of the model's `J_proj_cam` at the nearest
cell (a surface at the model's reference depth). Likewise along a j-line with (1, n2) and p1.
"""

from __future__ import annotations

import math
import weakref

import numpy as np

from reconstruction._jit import njit
from reconstruction.rigmodel import RigModel

_steps_cache: "weakref.WeakKeyDictionary[RigModel, np.ndarray]" = weakref.WeakKeyDictionary()


def family_steps_table(model: RigModel) -> np.ndarray:
    """(gh, gw, 2) float64: the predicted camera distance (px) between neighbouring junctions along an
    i-line [..., 0] and along a j-line [..., 1], on the model's coarse grid (cell `model.cell_px`).

    The spacing of the other family's lines is their smallest offset difference (uniform patterns: the
    pitch; De Bruijn spacings: the narrowest gap), so the arms stay short of the nearest neighbour."""
    tab = _steps_cache.get(model)
    if tab is not None:
        return tab
    pat = model.pattern
    n1, n2 = float(pat.n1), float(pat.n2)
    p1 = float(np.min(np.diff(pat.offsets_px(1)))) if pat.lines > 1 else float(pat.pitch_px)
    p2 = float(np.min(np.diff(pat.offsets_px(2)))) if pat.lines > 1 else float(pat.pitch_px)
    gh, gw = model.J_proj_cam.shape[:2]
    J_pc = model.J_proj_cam.reshape(-1, 2, 2)
    det = J_pc[:, 0, 0] * J_pc[:, 1, 1] - J_pc[:, 0, 1] * J_pc[:, 1, 0]
    ok = np.abs(det) > 1e-12
    J_cp = np.empty_like(J_pc)
    d = np.where(ok, det, 1.0)
    J_cp[:, 0, 0] = J_pc[:, 1, 1] / d
    J_cp[:, 1, 1] = J_pc[:, 0, 0] / d
    J_cp[:, 0, 1] = -J_pc[:, 0, 1] / d
    J_cp[:, 1, 0] = -J_pc[:, 1, 0] / d
    tab = np.empty((gh * gw, 2))
    for f, (n, p_other) in enumerate(((n1, p2), (n2, p1))):
        v = J_cp @ np.array([1.0, n])
        tab[:, f] = np.hypot(v[:, 0], v[:, 1]) * p_other / abs(n2 - n1)
    fallback = model.junction_step_cam_px
    tab[~ok] = fallback
    tab[~np.isfinite(tab)] = fallback
    tab = tab.reshape(gh, gw, 2)
    tab.setflags(write=False)
    _steps_cache[model] = tab
    return tab


def family_steps_at(model: RigModel, q_cam: np.ndarray) -> np.ndarray:
    """(N, 2) predicted junction spacing (camera px) along an i-line and a j-line at camera points q_cam
    (N, 2), from the nearest cell of `family_steps_table`."""
    tab = family_steps_table(model)
    q = np.asarray(q_cam, np.float64).reshape(-1, 2)
    gh, gw = tab.shape[:2]
    c = np.clip(np.rint(q[:, 0] / model.cell_px).astype(np.intp), 0, gw - 1)
    r = np.clip(np.rint(q[:, 1] / model.cell_px).astype(np.intp), 0, gh - 1)
    return tab[r, c]


@njit
def arms_by_family(sidx, sg, sproj, smin, smax, seg_seed, fam, qx, qy, sx32, sy32, R_fam32, d_trim, P):
    """As `_extract_kernels.arms`, with the arm radius of each candidate and family: R_fam32 (ns, 2) float32,
    column family − 1, and without the samples within d_trim (px along the segment) of a free end (an end
    that reaches no candidate: a line cut by a silhouette or shadow, whose ridge bends there, decision 0059).
    arm_of (P,) int64: the junction candidate whose arm each segment sample is, −1: none."""
    arm_of = np.full(P, -1, np.int64)
    for k in range(len(sidx)):
        g = sg[k]
        a0 = seg_seed[g, 0]
        a1 = seg_seed[g, 1]
        d_lo = sproj[k] - smin[g]
        d_hi = smax[g] - sproj[k]
        pick = a1 if (a1 >= 0 and (a0 < 0 or d_hi < d_lo)) else a0
        if pick < 0:
            continue
        if (a0 < 0 and d_lo < d_trim) or (a1 < 0 and d_hi < d_trim):
            continue
        i = sidx[k]
        dx = qx[i] - sx32[pick]
        dy = qy[i] - sy32[pick]
        if np.float32(math.sqrt(dx * dx + dy * dy)) <= R_fam32[pick, fam[i] - 1]:
            arm_of[i] = pick
    return arm_of


def _bent(fits: tuple, ns: int, *, rms_tol: float, sin_tol: float) -> np.ndarray:
    """(ns,) bool: a family's arm fit is not straight (the extraction's crooked, jump and turn tests)."""
    _, _, rms, cnt, n_neg, n_pos, m_neg, m_pos, mean_sin = fits
    return ((rms.reshape(ns, 2) > rms_tol) | (np.abs(m_neg - m_pos).reshape(ns, 2) > rms_tol)
            | (mean_sin.reshape(ns, 2) > sin_tol)).any(axis=1)


def _usable(fits: tuple, ns: int) -> np.ndarray:
    """(ns,) bool: both families' arms have ≥ 3 samples and samples on both sides of the candidate."""
    _, _, _, cnt, n_neg, n_pos, _, _, _ = fits
    return ((cnt.reshape(ns, 2) >= 3) & (n_neg.reshape(ns, 2) >= 1) & (n_pos.reshape(ns, 2) >= 1)).all(axis=1)


def retry_trimmed_arms(fits: tuple, arm_of: np.ndarray, arm_args: tuple, R_fam32: np.ndarray, d_trim: float, fit_args: tuple,
                       *, rms_tol: float, sin_tol: float) -> tuple[tuple, np.ndarray, int]:
    """Candidates whose arm fits are bent (crooked, a sideways jump or a turn) fitted again without the arm
    samples within d_trim of a free segment end (a line cut by a silhouette or a shadow: its ridge bends
    there, decision 0059). Where those arms are straight and still run through the candidate (≥ 3 samples
    per family, samples on both sides), their fits replace the first ones; other candidates keep theirs.

    fits: `_extract_kernels.junction_fits`' 9 arrays (rows 2·k + family − 1); arm_of (P,): the arms;
    arm_args: (sidx, sg, sproj, smin, smax, seg_seed, fam, qx, qy, sx32, sy32) for `arms_by_family`;
    fit_args: the arguments of `junction_fits` after arm_of. Returns the merged fits, the merged arm_of
    and how many candidates took the trimmed arms."""
    ns = len(R_fam32)
    bent = _bent(fits, ns, rms_tol=rms_tol, sin_tol=sin_tol) & _usable(fits, ns)
    if not bent.any():
        return fits, arm_of, 0
    R_retry = np.where(bent[:, None], R_fam32, np.float32(-1.0)).astype(np.float32)
    P = len(arm_of)
    arm_t = arms_by_family(*arm_args, R_retry, d_trim, P)
    from reconstruction._extract_kernels import junction_fits

    fits_t = junction_fits(arm_t, *fit_args)
    take = bent & _usable(fits_t, ns) & ~_bent(fits_t, ns, rms_tol=rms_tol, sin_tol=sin_tol)
    if not take.any():
        return fits, arm_of, 0
    rows = np.repeat(take, 2)
    merged = tuple(np.where(rows.reshape((-1,) + (1,) * (a.ndim - 1)), b, a) for a, b in zip(fits, fits_t))
    arm_new = arm_of.copy()
    moved = (arm_of >= 0) & take[np.maximum(arm_of, 0)]
    arm_new[moved] = arm_t[moved]
    return merged, arm_new, int(take.sum())
