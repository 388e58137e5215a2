"""Candidates at acute crossings: sides counted from the fitted intersection, not the blob's maximum (decision 0133).

A crossing candidate is a maximum of the weaker curvature −λ2, moved to the centroid of its blob (decisions 0055,
0058). Where two lines of width w cross at an acute angle θ in the image, their overlap is a rhombus whose long
diagonal, along the bisector of the acute angle, is w / sin(θ/2) (1.41 w at 90°, 2.3 w at 50°); smoothed, the −λ2
blob is elongated the same way and, with the neighbouring crossings a few px away (a face seen obliquely), its
maximum and centroid lie off the crossing along that bisector. Measured on unseen seed 133's compressed face (cells
about 6 × 8 px, crossings at about 50°): the candidates lie 1.3–2.2 px from the true junctions along the bisector
(1–2 projector px off both lines, where the line samples there are unbiased) while the intersection of the two arm
fits lies 0.2–0.7 px from them. So the tests made relative to the candidate fail a true crossing: "off centre" (the
intersection more than `max_junction_offset_px` from the candidate) and "not through" (a line's arm samples on
both sides of the *candidate*, beyond 0.5 px).

The retry (`recentre_acute`): a candidate that fails only at those two tests (both fits have ≥ 3 samples, not
parallel, finite intersection qj) whose offset qj − candidate lies along the acute bisector within the rhombus'
elongation — across the bisector at most the offset tolerance, along it at most that tolerance × sin 45° / sin(θ/2)
(the elongation relative to a right-angle crossing; θ from the two fits) — has its sides counted again from qj (the
same arm samples and fits: only n_neg, n_pos, m_neg, m_pos change), and is judged by the same tests (through, jump,
turn, crooked) at qj. A line ending at the crossing (a T, an L) still has samples on one side of qj only; a jump at a
depth edge is still compared on both sides.
"""

from __future__ import annotations

import math

import numpy as np

from reconstruction._jit import njit


@njit
def acute_retry(valid, cnt, n_neg, n_pos, par, offc, qj, dr, sx, sy, off_tol):
    """Candidates (rows 2·k + family − 1 in cnt, n_neg, n_pos, dr) rejected at the through or the off-centre test
    whose intersection qj lies along their acute bisector within the rhombus' elongation (module doc). Returns
    (retry (ns,) bool, the moved positions x, y (ns,) float64: qj for retried candidates, else the candidate)."""
    ns = len(sx)
    retry = np.zeros(ns, np.bool_)
    x = sx.copy()
    y = sy.copy()
    for k in range(ns):
        a = 2 * k
        b = a + 1
        if valid[k] or cnt[a] < 3 or cnt[b] < 3 or par[k]:
            continue
        through = n_neg[a] >= 1 and n_pos[a] >= 1 and n_neg[b] >= 1 and n_pos[b] >= 1
        if through and not offc[k]:
            continue  # failed later (crooked, jump, turn): not this retry's case
        qx = qj[k, 0]
        qy = qj[k, 1]
        if not (np.isfinite(qx) and np.isfinite(qy)):
            continue
        d1x = dr[a, 0]
        d1y = dr[a, 1]
        d2x = dr[b, 0]
        d2y = dr[b, 1]
        if d1x * d2x + d1y * d2y < 0:  # the acute angle is between d1 and −d2
            d2x = -d2x
            d2y = -d2y
        bx = d1x + d2x
        by = d1y + d2y
        bn = math.hypot(bx, by)
        if bn == 0:
            continue
        bx /= bn
        by /= bn
        cos_t = min(1.0, abs(d1x * d2x + d1y * d2y))
        sin_half = math.sqrt(max(0.5 * (1.0 - cos_t), 1e-12))  # sin(θ/2), θ the acute angle
        ox = qx - sx[k]
        oy = qy - sy[k]
        along = abs(ox * bx + oy * by)
        across = abs(ox * by - oy * bx)
        if across <= off_tol and along <= off_tol * math.sqrt(0.5) / sin_half:
            retry[k] = True
            x[k] = qx
            y[k] = qy
    return retry, x, y


def recentre_acute(fits: tuple, fresh: tuple, retry: np.ndarray) -> np.ndarray:
    """Copies the side counts and offsets (n_neg, n_pos, m_neg, m_pos) of `fresh` (`junction_fits` with the retried
    candidates moved to their intersections) into `fits` (IN PLACE) for the retried candidates whose fits are the
    same arm samples (equal counts and centres in both: not replaced by a refit of decisions 0077/0120). Returns the
    candidates taken (ns,) bool."""
    cen, _, _, cnt, n_neg, n_pos, m_neg, m_pos, _ = fits
    cen_f, _, _, cnt_f, n_neg_f, n_pos_f, m_neg_f, m_pos_f, _ = fresh
    rows = np.repeat(retry, 2)
    same = (cnt == cnt_f) & np.all(cen == cen_f, axis=1)
    ok = retry & same.reshape(-1, 2).all(axis=1)
    r = np.repeat(ok, 2) & rows
    n_neg[r], n_pos[r], m_neg[r], m_pos[r] = n_neg_f[r], n_pos_f[r], m_neg_f[r], m_pos_f[r]
    return ok
