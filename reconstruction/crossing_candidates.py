"""Crossing candidates that lie on one crossing: merged into one (decision 0129).

A crossing candidate is a local maximum of the weaker Hessian curvature −λ2 (non-maximum suppression on cells of
0.2 × the predicted junction step), moved to the centroid of its blob (`_extract_kernels.centroids`). Where two
lines cross at an acute angle in the image the blob is elongated along the bisector, and its two ends can each be
a maximum: two candidates 1–2 px apart on one crossing. The ring test then gives each sample to the nearer of the
two (a Voronoi partition), so each holds about half of each family's ring samples and both can fail it (unseen
seed 127: 404 of its 437 visible crossings lost at the ring test had two candidates within 3.5 px, the second
1.0–1.8 px away).

Two candidates closer than the core radius r0 are one crossing: r0 is where the crossing's own light biases the
ridges (at most 0.3 × the predicted junction step, and 1.6 σ + 0.5 px below that), so a second crossing inside it
would be two lines less than r0 apart, which the smoothing at σ does not resolve. `merge_within` joins every
pair closer than r0 (transitively) into the strongest of the group, at the score-weighted mean of their positions.
"""

from __future__ import annotations

import numpy as np
from reconstruction._jit import njit


@njit
def merge_within(sx, sy, score, radius):
    """Candidates (sx, sy float64, score float32, weakest first) closer than `radius` to each other joined.

    Returns (keep (n,) bool: the strongest of each group (the last in order, ties: the later), remap (n,) int64:
    the new index of each candidate's group, x (m,), y (m,) float64: the groups' score-weighted mean positions in
    the kept candidates' order, n_merged: candidates folded into another). Pairs are found on a grid of cells of
    `radius` (3×3 cells each); groups by union-find."""
    n = len(sx)
    parent = np.arange(n)
    keep = np.ones(n, np.bool_)
    remap = np.arange(n)
    if n < 2 or radius <= 0:
        return keep, remap, sx.copy(), sy.copy(), 0
    x0 = sx.min()
    y0 = sy.min()
    gw = int((sx.max() - x0) / radius) + 1
    gh = int((sy.max() - y0) / radius) + 1
    cell = np.empty(n, np.int64)
    head = np.full(gw * gh, -1, np.int64)
    nxt = np.full(n, -1, np.int64)
    for k in range(n):
        c = int((sy[k] - y0) / radius) * gw + int((sx[k] - x0) / radius)
        cell[k] = c
        nxt[k] = head[c]
        head[c] = k
    r2 = radius * radius
    n_pairs = 0
    for k in range(n):
        cx = cell[k] % gw
        cy = cell[k] // gw
        for yy in range(max(cy - 1, 0), min(cy + 2, gh)):
            for xx in range(max(cx - 1, 0), min(cx + 2, gw)):
                o = head[yy * gw + xx]
                while o >= 0:
                    if o > k and (sx[o] - sx[k]) ** 2 + (sy[o] - sy[k]) ** 2 < r2:
                        n_pairs += 1
                        a = k
                        while parent[a] != a:
                            a = parent[a]
                        b = o
                        while parent[b] != b:
                            b = parent[b]
                        if a != b:  # the later (stronger) root wins
                            if a < b:
                                parent[a] = b
                            else:
                                parent[b] = a
                    o = nxt[o]
    if n_pairs == 0:
        return keep, remap, sx.copy(), sy.copy(), 0
    root = np.empty(n, np.int64)
    for k in range(n):
        a = k
        while parent[a] != a:
            a = parent[a]
        root[k] = a
        keep[k] = a == k
    wx = np.zeros(n)
    wy = np.zeros(n)
    ws = np.zeros(n)
    for k in range(n):
        w = max(np.float64(score[k]), 1e-12)
        wx[root[k]] += w * sx[k]
        wy[root[k]] += w * sy[k]
        ws[root[k]] += w
    m = 0
    new = np.full(n, -1, np.int64)
    for k in range(n):
        if keep[k]:
            new[k] = m
            m += 1
    x = np.empty(m)
    y = np.empty(m)
    for k in range(n):
        if keep[k]:
            x[new[k]] = wx[k] / ws[k]
            y[new[k]] = wy[k] / ws[k]
    for k in range(n):
        remap[k] = new[root[k]]
    return keep, remap, x, y, n - m


@njit
def remap_grid(grid, remap):
    """A lookup grid's entries (candidate ids, −1: none) renumbered in place by `remap`."""
    g = grid.ravel()
    for i in range(len(g)):
        k = g[i]
        if k >= 0:
            g[i] = remap[k]
