"""Decision 0155: `compressed_spacing` with its neighbour arrays allocated once and candidates farther than the
reach along x skipped before the square root returns what the former kernel returned."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from reconstruction._extract_kernels import compressed_spacing


@njit
def _compressed_spacing_reference(n_ring, cx, cy, r0, r_att):
    """`_extract_kernels.compressed_spacing` before decision 0155."""
    ns = len(cx)
    out = np.zeros(ns)
    order = np.argsort(cy)
    ys = cy[order]
    lo_d = 2.0 * r0
    hi_d = min(2.0 * r_att, 2.0 * r0 + 4.0)
    for k in range(ns):
        if n_ring[k, 0] >= 2 and n_ring[k, 1] >= 2:
            continue
        a = np.searchsorted(ys, cy[k] - hi_d)
        b = np.searchsorted(ys, cy[k] + hi_d, side="right")
        n = 0
        dup = False
        nbx = np.empty(b - a)
        nby = np.empty(b - a)
        nbd = np.empty(b - a)
        for t in range(a, b):
            m = order[t]
            if m == k:
                continue
            dx = cx[m] - cx[k]
            dy = cy[m] - cy[k]
            d = math.sqrt(dx * dx + dy * dy)
            if d <= lo_d:
                dup = True
                break
            if d <= hi_d:
                nbx[n] = dx / d
                nby[n] = dy / d
                nbd[n] = d
                n += 1
        if dup:
            continue
        best = 0.0
        for p in range(n):
            for q in range(p + 1, n):
                if nbx[p] * nbx[q] + nby[p] * nby[q] < -0.94 and abs(nbd[p] - nbd[q]) <= 0.25 * max(nbd[p], nbd[q]):
                    d = 0.5 * (nbd[p] + nbd[q])
                    if best == 0.0 or d < best:
                        best = d
        out[k] = best
    return out


def test_compressed_spacing_equals_the_former_kernel():
    rng = np.random.default_rng(155)
    r0, r_att = 2.2, 5.0
    # rows of compressed crossings (spacing 4.6–8 px, some tilted), random crossings, near-duplicates, and
    # neighbours exactly at the reach along x
    xs, ys = [], []
    for row in range(30):
        x0, y0 = rng.uniform(0, 600), rng.uniform(0, 400)
        sp, ang = rng.uniform(4.6, 8.0), rng.uniform(-0.4, 0.4)
        for i in range(rng.integers(2, 9)):
            xs.append(x0 + i * sp * math.cos(ang) + rng.normal(0, 0.3))
            ys.append(y0 + i * sp * math.sin(ang) + rng.normal(0, 0.3))
    xs += list(rng.uniform(0, 600, 300))
    ys += list(rng.uniform(0, 400, 300))
    xs += [100.0, 101.0, 300.0, 300.0 + 2 * r0 + 4.0, 300.0 - (2 * r0 + 4.0)]
    ys += [50.0, 50.5, 200.0, 200.0, 200.0]
    cx = np.array(xs)
    cy = np.array(ys)
    n_ring = rng.integers(0, 4, (len(cx), 2)).astype(np.int64)
    got = compressed_spacing(n_ring, cx, cy, r0, r_att)
    ref = _compressed_spacing_reference(n_ring, cx, cy, r0, r_att)
    assert np.array_equal(got, ref)
    assert (ref > 0).sum() >= 10  # rows of compressed crossings were found
