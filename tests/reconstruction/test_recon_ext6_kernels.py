"""Round six of the extraction's speed work (decision 0091): the ridge pass that processes its candidate
blocks while their rows are scanned (`ridge_pass_into`) against the NumPy formulation it computes (OpenCV's
Laplacian, then the Hessian, eigenvector and Steger step in float32), including rows with more candidates
than a block, outputs that run out of room, and `extraction._ridges`' per-thread arrays that grow; the end
walks (binary search written out) against the previous kernel kept here as the reference."""

from __future__ import annotations

import math
import threading

import cv2
import numpy as np

from reconstruction import _extract_kernels as ek
from reconstruction import extraction
from reconstruction._extract_kernels import sample_at
from reconstruction._jit import njit


def _image(seed: int, shape: tuple[int, int], n_bars: int, horizontal: int = 0) -> np.ndarray:
    """Smoothed float32 image of bright bars at random angles on noise, plus `horizontal` bars along
    rows (a row with more candidates than one block of the vectorised pass)."""
    rng = np.random.default_rng(seed)
    H, W = shape
    img = np.zeros(shape, np.float32)
    vv, uu = np.mgrid[0:H, 0:W].astype(np.float32)
    for _ in range(n_bars):
        a, c = rng.uniform(0, np.pi), rng.uniform(-0.4 * min(H, W), 0.4 * min(H, W))
        d = np.abs((uu - W / 2) * np.sin(a) - (vv - H / 2) * np.cos(a) - c)
        img += 120 * (d < 1.5)
    for r in rng.integers(5, H - 5, horizontal):
        img[r - 1 : r + 2, :] += 150
    img += rng.normal(0, 2.0, img.shape).astype(np.float32)
    g = cv2.getGaussianKernel(9, 1.2, cv2.CV_32F)
    return cv2.sepFilter2D(img, cv2.CV_32F, g, g, borderType=cv2.BORDER_REFLECT)


def _reference(G: np.ndarray, thr: np.float32, aniso: np.float32, cross: np.float32) -> tuple:
    """The NumPy formulation: candidates where cv2.Laplacian < −thr/2 (inner pixels, row-major), the line
    samples kept and the crossing candidates, as ridge_pass returns them."""
    lap = cv2.Laplacian(G, cv2.CV_32F, ksize=1)
    mask = lap < np.float32(-0.5 * thr)
    mask[[0, -1], :] = False
    mask[:, [0, -1]] = False
    vv, uu = np.nonzero(mask)
    gg = lambda dv, du: G[vv + dv, uu + du]  # noqa: E731
    gx, gy = np.float32(0.5) * (gg(0, 1) - gg(0, -1)), np.float32(0.5) * (gg(1, 0) - gg(-1, 0))
    gxx = gg(0, 1) - 2 * gg(0, 0) + gg(0, -1)
    gyy = gg(1, 0) - 2 * gg(0, 0) + gg(-1, 0)
    gxy = np.float32(0.25) * ((gg(1, 1) - gg(1, -1)) - (gg(-1, 1) - gg(-1, -1)))
    half_tr = np.float32(0.5) * (gxx + gyy)
    disc = np.sqrt((np.float32(0.5) * (gxx - gyy)) ** 2 + gxy * gxy)
    lam1, lam2 = half_tr - disc, half_tr + disc
    strength = -lam1
    is_x = (lam2 < cross * strength) & (-lam2 > thr)
    ax, ay, bx, by = gxy, lam1 - gxx, lam1 - gyy, gxy
    use_b = (bx * bx + by * by) > (ax * ax + ay * ay)
    ex, ey = np.where(use_b, bx, ax), np.where(use_b, by, ay)
    nn = np.sqrt(ex * ex + ey * ey)
    nn[nn == 0] = 1
    ex, ey = ex / nn, ey / nn
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -(gx * ex + gy * ey) / lam1
    keep = (strength > thr) & (lam2 > aniso * strength) & (np.abs(t * ex) <= 0.5) & (np.abs(t * ey) <= 0.5)
    return (len(uu), uu[keep], vv[keep], (t * ex)[keep], (t * ey)[keep], ex[keep], ey[keep], strength[keep],
            uu[is_x], vv[is_x], -lam2[is_x])


def _assert_same(got: tuple, ref: tuple) -> None:
    assert got[0] == ref[0]
    for a, b in zip(got[1:], ref[1:]):
        np.testing.assert_array_equal(a, b)


def _outputs(cap: int) -> tuple:
    i64, f32 = np.int64, np.float32
    return tuple(np.empty(cap, t) for t in (i64, i64, f32, f32, f32, f32, f32, i64, i64, f32))


THR, ANISO, CROSS = np.float32(4.0), np.float32(-0.5), np.float32(-0.25)


def test_ridge_pass_into_matches_the_numpy_formulation_with_rows_longer_than_a_block():
    # 3 rows of ~1500 candidates each: a row alone fills more than a block (_STEGER_BLOCK = 512)
    G = _image(5, (90, 1500), 6, horizontal=3)
    ref = _reference(G, THR, ANISO, CROSS)
    lap = cv2.Laplacian(G, cv2.CV_32F, ksize=1)
    assert (lap[1:-1, 1:-1] < -0.5 * THR).sum(axis=1).max() > ek._STEGER_BLOCK
    assert len(ref[1]) > 1000 and len(ref[8]) > 20
    out = _outputs(G.size)
    n, m, mx = ek.ridge_pass_into(G, np.float32(-0.5 * THR), THR, ANISO, CROSS, *out)
    _assert_same((n,) + tuple(a[:m] for a in out[:7]) + tuple(a[:mx] for a in out[7:]), ref)
    _assert_same(ek.ridge_pass(G, np.float32(-0.5 * THR), THR, ANISO, CROSS), ref)


def test_ridge_pass_into_reports_outputs_too_small_and_fits_exactly_sized_ones():
    G = _image(7, (140, 200), 14)
    ref = _reference(G, THR, ANISO, CROSS)
    m_ref, mx_ref = len(ref[1]), len(ref[8])
    assert m_ref > 300 and mx_ref > 10
    # exactly the room needed: the same outputs
    out = _outputs(max(m_ref, mx_ref))
    n, m, mx = ek.ridge_pass_into(G, np.float32(-0.5 * THR), THR, ANISO, CROSS, *out)
    assert (m, mx) == (m_ref, mx_ref)
    _assert_same((n,) + tuple(a[:m] for a in out[:7]) + tuple(a[:mx] for a in out[7:]), ref)
    # one place too few for the line samples, or for the crossing candidates: m = −1
    small = _outputs(m_ref - 1)
    assert ek.ridge_pass_into(G, np.float32(-0.5 * THR), THR, ANISO, CROSS, *small)[1] == -1
    i64, f32 = np.int64, np.float32
    few_x = _outputs(m_ref)[:7] + (np.empty(mx_ref - 1, i64), np.empty(mx_ref - 1, i64), np.empty(mx_ref - 1, f32))
    assert ek.ridge_pass_into(G, np.float32(-0.5 * THR), THR, ANISO, CROSS, *few_x)[1] == -1


def test_ridges_grow_the_threads_arrays_and_keep_them_per_thread():
    G = _image(9, (160, 240), 16)
    ref = _reference(G, THR, ANISO, CROSS)
    results: dict = {}

    def run(name: str, start_cap: int) -> None:
        extraction._workspace.ridge = _outputs(start_cap)  # this thread's arrays, far too small at first
        got = extraction._ridges(G, np.float32(-0.5 * THR), THR, ANISO, CROSS)
        results[name] = (got, extraction._workspace.ridge)

    threads = [threading.Thread(target=run, args=("a", 16)), threading.Thread(target=run, args=("b", 100))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for name in ("a", "b"):
        got, bufs = results[name]
        _assert_same(got, ref)
        assert len(bufs[0]) >= len(ref[1])  # grown (doubling) to hold every line sample
        assert np.shares_memory(got[1], bufs[0])  # views of the thread's arrays
    assert not np.shares_memory(results["a"][1][0], results["b"][1][0])
    # and a thread without arrays yet starts from 1/16 of the image
    extraction._workspace.__dict__.pop("ridge", None)
    _assert_same(extraction._ridges(G, np.float32(-0.5 * THR), THR, ANISO, CROSS), ref)
    assert len(extraction._workspace.ridge[0]) >= max(G.size // 16, len(ref[1]))


def test_ridge_pass_into_on_images_too_small_for_inner_pixels():
    for shape in ((1, 5), (2, 7), (3, 3), (6, 2)):
        G = np.zeros(shape, np.float32)
        out = _outputs(4)
        assert ek.ridge_pass_into(G, np.float32(-2.0), THR, ANISO, CROSS, *out) == (0, 0, 0)


# --- end_walks: the T walk's binary search written out (decision 0091) ---------------------------------------


@njit
def _end_walks_reference(sidx, sg, sproj, smin, smax, qx, qy, nx, ny, fam, seg_family, seg_dir, probes, Hw, Ww,
              seed_grid, seed_remap, inv_cs, pad, sx, sy, sx32, sy32, r_side32, r_reach, row_start, u, core):
    """end_walks as it was before decision 0091 (calling sample_at per probe of the T walk)."""
    S = len(smin)
    seg_seed = np.full((S, 2), -1, np.int64)
    t_ids = np.empty(2 * S, np.int64)
    n_t = 0
    GH, GW = seed_grid.shape
    for e in range(2):
        e_i = np.zeros(S, np.int64)
        for k in range(len(sidx)):
            g = sg[k]
            if sproj[k] == (smin[g] if e == 0 else smax[g]):
                e_i[g] = sidx[k]
        sgn = -1.0 if e == 0 else 1.0
        for g in range(S):
            i = e_i[g]
            ex = np.float64(qx[i])
            ey = np.float64(qy[i])
            tx = -np.float64(ny[i])
            ty = np.float64(nx[i])
            if (tx * seg_dir[g, 0] + ty * seg_dir[g, 1]) * sgn < 0:
                tx = -tx
                ty = -ty
            kk = -1
            for p in range(len(probes)):
                pu32 = np.float32(ex + probes[p] * tx)
                pv32 = np.float32(ey + probes[p] * ty)
                c = min(max(int(pu32 * inv_cs) + pad, 0), GW - 1)
                r = min(max(int(pv32 * inv_cs) + pad, 0), GH - 1)
                h = seed_grid[r, c]
                if h >= 0:
                    h = seed_remap[h]
                if h >= 0:
                    dx = pu32 - sx32[h]
                    dy = pv32 - sy32[h]
                    if np.float32(math.sqrt(dx * dx + dy * dy)) <= r_side32:
                        kk = h
                        break
            if kk >= 0 and math.hypot(ex - sx[kk], ey - sy[kk]) <= r_reach:
                seg_seed[g, e] = kk
                continue
            # a free end running into a line of the other family is a T
            for p in range(len(probes)):
                pu = ex + probes[p] * tx
                pv = ey + probes[p] * ty
                iu = int(np.rint(pu))
                iv = int(np.rint(pv))
                if iu < 0 or iu >= Ww or iv < 0 or iv >= Hw:
                    continue
                h = sample_at(row_start, u, core, iu, iv)
                if h >= 0 and fam[h] != seg_family[g]:
                    t_ids[n_t] = h
                    n_t += 1
                    break
    return seg_seed, t_ids[:n_t].copy()


def test_end_walks_match_the_version_calling_sample_at(small_scene):
    """On the small simulated scene (a sphere in front of a plane: free ends at its silhouette and shadow,
    T-shapes where they run into the other family), the end walks give what the previous kernel gave."""
    from reconstruction.rigmodel import rig_model

    model = rig_model(small_scene.procam, small_scene.pattern, small_scene.depth_range_mm)
    cap = {}
    orig = ek.end_walks

    def spy(*a):
        cap["args"] = [x.copy() if isinstance(x, np.ndarray) else x for x in a]  # the grid buffer is reused later
        return orig(*a)

    extraction._k.end_walks = spy
    try:
        extraction.extract_grid(small_scene.image, model)
    finally:
        extraction._k.end_walks = orig
    seg_seed, t_ids = ek.end_walks(*cap["args"])
    ref_seed, ref_t = _end_walks_reference(*cap["args"])
    assert (seg_seed >= 0).sum() > 100 and (seg_seed < 0).sum() > 20 and len(t_ids) > 3
    np.testing.assert_array_equal(seg_seed, ref_seed)
    np.testing.assert_array_equal(t_ids, ref_t)


# --- gauss_u8: OpenCV's separable Gaussian to the bit (decision 0091) ----------------------------------------


def _random_u8(seed: int, shape: tuple[int, int]) -> np.ndarray:
    """Bars, a gradient and noise on 8 bits: every grey level and sharp edges."""
    rng = np.random.default_rng(seed)
    H, W = shape
    vv, uu = np.mgrid[0:H, 0:W].astype(np.float32)
    img = 40 + 0.2 * uu + 30 * (np.abs(np.sin(0.31 * uu + 0.17 * vv)) > 0.8) + rng.normal(0, 6.0, shape)
    img[rng.random(shape) < 0.01] = 255
    return np.clip(img, 0, 255).astype(np.uint8)


def test_gauss_u8_equals_opencvs_sepfilter2d():
    """Every kernel length the full-resolution path uses (σ from 1 to 2), on images whose width is a
    multiple of 16, border rows and columns included. On the pinned OpenCV 5.0 build of the development
    machine the two agree to the bit (decision 0091: the same fused multiply-adds in the same order); another
    build or CPU may sum in another order, so the test allows a few float32 ulps of the 8-bit scale."""
    for seed, shape in ((1, (37, 64)), (2, (120, 160)), (3, (301, 320))):
        img = _random_u8(seed, shape)
        for sigma in (1.0, 1.2, 1.45, 1.75, 2.0):
            k_cv = extraction._gauss_kernel(sigma)
            taps = extraction._gauss_taps(sigma)
            assert len(taps) == len(k_cv) <= ek.GAUSS_MAX_TAPS
            ref = cv2.sepFilter2D(img, cv2.CV_32F, k_cv, k_cv, borderType=cv2.BORDER_REFLECT)
            out = np.full(shape, np.nan, np.float32)
            ek.gauss_u8(img, taps, out)
            np.testing.assert_allclose(out, ref, rtol=0, atol=1e-4)


def test_smooth_takes_the_kernel_or_opencv_with_the_same_result():
    """`_smooth` uses gauss_u8 for 8-bit images of width 16·n and short kernels, OpenCV otherwise (other
    widths, longer kernels, float images): the working image is OpenCV's in every case."""
    cases = [((90, 160), 1.45, np.uint8), ((90, 150), 1.45, np.uint8), ((90, 160), 2.5, np.uint8), ((90, 160), 1.45, np.float32)]
    for shape, sigma, dtype in cases:
        img = _random_u8(7, shape)
        src = img if dtype == np.uint8 else img.astype(np.float32)
        k_cv = extraction._gauss_kernel(sigma)
        ref = cv2.sepFilter2D(src, cv2.CV_32F, k_cv, k_cv, borderType=cv2.BORDER_REFLECT)
        out = np.full(shape, np.nan, np.float32)
        got = extraction._smooth(src, sigma, 1, out=out)
        assert got is out
        np.testing.assert_allclose(out, ref, rtol=0, atol=1e-4)
    # and the kernel differs from a plain (unfused) multiply-add, so the equality above is not vacuous
    img = _random_u8(8, (60, 96))
    taps = extraction._gauss_taps(1.45)
    pad = np.pad(img.astype(np.float32), len(taps) // 2, mode="symmetric")
    rows = sum(pad[:, j : j + img.shape[1]] * taps[j] for j in range(len(taps)))
    plain = sum(rows[j : j + img.shape[0]] * taps[j] for j in range(len(taps)))
    fused = np.empty(img.shape, np.float32)
    ek.gauss_u8(img, taps, fused)
    assert not np.array_equal(fused, plain)
    np.testing.assert_allclose(fused, plain, rtol=0, atol=1e-3)


def test_smooth_ridges_u8_is_gauss_u8_then_ridge_pass_into():
    """The fused walk gives the same working image and the same samples and crossing candidates as the two
    kernels one after the other: several blocks, a row longer than a block, the final partial block, and
    outputs that run out of room (m = −1, then the same after growing in `_ridges`)."""
    for seed, shape, horizontal in ((11, (96, 1280), 2), (12, (150, 208), 0), (13, (3, 64), 0)):
        img = _random_u8(seed, shape)
        if horizontal:
            img[40:43, :] = 250  # a bright row: more candidates in one row than a block
        taps = extraction._gauss_taps(1.45)
        thr_args = (np.float32(-0.5 * 6.0), np.float32(6.0), ANISO, CROSS)
        G_ref = np.empty(shape, np.float32)
        ek.gauss_u8(img, taps, G_ref)
        out_ref = _outputs(img.size)
        n, m, mx = ek.ridge_pass_into(G_ref, *thr_args, *out_ref)
        G = np.full(shape, np.nan, np.float32)
        out = _outputs(img.size)
        assert ek.smooth_ridges_u8(img, taps, G, *thr_args, *out) == (n, m, mx)
        np.testing.assert_array_equal(G, G_ref)
        for a, b, cnt in zip(out, out_ref, (m,) * 7 + (mx,) * 3):
            np.testing.assert_array_equal(a[:cnt], b[:cnt])
        if shape[0] > 3:
            assert n > ek._STEGER_BLOCK and m > 50
            assert ek.smooth_ridges_u8(img, taps, G, *thr_args, *_outputs(m - 1))[1] == -1
            extraction._workspace.ridge = _outputs(8)
            got = extraction._ridges(np.empty(shape, np.float32), *thr_args, image=img, taps=taps)
            assert got[0] == n and len(got[1]) == m and len(got[8]) == mx
            for a, b in zip(got[1:8], out_ref[:7]):
                np.testing.assert_array_equal(a, b[:m])
