"""Decision 0145: `ambiguity_guard.attached_pairs` skips a sample whose 3×3 cells all lie off the ambiguous junctions'
grid before its cell loop. The pairs (samples, expected indices) and their order must be those of the loop without
the skip: the kernel as decision 0141 merged it (main acd1c94), kept here verbatim as the reference."""

from __future__ import annotations

import math

import numpy as np
import pytest

from reconstruction._jit import njit
from reconstruction.ambiguity_guard import attached_pairs


@njit
def _attached_pairs_reference(q, fam, valid, qj, amb, amb_lab, jdir, radius, lateral):
    """`attached_pairs` at acd1c94 (verbatim but for the name)."""
    A = amb.shape[0]
    P = q.shape[0]
    if A == 0 or P == 0:
        return np.zeros(0, np.intp), np.zeros(0, np.float64)
    x0 = np.inf
    y0 = np.inf
    for k in range(A):
        x0 = min(x0, qj[amb[k], 0])
        y0 = min(y0, qj[amb[k], 1])
    gw = 0
    gh = 0
    cx = np.empty(A, np.intp)
    cy = np.empty(A, np.intp)
    for k in range(A):
        cx[k] = np.intp(math.floor((qj[amb[k], 0] - x0) / radius))
        cy[k] = np.intp(math.floor((qj[amb[k], 1] - y0) / radius))
        gw = max(gw, cx[k] + 1)
        gh = max(gh, cy[k] + 1)
    cnt = np.zeros(gw * gh + 1, np.intp)
    for k in range(A):
        cnt[cy[k] * gw + cx[k] + 1] += 1
    for c in range(gw * gh):
        cnt[c + 1] += cnt[c]
    items = np.empty(A, np.intp)
    fill = cnt[:-1].copy()
    for k in range(A):
        c = cy[k] * gw + cx[k]
        items[fill[c]] = k
        fill[c] += 1
    out_s = np.empty(16 + 4 * A, np.intp)
    out_e = np.empty(16 + 4 * A, np.float64)
    n = 0
    r2 = radius * radius
    for s in range(P):
        if not valid[s]:
            continue
        f = fam[s]
        if f != 1 and f != 2:
            continue
        sx = np.intp(math.floor((q[s, 0] - x0) / radius))
        sy = np.intp(math.floor((q[s, 1] - y0) / radius))
        for yy in range(sy - 1, sy + 2):
            if yy < 0 or yy >= gh:
                continue
            for xx in range(sx - 1, sx + 2):
                if xx < 0 or xx >= gw:
                    continue
                c = yy * gw + xx
                for t in range(cnt[c], cnt[c + 1]):
                    k = items[t]
                    a = amb[k]
                    dx = q[s, 0] - qj[a, 0]
                    dy = q[s, 1] - qj[a, 1]
                    if dx * dx + dy * dy > r2:
                        continue
                    ux = jdir[a, f - 1, 0]
                    uy = jdir[a, f - 1, 1]
                    if not (abs(dx * uy - dy * ux) <= lateral):
                        continue
                    if n == out_s.shape[0]:
                        ns = np.empty(2 * n, np.intp)
                        ne = np.empty(2 * n, np.float64)
                        ns[:n] = out_s[:n]
                        ne[:n] = out_e[:n]
                        out_s = ns
                        out_e = ne
                    out_s[n] = s
                    out_e[n] = np.float64(amb_lab[k, f - 1])
                    n += 1
    return out_s[:n].copy(), out_e[:n].copy()


def _case(seed: int, n_amb: int, radius: float, lateral: float, spread: float):
    """Random samples over a 1280×1024 frame, most of them far from the ambiguous junctions, and dense clusters of
    samples on and around the junctions' lines (some exactly at cell boundaries), invalid ones and a third family."""
    rng = np.random.default_rng(seed)
    M = 3 * n_amb + 5
    qj = rng.uniform([100, 100], [100 + spread, 100 + 0.8 * spread], (M, 2))
    ang = rng.uniform(0, np.pi, (M, 2))
    jdir = np.stack([np.cos(ang), np.sin(ang)], axis=-1)
    amb = np.sort(rng.choice(M, n_amb, replace=False)).astype(np.intp)
    amb_lab = rng.integers(-40, 40, (n_amb, 2)).astype(np.int64)
    far = rng.uniform([0, 0], [1280, 1024], (4000, 2))
    near = []
    for a in amb:
        t = rng.uniform(-1.3 * radius, 1.3 * radius, (60, 1))
        f = rng.integers(0, 2, 60)
        off = rng.normal(0, lateral, (60, 1))
        d = jdir[a, f]
        n = np.stack([-d[:, 1], d[:, 0]], axis=1)
        near.append(qj[a] + t * d + off * n)
    x0, y0 = qj[amb, 0].min(), qj[amb, 1].min()
    edges = np.array([[x0 + k * radius, y0 + m * radius] for k in range(-2, 4) for m in range(-2, 4)])  # cell boundaries
    q = np.concatenate([far, *near, edges])
    q = q[rng.permutation(len(q))]
    fam = rng.integers(1, 3, len(q)).astype(np.intp)
    fam[rng.random(len(q)) < 0.05] = 0
    valid = rng.random(len(q)) > 0.1
    return q, fam, valid, qj, amb, amb_lab, jdir, float(radius), float(lateral)


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("n_amb,radius,lateral,spread", [(1, 7.0, 1.0, 50.0), (3, 7.0, 1.5, 300.0), (8, 12.5, 2.0, 900.0),
                                                        (20, 4.0, 1.0, 1000.0), (2, 40.0, 3.0, 60.0)])
def test_same_pairs_in_the_same_order(seed, n_amb, radius, lateral, spread):
    args = _case(seed, n_amb, radius, lateral, spread)
    s_ref, e_ref = _attached_pairs_reference(*args)
    s, e = attached_pairs(*args)
    assert len(s_ref) > 0  # the clusters give pairs
    assert np.array_equal(s, s_ref) and np.array_equal(e, e_ref)


def test_samples_beyond_the_grid_edges_are_read():
    """A sample one cell left of / above the grid, and one in the cell just past its right / lower edge, are within
    `radius` of a junction at the grid's edge: they must still pair (the skip is for cells at least two off)."""
    qj = np.array([[100.0, 100.0], [130.0, 130.0]])
    jdir = np.tile(np.array([[1.0, 0.0], [0.0, 1.0]]), (2, 1, 1))
    amb = np.array([0, 1], np.intp)
    lab = np.array([[5, 7], [6, 8]], np.int64)
    q = np.array([[95.0, 100.0], [100.0, 95.0], [135.5, 130.0], [130.0, 135.5], [60.0, 100.0], [170.0, 130.0]])
    fam = np.array([1, 2, 1, 2, 1, 1], np.intp)
    valid = np.ones(len(q), np.bool_)
    args = (q, fam, valid, qj, amb, lab, jdir, 10.0, 1.0)
    s, e = attached_pairs(*args)
    s_ref, e_ref = _attached_pairs_reference(*args)
    assert s.tolist() == [0, 1, 2, 3] and np.array_equal(s, s_ref) and np.array_equal(e, e_ref)
