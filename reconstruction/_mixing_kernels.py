"""Compiled kernel for the mixing zone shaped by the crossing's geometry (decision 0073).

A sample of one family near a line of the other family is pulled along its own normal by the other
line's light. With both lines' smoothed profiles approximated by one Gaussian of width σ_e
(σ_e² = σ² + w²/12: the extraction's smoothing σ and a line of width w camera px), the ridge of line A
at distance s (camera px, across B) from the centre of line B, crossing it at angle θ, lies where
g_A'(t) + cos θ · g_B'(s + t cos θ) = 0; to first order in the small pull

    t ≈ −cos θ · g_B'(s) / g_A''(0) = cos θ · s · exp(−s² / (2 σ_e²))      (camera px, along A's normal).

It vanishes at right angles and far from B and is largest at s = σ_e. The first-order expansion holds
only where the other line's curvature across A is small against A's own (s of at least about σ): closer
than that the two ridges merge and the sample is kept in the zone whatever the angle.
"""

from __future__ import annotations

import numpy as np

from reconstruction._jit import njit


@njit
def mixing_bias_release(q, r, c, fam, valid, near_other, H, W, dr, dc, sigma_e, s_min, tol_px, max_rms_px, min_count):
    """Release mixing-zone samples whose predicted pull is below tol_px (camera px); near_other (P,) bool is
    cleared in place for them. Returns how many were released.

    q (P, 2) camera px; r, c (P,) their cells on the padded grid H×W (as for `_label_kernels.mixing_zone`);
    dr, dc (K,) the offsets of the zone's disc. For a sample in the zone, the samples of each family in
    its disc are fitted with a straight line (principal axis); both fits need min_count samples and the
    other family's an RMS across its line below max_rms_px (one line, not a blob). s: the sample's
    distance from the other family's fitted line; cos θ from the two fitted directions. Released when
    s ≥ s_min and cos θ · s · exp(−s²/(2 σ_e²)) ≤ tol_px (module docstring)."""
    P = r.shape[0]
    id1 = np.full(H * W, -1, np.int64)
    id2 = np.full(H * W, -1, np.int64)
    for i in range(P):
        if valid[i]:
            if fam[i] == 1:
                id1[r[i] * W + c[i]] = i
            else:
                id2[r[i] * W + c[i]] = i
    K = dr.shape[0]
    released = 0
    inv2 = 1.0 / (2.0 * sigma_e * sigma_e)
    for i in range(P):
        if not valid[i] or not near_other[i]:
            continue
        # per family: count, sums of x, y, xx, xy, yy (relative to the sample)
        na = 0
        ax = 0.0
        ay = 0.0
        axx = 0.0
        axy = 0.0
        ayy = 0.0
        nb = 0
        bx = 0.0
        by = 0.0
        bxx = 0.0
        bxy = 0.0
        byy = 0.0
        x0 = q[i, 0]
        y0 = q[i, 1]
        for k in range(K):
            rr = r[i] + dr[k]
            cc = c[i] + dc[k]
            if rr < 0 or rr >= H or cc < 0 or cc >= W:
                continue
            g = rr * W + cc
            j1 = id1[g]
            j2 = id2[g]
            for t in range(2):
                j = j1 if t == 0 else j2
                if j < 0:
                    continue
                x = q[j, 0] - x0
                y = q[j, 1] - y0
                if fam[j] == fam[i]:
                    na += 1
                    ax += x
                    ay += y
                    axx += x * x
                    axy += x * y
                    ayy += y * y
                else:
                    nb += 1
                    bx += x
                    by += y
                    bxx += x * x
                    bxy += x * y
                    byy += y * y
        if na < min_count or nb < min_count:
            continue
        # principal axes
        mxa = ax / na
        mya = ay / na
        sxx = axx / na - mxa * mxa
        sxy = axy / na - mxa * mya
        syy = ayy / na - mya * mya
        pha = 0.5 * np.arctan2(2.0 * sxy, sxx - syy)
        mxb = bx / nb
        myb = by / nb
        sxx = bxx / nb - mxb * mxb
        sxy = bxy / nb - mxb * myb
        syy = byy / nb - myb * myb
        phb = 0.5 * np.arctan2(2.0 * sxy, sxx - syy)
        tbx = np.cos(phb)
        tby = np.sin(phb)
        # variance across B's fitted line
        var_across = sxx * tby * tby - 2.0 * sxy * tbx * tby + syy * tbx * tbx
        if var_across > max_rms_px * max_rms_px:
            continue
        cos_t = abs(np.cos(pha) * tbx + np.sin(pha) * tby)
        s = abs(-mxb * tby + myb * tbx)  # the sample (origin) from B's line through (mxb, myb)
        if s < s_min:
            continue
        if cos_t * s * np.exp(-s * s * inv2) <= tol_px:
            near_other[i] = False
            released += 1
    return released
