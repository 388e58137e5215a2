"""Decision 0156: the extraction stage's sample preparation, faster with outputs identical.

- `_label_kernels.ridge_brightness_u8` and `profile_drop_u8` read the image in blocks (`_bilinear_u8_block`); they
  must equal the one-point-at-a-time kernels they replaced (kept here as references, verbatim but for their
  docstrings) bit for bit, and cv2.remap (test_label_kernels_round2.py).
- `_label_kernels.sample_grid_cells_two` builds the valid samples' grid and every sample's grid by family in one
  kernel; each must equal its own kernel (`sample_grid_cells`, `crossing_fill._family_grid`), and the pipeline's
  prep must hold both.
"""

from __future__ import annotations

import dataclasses
import math

import numba
import numpy as np
import pytest

from reconstruction import _label_kernels as K
from reconstruction._label_kernels import _fma_f32, _rint_f32
from reconstruction.crossing_fill import _family_grid, family_grid, fill_grid_cell_px
from reconstruction.labelling import _box3, prepare_samples, trace_grid_cell_px
from reconstruction.pipeline import ReconstructOptions, extract_frame

@numba.njit(error_model="numpy")
def _ridge_brightness_u8_ref(img, q):
    """`ridge_brightness_u8` before decision 0156 (one point at a time)."""
    n = q.shape[0]
    H = img.shape[0]
    W = img.shape[1]
    out = np.empty(n, np.float32)
    for k in range(n):
        qx = q[k, 0]
        qy = q[k, 1]
        x = np.float32(qx) if math.isfinite(qx) else np.float32(0.0)
        y = np.float32(qy) if math.isfinite(qy) else np.float32(0.0)
        fx = np.floor(x)
        fy = np.floor(y)
        ax = np.float32(x - fx)
        ay = np.float32(y - fy)
        sx = np.int64(fx)
        sy = np.int64(fy)
        if sx >= 0 and sx < W - 1 and sy >= 0 and sy < H - 1:  # inside: no clipping
            p00 = np.float32(img[sy, sx])
            p01 = np.float32(img[sy, sx + 1])
            p10 = np.float32(img[sy + 1, sx])
            p11 = np.float32(img[sy + 1, sx + 1])
        else:
            x0 = min(max(sx, 0), W - 1)
            x1 = min(max(sx + 1, 0), W - 1)
            y0 = min(max(sy, 0), H - 1)
            y1 = min(max(sy + 1, 0), H - 1)
            p00 = np.float32(img[y0, x0])
            p01 = np.float32(img[y0, x1])
            p10 = np.float32(img[y1, x0])
            p11 = np.float32(img[y1, x1])
        f0 = _fma_f32(ax, np.float32(p01 - p00), p00)
        f1 = _fma_f32(ax, np.float32(p11 - p10), p10)
        v = _fma_f32(ay, np.float32(f1 - f0), f0)
        out[k] = min(max(_rint_f32(v), np.float32(0.0)), np.float32(255.0))
    return out


@numba.njit(error_model="numpy")
def _profile_drop_u8_ref(img, q, sid, tangent, pos, width_px, ridge, have_ridge):
    """`profile_drop_u8` before decision 0156 (one position at a time, the outer probes skipped where the drop is 0)."""
    n = pos.shape[0]
    H = img.shape[0]
    W = img.shape[1]
    out = np.empty(n, np.float32)
    w = np.float32(width_px)
    d = np.empty(7, np.float32)
    d[0] = np.float32(0.0) * w
    d[1] = np.float32(-0.25) * w
    d[2] = np.float32(0.25) * w
    d[3] = np.float32(-0.5) * w
    d[4] = np.float32(0.5) * w
    d[5] = np.float32(-1.0) * w
    d[6] = np.float32(1.0) * w
    v = np.empty(7, np.float32)
    one = np.float32(1.0)
    for m in range(n):
        k = pos[m]
        s = sid[k]
        qx = np.float32(q[s, 0])
        qy = np.float32(q[s, 1])
        nx = np.float32(-tangent[k, 1])
        ny = np.float32(tangent[k, 0])
        for p in range(7):
            if p == 0 and have_ridge:
                v[0] = ridge[s]
                continue
            if p == 5 and max(max(v[1], v[2]), max(v[3], v[4])) <= v[0]:
                break  # the sample is the brightest inner point: drop 0 whatever the outer points
            x = np.float32(qx + np.float32(d[p] * nx))
            y = np.float32(qy + np.float32(d[p] * ny))
            fx = np.floor(x)
            fy = np.floor(y)
            ax = np.float32(x - fx)
            ay = np.float32(y - fy)
            sx = np.int64(fx)
            sy = np.int64(fy)
            if sx >= 0 and sx < W - 1 and sy >= 0 and sy < H - 1:  # inside: no clipping
                p00 = np.float32(img[sy, sx])
                p01 = np.float32(img[sy, sx + 1])
                p10 = np.float32(img[sy + 1, sx])
                p11 = np.float32(img[sy + 1, sx + 1])
            else:
                x0 = min(max(sx, 0), W - 1)
                x1 = min(max(sx + 1, 0), W - 1)
                y0 = min(max(sy, 0), H - 1)
                y1 = min(max(sy + 1, 0), H - 1)
                p00 = np.float32(img[y0, x0])
                p01 = np.float32(img[y0, x1])
                p10 = np.float32(img[y1, x0])
                p11 = np.float32(img[y1, x1])
            f0 = _fma_f32(ax, np.float32(p01 - p00), p00)
            f1 = _fma_f32(ax, np.float32(p11 - p10), p10)
            vv = _fma_f32(ay, np.float32(f1 - f0), f0)
            v[p] = min(max(_rint_f32(vv), np.float32(0.0)), np.float32(255.0))
        inner = max(max(max(v[0], v[1]), max(v[2], v[3])), v[4])
        if inner == v[0]:
            out[m] = np.float32(0.0)
            continue
        outer = min(v[5], v[6])
        out[m] = (inner - v[0]) / max(inner - outer, one)
    return out


def _bits(a):
    return np.ascontiguousarray(a, np.float32).view(np.uint32)


@pytest.mark.parametrize("shape,n", [((37, 53), 40000), ((7, 5), 63), ((120, 90), 129), ((1024, 1280), 5000), ((3, 2), 1)])
def test_blocked_reads_equal_the_point_by_point_kernels(shape, n):
    rng = np.random.default_rng(shape[0] + n)
    H, W = shape
    img = _box3(rng.integers(0, 256, shape, dtype=np.uint8))
    q = np.column_stack([rng.uniform(-3, W + 2, n), rng.uniform(-3, H + 2, n)])
    q[::5] = np.round(q[::5] * 64) / 64  # exact halves of the rounding and of the interpolation
    q[::11, 0] = np.nan
    q[::13, 1] = np.inf
    assert np.array_equal(_bits(K.ridge_brightness_u8(img, q)), _bits(_ridge_brightness_u8_ref(img, q)))
    qq = np.nan_to_num(q, posinf=W + 1.5)
    t = rng.normal(size=(n, 2))
    t /= np.linalg.norm(t, axis=1)[:, None]
    sid = rng.permutation(n).astype(np.intp)
    ridge = K.ridge_brightness_u8(img, qq)
    for pos in (np.arange(n, dtype=np.intp), rng.permutation(n)[: max(1, n // 3)].astype(np.intp), np.zeros(0, np.intp)):
        for width in (5.3, 0.7, 11.0):
            for have in (False, True):
                r = ridge if have else np.zeros(0, np.float32)
                got = K.profile_drop_u8(img, qq, sid, t, pos, width, r, have)
                want = _profile_drop_u8_ref(img, qq, sid, t, pos, width, r, have)
                assert np.array_equal(_bits(got), _bits(want)), (width, have, len(pos))
    if n >= 1000:
        d = _profile_drop_u8_ref(img, qq, sid, t, np.arange(n, dtype=np.intp), 5.3, ridge, True)
        assert (d > 0).sum() > 50 and (d == 0).sum() > 50  # both branches taken


def test_blocked_reads_on_a_simulated_frame(small_scene_pitch16):
    s = small_scene_pitch16
    frame = extract_frame(s.image, s.procam, s.pattern, options=ReconstructOptions(
        depth_min_mm=s.depth_range_mm[0], depth_max_mm=s.depth_range_mm[1]))
    prep, obs = frame.prep, frame.obs
    q = np.ascontiguousarray(obs.q, np.float64)
    assert np.array_equal(_bits(prep.ridge), _bits(_ridge_brightness_u8_ref(prep.blurred, q)))
    tp = prep.traces
    pos = np.arange(len(tp.sid), dtype=np.intp)
    want = _profile_drop_u8_ref(prep.blurred, q, tp.sid, np.ascontiguousarray(tp.tangent), pos, float(frame.model.line_width_cam_px),
                                prep.ridge, True)
    assert len(pos) > 1000 and (want > 0).sum() > 0
    assert np.array_equal(_bits(tp.drop), _bits(want))


def _grids_equal(a, b):
    assert len(a) == len(b)
    for x, y in zip(a, b):
        if isinstance(x, np.ndarray):
            assert x.dtype == y.dtype
            np.testing.assert_array_equal(x, y)
        else:
            assert x == y and type(x) == type(y)


@pytest.mark.parametrize("seed", range(6))
def test_two_grids_equal_each_grid_alone(seed):
    rng = np.random.default_rng(seed)
    P = int(rng.integers(0, 3000)) if seed else 0
    q = np.column_stack([rng.uniform(-40, 1300, P), rng.uniform(-20, 1030, P)])
    if seed % 2:
        q = np.round(q / 6.5) * 6.5  # on cell boundaries
    fam = rng.integers(0, 4, P).astype(np.intp)
    q[rng.random(P) < 0.05] = np.nan
    q[rng.random(P) < 0.02, 1] = np.inf
    valid = K.sample_cells(q, fam, 1.0, 2)[0]
    for cell, cell_f in ((6.65, 13.3), (13.3, 6.65), (1.0, 40.0), (7.0, 7.0)):
        g, gf = K.sample_grid_cells_two(q, valid, fam, cell, cell_f)
        _grids_equal(g, K.sample_grid_cells(q, valid, fam, cell))
        _grids_equal(gf, _family_grid(q, fam, cell_f))


def test_the_pipeline_builds_both_grids_as_before(small_scene_pitch16):
    s = small_scene_pitch16
    o = ReconstructOptions(depth_min_mm=s.depth_range_mm[0], depth_max_mm=s.depth_range_mm[1])
    frame = extract_frame(s.image, s.procam, s.pattern, options=o)
    obs, prep = frame.obs, frame.prep
    gcell = trace_grid_cell_px(frame.model, o.trace)
    fcell = fill_grid_cell_px(float(obs.stats["sigma_px"]), float(max(1, int(obs.stats.get("scale", 1)))), o.crossing)
    assert sorted(prep.grids) == sorted([("valid", float(gcell)), ("family", float(fcell))])
    q = np.ascontiguousarray(obs.q, np.float64)
    fam = np.asarray(obs.family).astype(np.intp)
    _grids_equal(prep.grids[("valid", float(gcell))], K.sample_grid_cells(q, prep.valid, fam, float(gcell)))
    _grids_equal(prep.grids[("family", float(fcell))], family_grid(obs.q, obs.family, fcell))
    # one grid alone, or none, as asked
    sig = float(obs.stats["sigma_px"])
    p1 = prepare_samples(obs, sigma_px=sig, options=o.trace, image=s.image, family_cell_px=fcell)
    assert list(p1.grids) == [("family", float(fcell))]
    _grids_equal(p1.grids[("family", float(fcell))], family_grid(obs.q, obs.family, fcell))
    p2 = prepare_samples(obs, sigma_px=sig, options=o.trace, image=s.image, grid_cell_px=gcell)
    assert list(p2.grids) == [("valid", float(gcell))]
    assert prepare_samples(obs, sigma_px=sig, options=o.trace, image=s.image).grids == {}
    # no valid sample: the family grid is still built (as extract_frame did before)
    obs0 = dataclasses.replace(obs, family=np.zeros_like(obs.family))
    p0 = prepare_samples(obs0, sigma_px=sig, options=o.trace, image=s.image, grid_cell_px=gcell, family_cell_px=fcell)
    assert p0.n_valid == 0 and list(p0.grids) == [("family", float(fcell))]
    _grids_equal(p0.grids[("family", float(fcell))], family_grid(obs0.q, obs0.family, fcell))
