"""Round four of the extraction's speed (decision 0079): each new kernel against the NumPy/OpenCV code it
replaced, on seeded images."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from reconstruction import _extract_kernels as k
from reconstruction import extraction


def _noise_reference(img: np.ndarray) -> float:
    """`image_noise_grey` as it was before 0079: OpenCV's filter2D on the sampled rows, NumPy's partition."""
    H, W = img.shape
    rows = max(3, min(H, 65536 // max(W, 1)))
    if rows < H:
        starts = np.linspace(0, H - 4, max(1, rows // 4)).astype(np.intp)
        img = np.concatenate([img[s : s + 4] for s in starts])
    kern = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32)
    r = cv2.filter2D(img.astype(np.float32, copy=False), cv2.CV_32F, kern, borderType=cv2.BORDER_REFLECT)
    r = r.reshape(-1, 4, W)[:, 1:3, 1:-1] if rows < H else r[1:-1, 1:-1]
    a = np.abs(r).ravel()
    return float(np.partition(a, len(a) // 2)[len(a) // 2]) / (0.6745 * 6.0)


@pytest.mark.parametrize("shape", [(1024, 1280), (570, 758), (40, 50), (3, 9)])
@pytest.mark.parametrize("sigma_grey", [0.0, 2.0, 40.0])
def test_noise_kernel_gives_the_filter2d_median(shape, sigma_grey):
    rng = np.random.default_rng(7)
    H, W = shape
    vv, uu = np.mgrid[0:H, 0:W]
    base = 100 + 60 * np.sin(uu / 9.0) * (np.abs((vv % 23) - 11) < 3)  # lines and plateaus
    img = np.clip(base + rng.normal(0, sigma_grey, shape), 0, 255).astype(np.uint8)
    got = extraction.image_noise_grey(img)
    want = _noise_reference(img)
    assert got == want
    if sigma_grey == 40.0 and H > 100:
        assert 10.0 < got < 60.0  # a real estimate, not a constant (clipping lowers it)


def test_noise_kernel_saturated_extremes():
    # a one-pixel checkerboard gives the largest possible response everywhere (|r| = 8·255): the
    # histogram's last bin
    img = np.zeros((64, 64), np.uint8)
    img[::2, ::2] = 255
    img[1::2, 1::2] = 255
    assert extraction.image_noise_grey(img) == _noise_reference(img) == 2040 / (0.6745 * 6.0)
    assert k.noise_median_u8(img, np.zeros(0, np.intp), False) == 2040


def _verdicts_numpy(cen, dr, rms, cnt, n_neg, n_pos, m_neg, m_pos, mean_sin, seeds, jump_tol, sin_turn, off_tol, rms_tol):
    """The NumPy block of `extract_grid` that `junction_verdicts` replaced (before 0079)."""
    ns = len(seeds)
    reasons = {}
    n_neg, n_pos = n_neg.reshape(ns, 2), n_pos.reshape(ns, 2)
    jump = (np.abs(m_neg - m_pos).reshape(ns, 2) > jump_tol).any(axis=1)
    jump |= (mean_sin.reshape(ns, 2) > sin_turn).any(axis=1)
    cen = cen.reshape(ns, 2, 2)
    dr = dr.reshape(ns, 2, 2)
    rms = rms.reshape(ns, 2)
    cnt = cnt.reshape(ns, 2)
    valid = np.ones(ns, bool)
    few = (cnt < 3).any(axis=1)
    reasons["too_few"] = int(few.sum())
    valid &= ~few
    through = ((n_neg >= 1) & (n_pos >= 1)).all(axis=1)
    reasons["not_through"] = int((valid & ~through).sum())
    valid &= through
    d1, d2 = dr[:, 0], dr[:, 1]
    cross = d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]
    par = np.abs(cross) < 0.2
    reasons["parallel"] = int((valid & par).sum())
    valid &= ~par
    with np.errstate(divide="ignore", invalid="ignore"):
        diff = cen[:, 1] - cen[:, 0]
        a = (diff[:, 0] * d2[:, 1] - diff[:, 1] * d2[:, 0]) / cross
        qj = cen[:, 0] + a[:, None] * d1
    offc = np.hypot(*(qj - seeds).T) > off_tol
    offc |= ~np.isfinite(qj).all(axis=1)
    reasons["off_centre"] = int((valid & offc).sum())
    valid &= ~offc
    crooked = (rms > rms_tol).any(axis=1) | jump
    reasons["crooked"] = int((valid & crooked).sum())
    valid &= ~crooked
    return valid, qj, jump, par, offc, cross, np.array(list(reasons.values()))


def test_junction_verdicts_match_the_numpy_block():
    rng = np.random.default_rng(11)
    ns = 4000
    seeds = rng.uniform(0, 500, (ns, 2))
    ang = rng.uniform(0, np.pi, (2 * ns))
    ang[1::2] = ang[0::2] + rng.choice([np.pi / 2, 0.1, 0.0, 1.2], ns)  # right angles, near-parallel, parallel (cross 0)
    dr = np.column_stack([np.cos(ang), np.sin(ang)])
    cen = np.repeat(seeds, 2, axis=0) + rng.normal(0, 0.8, (2 * ns, 2))
    cen[:40] = np.nan  # a failed fit
    rms = np.abs(rng.normal(0, 0.4, 2 * ns))
    cnt = rng.integers(0, 12, 2 * ns)
    n_neg = rng.integers(0, 4, 2 * ns).astype(np.float64)
    n_pos = rng.integers(0, 4, 2 * ns).astype(np.float64)
    m_neg = rng.normal(0, 0.4, 2 * ns)
    m_pos = rng.normal(0, 0.4, 2 * ns)
    mean_sin = np.abs(rng.normal(0, 0.12, 2 * ns))
    args = (0.6, float(np.sin(np.deg2rad(9.0))), 1.5, 0.6)
    want = _verdicts_numpy(cen, dr, rms, cnt, n_neg, n_pos, m_neg, m_pos, mean_sin, seeds, *args)
    got = k.junction_verdicts(cen, dr, rms, cnt, n_neg, n_pos, m_neg, m_pos, mean_sin, seeds[:, 0].copy(), seeds[:, 1].copy(), *args)
    for g, w in zip(got, want):
        np.testing.assert_array_equal(g, w)  # bit for bit, NaN where NumPy had NaN
    counts = got[-1]
    assert (counts > 50).all()  # every reason occurs
    assert 30 < got[0].sum() < ns // 2  # and some candidates pass
    assert not np.isfinite(got[1][:20]).any()  # the failed fits: qj NaN, off centre


def test_segment_lists_and_chord_stats_ends_match_numpy():
    rng = np.random.default_rng(5)
    P, S, M = 5000, 300, 80
    seg = rng.integers(-1, S, P)
    seg[rng.random(P) < 0.2] = -1
    fam = rng.integers(1, 3, P).astype(np.int8)
    sidx, sg, seg_family = k.segment_lists(seg, fam, S)
    ref_sidx = np.nonzero(seg >= 0)[0]
    ref_family = np.zeros(S, np.int8)
    ref_family[seg[ref_sidx]] = fam[ref_sidx]
    np.testing.assert_array_equal(sidx, ref_sidx)
    np.testing.assert_array_equal(sg, seg[ref_sidx])
    np.testing.assert_array_equal(seg_family, ref_family)
    assert sidx.dtype == np.int64 and sg.dtype == np.int64

    q_junction = rng.uniform(0, 400, (M, 2))
    q_junction[7] = q_junction[3]  # a zero-length chord
    segment_ends = rng.integers(-1, M, (S, 2))
    segment_ends[:10] = [3, 7]
    segment_ends[10:20, 1] = segment_ends[10:20, 0]  # both ends on one junction: no candidate
    qx = rng.uniform(0, 400, P).astype(np.float32)
    qy = rng.uniform(0, 400, P).astype(np.float32)
    # the NumPy formulation before 0079
    cand = (segment_ends[:, 0] >= 0) & (segment_ends[:, 1] >= 0) & (segment_ends[:, 0] != segment_ends[:, 1])
    qa_ = np.full((S, 2), np.nan)
    qb_ = np.full((S, 2), np.nan)
    qa_[cand] = q_junction[segment_ends[cand, 0]]
    qb_[cand] = q_junction[segment_ends[cand, 1]]
    chord = qb_ - qa_
    clen = np.hypot(chord[:, 0], chord[:, 1])
    cn = np.column_stack([-chord[:, 1], chord[:, 0]]) / np.where(clen > 0, clen, 1)[:, None]
    rms_ref, max_ref = k.chord_stats(seg, cand, qx, qy, qa_, cn, S)
    c2, rms, mx = k.chord_stats_ends(seg, segment_ends, q_junction, qx, qy, S)
    np.testing.assert_array_equal(c2, cand)
    np.testing.assert_array_equal(rms, rms_ref)
    np.testing.assert_array_equal(mx, max_ref)
    assert cand[:10].all() and not cand[10:20].any() and (rms[cand] > 10).any()


@pytest.mark.parametrize("n", [0, 1, 3000])
def test_ordered_seeds_is_numpys_stable_order(n):
    rng = np.random.default_rng(n)
    xu = rng.integers(0, 1280, n)
    xv = np.sort(rng.integers(0, 1024, n))
    xs = rng.integers(1, 40, n).astype(np.float32) * np.float32(0.25)  # many ties
    seed = rng.random(n) < 0.3
    order = np.argsort(xs[seed], kind="stable")
    want = np.column_stack([xu[seed][order], xv[seed][order]]).astype(np.float64)
    seeds, score = k.ordered_seeds(xu, xv, xs, seed)
    np.testing.assert_array_equal(seeds, want.reshape(-1, 2))
    np.testing.assert_array_equal(score, xs[seed][order])
    assert seeds.dtype == np.float64 and score.dtype == np.float32
    if n > 100:
        assert len(np.unique(score)) < len(score) // 5 and (np.diff(score) >= 0).all()


@pytest.mark.parametrize("scale", [1, 2])
def test_edge_candidates_match_numpy(scale):
    rng = np.random.default_rng(21 + scale)
    S, M = 2000, 400
    cand = rng.random(S) < 0.7
    rms_ch = np.abs(rng.normal(0, 0.4, S))
    max_ch = rms_ch * rng.uniform(1, 4, S)
    segment_ends = rng.integers(-1, M, (S, 2))
    seg_family = rng.integers(1, 3, S).astype(np.int8)
    q_junction = rng.uniform(0, 600, (M, 2))
    tol = 0.6 / scale
    # the NumPy formulation before 0079
    straight = cand & (rms_ch <= tol) & (max_ch <= 3 * tol + 0.5)
    sid = np.nonzero(straight)[0]
    a_j, b_j = segment_ends[sid, 0], segment_ends[sid, 1]
    mid = 0.5 * (q_junction[a_j] + q_junction[b_j]) * scale
    dq = q_junction[b_j] - q_junction[a_j]
    elen = np.hypot(*(q_junction[b_j] - q_junction[a_j]).T)
    got = k.edge_candidates(cand, rms_ch, max_ch, tol, 3 * tol + 0.5, segment_ends, seg_family, q_junction, scale)
    for g, w in zip(got[:7], (sid, a_j, b_j, seg_family[sid], mid, dq, elen)):
        np.testing.assert_array_equal(g, w)
        assert g.dtype == w.dtype
    assert got[7] == int((cand & ~straight).sum()) > 100 and len(sid) > 100


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_drop_duplicates_marks_numpys_lexsort_duplicates(seed):
    rng = np.random.default_rng(seed)
    ns = 3000
    qj = rng.uniform(0, 120, (ns, 2))  # ~3600 cells of 2 px for 3000 points: many shared cells
    qj[::7] = np.round(qj[::7] / 2.0) * 2.0 + 1.0  # exact .5 cell boundaries (rint: half to even)
    score = rng.integers(1, 6, ns).astype(np.float32)  # ties in score
    valid = rng.random(ns) < 0.8
    # the NumPy formulation before 0079
    want = valid.copy()
    vid = np.nonzero(want)[0]
    key = np.rint(qj[vid] / 2.0).astype(np.int64)
    o2 = np.lexsort((-score[vid], key[:, 1], key[:, 0]))
    ks = key[o2]
    dup = np.zeros(len(vid), bool)
    dup[1:] = (ks[1:] == ks[:-1]).all(axis=1)
    want[vid[o2[dup]]] = False
    got = valid.copy()
    n = k.drop_duplicates(got, qj, score)
    np.testing.assert_array_equal(got, want)
    assert n == int(dup.sum()) > 300


def test_drop_duplicates_small():
    valid = np.array([True])
    assert k.drop_duplicates(valid, np.zeros((1, 2)), np.ones(1, np.float32)) == 0 and valid[0]
    valid = np.array([True, True, False])
    qj = np.array([[10.0, 10.0], [10.4, 9.8], [10.0, 10.0]])
    assert k.drop_duplicates(valid, qj, np.array([1.0, 1.0, 9.0], np.float32)) == 1
    np.testing.assert_array_equal(valid, [True, False, False])  # equal scores: the lower index stays


def _stamp_reference(cx, cy, radius, cs, grid, pad):
    """`stamp` as it was before 0079 (one loop over the disc's offsets per centre), in float32 as the kernel."""
    GH, GW = grid.shape
    gh, gw = GH - 2 * pad, GW - 2 * pad
    grid[:, :] = -1
    n = len(cx)
    rr = min(int(np.ceil(radius / cs)) + 1, pad - 1)
    lim = (radius + cs) ** 2
    offs = [(ox, oy) for oy in range(-rr, rr + 1) for ox in range(-rr, rr + 1) if np.float64(ox * ox + oy * oy) * cs * cs <= lim]
    lo, hix, hiy = 1 - pad + rr, gw + pad - rr - 2, gh + pad - rr - 2
    c0x, c0y, fx, fy = [0] * n, [0] * n, [np.float32(0)] * n, [np.float32(0)] * n
    for i in range(n):
        ccx, ccy = cx[i] / cs, cy[i] / cs
        c0x[i], c0y[i] = min(max(int(ccx), lo), hix), min(max(int(ccy), lo), hiy)
        fx[i], fy[i] = np.float32(ccx - c0x[i] - 0.5), np.float32(ccy - c0y[i] - 0.5)
        for ox, oy in offs:
            dx, dy = np.float32(ox) - fx[i], np.float32(oy) - fy[i]
            d2 = dx * dx + dy * dy
            r, c = c0y[i] + pad + oy, c0x[i] + pad + ox
            o = grid[r, c]
            if o >= 0:
                odx, ody = np.float32(c - pad - c0x[o]) - fx[o], np.float32(r - pad - c0y[o]) - fy[o]
                if d2 > odx * odx + ody * ody:
                    continue
            grid[r, c] = i


@pytest.mark.parametrize("radius", [1.3, 4.27, 8.48])
def test_stamp_by_rows_equals_the_offset_loop(radius):
    rng = np.random.default_rng(int(radius * 100))
    cs, pad = 2.0, 16
    grid = np.empty((40 + 2 * pad, 50 + 2 * pad), np.int32)
    ref = grid.copy()
    n = 150  # dense enough that discs overlap and owners are compared; some centres off the image
    cx = rng.uniform(-10, 110, n)
    cy = rng.uniform(-10, 90, n)
    cx[:5] = np.round(cx[:5]) + 1.0  # centres on cell corners: exact distance ties
    cy[:5] = np.round(cy[:5]) + 1.0
    k.stamp(cx, cy, radius, cs, grid, pad)
    _stamp_reference(cx, cy, radius, cs, ref, pad)
    np.testing.assert_array_equal(grid, ref)
    assert len(np.unique(grid[grid >= 0])) > n // 2
