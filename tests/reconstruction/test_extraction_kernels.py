"""The extraction's compiled kernels against what they replace: OpenCV's Laplacian and NumPy's Hessian
and Steger step (ridge_pass, over several blocks of its vectorised pass), NumPy's cell maxima, OpenCV's
dilation and the family test (albedo_and_families), a brute-force nearest-centre grid (stamp), and segments
of known sample sets numbered as scipy's connected_components numbers them (link_segments), and the small
kernels that replaced NumPy passes (junction_sample_ids, leave_near, edge_skips)."""

from __future__ import annotations

import cv2
import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from reconstruction import _extract_kernels as k


def _smoothed(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    img = np.zeros((120, 160), np.float32)
    for _ in range(12):  # bright bars at random angles, on noise
        a, c = rng.uniform(0, np.pi), rng.uniform(-60, 60)
        vv, uu = np.mgrid[0:120, 0:160].astype(np.float32)
        d = np.abs((uu - 80) * np.sin(a) - (vv - 60) * np.cos(a) - c)
        img += 120 * (d < 1.5)
    img += rng.normal(0, 2.0, img.shape).astype(np.float32)
    g = cv2.getGaussianKernel(9, 1.2, cv2.CV_32F)
    return cv2.sepFilter2D(img, cv2.CV_32F, g, g, borderType=cv2.BORDER_REFLECT)


def test_ridge_pass_matches_opencv_laplacian_and_the_numpy_steger_step():
    G = _smoothed(3)
    thr = np.float32(4.0)
    n, u, v, ox, oy, nx, ny, st, xu, xv, xs = k.ridge_pass(G, np.float32(-0.5 * thr), thr, np.float32(-0.5), np.float32(-0.25))
    lap = cv2.Laplacian(G, cv2.CV_32F, ksize=1)
    mask = lap < np.float32(-0.5 * thr)
    mask[[0, -1], :] = False
    mask[:, [0, -1]] = False
    vv, uu = np.nonzero(mask)  # row-major, as the kernel walks
    assert n == len(uu) > 2 * k._STEGER_BLOCK  # several blocks of the vectorised pass, the last one partial
    assert n % k._STEGER_BLOCK != 0
    # the NumPy formulation the kernel replaced (float32 throughout)
    gg = lambda dv, du: G[vv + dv, uu + du]  # noqa: E731
    gx, gy = np.float32(0.5) * (gg(0, 1) - gg(0, -1)), np.float32(0.5) * (gg(1, 0) - gg(-1, 0))
    gxx = gg(0, 1) - 2 * gg(0, 0) + gg(0, -1)
    gyy = gg(1, 0) - 2 * gg(0, 0) + gg(-1, 0)
    gxy = np.float32(0.25) * ((gg(1, 1) - gg(1, -1)) - (gg(-1, 1) - gg(-1, -1)))
    half_tr = np.float32(0.5) * (gxx + gyy)
    disc = np.sqrt((np.float32(0.5) * (gxx - gyy)) ** 2 + gxy * gxy)
    lam1, lam2 = half_tr - disc, half_tr + disc
    strength = -lam1
    is_x = (lam2 < np.float32(-0.25) * strength) & (-lam2 > thr)  # crossings: their own ratio
    np.testing.assert_array_equal(xu, uu[is_x])
    np.testing.assert_array_equal(xv, vv[is_x])
    np.testing.assert_array_equal(xs, -lam2[is_x])
    ax, ay, bx, by = gxy, lam1 - gxx, lam1 - gyy, gxy
    use_b = (bx * bx + by * by) > (ax * ax + ay * ay)
    ex, ey = np.where(use_b, bx, ax), np.where(use_b, by, ay)
    nn = np.sqrt(ex * ex + ey * ey)
    nn[nn == 0] = 1
    ex, ey = ex / nn, ey / nn
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -(gx * ex + gy * ey) / lam1
    keep = (strength > thr) & (lam2 > np.float32(-0.5) * strength) & (np.abs(t * ex) <= 0.5) & (np.abs(t * ey) <= 0.5)
    assert keep.sum() > 200
    np.testing.assert_array_equal(u, uu[keep])
    np.testing.assert_array_equal(v, vv[keep])
    np.testing.assert_array_equal(ox, (t * ex)[keep])
    np.testing.assert_array_equal(oy, (t * ey)[keep])
    np.testing.assert_array_equal(nx, ex[keep])
    np.testing.assert_array_equal(ny, ey[keep])
    np.testing.assert_array_equal(st, strength[keep])


def test_albedo_and_families_match_the_numpy_passes():
    rng = np.random.default_rng(11)
    Hw, Ww, n, nxc = 150, 230, 4000, 900
    u = np.sort(rng.integers(0, Ww, n)).astype(np.int64)
    v = rng.integers(0, Hw, n).astype(np.int64)
    ox, oy = rng.uniform(-0.5, 0.5, (2, n)).astype(np.float32)
    ang = rng.uniform(0, np.pi, n)
    nx, ny = np.cos(ang).astype(np.float32), np.sin(ang).astype(np.float32)
    st = (rng.uniform(1, 60, n) * np.where(u > Ww // 2, 0.1, 1.0)).astype(np.float32)  # a dark right half
    xu = rng.integers(0, Ww, nxc).astype(np.int64)
    xv = rng.integers(0, Hw, nxc).astype(np.int64)
    xs = rng.uniform(0, 20, nxc).astype(np.float32)
    gh_d, gw_d, cell_d = 6, 9, 32.0
    a1, a2 = rng.uniform(0.2, 0.6, (gh_d * gw_d)), rng.uniform(1.6, 2.0, (gh_d * gw_d))
    dir4 = np.column_stack([np.cos(a1), np.sin(a1), np.cos(a2), np.sin(a2)]).astype(np.float32)
    min_rel, cross_rel, margin = np.float32(0.15), np.float32(0.03), np.float32(0.15)
    out = k.albedo_and_families(u, v, ox, oy, nx, ny, st, xu, xv, xs, Hw, Ww, min_rel, cross_rel, dir4, gh_d, gw_d, cell_d, margin)
    # the NumPy passes: per-cell maximum, 3x3 dilation inside the grid, the tests, the nearest direction cell
    cells = np.zeros((Hw // 16 + 1, Ww // 16 + 1), np.float32)
    np.maximum.at(cells, (v // 16, u // 16), st)
    local = cv2.dilate(cells, np.ones((3, 3), np.uint8), borderType=cv2.BORDER_CONSTANT, borderValue=0)
    strong = st >= min_rel * local[v // 16, u // 16]
    cd = np.clip(((u + ox.astype(np.float64)) / cell_d + 0.5).astype(int), 0, gw_d - 1)
    rd = np.clip(((v + oy.astype(np.float64)) / cell_d + 0.5).astype(int), 0, gh_d - 1)
    d = dir4[rd * gw_d + cd]
    c1, c2 = np.abs(d[:, 1] * nx - d[:, 0] * ny), np.abs(d[:, 3] * nx - d[:, 2] * ny)
    keep = strong & (np.abs(c1 - c2) >= margin)
    assert 0.3 * n < keep.sum() < 0.9 * n and (~strong).sum() > 100  # both tests leave samples out
    fam = np.where(c1 >= c2, 1, 2).astype(np.int8)
    want = (u, v, ox, oy, nx, ny, st, fam, u.astype(np.float32) + ox, v.astype(np.float32) + oy)
    for got, w in zip(out[:10], want):
        assert got.dtype == w.dtype
        np.testing.assert_array_equal(got, w[keep])
    keep_x = xs >= cross_rel * local[xv // 16, xu // 16]
    assert 0 < keep_x.sum() < nxc
    for got, w in zip(out[10:], (xu, xv, xs)):
        np.testing.assert_array_equal(got, w[keep_x])


def test_stamp_holds_the_nearest_covering_centre():
    rng = np.random.default_rng(5)
    gh, gw, pad, cs, radius = 40, 50, 16, 2.0, 3.3
    cx = rng.uniform(0, 2 * gw - 2, 60)
    cy = rng.uniform(0, 2 * gh - 2, 60)
    grid = np.empty((gh + 2 * pad, gw + 2 * pad), np.int32)
    k.stamp(cx, cy, radius, cs, grid, pad)
    # brute force: a centre covers the cells whose offset from its own cell is within radius + one cell;
    # each cell holds the covering centre nearest to the cell's centre
    r, c = np.mgrid[0 : gh + 2 * pad, 0 : gw + 2 * pad]
    ox = c[..., None] - pad - (cx / cs).astype(int)
    oy = r[..., None] - pad - (cy / cs).astype(int)
    covers = (ox**2 + oy**2) * cs * cs <= (radius + cs) ** 2
    d = np.hypot((c[..., None] - pad + 0.5) * cs - cx, (r[..., None] - pad + 0.5) * cs - cy)
    d[~covers] = np.inf
    want = np.where(covers.any(axis=-1), d.argmin(axis=-1), -1)
    assert (want >= 0).sum() > 900  # most of the 40x50 image cells
    np.testing.assert_array_equal(grid, want)


def test_link_segments_finds_the_pieces_numbered_like_scipy():
    # three horizontal i-line pieces (one broken by a gap, one a single sample) and one vertical j-line
    pts = [(u, 20, 1) for u in range(5, 25)] + [(u, 20, 1) for u in range(30, 41)]  # gap of 5 px
    pts += [(50, 20, 1)]  # alone: no segment
    pts += [(12, vv, 2) for vv in range(8, 19)]  # stops short of the i-line: its own piece
    pts += [(u, 33, 1) for u in range(3, 9)]
    pts.sort(key=lambda p: (p[1], p[0]))  # row-major, as the ridge pass emits samples
    u = np.array([p[0] for p in pts], np.int64)
    v = np.array([p[1] for p in pts], np.int64)
    fam = np.array([p[2] for p in pts], np.int8)
    qx, qy = u.astype(np.float32), v.astype(np.float32)
    nx = np.where(fam == 1, 0.0, 1.0).astype(np.float32)  # normals across the lines
    ny = np.where(fam == 1, 1.0, 0.0).astype(np.float32)
    core = np.zeros(len(u), bool)
    seg, S = k.link_segments(u, v, core, qx, qy, nx, ny, fam, 40, 60)
    # the expected pieces, as sample-index sets; numbering: scipy's, by the lowest sample index
    piece = np.full(len(u), -1)
    piece[(v == 20) & (u < 25)] = 0
    piece[(v == 20) & (u >= 30) & (u <= 40)] = 1
    piece[fam == 2] = 2
    piece[v == 33] = 3
    a = [i for i in range(len(u)) for j in range(len(u)) if piece[i] >= 0 and piece[i] == piece[j] and i != j]
    b = [j for i in range(len(u)) for j in range(len(u)) if piece[i] >= 0 and piece[i] == piece[j] and i != j]
    n_comp, comp = connected_components(coo_matrix((np.ones(len(a)), (a, b)), shape=(len(u), len(u))), directed=False)
    sizes = np.bincount(comp)
    keep = sizes >= 2
    remap = np.full(n_comp, -1)
    remap[keep] = np.arange(keep.sum())
    assert S == 4
    np.testing.assert_array_equal(seg, remap[comp])


def test_junction_sample_ids_bias_cut_and_edge_skips_match_numpy():
    rng = np.random.default_rng(21)
    P, ns = 3000, 40
    arm_of = np.where(rng.random(P) < 0.4, rng.integers(0, ns, P), -1).astype(np.int64)
    valid = rng.random(ns) < 0.7
    new_id = np.full(ns + 1, -1, np.int64)
    new_id[:ns][valid] = np.arange(int(valid.sum()))
    seg = np.where(rng.random(P) < 0.8, rng.integers(0, 200, P), -1).astype(np.int64)
    sample_junction, seg_out = k.junction_sample_ids(arm_of, new_id, seg)
    want_j = new_id[arm_of]
    np.testing.assert_array_equal(sample_junction, want_j)
    np.testing.assert_array_equal(seg_out, np.where(want_j >= 0, -1, seg))
    assert (want_j >= 0).sum() > 300 and ((arm_of >= 0) & (want_j < 0)).sum() > 50

    # the bias cut: as look_dist on the same grid, then the NumPy mask
    gh, gw, pad, cs, radius = 40, 50, 16, 2.0, 3.0
    cx, cy = rng.uniform(0, 2 * gw - 2, 30), rng.uniform(0, 2 * gh - 2, 30)
    grid = np.empty((gh + 2 * pad, gw + 2 * pad), np.int32)
    k.stamp(cx, cy, radius, cs, grid, pad)
    px, py = rng.uniform(0, 2 * gw, P).astype(np.float32), rng.uniform(0, 2 * gh, P).astype(np.float32)
    c32x, c32y, r32, inv = cx.astype(np.float32), cy.astype(np.float32), np.float32(radius), np.float32(1 / cs)
    kb, _ = k.look_dist(grid, px, py, inv, pad, c32x, c32y, r32)
    want_seg = seg_out.copy()
    want_seg[(kb >= 0) & (sample_junction < 0)] = -1
    got_seg = seg_out.copy()
    n_near = k.leave_near(grid, px, py, inv, pad, c32x, c32y, r32, sample_junction, got_seg)
    assert n_near == (kb >= 0).sum() > 100
    np.testing.assert_array_equal(got_seg, want_seg)

    # the skip test against np.minimum.at
    E, M = 500, 60
    a_j, b_j = rng.integers(0, M, E), rng.integers(0, M, E)
    f_ = rng.integers(0, 2, E)
    elen = rng.uniform(5, 20, E)
    shortest = np.full((M + 1, 2), np.inf)
    for ends_ in (a_j, b_j):
        np.minimum.at(shortest, (ends_, f_), elen)
    want = (elen > 1.6 * shortest[a_j, f_]) | (elen > 1.6 * shortest[b_j, f_])
    assert 0 < want.sum() < E
    np.testing.assert_array_equal(k.edge_skips(a_j, b_j, f_, elen, M), want)


def test_crossing_cores_are_the_samples_near_a_kept_candidate():
    rng = np.random.default_rng(8)
    P, ns, r0 = 2000, 50, np.float32(2.5)
    near = np.where(rng.random(P) < 0.6, rng.integers(0, ns, P), -1).astype(np.int64)
    dist = np.where(near >= 0, rng.uniform(0, 6, P), np.inf).astype(np.float32)
    kept = rng.random(ns) < 0.5
    remap = np.full(ns, -1, np.int64)
    remap[kept] = np.arange(int(kept.sum()))
    # the NumPy steps this replaced: remap the ids, distance inf where none is left, then the threshold
    new_near = np.where(near >= 0, remap[np.maximum(near, 0)], -1)
    want = np.where(new_near >= 0, dist, np.inf) <= r0
    assert 100 < want.sum() < (near >= 0).sum()
    np.testing.assert_array_equal(k.crossing_cores(near, dist, remap, r0), want)
