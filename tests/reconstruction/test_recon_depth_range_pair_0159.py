"""Decision 0159: `_k_stretch_pair` (a ray's two depth-range ends in one call) gives `_k_stretch_one`'s values at
z0 and z1 bit for bit, and `_k_stretches_meet` built on it gives the old per-end formulation's (lo, hi), on the
bench rigs' models (with and without projector distortion), for rays inside, beside and behind the projector."""

from __future__ import annotations

import math

import numpy as np
import pytest

from benchmarks._common import bench_scenes
from reconstruction.depth_range_labels import _k_stretch_one, _k_stretch_pair, _k_stretches_meet
from reconstruction.rigmodel import rig_model


def _args(model, has_dist=None):
    proj = model.procam.projector
    pat = model.pattern
    dist = np.zeros(5)
    dist[: min(5, proj.dist.size)] = np.asarray(proj.dist, np.float64).ravel()[:5]
    hd = bool(proj.has_distortion) if has_dist is None else has_dist
    if hd and not dist.any():
        dist = np.array([0.05, -0.02, 0.001, -0.002, 0.003])
    return (np.ascontiguousarray(model.procam.R_proj_cam, np.float64), np.ascontiguousarray(model.procam.t_proj_cam, np.float64),
            np.ascontiguousarray(proj.K, np.float64), dist, hd, float(pat.centre_px[0]), float(pat.centre_px[1]),
            np.array([pat.n1, pat.n2], np.float64), np.ascontiguousarray(model.line_offsets_px, np.float64), int(model.index_min))


@pytest.fixture(scope="module", params=["paper-parallel", "converged-1280 pitch 16, 35/125 deg"])
def model(request):
    if request.param.startswith("paper"):
        sc = bench_scenes([request.param], [], noise_grey=2.0)[0]
    else:
        sc = bench_scenes([], [request.param], noise_grey=2.0)[0]
    return rig_model(sc.procam, sc.pattern, sc.depth_range_mm), sc.depth_range_mm


def _bits(x):
    return np.float64(x).view(np.int64)


def _meet_reference(xy, a, b, f, R, t, z0, z1, Kp, dist, hd, cu, cv, nn, offs, imin, tol_f):
    """`_k_stretches_meet` as it was before decision 0159 (two `_k_stretch_one` calls a sample), in Python."""
    lo, hi = -np.inf, np.inf
    for s in range(a, b):
        c0 = _k_stretch_one(xy[s, 0], xy[s, 1], f, R, t, z0, Kp, dist, hd, cu, cv, nn, offs, imin)
        c1 = _k_stretch_one(xy[s, 0], xy[s, 1], f, R, t, z1, Kp, dist, hd, cu, cv, nn, offs, imin)
        if not (math.isfinite(c0) and math.isfinite(c1)):
            return np.inf, hi
        lo = max(lo, min(c0, c1) - tol_f)
        hi = min(hi, max(c0, c1) + tol_f)
        if np.ceil(lo) > np.floor(hi):
            break
    return lo, hi


@pytest.mark.parametrize("has_dist", [None, True, False])
def test_pair_is_two_single_ends_bit_for_bit(model, has_dist):
    m, (z_near, z_far) = model
    R, t, Kp, dist, hd, cu, cv, nn, offs, imin = _args(m, has_dist)
    rng = np.random.default_rng(159)
    # rays through the camera's field, far beside it, and depth pairs in and out of order, some behind the projector
    xy = np.concatenate([rng.uniform(-0.6, 0.6, (400, 2)), rng.uniform(-8.0, 8.0, (100, 2))])
    zs = [(z_near, z_far), (z_far, z_near), (-z_far, z_near), (1e-9, 1e6), (0.5 * z_near, 3.0 * z_far)]
    n_nan = n_out = 0
    for f in (1, 2):
        for z0, z1 in zs:
            for x, y in xy:
                p0, p1 = _k_stretch_pair(x, y, f, R, t, z0, z1, Kp, dist, hd, cu, cv, nn, offs, imin)
                s0 = _k_stretch_one(x, y, f, R, t, z0, Kp, dist, hd, cu, cv, nn, offs, imin)
                s1 = _k_stretch_one(x, y, f, R, t, z1, Kp, dist, hd, cu, cv, nn, offs, imin)
                for p, s in ((p0, s0), (p1, s1)):
                    if np.isnan(s):
                        assert np.isnan(p)
                        n_nan += 1
                    else:
                        assert _bits(p) == _bits(s), (x, y, f, z0, z1, p, s)
                        n_out += not (imin <= s <= imin + offs.shape[1] - 1)
    # the cases the branches exist for did occur: rays behind the projector, and ends beyond the outer lines
    assert n_nan > 0 and n_out > 0


def test_meet_matches_the_per_end_formulation(model):
    m, (z_near, z_far) = model
    R, t, Kp, dist, hd, cu, cv, nn, offs, imin = _args(m)
    rng = np.random.default_rng(7)
    xy = np.ascontiguousarray(rng.uniform(-0.5, 0.5, (2000, 2)))
    # runs of neighbouring rays (a line piece's samples) and runs of scattered ones
    xy[:1000] = xy[0] + np.cumsum(rng.normal(scale=0.002, size=(1000, 2)), axis=0)
    bounds = np.r_[0, np.sort(rng.choice(np.arange(1, 2000), 120, replace=False)), 2000]
    for f in (1, 2):
        for tol_f in (0.0, 0.1, 0.5):
            for a, b in zip(bounds[:-1], bounds[1:]):
                got = _k_stretches_meet(xy, a, b, f, R, t, z_near, z_far, Kp, dist, hd, cu, cv, nn, offs, imin, tol_f)
                ref = _meet_reference(xy, a, b, f, R, t, z_near, z_far, Kp, dist, hd, cu, cv, nn, offs, imin, tol_f)
                assert _bits(got[0]) == _bits(ref[0]) and _bits(got[1]) == _bits(ref[1]), (a, b, f, got, ref)
