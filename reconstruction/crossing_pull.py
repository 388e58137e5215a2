"""The other line's pull on a line's samples next to a crossing, taken out (decision 0154).

Near a crossing the two lines' smoothed profiles overlap: line B's light adds a slope across line A, and A's
ridge (Steger's centre) moves towards B. With both profiles approximated by one Gaussian of width σ_e
(σ_e² = σ² + w²/12, σ the extraction's smoothing, w the line width in the camera) and equal peak brightness,
A's ridge at signed distance s across B (camera px along B's normal n_B) moves along A's normal n_A by

    t = −(n_A · n_B) · s · exp(−s² / (2 σ_e²))

to first order (decision 0073's formula, the ridge's curvature −a/σ_e² against the slope B adds), zero at right
angles, largest at s = σ_e, valid where s is at least about σ (closer, the two ridges merge; those samples are
in the label stage's mixing zone). A sample a kept junction's arm holds knows B's line: the junction's fitted
intersection and the other family's fitted direction. The correction moves it by −t along n_A (its own
family's fitted direction's normal); samples closer than `min_sigma`·σ to B are not moved (nor those
beyond 4 σ_e, where the pull is negligible).
"""

from __future__ import annotations

import math

import numpy as np

from reconstruction._jit import njit


def _sigma_e(sigma_px: float, line_width_px: float) -> float:
    """The width of the one Gaussian both lines' smoothed profiles are taken as (module doc)."""
    return math.sqrt(sigma_px * sigma_px + line_width_px * line_width_px / 12.0)


@njit
def _pull(dx, dy, junction_dir, j, a, inv2, s_min2, s_max2):
    """The pull t along line A's normal (module doc) on a sample at (dx, dy) from junction j, A = family a + 1 (0-based
    a), B the other family; NaN where |s| is outside [s_min, s_max] (and where t is not finite)."""
    b = 1 - a
    # normals (−dy, dx) of the sample's own line (A) and of the other family's line (B) at the junction
    nbx = -junction_dir[j, b, 1]
    nby = junction_dir[j, b, 0]
    s = dx * nbx + dy * nby
    s2 = s * s
    if not (s2 >= s_min2 and s2 <= s_max2):
        return math.nan
    return (-junction_dir[j, a, 1] * nbx + junction_dir[j, a, 0] * nby) * s * math.exp(-s2 * inv2)


@njit
def _k_unpull(q, family, junction, q_junction, junction_dir, sigma_e, s_min, out):
    """q (P, 2) float64 samples (camera px), family (P,) 1/2, junction (P,) kept junction id or −1,
    q_junction (M, 2), junction_dir (M, 2, 2) unit directions of the i- and j-line; out (P, 2) a copy of q, the
    moved samples rewritten in place; returns the number moved. Beyond 4 σ_e from the other line the pull is
    below |c|·s·3.4e-4 px and falling (0.0024 px at s = 4 σ_e = 7.2 px, |c| = 1) and the sample is left as
    it is (no exp)."""
    P = q.shape[0]
    inv2 = 0.5 / (sigma_e * sigma_e)
    s_max2 = 16.0 * sigma_e * sigma_e
    s_min2 = s_min * s_min
    n = 0
    for i in range(P):
        j = junction[i]
        if j < 0:
            continue
        f = family[i]
        if f < 1 or f > 2:
            continue
        a = f - 1
        k = _pull(q[i, 0] - q_junction[j, 0], q[i, 1] - q_junction[j, 1], junction_dir, j, a, inv2, s_min2, s_max2)
        if not math.isfinite(k):
            continue
        out[i, 0] = q[i, 0] + k * -junction_dir[j, a, 1]
        out[i, 1] = q[i, 1] + k * junction_dir[j, a, 0]
        n += 1
    return n


@njit
def _k_triangulated_positions(q_labels, q_samples, q_unpulled, out):
    """out[i] = q_unpulled[i] where the label stage left sample i at its ridge centre (q_labels[i] ==
    q_samples[i]), else q_labels[i] (a snapped or gap-filled position)."""
    for i in range(q_labels.shape[0]):
        if q_labels[i, 0] == q_samples[i, 0] and q_labels[i, 1] == q_samples[i, 1]:
            out[i, 0] = q_unpulled[i, 0]
            out[i, 1] = q_unpulled[i, 1]
        else:
            out[i, 0] = q_labels[i, 0]
            out[i, 1] = q_labels[i, 1]


def triangulated_positions(q_labels: np.ndarray, q_samples: np.ndarray, q_unpulled: np.ndarray) -> np.ndarray:
    """The line samples' positions to triangulate: the unpulled ones where the label stage did not move them."""
    out = np.empty((len(q_labels), 2), np.float64)
    _k_triangulated_positions(np.ascontiguousarray(q_labels, np.float64), np.ascontiguousarray(q_samples, np.float64),
                              np.ascontiguousarray(q_unpulled, np.float64), out)
    return out


def unpull_samples(q: np.ndarray, family: np.ndarray, junction: np.ndarray, q_junction: np.ndarray,
                   junction_dir: np.ndarray, sigma_px: float, line_width_px: float, min_sigma: float = 1.0) -> tuple[np.ndarray, int]:
    """The samples with the other line's first-order pull taken out (module docstring); (q', number moved).
    sigma_px: the extraction's smoothing, line_width_px: the line width in the camera (both camera px)."""
    q = np.ascontiguousarray(q, np.float64)
    out = q.copy()
    if len(q) == 0 or len(q_junction) == 0:
        return out, 0
    sigma_e = _sigma_e(sigma_px, line_width_px)
    n = _k_unpull(q, np.ascontiguousarray(family), np.ascontiguousarray(junction, np.int64),
                  np.ascontiguousarray(q_junction, np.float64), np.ascontiguousarray(junction_dir, np.float64),
                  float(sigma_e), float(min_sigma * sigma_px), out)
    return out, int(n)


@njit
def _k_untilted_dirs(q, family, junction, q_junction, junction_dir, sigma_e, s_min, out_dir):
    """The junctions' fitted directions without the tilt the pull put into them (development option, decision
    0154's open lead): each arm's samples are pulled by −k along its normal (k as in `_k_unpull`); a straight
    least-squares fit turns by cov(−k, u) / var(u) (u the position along the arm), so the direction is turned
    back by that. out_dir (M, 2, 2) is written."""
    M = q_junction.shape[0]
    acc = np.zeros((M, 2, 5))  # n, Σu, Σk, Σku, Σuu
    inv2 = 0.5 / (sigma_e * sigma_e)
    s_max2 = 16.0 * sigma_e * sigma_e
    s_min2 = s_min * s_min
    for i in range(q.shape[0]):
        j = junction[i]
        f = family[i]
        if j < 0 or f < 1 or f > 2:
            continue
        a = f - 1
        dx = q[i, 0] - q_junction[j, 0]
        dy = q[i, 1] - q_junction[j, 1]
        u = dx * junction_dir[j, a, 0] + dy * junction_dir[j, a, 1]
        k = _pull(dx, dy, junction_dir, j, a, inv2, s_min2, s_max2)
        if not math.isfinite(k):
            k = 0.0
        acc[j, a, 0] += 1.0
        acc[j, a, 1] += u
        acc[j, a, 2] += k
        acc[j, a, 3] += k * u
        acc[j, a, 4] += u * u
    for j in range(M):
        for a in range(2):
            dx = junction_dir[j, a, 0]
            dy = junction_dir[j, a, 1]
            n = acc[j, a, 0]
            m = 0.0
            if n >= 3.0:
                mu = acc[j, a, 1] / n
                var = acc[j, a, 4] / n - mu * mu
                if var > 1e-9:
                    m = (acc[j, a, 3] / n - mu * acc[j, a, 2] / n) / var
            # turned towards the normal (−dy, dx) by m
            ex = dx - m * dy
            ey = dy + m * dx
            l = math.sqrt(ex * ex + ey * ey)
            out_dir[j, a, 0] = ex / l
            out_dir[j, a, 1] = ey / l


def untilted_dirs(q, family, junction, q_junction, junction_dir, sigma_px: float, line_width_px: float,
                  min_sigma: float = 1.0) -> np.ndarray:
    """`_k_untilted_dirs`: the junctions' directions with the pull's tilt taken out."""
    out = np.array(junction_dir, np.float64, copy=True)
    if len(q) == 0 or len(q_junction) == 0:
        return out
    sigma_e = _sigma_e(sigma_px, line_width_px)
    _k_untilted_dirs(np.ascontiguousarray(q, np.float64), np.ascontiguousarray(family),
                     np.ascontiguousarray(junction, np.int64), np.ascontiguousarray(q_junction, np.float64),
                     np.ascontiguousarray(junction_dir, np.float64), float(sigma_e), float(min_sigma * sigma_px), out)
    return out
