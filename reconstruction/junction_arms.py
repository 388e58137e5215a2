"""Junction arms cut by a silhouette or a shadow: refit without the bent ends (decision 0077).

A junction's arms are the samples of the segments that reach its crossing, up to 0.6 junction steps away
(extraction step 4b). Where a silhouette or a shadow edge cuts a line a little past the crossing, the cut
half of the bar pulls the smoothed ridge sideways within about two smoothing scales of the cut (decision
0059), and on wide lines (the paper's rigs, σ ≈ 5 px) that bent stretch is a large share of a short arm: the
arm's straight-line fit fails the crooked, jump or turn test and a true junction is lost. The refit takes,
for the candidates that fail only those tests, the same arms without the samples within
`free_end_trim_sigma`·σ of a free segment end (an end that reaches no crossing) and keeps the candidate if
the shorter arms are straight and still run through it. Samples are only ever removed: the through, count,
offset and parallel tests are unchanged, so T and L shapes (a line ending at the crossing) stay out.

A candidate still bent after that is fitted once more on its arm samples within half the arm radius
(`ExtractOptions.arm_short_share`, round 4b of decision 0077): a line curved by the surface is off its chord
by an amount that shrinks with the arm's length squared, a sideways step at the crossing (a depth edge) is
not, so the jump test keeps its meaning.
"""

from __future__ import annotations

import numpy as np

from reconstruction._jit import njit


@njit
def _straight_usable(rms, cnt, n_neg, n_pos, m_neg, m_pos, mean_sin, k, rms_tol, sin_tol):
    """Candidate k's two arm fits: (straight: no crooked, jump or turn; usable: ≥ 3 samples per family and
    samples on both sides of the candidate), the extraction's tests."""
    straight = True
    usable = True
    for g in (2 * k, 2 * k + 1):
        if rms[g] > rms_tol or abs(m_neg[g] - m_pos[g]) > rms_tol or mean_sin[g] > sin_tol:
            straight = False
        if cnt[g] < 3 or n_neg[g] < 1 or n_pos[g] < 1:
            usable = False
    return straight, usable


@njit
def _bent_candidates(rms, cnt, n_neg, n_pos, m_neg, m_pos, mean_sin, rms_tol, sin_tol):
    ns = len(rms) // 2
    bent = np.zeros(ns, np.bool_)
    for k in range(ns):
        straight, usable = _straight_usable(rms, cnt, n_neg, n_pos, m_neg, m_pos, mean_sin, k, rms_tol, sin_tol)
        bent[k] = usable and not straight
    return bent


@njit
def _arm_positions(sidx, arm_of, retry):
    """The positions k in the segment-sample order (sidx) of the arm samples of the candidates flagged in
    `retry`: one scan over the segment samples for both refits."""
    pos = np.empty(len(sidx), np.int64)
    n = 0
    for k in range(len(sidx)):
        a = arm_of[sidx[k]]
        pos[n] = k
        n += a >= 0 and retry[max(a, 0)]
    return pos[:n]


@njit
def _split_near(near, pos, sidx, n_kept, n_dropped):
    """The sample ids sidx[pos[p]] with near[p] == 1 (kept, n_kept of them) and == 2 (dropped, n_dropped),
    in position order; near[p] == 0: neither."""
    kept = np.empty(n_kept, np.int64)
    dropped = np.empty(n_dropped, np.int64)
    n = 0
    m = 0
    for p in range(len(pos)):
        if near[p] == 1:
            kept[n] = sidx[pos[p]]
            n += 1
        elif near[p] == 2:
            dropped[m] = sidx[pos[p]]
            m += 1
    return kept, dropped


@njit
def _trimmed_arm_samples(sidx, sg, sproj, smin, smax, seg_seed, arm_of, retry, d_trim, pos):
    """The arm samples of the candidates flagged in `retry` (at positions pos in sidx, `_arm_positions`):
    those farther than d_trim (px along the segment) from every free end of their segment (kept), and the
    others (dropped); ids in segment-sample order."""
    # only segments with a free end and the other end at a retried candidate can lose samples
    S = len(seg_seed)
    free = np.zeros(S, np.bool_)
    any_free = False
    for g in range(S):
        a0 = seg_seed[g, 0]
        a1 = seg_seed[g, 1]
        if (a0 < 0 and a1 >= 0 and retry[a1]) or (a1 < 0 and a0 >= 0 and retry[a0]):
            free[g] = True
            any_free = True
    if not any_free:
        return np.empty(0, np.int64), np.empty(0, np.int64)
    near = np.zeros(len(pos), np.int8)  # per retried arm sample: 1 kept, 2 dropped
    n = 0
    m = 0
    for p in range(len(pos)):
        k = pos[p]
        g = sg[k]
        if free[g] and ((seg_seed[g, 0] < 0 and sproj[k] - smin[g] < d_trim) or (seg_seed[g, 1] < 0 and smax[g] - sproj[k] < d_trim)):
            near[p] = 2
            m += 1
        else:
            near[p] = 1
            n += 1
    return _split_near(near, pos, sidx, n, m)


@njit
def _short_arm_samples(sidx, sg, sproj, smin, smax, seg_seed, arm_of, retry, d_trim, pos, qx, qy, sx, sy, r_short):
    """Of the arm samples at positions pos (`_arm_positions`), those of the candidates flagged in `retry`:
    those within r_short (px) of their candidate and farther than d_trim (px along the segment) from every
    free end of their segment (kept), and the others (dropped); ids in segment-sample order."""
    near = np.zeros(len(pos), np.int8)  # per arm sample: 0 not retried, 1 kept, 2 dropped
    n = 0
    m = 0
    for p in range(len(pos)):
        k = pos[p]
        i = sidx[k]
        a = arm_of[i]
        if a < 0 or not retry[a]:
            continue
        g = sg[k]
        dx = np.float64(qx[i]) - sx[a]
        dy = np.float64(qy[i]) - sy[a]
        if dx * dx + dy * dy > r_short * r_short or (seg_seed[g, 0] < 0 and sproj[k] - smin[g] < d_trim) or (
            seg_seed[g, 1] < 0 and smax[g] - sproj[k] < d_trim
        ):
            near[p] = 2
            m += 1
        else:
            near[p] = 1
            n += 1
    return _split_near(near, pos, sidx, n, m)


@njit
def _merge(fits, fits_t, cand, arm_of, dropped, rms_tol, sin_tol):
    """fits_t: the refits of candidates cand (row 2·c + family − 1 for cand[c]). Where they are straight and
    usable, copy them over the first fits and take the dropped samples out of arm_of (in place). Returns
    how many candidates took them."""
    cen, dr, rms, cnt, n_neg, n_pos, m_neg, m_pos, mean_sin = fits
    cen_t, dr_t, rms_t, cnt_t, n_neg_t, n_pos_t, m_neg_t, m_pos_t, mean_sin_t = fits_t
    take = np.zeros(len(rms) // 2, np.bool_)
    n_take = 0
    for c in range(len(cand)):
        straight, usable = _straight_usable(rms_t, cnt_t, n_neg_t, n_pos_t, m_neg_t, m_pos_t, mean_sin_t, c, rms_tol, sin_tol)
        if not (straight and usable):
            continue
        k = cand[c]
        take[k] = True
        n_take += 1
        for f in range(2):
            g = 2 * k + f
            h = 2 * c + f
            cen[g, 0] = cen_t[h, 0]
            cen[g, 1] = cen_t[h, 1]
            dr[g, 0] = dr_t[h, 0]
            dr[g, 1] = dr_t[h, 1]
            rms[g] = rms_t[h]
            cnt[g] = cnt_t[h]
            n_neg[g] = n_neg_t[h]
            n_pos[g] = n_pos_t[h]
            m_neg[g] = m_neg_t[h]
            m_pos[g] = m_pos_t[h]
            mean_sin[g] = mean_sin_t[h]
    for i in dropped:
        if take[arm_of[i]]:
            arm_of[i] = -1
    return n_take


def retry_trimmed_arms(fits: tuple, arm_of: np.ndarray, seg_args: tuple, d_trim: float, sample_args: tuple, seeds_xy: tuple,
                       *, rms_tol: float, sin_tol: float, r_short: float = 0.0) -> int:
    """Candidates whose arm fits are bent (crooked, a sideways jump or a turn) are fitted again without the
    arm samples within d_trim of a free segment end (a line cut by a silhouette or a shadow: its ridge bends
    there, decision 0059). Where those arms are straight and still run through the candidate (≥ 3 samples
    per family, samples on both sides), their fits replace the first ones IN PLACE (and the trimmed-away
    samples leave arm_of); other candidates keep theirs. Only the retried candidates' samples are refitted.

    fits: `_extract_kernels.junction_fits`' 9 arrays (rows 2·k + family − 1), modified in place; arm_of (P,):
    the arms, modified in place; seg_args: (sidx, sg, sproj, smin, smax, seg_seed); sample_args: (fam, qx,
    qy, nx, ny) per sample; seeds_xy: (sx, sy) float64 candidate positions. r_short > 0: candidates still
    bent after that are fitted once more on their arm samples within r_short px of the candidate (and not
    within d_trim of a free end), taken on the same terms. Returns how many candidates took a refit."""
    _, _, rms, cnt, n_neg, n_pos, m_neg, m_pos, mean_sin = fits
    bent = _bent_candidates(rms, cnt, n_neg, n_pos, m_neg, m_pos, mean_sin, rms_tol, sin_tol)
    cand = np.flatnonzero(bent)
    if len(cand) == 0:
        return 0
    pos = _arm_positions(seg_args[0], arm_of, bent)
    kept, dropped = _trimmed_arm_samples(*seg_args, arm_of, bent, float(d_trim), pos)
    n_take = 0
    if len(dropped):  # else nothing near a free end: the same fits
        n_take = _refit(fits, arm_of, cand, kept, dropped, sample_args, seeds_xy, rms_tol, sin_tol)
    if r_short <= 0:
        return n_take
    # still bent: once more on arms of r_short around the candidate (without the free ends' samples too)
    bent &= _bent_candidates(rms, cnt, n_neg, n_pos, m_neg, m_pos, mean_sin, rms_tol, sin_tol)
    cand = np.flatnonzero(bent)
    if len(cand) == 0:
        return n_take
    fam, qx, qy, nx, ny = sample_args
    kept, dropped = _short_arm_samples(*seg_args, arm_of, bent, float(d_trim), pos, qx, qy, seeds_xy[0], seeds_xy[1], float(r_short))
    if len(dropped) == 0:
        return n_take
    return n_take + _refit(fits, arm_of, cand, kept, dropped, sample_args, seeds_xy, rms_tol, sin_tol)


@njit
def _refit_inputs(cand, kept, arm_of, fam, qx, qy, nx, ny, sx, sy, ns):
    """`junction_fits`' inputs for the candidates cand refitted on samples kept: the arm of each kept sample
    renumbered as its candidate's position in cand (int64, −1 for others), its family, position and normal,
    and the candidates' positions (the gathers `compact[arm_of[kept]]`, `fam[kept]`, ..., `sx[cand]`)."""
    compact = np.full(ns, -1, np.int64)
    for c in range(cand.shape[0]):
        compact[cand[c]] = c
    n = kept.shape[0]
    arm = np.empty(n, np.int64)
    f = np.empty(n, fam.dtype)
    x = np.empty(n, qx.dtype)
    y = np.empty(n, qy.dtype)
    ax = np.empty(n, nx.dtype)
    ay = np.empty(n, ny.dtype)
    for i in range(n):
        s = kept[i]
        arm[i] = compact[arm_of[s]]
        f[i] = fam[s]
        x[i] = qx[s]
        y[i] = qy[s]
        ax[i] = nx[s]
        ay[i] = ny[s]
    nc = cand.shape[0]
    cx = np.empty(nc, sx.dtype)
    cy = np.empty(nc, sy.dtype)
    for c in range(nc):
        cx[c] = sx[cand[c]]
        cy[c] = sy[cand[c]]
    return arm, f, x, y, ax, ay, cx, cy


def _refit(fits: tuple, arm_of: np.ndarray, cand: np.ndarray, kept: np.ndarray, dropped: np.ndarray, sample_args: tuple,
           seeds_xy: tuple, rms_tol: float, sin_tol: float) -> int:
    """Fit candidates cand on their arm samples `kept` only; merge where straight and usable (in place)."""
    from reconstruction._extract_kernels import junction_fits

    # the kept samples' arms renumbered among cand, their samples' arrays and cand's positions: one
    # compiled gather (decision 0087)
    fits_in = _refit_inputs(cand, kept, arm_of, *sample_args, seeds_xy[0], seeds_xy[1], len(fits[2]) // 2)
    fits_t = junction_fits(*fits_in, len(cand))
    return int(_merge(fits, fits_t, cand, arm_of, dropped, rms_tol, sin_tol))
