"""Decision 0163: `_k_stretches_meet_walk` (each sample's segment of the line offsets found by a walk from the
previous sample's, not by bisection) gives `_k_stretches_meet`'s (lo, hi) bit for bit, and `_k_piece_candidates`
with it (the default) gives the same pieces and indices as with the bisection, on the bench rigs' models (with and
without projector distortion), for runs of neighbouring rays, scattered rays, rays beyond the outer lines and behind
the projector. Offsets that do not increase strictly take the bisection."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks._common import bench_scenes
from reconstruction.depth_range_labels import (_fractional_k, _fractional_k_from, _k_offsets_strict, _k_piece_candidates,
                                               _k_stretches_meet, _k_stretches_meet_walk)
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


def _rays(seed):
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-0.5, 0.5, (3000, 2))
    # runs of neighbouring rays (a line piece's samples), long sweeps across many lines, scattered rays, rays far beside
    xy[:1000] = xy[0] + np.cumsum(rng.normal(scale=0.002, size=(1000, 2)), axis=0)
    xy[1000:1500] = np.linspace([-0.7, -0.6], [0.7, 0.6], 500)
    xy[2500:] = rng.uniform(-8.0, 8.0, (500, 2))
    bounds = np.r_[0, np.sort(rng.choice(np.arange(1, 3000), 150, replace=False)), 3000]
    return np.ascontiguousarray(xy), bounds


def test_offsets_strict_on_the_bench_rigs(model):
    m, _ = model
    assert _k_offsets_strict(np.ascontiguousarray(m.line_offsets_px, np.float64))


def test_fractional_walk_is_the_bisection_bit_for_bit():
    rng = np.random.default_rng(163)
    offs = np.cumsum(rng.uniform(3.0, 30.0, 40)) - 400.0
    cs = np.r_[rng.uniform(offs[0] - 50, offs[-1] + 50, 3000), offs, offs[0], offs[-1], np.nextafter(offs, np.inf)]
    n_walked = 0
    for h in (0, 5, 20, 38, 39, 60, -3):
        for c in cs:
            got, seg = _fractional_k_from(c, offs, -7, h)
            ref = _fractional_k(c, offs, -7)
            assert _bits(got) == _bits(ref), (c, h, got, ref)
            n_walked += seg != h
    assert n_walked > 0  # the walks moved


@pytest.mark.parametrize("has_dist", [None, True, False])
def test_walk_meets_as_the_bisection(model, has_dist):
    m, (z_near, z_far) = model
    R, t, Kp, dist, hd, cu, cv, nn, offs, imin = _args(m, has_dist)
    xy, bounds = _rays(0o163)
    n_finite = n_inf = 0
    for z0, z1 in ((z_near, z_far), (z_far, z_near), (-z_far, z_near), (0.5 * z_near, 3.0 * z_far)):
        for f in (1, 2):
            for tol_f in (0.0, 0.3):
                for a, b in zip(bounds[:-1], bounds[1:]):
                    got = _k_stretches_meet_walk(xy, a, b, f, R, t, z0, z1, Kp, dist, hd, cu, cv, nn, offs, imin, tol_f)
                    ref = _k_stretches_meet(xy, a, b, f, R, t, z0, z1, Kp, dist, hd, cu, cv, nn, offs, imin, tol_f)
                    assert _bits(got[0]) == _bits(ref[0]) and _bits(got[1]) == _bits(ref[1]), (a, b, f, z0, z1, got, ref)
                    if np.isfinite(ref[0]):
                        n_finite += 1
                    else:
                        n_inf += 1
                # every sample alone: the walk starts at segment 0 for each
                for s in range(0, 3000, 7):
                    got = _k_stretches_meet_walk(xy, s, s + 1, f, R, t, z0, z1, Kp, dist, hd, cu, cv, nn, offs, imin, tol_f)
                    ref = _k_stretches_meet(xy, s, s + 1, f, R, t, z0, z1, Kp, dist, hd, cu, cv, nn, offs, imin, tol_f)
                    assert _bits(got[0]) == _bits(ref[0]) and _bits(got[1]) == _bits(ref[1])
    assert n_finite > 0 and n_inf > 0


def test_piece_candidates_the_same_with_and_without_the_walk(model):
    m, (z_near, z_far) = model
    R, t, Kp, dist, hd, cu, cv, nn, offs, imin = _args(m)
    rng = np.random.default_rng(1630)
    # short pieces of neighbouring rays (most name one index or none) and a few scattered ones
    n_p = 400
    sizes = rng.integers(1, 30, n_p)
    pid = np.repeat(np.arange(n_p), sizes).astype(np.int64)
    starts = rng.uniform(-0.5, 0.5, (n_p, 2))
    step = rng.normal(scale=0.0015, size=(len(pid), 2))
    xy = np.ascontiguousarray(starts[pid] + np.cumsum(step, axis=0) - np.cumsum(step, axis=0)[np.r_[0, np.cumsum(sizes)[:-1]]][pid])
    fam = (pid % 2 + 1).astype(np.int64)
    tol = np.array([0.05, 0.05])
    n_named = 0
    for other in (True, False):
        for zz in ((z_near, z_far), (z_near, z_near * 1.02)):
            args = (xy, fam, pid, R, t, zz[0], zz[1], Kp, dist, hd, cu, cv, nn, offs, imin, int(m.index_max), tol, other)
            ids_w, k_w = _k_piece_candidates(*args)
            ids_b, k_b = _k_piece_candidates(*args, False)
            assert np.array_equal(ids_w, ids_b) and np.array_equal(k_w, k_b)
            n_named += len(ids_w)
    assert n_named > 0  # some pieces were named, so the comparison covered the path that writes


def test_offsets_not_strict_take_the_bisection(model):
    m, (z_near, z_far) = model
    R, t, Kp, dist, hd, cu, cv, nn, offs, imin = _args(m)
    bad = offs.copy()
    bad[0, 5] = bad[0, 4]  # two lines at one offset: the walk's segment would not be unique
    assert not _k_offsets_strict(bad)
    xy, bounds = _rays(5)
    pid = np.repeat(np.arange(len(bounds) - 1), np.diff(bounds)).astype(np.int64)
    fam = np.ones(len(pid), np.int64)
    args = (xy, fam, pid, R, t, z_near, z_far, Kp, dist, hd, cu, cv, nn, bad, imin, int(m.index_max), np.array([0.3, 0.3]), False)
    got = _k_piece_candidates(*args)
    ref = _k_piece_candidates(*args, False)
    assert np.array_equal(got[0], ref[0]) and np.array_equal(got[1], ref[1])
