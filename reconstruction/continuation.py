"""Carry a line's index across the crossings where no junction was labelled (decisions 0066, 0072).

Trace pieces end at every crossing: the other line's light pulls the ridge there (the mixing zone), so
`labelling.label_samples` cuts it out. A piece is labelled from a labelled junction on it, from crossings
with labelled lines at both its ends, or by filling a gap between two labelled pieces of one line. Where
extraction found no junctions (crossings foreshortened, curved or dim), whole patches of lines stay
unlabelled although each of their lines is labelled a few crossings away.

Here the pieces that continue one another across a crossing's gap are chained:

1. **Links.** Two ends of pieces of one family, at most `reach_px` apart, facing each other (directions
   within 12°), whose tangent lines extrapolated to the middle of the gap meet there within `lateral_px`
   (the depth-continuity test of the traces: along one light sheet the depth is a function of the image
   position across the line, so a line that continues on another surface jumps sideways; at the middle a
   smoothly bending line's two tangents agree whatever the gap's length, decision 0072), with a sample of
   the other family near the middle of the gap (a crossing, not a silhouette or a shadow: gaps without a
   crossing are not bridged). `label_samples` makes the reach at least a crossing's gap
   (`crossing_gap_px`), which does not shrink with the junction step on foreshortened surfaces.
2. **Check.** A chain of linked pieces is one line, so an unlabelled piece linked to labelled pieces of
   index k can only be line k. That is checked against the physics, without any label of the other
   family: at each end of the piece, the crossing with the nearest line of the other family (the
   intersection of the two samples' tangents) is triangulated on light sheet k; the projector point must
   lie within `tol_px` of a line of the other family (the crossing is a pattern junction) — with a wrong
   k it lands anywhere along line k, and two such checks at random pass with probability about
   (2·tol/junction spacing)². The piece's samples must lie inside the working volume on sheet k.
   A piece needs at least one crossing checked and none failed.
3. **Spread.** Pieces that fail are removed; the index spreads over the links from labelled pieces through
   checked pieces only (connected components); a component whose labelled pieces disagree is left alone.

The gap samples between newly labelled pieces are filled afterwards by `label_samples` (fill_gaps).

Speed (decision 0067): the ends, the links (`_link_kernels.facing_links_mid`), the crossing-in-the-gap test and the crossings of the check
(both on the frame's bucket grid of samples that `label_samples` builds), the chains (a union–find) and
the writes are compiled (`reconstruction._continuation_kernels`, `_label_kernels`); the check's light
sheets and projections go through `RigModel`.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from reconstruction._continuation_kernels import chain_values, crossing_in_gap, piece_ends, samples_of, write_pieces
from reconstruction._label_kernels import crossing_hits_traces, sample_grid
from reconstruction._link_kernels import (check_depth, check_ends, check_hits, check_samples, check_verdicts, checked_pieces,
                                          facing_links_mid, linked_unlabelled, with_index)
from reconstruction._label_kernels import project_nearest_line as project_nearest_line_kernel
from reconstruction.rigmodel import RigModel

#: directions of two facing ends may differ by at most this
FACING_DEG = 12.0
#: a crossing's two tangents must differ by at least this to be intersected
MIN_CROSSING_DEG = 20.0
_SIN_MIN_CROSSING = float(np.sin(np.deg2rad(MIN_CROSSING_DEG)))
_COS_FACING = float(np.cos(np.deg2rad(FACING_DEG)))


@lru_cache(maxsize=64)
def crossing_gap_px(sigma_px: float, *, mix_sigma: float, trim_sigma: float, min_angle_deg: float) -> float:
    """The longest gap a crossing leaves in a trace (camera px, decision 0072): the mixing zone (mix_sigma·σ
    from the other line's samples) and the trimmed ends (trim_sigma·σ) on both sides, measured along a line
    that crosses the other at min_angle_deg. It depends on the smoothing and the crossing angle, not on the
    grid's pitch: on a foreshortened surface the junction step shrinks, the gap does not."""
    return 2.0 * (mix_sigma + trim_sigma) * sigma_px / np.sin(np.deg2rad(min_angle_deg))


def nearest_line(model: RigModel, family: np.ndarray, uv_proj: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The nearest line of `family` (N,) (1 or 2) to projector pixels uv_proj (N, 2), not clamped to the
    pattern: its index (N,) int (0 where none) and the perpendicular distance to it in projector px (N,)
    (inf where none; a point beyond the outermost line is that line's distance away, so it fails a
    residual test instead of snapping)."""
    pat = model.pattern
    uv = np.asarray(uv_proj, np.float64).reshape(-1, 2)
    x = uv[:, 0] - pat.centre_px[0]
    y = uv[:, 1] - pat.centre_px[1]
    idx = np.zeros(len(uv), np.int64)
    dist = np.full(len(uv), np.inf)
    for f, n in ((1, pat.n1), (2, pat.n2)):
        sel = np.flatnonzero(family == f)
        if len(sel) == 0:
            continue
        offs = np.asarray(pat.offsets_px(f), np.float64)
        s = y[sel] - n * x[sel]
        k = np.clip(np.searchsorted(offs, s), 1, len(offs) - 1)
        k = np.where(np.abs(s - offs[k - 1]) <= np.abs(s - offs[k]), k - 1, k)
        ok = np.isfinite(s)
        idx[sel[ok]] = pat.indices[k[ok]]
        dist[sel[ok]] = np.abs(s[ok] - offs[k[ok]]) / np.hypot(1.0, n)
    return idx, dist


def project_nearest_line(model: RigModel, family: np.ndarray, p_proj: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`nearest_line` of the projector pixels of points p_proj (N, 3) (`Intrinsics.project`; none where
    z ≤ 0): index (N,) and distance (N,) projector px. One compiled pass for OpenCV's 5-coefficient
    distortion (`_label_kernels.project_nearest_line`, the same float operations); other models project
    with `Intrinsics.project`."""
    proj = model.procam.projector
    fam = np.ascontiguousarray(np.asarray(family).reshape(-1), np.int64)
    p = np.ascontiguousarray(np.asarray(p_proj, np.float64).reshape(-1, 3))
    if proj.dist.size > 5:
        return nearest_line(model, fam, proj.project(p))
    return project_nearest_line_kernel(p, fam, *model.nearest_line_tables)  # tables cached per rig (decision 0078)


def continue_lines(
    q: np.ndarray,
    fam: np.ndarray,
    sid: np.ndarray,
    piece: np.ndarray,
    ts: np.ndarray,
    tangent: np.ndarray,
    index: np.ndarray,
    seed_jid: np.ndarray,
    valid: np.ndarray,
    *,
    model: RigModel,
    depth_range_mm: tuple[float, float],
    reach_px: float,
    lateral_px: float = 1.0,
    tol_px: float = 1.5,
    anchor: int = 3,
    trim_px: float = 0.0,
    grid: tuple | None = None,
    check_radius_px: float | None = None,
) -> dict:
    """Label unlabelled trace pieces that continue a labelled piece's line across crossings (module doc).

    q (P, 2) camera px and fam (P,) of all samples; valid (P,) bool: the samples that count as lines (for
    the crossing-in-the-gap test, the mixing zone included). The traces, as `label_samples` builds them:
    sid (n,) sample ids sorted by piece and position, piece (n,) non-decreasing piece ids, ts (n,) positions
    along the piece (px), tangent (n, 2) unit directions. The samples within trim_px of a continued piece's
    ends are left out (the crossing's light pulls the ridge there; the gap filling puts them on the line). index (P,) float (NaN: unlabelled) and seed_jid (P,) int are written in place for the
    newly labelled samples (seed_jid: that of the labelled piece the index came from). grid: the frame's
    bucket grid of the valid samples (`labelling._sample_grid`, cells at least check_radius_px wide; built
    here when not given). check_radius_px: how far from a piece's end the check looks for the crossing
    (default reach_px; `label_samples` keeps the junction-step share there, so that a longer reach does not
    widen the frame's shared grid, decision 0072).
    Returns counts.
    """
    stats = {"links": 0, "pieces_checked": 0, "pieces_failed": 0, "samples": 0}
    n_p = int(piece[-1]) + 1 if len(piece) else 0
    if n_p < 2:
        return stats
    e, u, end_pos, labelled, val, jsrc = piece_ends(q, sid, piece, tangent, index, seed_jid, n_p, int(anchor))
    if labelled.all() or not labelled.any():
        return stats
    f_e = fam[sid[end_pos]].astype(np.int64)

    # 1. links between facing ends across a crossing's gap
    a, b, gap, i, j = facing_links_mid(e, u, f_e, n_p, labelled, float(reach_px), float(lateral_px), _COS_FACING)
    if len(a) == 0:
        return stats
    radius = float(reach_px if check_radius_px is None else check_radius_px)
    if grid is None:
        x0, y0, gw, gh, start, items, pos_of = sample_grid(q, valid, sid, radius)
        grid = (float(x0), float(y0), radius, int(gw), int(gh), start, items, pos_of)
    crossing = crossing_in_gap(q, fam, e, f_e, i, j, gap, *grid[:7])
    a, b = a[crossing], b[crossing]
    stats["links"] = int(len(a))
    if len(a) == 0:
        return stats

    # 2. check every unlabelled linked piece against its chain's index (the masks around the kernels
    # compiled, decision 0087: `_link_kernels.linked_unlabelled`, `checked_pieces`, `with_index`)
    k_of, _ = chain_values(n_p, a, b, np.ones(n_p, np.bool_), labelled, val, jsrc)
    cand = linked_unlabelled(n_p, a, b, labelled, k_of)
    stats["pieces_checked"] = int(len(cand))
    if len(cand) == 0:
        return stats
    good = _check_pieces(cand, k_of, q, fam, sid, piece, tangent, e, u, f_e, model, depth_range_mm, radius, tol_px, grid)
    # 3. spread through the checked pieces only
    keep, new, n_failed = checked_pieces(labelled, cand, good)
    stats["pieces_failed"] = int(n_failed)
    k_of, src_of = chain_values(n_p, a, b, keep, labelled, val, jsrc)
    if not with_index(new, k_of):
        return stats
    # the seed junction of a labelled piece of the same chain
    stats["samples"] = int(write_pieces(sid, piece, ts, new, k_of, src_of, float(trim_px), index, seed_jid))
    return stats


def _check_pieces(cand, k_of, q, fam, sid, piece, tangent, e, u, f_e, model: RigModel, depth_range_mm, radius, tol_px, grid):
    """Step 2 of the module doc for pieces `cand`: (len(cand),) bool."""
    # (the gathers and tests around the two searches compiled, decision 0087: `_link_kernels.check_*`)
    n_p = len(e) // 2
    nc = len(cand)
    E, U, fe = check_ends(cand, n_p, e, u, f_e)  # first ends, then last ends
    o, c = crossing_hits_traces(E, U, np.ones(2 * nc), fe, q, sid, tangent, fam, np.zeros(0), False, float(radius), _SIN_MIN_CROSSING,
                                *grid)
    sel, c_sel, f_sel, k_sel = check_hits(o, c, fe, k_of, cand)
    res = model.sheet_check(c_sel, f_sel, k_sel)[3] if len(sel) else np.zeros(0)  # nearest line of 3 − fe
    good = check_verdicts(o, sel, res, float(tol_px), nc)
    # the working volume, on the piece's light sheet
    flag = np.zeros(n_p, bool)
    flag[cand[good]] = True
    pos = samples_of(piece, flag)
    if len(pos):
        q_pos, f_pos, k_pos = check_samples(pos, q, sid, fam, piece, k_of)
        z = model.sheet_depth(q_pos, f_pos, k_pos)  # `sheet_check`'s z alone, to the bit (decisions 0094, 0096)
        check_depth(good, cand, pos, piece, z, float(depth_range_mm[0]), float(depth_range_mm[1]), n_p)
    return good
