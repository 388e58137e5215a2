"""Compiled kernels of the grid extraction (decisions 0062, 0063).

Each kernel is a plain loop over flat arrays that does what a sequence of NumPy passes in
`reconstruction/extraction.py` did before, with the same arithmetic: float32 where the NumPy code was
float32 (thresholds are handed in as float32, as NumPy compared float32 arrays with Python floats), float64
where it was float64, the same order of summation (NumPy's `bincount` adds in input order), the same
tie-breaking (the last writer wins where NumPy's fancy assignment wrote several values to one cell).
Working pixels: the image the extraction works on (full or half resolution), pixel (0, 0) = centre of the
top-left pixel.
"""

from __future__ import annotations

import math

import numpy as np
from llvmlite import ir
from numba.core import types
from numba.extending import intrinsic

from reconstruction._jit import njit

_F32_HALF = np.float32(0.5)
_F32_QUARTER = np.float32(0.25)
_F32_TWO = np.float32(2.0)
_F32_M4 = np.float32(-4.0)
_F32_ONE = np.float32(1.0)
_F32_ZERO = np.float32(0.0)


@intrinsic
def fma32(typingctx, a, b, c):
    """a·b + c with one rounding (LLVM's llvm.fma.f32: the FMA instruction), float32."""
    sig = types.float32(types.float32, types.float32, types.float32)

    def codegen(context, builder, signature, args):
        f32 = ir.FloatType()
        fn = builder.module.declare_intrinsic("llvm.fma", [f32], ir.FunctionType(f32, [f32, f32, f32]))
        return builder.call(fn, args)

    return sig, codegen


@njit(inline="always")
def hypot_le(dx, dy, r):
    """`math.hypot(dx, dy) <= r` (float64), the same truth value, with the hypot (a libm call, ~17 ns here; decision
    0155) evaluated only where dx² + dy² lies within a relative 1e-9 of r². Elsewhere the sum of squares decides:
    its relative error is below 1e-15 and hypot's below 1 ulp, far inside that margin. The short cut is taken only
    for r² in [1e-290, 1e290] (no underflow or overflow of the squares decides anything) and r ≥ 0; NaN falls
    through to the hypot (both comparisons false)."""
    d2 = dx * dx + dy * dy
    r2 = r * r
    if r >= 0.0 and r2 >= 1e-290 and r2 <= 1e290:
        if d2 < r2 * (1.0 - 1e-9):
            return True
        if d2 > r2 * (1.0 + 1e-9):
            return False
    return math.hypot(dx, dy) <= r


@njit(inline="always")
def hypot_gt(dx, dy, r):
    """`math.hypot(dx, dy) > r`, the same truth value, short-cut as `hypot_le` (NaN: false, as hypot's NaN > r)."""
    d2 = dx * dx + dy * dy
    r2 = r * r
    if r >= 0.0 and r2 >= 1e-290 and r2 <= 1e290:
        if d2 < r2 * (1.0 - 1e-9):
            return False
        if d2 > r2 * (1.0 + 1e-9):
            return True
    return math.hypot(dx, dy) > r


GAUSS_MAX_TAPS = 15  # longer kernels: LLVM stops unrolling the tap loops and the kernel is ~10x slower


@njit(error_model="numpy")
def gauss_u8(img, k, out):
    """The separable Gaussian of an 8-bit image as this OpenCV build's `cv2.sepFilter2D(img, CV_32F, k, k,
    borderType=BORDER_REFLECT)` computes it, to the bit (decision 0091): per source row (reflected at the
    top and bottom) the row pass s = fma(x_j, k_j, s) over taps j = 0…K−1 from s = x_0·k_0 (x reflected at
    the left and right), then per output row the column pass s = R_0·k_c, s = fma(R_−j + R_+j, k_c+j, s)
    for j = 1…r (k symmetric). img (H, W) uint8 with H, W > r; k: UniTuple(float32, K), K odd, at most
    GAUSS_MAX_TAPS (a tuple, so that the tap loops have a constant trip count and vectorise across x);
    out (H, W) float32.

    Equal to OpenCV where its SIMD loops cover every column (W a multiple of 16 here): OpenCV's scalar
    tail does not fuse the column pass's multiply-add (at W = 758 about 0.7 % of the pixels differ by an
    ulp), so `extraction._smooth` uses this kernel only when W is a multiple of 16. The row pass keeps each
    filtered row twice in a ring of 2K rows (slots i mod K and i mod K + K), so the K rows an output row
    needs are always consecutive."""
    H, W = img.shape
    K = len(k)
    r = K // 2
    ext = np.empty(W + 2 * r, np.float32)
    T = np.empty((2 * K, W), np.float32)
    for yy in range(-r, H + r):
        sy = yy
        if sy < 0:
            sy = -sy - 1
        elif sy >= H:
            sy = 2 * H - sy - 1
        src = img[sy]
        for x in range(W):
            ext[x + r] = np.float32(src[x])
        for x in range(r):  # BORDER_REFLECT: fedcba|abcdef
            ext[r - 1 - x] = np.float32(src[x])
            ext[W + r + x] = np.float32(src[W - 1 - x])
        slot = (yy + r) % K
        row = T[slot]
        row2 = T[slot + K]
        for x in range(W):
            acc = ext[x] * k[0]
            for j in range(1, K):
                acc = fma32(ext[x + j], k[j], acc)
            row[x] = acc
            row2[x] = acc
        y = yy - r
        if y >= 0:
            s0 = y % K  # rows y − r … y + r are in slots s0 … s0 + K − 1
            o = out[y]
            for x in range(W):
                acc = T[s0 + r, x] * k[r]
                for j in range(1, r + 1):
                    acc = fma32(T[s0 + r - j, x] + T[s0 + r + j, x], k[r + j], acc)
                o[x] = acc


_STEGER_BLOCK = 512  # candidates per block of the ridge walk's vectorised Hessian pass


@njit(error_model="numpy")
def steger_block(nb, V, thr, neg_aniso, neg_cross, thr_cross, O):
    """The Hessian, its eigenvalues, the normal and Steger's offset of `nb` candidates, branch-free so that
    LLVM vectorises the loop (two arrays only: with more, its runtime alias checks make it give up).

    V: (9, B) float32 the 3×3 neighbourhood per candidate (centre, right, left, down, up, down-right,
    down-left, up-right, up-left). O: (8, B) float32 out: dx, dy, ex, ey, strength = −λ1, −λ2, crossing
    flag, line-sample flag (1.0 / 0.0). Same operations and float32 widths as the scalar walk before
    (np.sqrt of a float32 is the correctly rounded float32 square root)."""
    for j in range(nb):
        c0 = V[0, j]
        r_ = V[1, j]
        lf = V[2, j]
        dn = V[3, j]
        up = V[4, j]
        gx = _F32_HALF * (r_ - lf)
        gy = _F32_HALF * (dn - up)
        gxx = r_ - _F32_TWO * c0 + lf
        gyy = dn - _F32_TWO * c0 + up
        gxy = _F32_QUARTER * ((V[5, j] - V[6, j]) - (V[7, j] - V[8, j]))
        half_tr = _F32_HALF * (gxx + gyy)
        h = _F32_HALF * (gxx - gyy)
        disc = np.sqrt(h * h + gxy * gxy)
        lam1 = half_tr - disc
        lam2 = half_tr + disc
        strength = -lam1
        lim = neg_aniso * strength
        ax = gxy
        ay = lam1 - gxx
        bx = lam1 - gyy
        by = gxy
        use_b = (bx * bx + by * by) > (ax * ax + ay * ay)
        ex = bx if use_b else ax
        ey = by if use_b else ay
        nn = np.sqrt(ex * ex + ey * ey)
        nn = _F32_ONE if nn == 0 else nn
        ex = ex / nn
        ey = ey / nn
        t = -(gx * ex + gy * ey) / lam1
        dx = t * ex
        dy = t * ey
        O[0, j] = dx
        O[1, j] = dy
        O[2, j] = ex
        O[3, j] = ey
        O[4, j] = strength
        O[5, j] = -lam2
        O[6, j] = _F32_ONE if ((lam2 < neg_cross * strength) & (-lam2 > thr_cross)) else _F32_ZERO
        keep = (strength > thr) & (lam2 > lim) & (abs(dx) <= _F32_HALF) & (abs(dy) <= _F32_HALF)
        O[7, j] = _F32_ONE if keep else _F32_ZERO


@njit(error_model="numpy")
def ridge_pass(G, thr_lap, thr, neg_aniso, neg_cross, thr_cross=-1.0):
    """Ridge candidates, Steger samples and crossing candidates of the smoothed image, in one walk.

    G: (H, W) float32 C-contiguous working image. thr_lap, thr, neg_aniso, neg_cross: float32 — a candidate's
    discrete Laplacian must be below `thr_lap` (−0.5·thr), a line sample's strength −λ1 above
    `thr`, λ2 above `neg_aniso`·strength (neg_aniso = −anisotropy); a crossing candidate has λ2 below
    `neg_cross`·strength (neg_cross = −crossing anisotropy, at most neg_aniso) and −λ2 above `thr_cross`
    (float32; omitted or negative: `thr`; decision 0129 sets it from the noise of one eigenvalue) (a pixel
    can be both a line sample and a crossing candidate when neg_cross > neg_aniso). The Laplacian is summed as OpenCV's 3×3 filter does (up, left, −4·centre, right,
    down; bit-identical to `cv2.Laplacian(ksize=1)` on float32), border pixels are never candidates.

    Returns n_candidates, the line samples in row-major order (u, v int64; ox, oy offset to the ridge,
    nx, ny unit normal, strength: float32) — kept when the ridge passes through the pixel's square — and
    the crossing candidates (xu, xv int64, xs = −λ2 float32), row-major too. The work is `ridge_pass_into`'s
    (this allocates its outputs, 1/16 of the pixels at first, doubled while they run out of room, and
    returns views; `extraction._ridges` keeps them per thread instead)."""
    H, W = G.shape
    most = max(H - 2, 0) * max(W - 2, 0)  # every inner pixel
    cap = max(min(4096, most), (H * W) // 16)
    while True:
        u = np.empty(cap, np.int64)
        v = np.empty(cap, np.int64)
        ox = np.empty(cap, np.float32)
        oy = np.empty(cap, np.float32)
        nx = np.empty(cap, np.float32)
        ny = np.empty(cap, np.float32)
        st = np.empty(cap, np.float32)
        xu = np.empty(cap, np.int64)
        xv = np.empty(cap, np.int64)
        xs = np.empty(cap, np.float32)
        n, m, mx = ridge_pass_into(G, thr_lap, thr, neg_aniso, neg_cross, u, v, ox, oy, nx, ny, st, xu, xv, xs, thr_cross)
        if m >= 0:
            return n, u[:m], v[:m], ox[:m], oy[:m], nx[:m], ny[:m], st[:m], xu[:mx], xv[:mx], xs[:mx]
        cap = min(2 * cap, most)


@njit(error_model="numpy")
def ridge_pass_into(G, thr_lap, thr, neg_aniso, neg_cross, u, v, ox, oy, nx, ny, st, xu, xv, xs, thr_cross=-1.0):
    """`ridge_pass` into the caller's arrays (decision 0091: extraction passes per-thread scratch arrays).

    u, v, ox, oy, nx, ny, st: (C,) the line samples' outputs (int64, int64, float32 ×5); xu, xv, xs: (C',)
    the crossing candidates' (int64, int64, float32). Returns (n_candidates, m line samples, mx crossing
    candidates) written to the first m / mx places; m = −1 when an output ran out of room (C or C' too
    small: call again with larger arrays; the outputs are then partial).

    How (decisions 0069, 0091): row by row, the Laplacian test into a byte per pixel (a vectorised loop),
    then the candidates of each 8-byte word with a flag, branch-free (every pixel of the word written, the
    count advanced by its flag); as soon as a row leaves at least `_STEGER_BLOCK` candidates pending, they
    are processed as one block while their rows are still in cache: their 3×3 neighbourhoods gathered,
    `steger_block` (vectorised), the places of the kept ones listed branch-free, and only those copied
    out. The blocks' boundaries do not change any value (each candidate is computed on its own)."""
    H, W = G.shape
    B = _STEGER_BLOCK
    tc = thr if thr_cross < 0 else np.float32(thr_cross)  # the crossing candidates' −λ2 threshold (0129)
    cap = B + W + 8  # pending candidates never exceed B − 1 + one row's
    cand = np.empty(cap, np.int32)
    flag = np.zeros((W + 7) // 8 * 8, np.uint8)
    flag8 = flag.view(np.uint64)
    V = np.empty((9, cap), np.float32)
    O = np.empty((8, cap), np.float32)
    il = np.empty(cap, np.int64)  # kept line samples' and crossing candidates' places in a block
    ix = np.empty(cap, np.int64)
    g = G.ravel()
    cap_l = u.shape[0]
    cap_x = xu.shape[0]
    n = 0
    npend = 0
    m = 0
    mx = 0
    for r in range(1, H):
        if r < H - 1:
            a = G[r - 1]
            b = G[r]
            d = G[r + 1]
            for c in range(1, W - 1):  # flag[0] and flag[W - 1 ...] stay 0: border pixels are never candidates
                flag[c] = ((((a[c] + b[c - 1]) + _F32_M4 * b[c]) + b[c + 1]) + d[c]) < thr_lap
            base = r * W
            for w in range(len(flag8)):
                if flag8[w] != 0:
                    for c in range(8 * w, 8 * w + 8):
                        cand[npend] = base + c
                        npend += flag[c]
            if npend < B:
                continue
        # (after the last inner row, r = H − 1: whatever is pending)
        nb = npend
        n += nb
        npend = 0
        for j in range(nb):
            i = cand[j]
            V[0, j] = g[i]
            V[1, j] = g[i + 1]
            V[2, j] = g[i - 1]
            V[3, j] = g[i + W]
            V[4, j] = g[i - W]
            V[5, j] = g[i + W + 1]
            V[6, j] = g[i + W - 1]
            V[7, j] = g[i - W + 1]
            V[8, j] = g[i - W - 1]
        steger_block(nb, V, thr, neg_aniso, neg_cross, tc, O)
        kl = 0
        kx = 0
        for j in range(nb):  # the places of the kept ones in the block, branch-free
            il[kl] = j
            kl += O[7, j] != 0
            ix[kx] = j
            kx += O[6, j] != 0
        if m + kl > cap_l or mx + kx > cap_x:
            return n, -1, mx
        for t in range(kx):
            j = ix[t]
            i = cand[j]
            vv = i // W
            xu[mx] = i - vv * W
            xv[mx] = vv
            xs[mx] = O[5, j]
            mx += 1
        for t in range(kl):
            j = il[t]
            i = cand[j]
            vv = i // W
            u[m] = i - vv * W
            v[m] = vv
            ox[m] = O[0, j]
            oy[m] = O[1, j]
            nx[m] = O[2, j]
            ny[m] = O[3, j]
            st[m] = O[4, j]
            m += 1
    return n, m, mx


@njit(error_model="numpy")
def _column_pair(T, s0, k, o1, o2, W):
    """The Gaussian's column pass (as `gauss_u8`'s) of two consecutive output rows at once: o1 from ring slots
    s0 … s0 + K − 1, o2 from s0 + 1 … s0 + K. Each row's FMAs are `gauss_u8`'s, in the same order (the same bits);
    the two rows share 12 of their 13 row loads, which halves the loads per output (decision 0155). The radius comes
    from len(k) (a compile-time constant: the tap loop unrolls and the x loop vectorises)."""
    r = len(k) // 2
    for x in range(W):
        acc = T[s0 + r, x] * k[r]
        acc2 = T[s0 + r + 1, x] * k[r]
        for j in range(1, r + 1):
            acc = fma32(T[s0 + r - j, x] + T[s0 + r + j, x], k[r + j], acc)
            acc2 = fma32(T[s0 + 1 + r - j, x] + T[s0 + 1 + r + j, x], k[r + j], acc2)
        o1[x] = acc
        o2[x] = acc2


@njit(error_model="numpy")
def _column_one(T, s0, k, o, W):
    """`gauss_u8`'s column pass of one output row from ring slots s0 … s0 + K − 1."""
    r = len(k) // 2
    for x in range(W):
        acc = T[s0 + r, x] * k[r]
        for j in range(1, r + 1):
            acc = fma32(T[s0 + r - j, x] + T[s0 + r + j, x], k[r + j], acc)
        o[x] = acc


@njit(error_model="numpy")
def _steger_flush(nb, cand, g, W, V, O, il, ix, thr, neg_aniso, neg_cross, tc, u, v, ox, oy, nx, ny, st, xu, xv, xs, m, mx):
    """`ridge_pass_into`'s block step: the 3×3 neighbourhoods of the `nb` pending candidates gathered, `steger_block`,
    the kept line samples and crossing candidates appended at m / mx. Returns the new (m, mx); m = −1 when an output
    ran out of room."""
    for j in range(nb):
        i = cand[j]
        V[0, j] = g[i]
        V[1, j] = g[i + 1]
        V[2, j] = g[i - 1]
        V[3, j] = g[i + W]
        V[4, j] = g[i - W]
        V[5, j] = g[i + W + 1]
        V[6, j] = g[i + W - 1]
        V[7, j] = g[i - W + 1]
        V[8, j] = g[i - W - 1]
    steger_block(nb, V, thr, neg_aniso, neg_cross, tc, O)
    kl = 0
    kx = 0
    for j in range(nb):
        il[kl] = j
        kl += O[7, j] != 0
        ix[kx] = j
        kx += O[6, j] != 0
    if m + kl > u.shape[0] or mx + kx > xu.shape[0]:
        return -1, mx
    for t in range(kx):
        j = ix[t]
        i = cand[j]
        vv = i // W
        xu[mx] = i - vv * W
        xv[mx] = vv
        xs[mx] = O[5, j]
        mx += 1
    for t in range(kl):
        j = il[t]
        i = cand[j]
        vv = i // W
        u[m] = i - vv * W
        v[m] = vv
        ox[m] = O[0, j]
        oy[m] = O[1, j]
        nx[m] = O[2, j]
        ny[m] = O[3, j]
        st[m] = O[4, j]
        m += 1
    return m, mx


@njit(error_model="numpy")
def smooth_ridges_u8(img, k, G, thr_lap, thr, neg_aniso, neg_cross, u, v, ox, oy, nx, ny, st, xu, xv, xs, thr_cross=-1.0):
    """`gauss_u8(img, k, G)` and then `ridge_pass_into(G, ...)` in one walk down the image (decision 0091):
    as soon as smoothed rows are written, the rows above them get the Laplacian test, and a block of candidates is
    processed when a row leaves at least `_STEGER_BLOCK` pending, while the rows it reads are still in
    cache. The same arithmetic in the same order as the two kernels, so the same G and the same outputs
    (returns what `ridge_pass_into` returns; m = −1 when an output ran out of room).

    The column pass makes two output rows at a time (`_column_pair`, decision 0155; a last odd row alone), so the
    row ring holds K + 1 source rows (each twice, as in `gauss_u8`), and the rows are scanned in pairs: each scan is
    followed by the block test as before, so the blocks, their order and every value are those of the row-by-row
    walk."""
    H, W = img.shape
    K = len(k)
    rk = K // 2
    R2 = K + 1  # ring slots: K + 1 source rows, each stored at slot and slot + R2
    ext = np.empty(W + 2 * rk, np.float32)
    T = np.empty((2 * R2, W), np.float32)
    B = _STEGER_BLOCK
    tc = thr if thr_cross < 0 else np.float32(thr_cross)  # the crossing candidates' −λ2 threshold (0129)
    cap = B + W + 8
    cand = np.empty(cap, np.int32)
    flag = np.zeros((W + 7) // 8 * 8, np.uint8)
    flag8 = flag.view(np.uint64)
    V = np.empty((9, cap), np.float32)
    O = np.empty((8, cap), np.float32)
    il = np.empty(cap, np.int64)
    ix = np.empty(cap, np.int64)
    g = G.ravel()
    n = 0
    npend = 0
    m = 0
    mx = 0
    r_next = 1  # the next row to scan (row 0 is a border row)
    for yy in range(-rk, H + rk):
        # the Gaussian (gauss_u8): row pass of source row yy
        sy = yy
        if sy < 0:
            sy = -sy - 1
        elif sy >= H:
            sy = 2 * H - sy - 1
        src = img[sy]
        for x in range(W):
            ext[x + rk] = np.float32(src[x])
        for x in range(rk):
            ext[rk - 1 - x] = np.float32(src[x])
            ext[W + rk + x] = np.float32(src[W - 1 - x])
        slot = (yy + rk) % R2
        row = T[slot]
        row2 = T[slot + R2]
        for x in range(W):
            acc = ext[x] * k[0]
            for j in range(1, K):
                acc = fma32(ext[x + j], k[j], acc)
            row[x] = acc
            row2[x] = acc
        y = yy - rk  # source rows up to y + rk are filtered: output row y can be made
        if y < 0:
            continue
        if (y & 1) == 1:  # output rows y − 1 and y (source rows y − 1 − rk … y + rk)
            _column_pair(T, (y - 1) % R2, k, G[y - 1], G[y], W)
        elif y == H - 1:  # the last row of an odd height, alone
            _column_one(T, y % R2, k, G[y], W)
        else:
            continue
        # the ridge pass (ridge_pass_into) on the rows whose lower neighbour is now smoothed: r < y (r = H − 1, a
        # border row, is never scanned: the final step below takes whatever is pending)
        while r_next < y and r_next < H - 1:
            r = r_next
            r_next += 1
            a = G[r - 1]
            b = G[r]
            d = G[r + 1]
            for c in range(1, W - 1):
                flag[c] = ((((a[c] + b[c - 1]) + _F32_M4 * b[c]) + b[c + 1]) + d[c]) < thr_lap
            base = r * W
            for w in range(len(flag8)):
                if flag8[w] != 0:
                    for c in range(8 * w, 8 * w + 8):
                        cand[npend] = base + c
                        npend += flag[c]
            if npend < B:
                continue
            nb = npend
            n += nb
            npend = 0
            m, mx = _steger_flush(nb, cand, g, W, V, O, il, ix, thr, neg_aniso, neg_cross, tc, u, v, ox, oy, nx, ny, st,
                                  xu, xv, xs, m, mx)
            if m < 0:
                return n, -1, mx
    # the final block: whatever is pending
    nb = npend
    n += nb
    m, mx = _steger_flush(nb, cand, g, W, V, O, il, ix, thr, neg_aniso, neg_cross, tc, u, v, ox, oy, nx, ny, st,
                          xu, xv, xs, m, mx)
    if m < 0:
        return n, -1, mx
    return n, m, mx


_G_RING = 16  # rows of the working image `smooth_ridges_ring_u8` keeps (besides two copies at the ring's ends)


@njit(error_model="numpy")
def _ring_slot(r):
    """The slot of working row r in `smooth_ridges_ring_u8`'s ring (1 … _G_RING; slots 0 and _G_RING + 1 hold
    copies of the rows in slots _G_RING and 1, so that rows r − 1, r, r + 1 are always three consecutive slots)."""
    return r % _G_RING + 1


@njit(error_model="numpy")
def _steger_flush_ring(nb, cand, candr, g, W, V, O, il, ix, thr, neg_aniso, neg_cross, tc, u, v, ox, oy, nx, ny, st, xu,
                       xv, xs, m, mx):
    """`_steger_flush` for candidates given by their place in the ring (cand: slot·W + column) and their row (candr)."""
    for j in range(nb):
        i = cand[j]
        V[0, j] = g[i]
        V[1, j] = g[i + 1]
        V[2, j] = g[i - 1]
        V[3, j] = g[i + W]
        V[4, j] = g[i - W]
        V[5, j] = g[i + W + 1]
        V[6, j] = g[i + W - 1]
        V[7, j] = g[i - W + 1]
        V[8, j] = g[i - W - 1]
    steger_block(nb, V, thr, neg_aniso, neg_cross, tc, O)
    kl = 0
    kx = 0
    for j in range(nb):
        il[kl] = j
        kl += O[7, j] != 0
        ix[kx] = j
        kx += O[6, j] != 0
    if m + kl > u.shape[0] or mx + kx > xu.shape[0]:
        return -1, mx
    for t in range(kx):
        j = ix[t]
        vv = np.int64(candr[j])
        xu[mx] = cand[j] - _ring_slot(vv) * W
        xv[mx] = vv
        xs[mx] = O[5, j]
        mx += 1
    for t in range(kl):
        j = il[t]
        vv = np.int64(candr[j])
        u[m] = cand[j] - _ring_slot(vv) * W
        v[m] = vv
        ox[m] = O[0, j]
        oy[m] = O[1, j]
        nx[m] = O[2, j]
        ny[m] = O[3, j]
        st[m] = O[4, j]
        m += 1
    return m, mx


@njit(error_model="numpy")
def smooth_ridges_ring_u8(img, k, thr_lap, thr, neg_aniso, neg_cross, u, v, ox, oy, nx, ny, st, xu, xv, xs, thr_cross=-1.0):
    """`smooth_ridges_u8` without the full working image (decision 0155): the smoothed rows go into a ring of
    `_G_RING` rows (plus copies of its first and last slot, so that a candidate's three rows are consecutive), which
    the Laplacian test and the blocks read. A block is also processed (early) when the ring is about to overwrite a row
    its pending candidates read. Every candidate is computed on its own, so the block boundaries change no value: the
    outputs are `smooth_ridges_u8`'s (and `gauss_u8` + `ridge_pass_into`'s), in the same order; n likewise when
    m ≥ 0. Saves writing and reading back the 4·H·W-byte image (5 MB at 1280×1024)."""
    H, W = img.shape
    K = len(k)
    rk = K // 2
    R2 = K + 1
    RG = _G_RING
    ext = np.empty(W + 2 * rk, np.float32)
    T = np.empty((2 * R2, W), np.float32)
    Gr = np.zeros((RG + 2, W), np.float32)
    g = Gr.ravel()
    B = _STEGER_BLOCK
    tc = thr if thr_cross < 0 else np.float32(thr_cross)  # the crossing candidates' −λ2 threshold (0129)
    cap = B + W + 8
    cand = np.empty(cap, np.int32)
    candr = np.empty(cap, np.int32)
    flag = np.zeros((W + 7) // 8 * 8, np.uint8)
    flag8 = flag.view(np.uint64)
    V = np.empty((9, cap), np.float32)
    O = np.empty((8, cap), np.float32)
    il = np.empty(cap, np.int64)
    ix = np.empty(cap, np.int64)
    n = 0
    npend = 0
    m = 0
    mx = 0
    r_next = 1
    for yy in range(-rk, H + rk):
        sy = yy
        if sy < 0:
            sy = -sy - 1
        elif sy >= H:
            sy = 2 * H - sy - 1
        src = img[sy]
        for x in range(W):
            ext[x + rk] = np.float32(src[x])
        for x in range(rk):
            ext[rk - 1 - x] = np.float32(src[x])
            ext[W + rk + x] = np.float32(src[W - 1 - x])
        slot = (yy + rk) % R2
        row = T[slot]
        row2 = T[slot + R2]
        for x in range(W):
            acc = ext[x] * k[0]
            for j in range(1, K):
                acc = fma32(ext[x + j], k[j], acc)
            row[x] = acc
            row2[x] = acc
        y = yy - rk
        if y < 0:
            continue
        pair = (y & 1) == 1
        if not pair and y != H - 1:
            continue
        # writing row y overwrites row y − RG: pending candidates read rows from candr[0] − 1 on
        if npend > 0 and y >= candr[0] - 1 + RG:
            nb = npend
            n += nb
            npend = 0
            m, mx = _steger_flush_ring(nb, cand, candr, g, W, V, O, il, ix, thr, neg_aniso, neg_cross, tc, u, v, ox, oy,
                                       nx, ny, st, xu, xv, xs, m, mx)
            if m < 0:
                return n, -1, mx
        if pair:
            _column_pair(T, (y - 1) % R2, k, Gr[_ring_slot(y - 1)], Gr[_ring_slot(y)], W)
            lo = y - 1
        else:
            _column_one(T, y % R2, k, Gr[_ring_slot(y)], W)
            lo = y
        for yr in range(lo, y + 1):  # the copies at the ring's ends
            sl = _ring_slot(yr)
            if sl == RG:
                Gr[0, :] = Gr[RG, :]
            elif sl == 1:
                Gr[RG + 1, :] = Gr[1, :]
        while r_next < y and r_next < H - 1:
            r = r_next
            r_next += 1
            sr = _ring_slot(r)
            a = Gr[sr - 1]
            b = Gr[sr]
            d = Gr[sr + 1]
            for c in range(1, W - 1):
                flag[c] = ((((a[c] + b[c - 1]) + _F32_M4 * b[c]) + b[c + 1]) + d[c]) < thr_lap
            base = sr * W
            for w in range(len(flag8)):
                if flag8[w] != 0:
                    for c in range(8 * w, 8 * w + 8):
                        cand[npend] = base + c
                        candr[npend] = r
                        npend += flag[c]
            if npend < B:
                continue
            nb = npend
            n += nb
            npend = 0
            m, mx = _steger_flush_ring(nb, cand, candr, g, W, V, O, il, ix, thr, neg_aniso, neg_cross, tc, u, v, ox, oy,
                                       nx, ny, st, xu, xv, xs, m, mx)
            if m < 0:
                return n, -1, mx
    nb = npend
    n += nb
    m, mx = _steger_flush_ring(nb, cand, candr, g, W, V, O, il, ix, thr, neg_aniso, neg_cross, tc, u, v, ox, oy, nx, ny,
                               st, xu, xv, xs, m, mx)
    if m < 0:
        return n, -1, mx
    return n, m, mx


@njit
def albedo_and_families(u, v, ox, oy, nx, ny, st, xu, xv, xs, Hw, Ww, min_rel, cross_rel, dir4, gh_d, gw_d, cell_d, margin):
    """The uneven-albedo test (a fraction of the strongest ridge in the 3×3 cells of 16 px around: the
    per-cell maximum, then its 3×3 dilation within the grid) on line samples and crossing candidates,
    then the family of each line sample from the model's direction grid `dir4` ((gh_d·gw_d, 4) float32:
    i-line (dx, dy), j-line (dx, dy); nearest cell of `cell_d` px).

    min_rel, cross_rel, margin: float32. Returns the kept samples (u, v, ox, oy, nx, ny, strength, fam int8,
    qx, qy float32 = u + ox, v + oy) and the kept crossing candidates (xu, xv, xs), in input order, as
    views of arrays of the input's length (every sample is written at the next free place, the place
    advances only where it is kept: branch-free)."""
    cell_s = 16  # pixel coordinates are ≥ 0: `>> 4` below is their `// cell_s` without the signed floor (0079)
    gh = Hw // cell_s + 1
    gw = Ww // cell_s + 1
    n = len(u)
    m0 = np.zeros((gh, gw), np.float32)
    for k in range(n):
        r = v[k] >> 4
        c = u[k] >> 4
        if st[k] > m0[r, c]:
            m0[r, c] = st[k]
    local = np.zeros((gh, gw), np.float32)
    for r in range(gh):
        for c in range(gw):
            best = m0[r, c]
            for rr in range(max(r - 1, 0), min(r + 2, gh)):
                for cc in range(max(c - 1, 0), min(c + 2, gw)):
                    if m0[rr, cc] > best:
                        best = m0[rr, cc]
            local[r, c] = best
    ou = np.empty(n, np.int64)
    ov = np.empty(n, np.int64)
    oox = np.empty(n, np.float32)
    ooy = np.empty(n, np.float32)
    onx = np.empty(n, np.float32)
    ony = np.empty(n, np.float32)
    ost = np.empty(n, np.float32)
    ofam = np.empty(n, np.int8)
    qx = np.empty(n, np.float32)
    qy = np.empty(n, np.float32)
    # the direction grid's cell of every sample first, in a loop without branches (vector code; the same
    # operations, decision 0162)
    jd = np.empty(n, np.int64)
    for k in range(n):
        cd = int((u[k] + np.float64(ox[k])) / cell_d + 0.5)
        rd = int((v[k] + np.float64(oy[k])) / cell_d + 0.5)
        cd = min(max(cd, 0), gw_d - 1)
        rd = min(max(rd, 0), gh_d - 1)
        jd[k] = rd * gw_d + cd
    m = 0
    for k in range(n):
        uk = u[k]
        vk = v[k]
        j = jd[k]
        c1 = abs(dir4[j, 1] * nx[k] - dir4[j, 0] * ny[k])
        c2 = abs(dir4[j, 3] * nx[k] - dir4[j, 2] * ny[k])
        keep = (st[k] >= min_rel * local[vk >> 4, uk >> 4]) & (abs(c1 - c2) >= margin)
        ou[m] = uk
        ov[m] = vk
        oox[m] = ox[k]
        ooy[m] = oy[k]
        onx[m] = nx[k]
        ony[m] = ny[k]
        ost[m] = st[k]
        ofam[m] = 1 if c1 >= c2 else 2
        qx[m] = np.float32(uk) + ox[k]
        qy[m] = np.float32(vk) + oy[k]
        m += keep
    nxs = len(xs)
    oxu = np.empty(nxs, np.int64)
    oxv = np.empty(nxs, np.int64)
    oxs = np.empty(nxs, np.float32)
    j = 0
    for k in range(nxs):
        oxu[j] = xu[k]
        oxv[j] = xv[k]
        oxs[j] = xs[k]
        j += xs[k] >= cross_rel * local[xv[k] >> 4, xu[k] >> 4]
    return ou[:m], ov[:m], oox[:m], ooy[:m], onx[:m], ony[:m], ost[:m], ofam[:m], qx[:m], qy[:m], oxu[:j], oxv[:j], oxs[:j]


@njit
def crossing_seeds(xu, xv, xs, cell, gh, gw):
    """Crossing candidates that are the maximum of `xs` over the 3×3 cells (of `cell` px, (gh, gw) of
    them) around theirs (the grid is dilated only where a candidate looks)."""
    return crossing_seeds_max(xu, xv, xs, cell, gh, gw)[0]


@njit
def crossing_seeds_max(xu, xv, xs, cell, gh, gw):
    """`crossing_seeds` and the grid of the cells' maxima it used ((gh, gw) float32, 0: no pixel)."""
    n = len(xs)
    cu = np.empty(n, np.int64)
    cv = np.empty(n, np.int64)
    m = np.zeros((gh, gw), np.float32)
    for k in range(n):
        cu[k] = int(xu[k] / cell)
        cv[k] = int(xv[k] / cell)
        if xs[k] > m[cv[k], cu[k]]:
            m[cv[k], cu[k]] = xs[k]
    seed = np.zeros(n, np.bool_)
    for k in range(n):
        best = np.float32(0.0)
        for rr in range(max(cv[k] - 1, 0), min(cv[k] + 2, gh)):
            for cc in range(max(cu[k] - 1, 0), min(cu[k] + 2, gw)):
                best = max(best, m[rr, cc])
        seed[k] = xs[k] >= best
    return seed, m


@njit
def stamp(cx, cy, radius, cs, grid, pad):
    """Fill `grid` ((gh + 2·pad, gw + 2·pad) int32, in place) as a lookup grid of cells of `cs` px: the index
    of the centre nearest to the cell's centre, if within `radius` + one cell, −1 elsewhere (ties: the
    later centre). Centres (cx, cy) float64 working px; cell (0, 0) of the image is grid[pad, pad]."""
    GH, GW = grid.shape
    gh = GH - 2 * pad
    gw = GW - 2 * pad
    grid[:, :] = -1
    n = len(cx)
    if n == 0:
        return
    rr = min(int(math.ceil(radius / cs)) + 1, pad - 1)
    lim = (radius + cs) ** 2
    no = 0
    offx = np.empty((2 * rr + 1) ** 2, np.int64)
    offy = np.empty((2 * rr + 1) ** 2, np.int64)
    for oy in range(-rr, rr + 1):
        for ox in range(-rr, rr + 1):
            if np.float64(ox * ox + oy * oy) * cs * cs <= lim:
                offx[no] = ox
                offy[no] = oy
                no += 1
    lo = 1 - pad + rr
    hix = gw + pad - rr - 2
    hiy = gh + pad - rr - 2
    # the offsets by row: row oy holds ox in [oxa[oy + rr], oxb[oy + rr]] (a contiguous run, |ox| rising);
    # each centre walks its rows with dy·dy computed once per row (the same float32 values; decision 0079)
    oxa = np.zeros(2 * rr + 1, np.int64)
    oxb = np.full(2 * rr + 1, -1, np.int64)
    for j in range(no):
        t = offy[j] + rr
        if oxb[t] < oxa[t]:
            oxa[t] = offx[j]
            oxb[t] = offx[j]
        else:
            oxa[t] = min(oxa[t], offx[j])
            oxb[t] = max(oxb[t], offx[j])
    c0x = np.empty(n, np.int64)
    c0y = np.empty(n, np.int64)
    fx = np.empty(n, np.float32)
    fy = np.empty(n, np.float32)
    for i in range(n):
        ccx = cx[i] / cs
        ccy = cy[i] / cs
        c0x[i] = min(max(int(ccx), lo), hix)
        c0y[i] = min(max(int(ccy), lo), hiy)
        fx[i] = np.float32(ccx - c0x[i] - 0.5)  # centre relative to its cell's centre, in cells
        fy[i] = np.float32(ccy - c0y[i] - 0.5)
        fxi = fx[i]
        for t in range(2 * rr + 1):
            if oxb[t] < oxa[t]:
                continue
            oy = t - rr
            dy = np.float32(oy) - fy[i]
            dy2 = dy * dy
            r = c0y[i] + pad + oy
            row = grid[r]
            for ox in range(oxa[t], oxb[t] + 1):
                dx = np.float32(ox) - fxi
                d2 = dx * dx + dy2
                c = c0x[i] + pad + ox
                o = row[c]
                if o >= 0:  # the owner's squared distance, recomputed exactly as when it was stamped
                    odx = np.float32(c - pad - c0x[o]) - fx[o]
                    ody = np.float32(r - pad - c0y[o]) - fy[o]
                    if d2 > odx * odx + ody * ody:
                        continue
                row[c] = i


@njit
def look_dist(grid, px, py, inv_cs, pad, cx, cy, rmax):
    """For points (px, py) float32: the grid's entry k (−1: none) and the float32 distance to centre k
    (float32 centres cx, cy; inf where none); k is −1 where that distance exceeds `rmax` (float32)."""
    GH, GW = grid.shape
    n = len(px)
    k_out = np.full(n, -1, np.int64)
    d_out = np.full(n, np.inf, np.float32)
    for i in range(n):
        c = min(max(int(px[i] * inv_cs) + pad, 0), GW - 1)
        r = min(max(int(py[i] * inv_cs) + pad, 0), GH - 1)
        k = grid[r, c]
        if k >= 0:
            dx = px[i] - cx[k]
            dy = py[i] - cy[k]
            d = np.float32(math.sqrt(dx * dx + dy * dy))
            d_out[i] = d
            if d <= rmax:
                k_out[i] = k
    return k_out, d_out


@njit
def centroids(grid, xu, xv, xs, sx, sy, cs, pad, rmax):
    """Score-weighted centroids of the crossing pixels (xu, xv, score xs) within `rmax` (float64) of the
    centre (sx, sy) whose cell of `grid` they fall in; (n, 2) float64."""
    GH, GW = grid.shape
    n = len(sx)
    wsum = np.zeros(n)
    su = np.zeros(n)
    sv = np.zeros(n)
    for i in range(len(xs)):
        qx = np.float64(xu[i])
        qy = np.float64(xv[i])
        c = min(max(int(qx / cs) + pad, 0), GW - 1)
        r = min(max(int(qy / cs) + pad, 0), GH - 1)
        k = grid[r, c]
        if k < 0 or hypot_gt(qx - sx[k], qy - sy[k], rmax):
            continue
        w = np.float64(xs[i])
        wsum[k] += w
        su[k] += w * qx
        sv[k] += w * qy
    out = np.empty((n, 2))
    for k in range(n):
        d = max(wsum[k], 1e-12)
        out[k, 0] = su[k] / d
        out[k, 1] = sv[k] / d
    return out


@njit
def ring_counts(near, dist, fam, r0, ns):
    """(ns, 2) samples of each family with a candidate `near` (−1: none) at a distance above r0 (float32)."""
    n_ring = np.zeros((ns, 2), np.int64)
    if ns == 0:
        return n_ring
    for i in range(len(near)):  # branch-free: samples without a candidate add 0 to candidate 0
        k = near[i]
        n_ring[max(k, 0), fam[i] - 1] += (k >= 0) & (dist[i] > r0)
    return n_ring


@njit
def crossing_cores(near, dist, remap, r0):
    """(P,) bool: samples whose candidate `near` (−1: none) is kept (remap[near] ≥ 0) and within r0
    (float32) of it: the crossings' cores."""
    core = np.zeros(len(near), np.bool_)
    for i in range(len(near)):
        k = near[i]
        if k >= 0 and remap[k] >= 0:
            core[i] = dist[i] <= r0
    return core


@njit
def row_starts(v, Hw):
    """(Hw + 1,) int64: samples sorted by row (v) — as the ridge pass emits them — start row r at index
    row_start[r]."""
    rs = np.empty(Hw + 1, np.int64)
    k = 0
    for r in range(Hw + 1):
        while k < len(v) and v[k] < r:
            k += 1
        rs[r] = k
    return rs


@njit
def sample_at(row_start, u, core, iu, iv):
    """The sample (outside the cores) at integer pixel (iu, iv), −1: none (binary search in its row)."""
    lo = row_start[iv]
    hi = row_start[iv + 1]
    while lo < hi:
        mid = (lo + hi) >> 1
        if u[mid] < iu:
            lo = mid + 1
        else:
            hi = mid
    if lo < row_start[iv + 1] and u[lo] == iu and not core[lo]:
        return lo
    return -1


_RING = 8  # rows of the linking's sample-id window (probes reach 2 rows up and 3 down)


@njit(error_model="numpy")
def link_segments(u, v, core, qx, qy, nx, ny, fam, Hw, Ww):
    """Segments: samples outside the cores linked to the samples their 4 probes along their own tangent
    hit (one and two steps along its dominant axis, the two pixels across that the line reaches) when on
    the same line (same family, |n_a·n_b| ≥ 0.9, offset across ≤ 0.5 + 0.25·distance; float32), then the
    connected components (union-find), numbered by their lowest sample index (as scipy's
    connected_components), single samples dropped. Samples must come sorted by row (v), as the ridge pass
    emits them: the sample ids are kept for a window of `_RING` rows (columns padded by 2 px). The
    components do not depend on the order of the unions (the smaller root always becomes the parent), so
    a sample's own root is looked up once, at its first link, and updated by its unions.

    Returns seg (P,) int64 (−1: none) and the number of segments S."""
    P = len(u)
    parent = np.arange(P).astype(np.int32)
    Wp = Ww + 4
    win = np.full(_RING * Wp, -1, np.int32)
    filled = -1  # rows up to this one are in the window
    nxt = 0  # next sample to put into the window
    # every sample's slope along its dominant axis first, in a loop without branches (vector code; the same
    # float32 divisions, decision 0162)
    slopes = np.empty(P, np.float32)
    for a in range(P):
        tx = -ny[a]
        ty = nx[a]
        xd = abs(tx) >= abs(ty)
        slopes[a] = (ty if xd else tx) / (tx if xd else ty)
    for a in range(P):
        if core[a]:
            continue
        va = v[a]
        while filled < min(va + 3, Hw - 1):
            filled += 1
            base_r = (filled % _RING) * Wp
            win[base_r : base_r + Wp] = -1
            while nxt < P and v[nxt] == filled:
                if not core[nxt]:
                    win[base_r + u[nxt] + 2] = nxt
                nxt += 1
        xdom = abs(ny[a]) >= abs(nx[a])  # |tx| ≥ |ty|, the tangent (tx, ty) = (−ny, nx)
        slope = slopes[a]
        if not np.isfinite(slope):
            continue
        ra = -1  # a's root: found at its first link, then kept up to date by its unions (decision 0091)
        for k in range(1, 3):
            x = np.float32(k) * slope
            lo = int(x)  # floor(x), x finite, |x| <= 2
            lo -= x < lo
            for extra in range(2):
                if xdom:
                    pr = va + lo + extra
                    pc = u[a] + k
                else:
                    pr = va + k
                    pc = u[a] + lo + extra
                if pr < 0 or pr >= Hw:
                    continue
                b = win[(pr % _RING) * Wp + pc + 2]
                if b < 0 or fam[a] != fam[b]:
                    continue
                if abs(nx[a] * nx[b] + ny[a] * ny[b]) < np.float32(0.9):
                    continue
                dqx = qx[b] - qx[a]
                dqy = qy[b] - qy[a]
                across = max(abs(dqx * nx[a] + dqy * ny[a]), abs(dqx * nx[b] + dqy * ny[b]))
                if across <= np.float32(0.5) + np.float32(0.25) * np.float32(math.sqrt(dqx * dqx + dqy * dqy)):
                    if ra < 0:
                        ra = a
                        while parent[ra] != ra:
                            parent[ra] = parent[parent[ra]]
                            ra = parent[ra]
                    rb = b
                    while parent[rb] != rb:
                        parent[rb] = parent[parent[rb]]
                        rb = parent[rb]
                    if ra != rb:
                        if ra < rb:
                            parent[rb] = np.int32(ra)
                        else:
                            parent[ra] = np.int32(rb)
                            ra = rb
    # the smaller root always becomes the parent, so parent[a] <= a: in index order each root is known
    # from the parent's, and a component's root is its lowest sample
    root = np.empty(P, np.int32)
    size = np.zeros(P, np.int32)
    for a in range(P):
        r = a if parent[a] == a else root[parent[a]]
        root[a] = r
        if not core[a]:
            size[r] += 1
    label = np.full(P, -1, np.int32)
    seg = np.full(P, -1, np.int64)
    S = 0
    for a in range(P):
        if core[a]:
            continue
        r = root[a]
        if r == a and size[a] >= 2:
            label[a] = S
            S += 1
        seg[a] = label[r]
    return seg, S


@njit
def line_fit_xy(groups, X, Y, n, n_groups):
    """Per-group total-least-squares line of the points (X[k], Y[k]) float64 of group groups[k], k < n:
    centroid (G, 2), unit direction (G, 2), RMS distance (G,), count (G,) int64 (sums in input order, as
    np.bincount)."""
    num = np.zeros(n_groups, np.int64)
    mx = np.zeros(n_groups)
    my = np.zeros(n_groups)
    for k in range(n):
        g = groups[k]
        num[g] += 1
        mx[g] += X[k]
        my[g] += Y[k]
    for g in range(n_groups):
        s = np.float64(max(num[g], 1))
        mx[g] /= s
        my[g] /= s
    sxx = np.zeros(n_groups)
    syy = np.zeros(n_groups)
    sxy = np.zeros(n_groups)
    for k in range(n):
        g = groups[k]
        dx = X[k] - mx[g]
        dy = Y[k] - my[g]
        sxx[g] += dx * dx
        syy[g] += dy * dy
        sxy[g] += dx * dy
    cen = np.empty((n_groups, 2))
    dr = np.empty((n_groups, 2))
    rms = np.empty(n_groups)
    for g in range(n_groups):
        s = np.float64(max(num[g], 1))
        a = sxx[g] / s
        b = syy[g] / s
        c = sxy[g] / s
        theta = 0.5 * math.atan2(2 * c, a - b)
        dr[g, 0] = math.cos(theta)
        dr[g, 1] = math.sin(theta)
        h = 0.5 * (a - b)
        disc = math.sqrt(h * h + c * c)
        rms[g] = math.sqrt(max(0.5 * (a + b) - disc, 0.0))
        cen[g, 0] = mx[g]
        cen[g, 1] = my[g]
    return cen, dr, rms, num


@njit
def _line_fit_xy_redo(groups, X, Y, n, n_groups, redo, cen, dr, rms, num):
    """`line_fit_xy` of the groups with redo[g], written into its outputs (cen, dr, rms, num) in place; the other
    groups' rows are left as they are. Each group's sums run over its own points in input order, so a group's
    fit does not depend on the others'."""
    cnt = np.zeros(n_groups, np.int64)
    mx = np.zeros(n_groups)
    my = np.zeros(n_groups)
    for k in range(n):
        g = groups[k]
        if not redo[g]:  # (few groups lose a sample)
            continue
        cnt[g] += 1
        mx[g] += X[k]
        my[g] += Y[k]
    for g in range(n_groups):
        if not redo[g]:
            continue
        s = np.float64(max(cnt[g], 1))
        mx[g] /= s
        my[g] /= s
    sxx = np.zeros(n_groups)
    syy = np.zeros(n_groups)
    sxy = np.zeros(n_groups)
    for k in range(n):
        g = groups[k]
        if not redo[g]:
            continue
        dx = X[k] - mx[g]
        dy = Y[k] - my[g]
        sxx[g] += dx * dx
        syy[g] += dy * dy
        sxy[g] += dx * dy
    for g in range(n_groups):
        if not redo[g]:
            continue
        s = np.float64(max(cnt[g], 1))
        a = sxx[g] / s
        b = syy[g] / s
        c = sxy[g] / s
        theta = 0.5 * math.atan2(2 * c, a - b)
        dr[g, 0] = math.cos(theta)
        dr[g, 1] = math.sin(theta)
        h = 0.5 * (a - b)
        disc = math.sqrt(h * h + c * c)
        rms[g] = math.sqrt(max(0.5 * (a + b) - disc, 0.0))
        cen[g, 0] = mx[g]
        cen[g, 1] = my[g]
        num[g] = cnt[g]

@njit
def line_fit(groups, idx, qx, qy, n_groups):
    """`line_fit_xy` of the points (qx[idx[k]], qy[idx[k]]) (float32, taken as float64)."""
    N = len(groups)
    X = np.empty(N)
    Y = np.empty(N)
    for k in range(N):
        X[k] = np.float64(qx[idx[k]])
        Y[k] = np.float64(qy[idx[k]])
    return line_fit_xy(groups, X, Y, N, n_groups)


@njit
def segment_extents(sidx, sg, qx, qy, cen, dr, S):
    """Each segment sample's position along its segment's fitted line (float64, from the centroid) and
    each segment's smallest and largest one."""
    n = len(sidx)
    sproj = np.empty(n)
    smin = np.full(S, np.inf)
    smax = np.full(S, -np.inf)
    for k in range(n):
        i = sidx[k]
        g = sg[k]
        s = (np.float64(qx[i]) - cen[g, 0]) * dr[g, 0] + (np.float64(qy[i]) - cen[g, 1]) * dr[g, 1]
        sproj[k] = s
        smin[g] = min(smin[g], s)
        smax[g] = max(smax[g], s)
    return sproj, smin, smax


@njit
def end_walks(sidx, sg, sproj, smin, smax, qx, qy, nx, ny, fam, seg_family, seg_dir, probes, Hw, Ww,
              seed_grid, seed_remap, inv_cs, pad, sx, sy, sx32, sy32, r_side32, r_reach, row_start, u, core):
    """From each end of each segment (the last sample at the extreme position), walk on along the end
    sample's own tangent (pointing away from the segment) at `probes` (px): the first crossing candidate
    whose lookup cell a probe falls in (`seed_grid` holds candidate ids before the crossing test,
    `seed_remap` maps them to the kept ones, −1: dropped), within `r_side32` of it, is the one the end reaches (if the end
    itself is within `r_reach` of it). For an end that reaches none, the first probe that lands on a
    sample of the other family marks a T.

    Returns seg_seed (S, 2) int64 (−1: none) and the T samples (ids, lower ends first, then upper)."""
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
            if kk >= 0 and hypot_le(ex - sx[kk], ey - sy[kk], r_reach):
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
                # the sample (outside the cores) at (iu, iv): `sample_at` written out (a call per probe with
                # its array arguments cost more than the binary search itself; decision 0091)
                lo = row_start[iv]
                hi = row_start[iv + 1]
                end = hi
                while lo < hi:
                    mid = (lo + hi) >> 1
                    if u[mid] < iu:
                        lo = mid + 1
                    else:
                        hi = mid
                h = lo if (lo < end and u[lo] == iu and not core[lo]) else -1
                if h >= 0 and fam[h] != seg_family[g]:
                    t_ids[n_t] = h
                    n_t += 1
                    break
    return seg_seed, t_ids[:n_t].copy()


@njit
def arms(sidx, sg, sproj, smin, smax, seg_seed, qx, qy, sx32, sy32, R32, P):
    """arm_of (P,) int64: the junction candidate whose arm each segment sample is (the candidate its
    segment's nearer attached end reaches, within R32 px), −1: none."""
    arm_of = np.full(P, -1, np.int64)
    for k in range(len(sidx)):
        g = sg[k]
        a0 = seg_seed[g, 0]
        a1 = seg_seed[g, 1]
        d_lo = sproj[k] - smin[g]
        d_hi = smax[g] - sproj[k]
        pick = a1 if (a1 >= 0 and (a0 < 0 or d_hi < d_lo)) else a0
        if pick < 0:
            continue
        i = sidx[k]
        dx = qx[i] - sx32[pick]
        dy = qy[i] - sy32[pick]
        if np.float32(math.sqrt(dx * dx + dy * dy)) <= R32:
            arm_of[i] = pick
    return arm_of


@njit
def junction_fits(arm_of, fam, qx, qy, nx, ny, sx, sy, ns):
    """Per candidate and family (rows 2·k + family − 1): the straight-line fit of its arm samples with
    outliers (farther than max(1, 3·RMS) from a first fit) dropped, and along that fit the inliers' counts
    on either side of the candidate (beyond 0.5 px), their mean signed offsets from the fit on either
    side, and the mean |sin| between the fit and the samples' own directions.

    Returns cen (2ns, 2), dr (2ns, 2), rms (2ns,), cnt (2ns,), n_neg, n_pos, m_neg, m_pos, mean_sin (2ns,).
    The side counts and sums are taken branch-free (adding 0 where a sample is not on that side: the
    same sums)."""
    G = 2 * ns
    P = len(arm_of)
    grp = np.empty(P, np.int64)  # the arm samples (float64 coordinates and normals), in sample order
    X = np.empty(P)
    Y = np.empty(P)
    NX = np.empty(P)
    NY = np.empty(P)
    na = 0
    for i in range(P):  # branch-free: every sample written at the next place, kept where on an arm
        a = arm_of[i]
        grp[na] = 2 * a + fam[i] - 1
        X[na] = np.float64(qx[i])
        Y[na] = np.float64(qy[i])
        NX[na] = np.float64(nx[i])
        NY[na] = np.float64(ny[i])
        na += a >= 0
    return _fits_of_groups(grp, X, Y, NX, NY, na, G, sx, sy)


@njit
def _fits_of_groups(grp, X, Y, NX, NY, na, G, sx, sy):
    """`junction_fits` on collected arm samples: points (X, Y), own normals (NX, NY) float64 of group grp[k]
    (row 2·candidate + family − 1), k < na (overwritten: the inliers are compacted in place); candidates at
    (sx, sy). Same outputs as `junction_fits`."""
    cen, dr, rms, cnt = line_fit_xy(grp, X, Y, na, G)
    m = 0  # inliers, compacted in place (order kept)
    redo = np.zeros(G, np.bool_)  # groups that lost a sample
    for k in range(na):
        g = grp[k]
        off = abs((X[k] - cen[g, 0]) * dr[g, 1] - (Y[k] - cen[g, 1]) * dr[g, 0])
        if off <= max(1.0, 3 * rms[g]):
            grp[m] = g
            X[m] = X[k]
            Y[m] = Y[k]
            NX[m] = NX[k]
            NY[m] = NY[k]
            m += 1
        else:
            redo[g] = True
    # a group that lost no sample has the same points in the same order: its fit is the first (decision 0162)
    if m < na:
        _line_fit_xy_redo(grp, X, Y, m, G, redo, cen, dr, rms, cnt)
    n_neg = np.zeros(G)
    n_pos = np.zeros(G)
    s_neg = np.zeros(G)
    s_pos = np.zeros(G)
    s_sin = np.zeros(G)
    for k in range(m):
        g = grp[k]
        c = g // 2
        bx = X[k]
        by = Y[k]
        s = (bx - sx[c]) * dr[g, 0] + (by - sy[c]) * dr[g, 1]
        off = (bx - cen[g, 0]) * dr[g, 1] - (by - cen[g, 1]) * dr[g, 0]
        neg = s < -0.5
        pos = s > 0.5
        n_neg[g] += 1.0 if neg else 0.0
        s_neg[g] += off if neg else 0.0
        n_pos[g] += 1.0 if pos else 0.0
        s_pos[g] += off if pos else 0.0
        s_sin[g] += abs(NX[k] * dr[g, 0] + NY[k] * dr[g, 1])
    m_neg = np.empty(G)
    m_pos = np.empty(G)
    mean_sin = np.empty(G)
    for g in range(G):
        m_neg[g] = s_neg[g] / max(n_neg[g], 1.0)
        m_pos[g] = s_pos[g] / max(n_pos[g], 1.0)
        mean_sin[g] = s_sin[g] / max(cnt[g], 1)
    return cen, dr, rms, cnt, n_neg, n_pos, m_neg, m_pos, mean_sin


@njit
def _fit_run(X, Y, lo, n):
    """`line_fit_xy` of one group whose points are X[lo : lo + n], Y[...] (the same operations in the same order):
    centroid (x, y), unit direction (x, y), RMS distance."""
    mx = 0.0
    my = 0.0
    for k in range(lo, lo + n):
        mx += X[k]
        my += Y[k]
    s = np.float64(max(n, 1))
    mx /= s
    my /= s
    sxx = 0.0
    syy = 0.0
    sxy = 0.0
    for k in range(lo, lo + n):
        dx = X[k] - mx
        dy = Y[k] - my
        sxx += dx * dx
        syy += dy * dy
        sxy += dx * dy
    a = sxx / s
    b = syy / s
    c = sxy / s
    theta = 0.5 * math.atan2(2 * c, a - b)
    h = 0.5 * (a - b)
    disc = math.sqrt(h * h + c * c)
    return mx, my, math.cos(theta), math.sin(theta), math.sqrt(max(0.5 * (a + b) - disc, 0.0))


@njit
def _fits_of_runs(start, X, Y, NX, NY, G, sx, sy):
    """`_fits_of_groups` on samples already ordered by group: group g's points are X[start[g] : start[g + 1]], ...
    (float64; each group's in the order `_fits_of_groups` would read them; the inliers are compacted in place).
    Each group's sums run in registers, in that order, so every output is `_fits_of_groups`' (decision 0162).
    Groups without samples get the fit of an empty group, computed once (by the same code)."""
    cen = np.empty((G, 2))
    dr = np.empty((G, 2))
    rms = np.empty(G)
    cnt = np.empty(G, np.int64)
    n_neg = np.empty(G)
    n_pos = np.empty(G)
    m_neg = np.empty(G)
    m_pos = np.empty(G)
    mean_sin = np.empty(G)
    e_done = False
    e0 = e1 = e2 = e3 = e4 = 0.0
    for g in range(G):
        lo = start[g]
        n = start[g + 1] - lo
        if n == 0:
            if not e_done:  # every empty group's fit is the same: computed once, by the same code
                e0, e1, e2, e3, e4 = _fit_run(X, Y, lo, 0)
                e_done = True
            cen[g, 0] = e0
            cen[g, 1] = e1
            dr[g, 0] = e2
            dr[g, 1] = e3
            rms[g] = e4
            cnt[g] = 0
            n_neg[g] = 0.0
            n_pos[g] = 0.0
            m_neg[g] = 0.0 / 1.0
            m_pos[g] = 0.0 / 1.0
            mean_sin[g] = 0.0 / 1
            continue
        c0, c1, d0, d1, r = _fit_run(X, Y, lo, n)
        tol = max(1.0, 3 * r)
        m = lo  # inliers, compacted in place (order kept)
        for k in range(lo, lo + n):
            off = abs((X[k] - c0) * d1 - (Y[k] - c1) * d0)
            if off <= tol:
                X[m] = X[k]
                Y[m] = Y[k]
                NX[m] = NX[k]
                NY[m] = NY[k]
                m += 1
        m -= lo
        c0, c1, d0, d1, r = _fit_run(X, Y, lo, m)
        c = g // 2
        cxs = sx[c]
        cys = sy[c]
        nn = 0.0
        np_ = 0.0
        sn = 0.0
        sp = 0.0
        ss = 0.0
        for k in range(lo, lo + m):
            bx = X[k]
            by = Y[k]
            s = (bx - cxs) * d0 + (by - cys) * d1
            off = (bx - c0) * d1 - (by - c1) * d0
            neg = s < -0.5
            pos = s > 0.5
            nn += 1.0 if neg else 0.0
            sn += off if neg else 0.0
            np_ += 1.0 if pos else 0.0
            sp += off if pos else 0.0
            ss += abs(NX[k] * d0 + NY[k] * d1)
        cen[g, 0] = c0
        cen[g, 1] = c1
        dr[g, 0] = d0
        dr[g, 1] = d1
        rms[g] = r
        cnt[g] = m
        n_neg[g] = nn
        n_pos[g] = np_
        m_neg[g] = sn / max(nn, 1.0)
        m_pos[g] = sp / max(np_, 1.0)
        mean_sin[g] = ss / max(m, 1)
    return cen, dr, rms, cnt, n_neg, n_pos, m_neg, m_pos, mean_sin


@njit
def trim_free_ends(seg_out, sidx, sg, sproj, smin, smax, seg_seed, sample_junction, d_trim):
    """Samples within d_trim (px) of a segment end that reaches no crossing leave their segment
    (seg_out set to −1 in place, unless a junction holds them); returns how many are that close."""
    n_near = 0
    for k in range(len(sidx)):
        g = sg[k]
        near_end = (seg_seed[g, 0] < 0 and sproj[k] - smin[g] < d_trim) or (seg_seed[g, 1] < 0 and smax[g] - sproj[k] < d_trim)
        if near_end:
            n_near += 1
            if sample_junction[sidx[k]] < 0:
                seg_out[sidx[k]] = -1
    return n_near


@njit
def junction_sample_ids(arm_of, new_id, seg):
    """Per sample: the kept junction holding it (new_id[arm_of], −1: none; new_id's last entry is −1) and
    its segment as reported (−1 where a junction holds it). int64 (P,) each, as NumPy's fancy indexing
    and np.where gave."""
    P = len(arm_of)
    sample_junction = np.empty(P, np.int64)
    seg_out = np.empty(P, np.int64)
    none = new_id[len(new_id) - 1]
    for i in range(P):
        a = arm_of[i]
        j = new_id[a] if a >= 0 else none
        sample_junction[i] = j
        seg_out[i] = -1 if j >= 0 else seg[i]
    return sample_junction, seg_out


@njit
def leave_near(grid, px, py, inv_cs, pad, cx, cy, rmax, sample_junction, seg_out):
    """The samples (px, py) float32 whose `grid` entry k (as `look_dist`) is within `rmax` (float32) of
    centre k leave their segment (seg_out = −1 in place) unless a junction holds them; returns how many
    samples are that close."""
    GH, GW = grid.shape
    n_near = 0
    for i in range(len(px)):
        c = min(max(int(px[i] * inv_cs) + pad, 0), GW - 1)
        r = min(max(int(py[i] * inv_cs) + pad, 0), GH - 1)
        k = grid[r, c]
        if k >= 0:
            dx = px[i] - cx[k]
            dy = py[i] - cy[k]
            if np.float32(math.sqrt(dx * dx + dy * dy)) <= rmax:
                n_near += 1
                if sample_junction[i] < 0:
                    seg_out[i] = -1
    return n_near


@njit
def edge_skips(a_j, b_j, f_, elen, M):
    """An edge skips a crossing when it is more than 1.6 × the shortest edge of its family at either end:
    per edge, elen > 1.6·min over the edges of family f_ at junction a_j, or at b_j (float64; the
    minimum as np.minimum.at takes it, NaN propagating)."""
    shortest = np.full((M + 1, 2), np.inf)
    for ends_ in (a_j, b_j):
        for e in range(len(elen)):
            s = shortest[ends_[e], f_[e]]
            x = elen[e]
            if x < s or x != x:
                shortest[ends_[e], f_[e]] = x
    skip = np.empty(len(elen), np.bool_)
    for e in range(len(elen)):
        skip[e] = (elen[e] > 1.6 * shortest[a_j[e], f_[e]]) | (elen[e] > 1.6 * shortest[b_j[e], f_[e]])
    return skip


@njit
def chord_stats(seg, cand, qx, qy, qa, cn, S):
    """Per segment with both ends on junctions (`cand`): RMS and maximum distance (float64) of its
    samples from the chord through point qa (S, 2) with unit normal cn (S, 2)."""
    n = np.zeros(S, np.int64)
    ss = np.zeros(S)
    mx = np.zeros(S)
    for i in range(len(seg)):
        g = seg[i]
        if g < 0 or not cand[g]:
            continue
        d = abs((np.float64(qx[i]) - qa[g, 0]) * cn[g, 0] + (np.float64(qy[i]) - qa[g, 1]) * cn[g, 1])
        n[g] += 1
        ss[g] += d * d
        mx[g] = max(mx[g], d)
    rms = np.empty(S)
    for g in range(S):
        rms[g] = math.sqrt(ss[g] / max(n[g], 1))
    return rms, mx


@njit
def noise_median_u8(img, starts, blocks):
    """The median of |r| over the pixels `image_noise_grey` samples, for a uint8 (H, W) image: r is the
    response to [[1,−2,1],[−2,4,−2],[1,−2,1]] (integers, |r| ≤ 8·255, exact in float32, so the order of the
    sum does not matter), on rows s+1 and s+2 of each 4-row block starting at `starts` (blocks=True) or on
    every interior row (blocks=False), columns 1 … W−2. The median is the element of rank n//2 (as
    `np.partition(a, n // 2)[n // 2]`), found in a histogram of the values (decision 0079)."""
    H, W = img.shape
    hist = np.zeros(2041, np.int64)
    n = 0
    nb = len(starts) if blocks else 1
    for b in range(nb):
        if blocks:
            r_lo = starts[b] + 1
            r_hi = starts[b] + 3
        else:
            r_lo = 1
            r_hi = H - 1
        for y in range(r_lo, r_hi):
            a = img[y - 1]
            m = img[y]
            d = img[y + 1]
            for x in range(1, W - 1):
                r = (
                    (np.int32(a[x - 1]) + np.int32(a[x + 1]) + np.int32(d[x - 1]) + np.int32(d[x + 1]))
                    - 2 * (np.int32(a[x]) + np.int32(m[x - 1]) + np.int32(m[x + 1]) + np.int32(d[x]))
                    + 4 * np.int32(m[x])
                )
                hist[abs(r)] += 1
            n += W - 2
    k = n // 2
    acc = 0
    for val in range(2041):
        acc += hist[val]
        if acc > k:
            return val
    return 0


@njit(error_model="numpy")
def junction_verdicts(cen, dr, rms, cnt, n_neg, n_pos, m_neg, m_pos, mean_sin, sx, sy, jump_tol, sin_turn, off_tol, rms_tol):
    """The per-candidate tests of `extract_grid` on `junction_fits`' output (rows 2·k + family − 1) in one
    pass, with the NumPy version's float64 operations in the same order (decision 0079): a jump (the mean
    signed offsets on the two sides differ by more than `jump_tol`, or the mean |sin| exceeds `sin_turn`),
    too few samples (a family with < 3), not through (a family without samples on both sides), parallel
    (|d1 × d2| < 0.2), the intersection qj of the two fits off its candidate (sx, sy) by more than
    `off_tol` or not finite, crooked (an RMS above `rms_tol`, or a jump); each test counts only candidates
    that passed the ones before.

    Returns valid (ns,) bool, qj (ns, 2), jump, par, offc (ns,) bool, cross (ns,) and the counts
    (too_few, not_through, parallel, off_centre, crooked) int64 (5,)."""
    ns = len(sx)
    valid = np.empty(ns, np.bool_)
    qj = np.empty((ns, 2))
    jump = np.empty(ns, np.bool_)
    par = np.empty(ns, np.bool_)
    offc = np.empty(ns, np.bool_)
    cross = np.empty(ns)
    counts = np.zeros(5, np.int64)
    for k in range(ns):
        a = 2 * k
        b = a + 1
        jp = (abs(m_neg[a] - m_pos[a]) > jump_tol) | (abs(m_neg[b] - m_pos[b]) > jump_tol)
        jp |= (mean_sin[a] > sin_turn) | (mean_sin[b] > sin_turn)
        jump[k] = jp
        ok = True
        if (cnt[a] < 3) | (cnt[b] < 3):
            counts[0] += 1
            ok = False
        through = (n_neg[a] >= 1) & (n_pos[a] >= 1) & (n_neg[b] >= 1) & (n_pos[b] >= 1)
        if ok and not through:
            counts[1] += 1
            ok = False
        c = dr[a, 0] * dr[b, 1] - dr[a, 1] * dr[b, 0]
        cross[k] = c
        p = abs(c) < 0.2
        par[k] = p
        if ok and p:
            counts[2] += 1
            ok = False
        dx = cen[b, 0] - cen[a, 0]
        dy = cen[b, 1] - cen[a, 1]
        t = (dx * dr[b, 1] - dy * dr[b, 0]) / c
        qx = cen[a, 0] + t * dr[a, 0]
        qy = cen[a, 1] + t * dr[a, 1]
        qj[k, 0] = qx
        qj[k, 1] = qy
        o = hypot_gt(qx - sx[k], qy - sy[k], off_tol) | (not (np.isfinite(qx) & np.isfinite(qy)))
        offc[k] = o
        if ok and o:
            counts[3] += 1
            ok = False
        crooked = (rms[a] > rms_tol) | (rms[b] > rms_tol) | jp
        if ok and crooked:
            counts[4] += 1
            ok = False
        valid[k] = ok
    return valid, qj, jump, par, offc, cross, counts


@njit
def segment_lists(seg, fam, S):
    """The samples in segments (sidx, ascending), their segment ids (sg) and each segment's family (S,)
    int8 (the last sample's, as NumPy's fancy assignment `seg_family[sg] = fam[sidx]`) in one pass."""
    P = len(seg)
    sidx = np.empty(P, np.int64)
    sg = np.empty(P, np.int64)
    seg_family = np.zeros(S, np.int8)
    n = 0
    for i in range(P):
        g = seg[i]
        if g >= 0:
            sidx[n] = i
            sg[n] = g
            seg_family[g] = fam[i]
            n += 1
    return sidx[:n], sg[:n], seg_family


@njit
def chord_stats_ends(seg, segment_ends, q_junction, qx, qy, S):
    """`chord_stats` with its inputs made in the same pass (decision 0079): a segment is a candidate edge
    when both ends reach two different kept junctions; its chord runs from qa = q_junction[end 0] to
    qb = q_junction[end 1], cn = (−chord_y, chord_x) / |chord| (np.hypot; 1 where |chord| = 0), NaN for the
    others, as the NumPy code built them. Returns cand (S,) bool, rms (S,), max (S,) of the samples'
    distances from the chord."""
    cand = np.empty(S, np.bool_)
    qa = np.full((S, 2), np.nan)
    cn = np.full((S, 2), np.nan)
    for g in range(S):
        a = segment_ends[g, 0]
        b = segment_ends[g, 1]
        c = (a >= 0) & (b >= 0) & (a != b)
        cand[g] = c
        if c:
            ax = q_junction[a, 0]
            ay = q_junction[a, 1]
            chx = q_junction[b, 0] - ax
            chy = q_junction[b, 1] - ay
            clen = math.hypot(chx, chy)
            d = clen if clen > 0 else 1.0
            qa[g, 0] = ax
            qa[g, 1] = ay
            cn[g, 0] = -chy / d
            cn[g, 1] = chx / d
    rms, mx = chord_stats(seg, cand, qx, qy, qa, cn, S)
    return cand, rms, mx


@njit
def ordered_seeds(xu, xv, xs, seed):
    """The crossing candidates flagged in `seed`, weakest first (a stable sort by xs: ties keep their
    scan order, as `np.argsort(kind="stable")`): positions (k, 2) float64 (xu, xv) and scores (k,) float32.
    The sort is numba's quicksort, then each run of equal scores put back into index order (the stable
    order is the one by (score, index); decision 0079)."""
    idx = np.nonzero(seed)[0]
    sc = xs[idx]
    order = np.argsort(sc)
    k = len(idx)
    t = 0
    while t < k:
        e = t + 1
        while e < k and sc[order[e]] == sc[order[t]]:
            e += 1
        if e - t > 1:
            order[t:e] = np.sort(order[t:e])
        t = e
    out = np.empty((k, 2))
    score = np.empty(k, np.float32)
    for t in range(k):
        i = idx[order[t]]
        out[t, 0] = np.float64(xu[i])
        out[t, 1] = np.float64(xv[i])
        score[t] = xs[i]
    return out, score


@njit
def edge_candidates(cand, rms_ch, max_ch, tol, max_tol, segment_ends, seg_family, q_junction, scale):
    """The straight candidate edges (cand, RMS ≤ tol and maximum ≤ max_tol from the chord) in segment
    order, as the NumPy code listed them (decision 0079): sid, a_j, b_j (junction ids), fam_s (int8),
    mid = 0.5·(q_a + q_b)·scale (full-resolution px, for the model's Jacobian), dq = q_b − q_a, elen =
    hypot(dq) (float64), and the number of candidates that were not straight."""
    S = len(cand)
    sid = np.empty(S, np.int64)
    n = 0
    n_crooked = 0
    for g in range(S):
        if cand[g]:
            if (rms_ch[g] <= tol) & (max_ch[g] <= max_tol):
                sid[n] = g
                n += 1
            else:
                n_crooked += 1
    sid = sid[:n]
    a_j = np.empty(n, np.int64)
    b_j = np.empty(n, np.int64)
    fam_s = np.empty(n, np.int8)
    mid = np.empty((n, 2))
    dq = np.empty((n, 2))
    elen = np.empty(n)
    sc = np.float64(scale)
    for t in range(n):
        g = sid[t]
        a = segment_ends[g, 0]
        b = segment_ends[g, 1]
        a_j[t] = a
        b_j[t] = b
        fam_s[t] = seg_family[g]
        for c in range(2):
            mid[t, c] = 0.5 * (q_junction[a, c] + q_junction[b, c]) * sc
            dq[t, c] = q_junction[b, c] - q_junction[a, c]
        elen[t] = math.hypot(dq[t, 0], dq[t, 1])
    return sid, a_j, b_j, fam_s, mid, dq, elen, n_crooked


@njit
def drop_duplicates(valid, qj, score):
    """Two candidates on one crossing converge to one intersection: among the valid junctions whose
    rint(qj / 2) cells are equal, keep the one with the highest score (ties: the lower index) and clear
    `valid` (in place) for the others — the set `np.lexsort((−score, key_y, key_x))` marked as duplicates
    before (decision 0079): the groups come from one sort by the cell, the rule picks lexsort's first.
    Returns their number."""
    vid = np.nonzero(valid)[0]
    n = len(vid)
    if n <= 1:
        return 0
    kx = np.empty(n, np.int64)
    ky = np.empty(n, np.int64)
    for t in range(n):
        kx[t] = np.int64(np.rint(qj[vid[t], 0] / 2.0))
        ky[t] = np.int64(np.rint(qj[vid[t], 1] / 2.0))
    lo_y = ky.min()
    key = (kx - kx.min()) * (ky.max() - lo_y + 1) + (ky - lo_y)  # one integer per cell
    order = np.argsort(key)
    n_dup = 0
    t = 0
    while t < n:
        e = t + 1
        while e < n and key[order[e]] == key[order[t]]:
            e += 1
        if e - t > 1:
            best = order[t]
            for q in range(t + 1, e):
                c = order[q]
                sc = score[vid[c]]
                sb = score[vid[best]]
                if (sc > sb) | ((sc == sb) & (c < best)):
                    best = c
            for q in range(t, e):
                c = order[q]
                if c != best:
                    valid[vid[c]] = False
                    n_dup += 1
        t = e
    return n_dup


# --- glue round five (decision 0087) ------------------------------------------------------------------------


@njit
def _grid_cell(x, cell, n):
    """np.clip(np.rint(x / cell).astype(np.intp), 0, n − 1) for one float64 x (NaN, ±inf and values beyond
    int64 convert to INT64_MIN there, as NumPy's cast on x86-64 does: cell 0)."""
    v = np.rint(x / cell)
    if not (abs(v) < 9.2e18):
        return 0
    return min(max(int(v), 0), n - 1)


@njit
def edge_steps(sid, a_j, b_j, fam_s, mid, dq, elen, J_proj_cam, cell_px, n1, n2, M):
    """The edges' index steps and the kept edges, after `edge_candidates` (one pass each; the NumPy steps
    they replace: `RigModel.lookup(mid)`'s Jacobian, `einsum("nij,nj->ni", J, dq)` (a0·b0 + a1·b1, no fma,
    as NumPy computes it), s = sign(dq_proj₁ − n_other·dq_proj₀) as int64 (NaN → INT64_MIN, as the cast),
    delta (i changes along a j-line, j along an i-line), good = s ≠ 0 and not `edge_skips`).
    Returns edges (E, 2), edge_family (E,) int8, edge_delta (E, 2), edge_segment (E,), the number of
    edges with s ≠ 0 that skip a crossing."""
    n = sid.shape[0]
    gh = J_proj_cam.shape[0]
    gw = J_proj_cam.shape[1]
    s_other = np.empty(n, np.int64)
    f_ = np.empty(n, np.intp)
    for e in range(n):
        c = _grid_cell(mid[e, 0], cell_px, gw)
        r = _grid_cell(mid[e, 1], cell_px, gh)
        p0 = J_proj_cam[r, c, 0, 0] * dq[e, 0] + J_proj_cam[r, c, 0, 1] * dq[e, 1]
        p1 = J_proj_cam[r, c, 1, 0] * dq[e, 0] + J_proj_cam[r, c, 1, 1] * dq[e, 1]
        no = n2 if fam_s[e] == 1 else n1
        x = p1 - no * p0
        if x > 0:
            s_other[e] = 1
        elif x < 0:
            s_other[e] = -1
        elif x == 0:
            s_other[e] = 0
        else:
            s_other[e] = np.iinfo(np.int64).min
        f_[e] = np.intp(fam_s[e]) - 1
    skip = edge_skips(a_j, b_j, f_, elen, M)
    n_skip = 0
    m = 0
    for e in range(n):
        if s_other[e] != 0:
            if skip[e]:
                n_skip += 1
            else:
                m += 1
    edges = np.empty((m, 2), np.int64)
    efam = np.empty(m, fam_s.dtype)
    delta = np.empty((m, 2), np.int64)
    eseg = np.empty(m, sid.dtype)
    k = 0
    for e in range(n):
        if s_other[e] != 0 and not skip[e]:
            edges[k, 0] = a_j[e]
            edges[k, 1] = b_j[e]
            efam[k] = fam_s[e]
            delta[k, 0] = s_other[e] if fam_s[e] == 2 else 0
            delta[k, 1] = s_other[e] if fam_s[e] == 1 else 0
            eseg[k] = sid[e]
            k += 1
    return edges, efam, delta, eseg, n_skip


@njit
def keep_crossings(n_ring, seeds, seed_score):
    """The candidates with at least 2 ring samples of each family (`ring_counts`): remap (ns,) int64 (the
    kept ones numbered in order, −1 the others), their positions (K, 2) and scores (K,), the positions'
    columns as float64 and float32 copies, and the number dropped. Formerly NumPy masks and gathers."""
    ns = n_ring.shape[0]
    remap = np.full(ns, -1, np.int64)
    m = 0
    for k in range(ns):
        if n_ring[k, 0] >= 2 and n_ring[k, 1] >= 2:
            remap[k] = m
            m += 1
    out = np.empty((m, 2))
    sc = np.empty(m, seed_score.dtype)
    sx = np.empty(m)
    sy = np.empty(m)
    sx32 = np.empty(m, np.float32)
    sy32 = np.empty(m, np.float32)
    for k in range(ns):
        i = remap[k]
        if i >= 0:
            out[i, 0] = seeds[k, 0]
            out[i, 1] = seeds[k, 1]
            sc[i] = seed_score[k]
            sx[i] = seeds[k, 0]
            sy[i] = seeds[k, 1]
            sx32[i] = np.float32(seeds[k, 0])
            sy32[i] = np.float32(seeds[k, 1])
    return remap, out, sc, sx, sy, sx32, sy32, ns - m


@njit
def kept_junctions(valid, qj, dr, rms, scale, seg_seed):
    """The kept junctions in candidate order: new_id (ns + 1,) int64 (−1: dropped, and at ns), q_junction
    (M, 2), junction_dir (M, 2, 2), junction_rms (M, 2) × scale, and segment_ends = new_id[seg_seed]
    (S, 2). Formerly NumPy masks and gathers."""
    ns = valid.shape[0]
    new_id = np.full(ns + 1, -1, np.int64)
    m = 0
    for k in range(ns):
        if valid[k]:
            new_id[k] = m
            m += 1
    q = np.empty((m, 2))
    d = np.empty((m, 2, 2))
    r = np.empty((m, 2))
    sc = np.float64(scale)
    for k in range(ns):
        i = new_id[k]
        if i >= 0:
            q[i, 0] = qj[k, 0]
            q[i, 1] = qj[k, 1]
            for a in range(2):
                for b in range(2):
                    d[i, a, b] = dr[k, a, b]
            r[i, 0] = rms[k, 0] * sc
            r[i, 1] = rms[k, 1] * sc
    S = seg_seed.shape[0]
    ends = np.empty((S, 2), np.int64)
    for g in range(S):
        for a in range(2):
            ends[g, a] = new_id[seg_seed[g, a]]
    return new_id, q, d, r, ends


@njit
def samples_f64(qx32, qy32, strength):
    """q (P, 2) float64 from the float32 sample columns, and the strengths as float64."""
    P = qx32.shape[0]
    q = np.empty((P, 2))
    st = np.empty(P)
    for i in range(P):
        q[i, 0] = qx32[i]
        q[i, 1] = qy32[i]
        st[i] = strength[i]
    return q, st


@njit
def _row_span(row_start, u, r, u_lo, u_hi):
    """The samples of working row r (scan order: u rising within a row) with u_lo ≤ u ≤ u_hi: [a, b)."""
    lo = row_start[r]
    hi = row_start[r + 1]
    a = lo
    b = hi
    while a < b:
        mid = (a + b) >> 1
        if u[mid] < u_lo:
            a = mid + 1
        else:
            b = mid
    first = a
    b = hi
    while a < b:
        mid = (a + b) >> 1
        if u[mid] <= u_hi:
            a = mid + 1
        else:
            b = mid
    return first, a


@njit
def compressed_spacing(n_ring, cx, cy, r0, r_att):
    """For the candidates short of ring samples (`ring_counts`: < 2 of a family): the spacing (px) of the row
    of crossings they sit in, 0 where they sit in none (decision 0120). A crossing whose neighbours along one
    line are only a few px away (the other family's lines compressed by an oblique surface) has two
    neighbouring candidates on opposite sides (directions within ~20° of opposite) at nearly the same distance
    d (within 25 %), with 2·r0 < d ≤ min(2·r_att, 2·r0 + 4) (cores apart; the Voronoi boundary d/2 inside the
    ring and within 2 px of the core, where samples 1 px apart along the line leave fewer than 2 there), and no
    candidate closer than 2·r0 (a second candidate on the same crossing). (ns,) float64; cx, cy float64."""
    ns = len(cx)
    out = np.zeros(ns)
    order = np.argsort(cy)
    ys = cy[order]
    lo_d = 2.0 * r0
    hi_d = min(2.0 * r_att, 2.0 * r0 + 4.0)
    nbx = np.empty(ns)  # the neighbours of one candidate at a time (allocated once; decision 0155)
    nby = np.empty(ns)
    nbd = np.empty(ns)
    for k in range(ns):
        if n_ring[k, 0] >= 2 and n_ring[k, 1] >= 2:
            continue
        a = np.searchsorted(ys, cy[k] - hi_d)
        b = np.searchsorted(ys, cy[k] + hi_d, side="right")
        n = 0
        dup = False
        for t in range(a, b):
            m = order[t]
            if m == k:
                continue
            dx = cx[m] - cx[k]
            if abs(dx) > hi_d:  # then d ≥ |dx| > hi_d > lo_d: neither a duplicate nor a neighbour (0155)
                continue
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


@njit
def shared_ring_counts(n_ring, spacing, cx32, cy32, qx, qy, fam, near_dist, row_start, u, r0, r_att):
    """Ring counts for candidates in a row of compressed crossings (`compressed_spacing` > 0; decision 0120):
    (ns, 2) int64, `n_ring` elsewhere; there the samples of each family at a distance in (r0, r_att] (float32)
    of candidate (cx32, cy32) whatever candidate is nearest to them, except samples within r0 of their nearest
    candidate (`near_dist`: another crossing's core). Samples are in scan order (`row_start`: the first sample
    of each working row). Where crossings along a line are only a few px apart, the Voronoi cells of
    `ring_counts` hold at most one sample per side of that line, shared with the neighbour."""
    out = n_ring.copy()
    Hw = len(row_start) - 1
    for k in range(len(cx32)):
        if spacing[k] <= 0.0:
            continue
        c0 = 0
        c1 = 0
        ra = np.float32(r_att)
        lo_r = max(int(math.floor(cy32[k] - ra)) - 1, 0)
        hi_r = min(int(math.ceil(cy32[k] + ra)) + 1, Hw - 1)
        u_lo = int(math.floor(cx32[k] - ra)) - 1
        u_hi = int(math.ceil(cx32[k] + ra)) + 1
        for r in range(lo_r, hi_r + 1):
            a, b = _row_span(row_start, u, r, u_lo, u_hi)
            for i in range(a, b):
                if near_dist[i] <= r0:
                    continue
                dx = qx[i] - cx32[k]
                dy = qy[i] - cy32[k]
                d = np.float32(math.sqrt(dx * dx + dy * dy))
                if d > r0 and d <= ra:
                    if fam[i] == 1:
                        c0 += 1
                    else:
                        c1 += 1
        out[k, 0] = c0
        out[k, 1] = c1
    return out


@njit
def shared_arm_fits(fits, core, row_start, u, fam, qx, qy, nx, ny, sx, sy, R32):
    """Refit, in place, the arms that have fewer than 3 samples (`junction_fits`' outputs `fits`, rows
    2·k + family − 1) from every sample of that family within R32[k] (float32, per candidate) of candidate k outside the
    crossings' cores (`core`), whichever segment holds it or none: where the other family's lines are a few px
    apart, a line's pieces between two crossings hold one or two samples, too few to be segments or shared by
    both crossings (decision 0120). Samples in scan order (`row_start`). A row is replaced only where the new
    arm has more samples. Returns the number of candidates with a row replaced."""
    cen, dr, rms, cnt, n_neg, n_pos, m_neg, m_pos, mean_sin = fits
    G = len(cnt)
    ns = G // 2
    Hw = len(row_start) - 1
    want = np.zeros(G, np.bool_)
    cap = 0
    for g in range(G):
        if cnt[g] < 3:
            want[g] = True
            c = g // 2
            rr = int(math.ceil(R32[c])) + 1
            cy = int(sy[c])
            cx = int(sx[c])
            for r in range(max(cy - rr, 0), min(cy + rr, Hw - 1) + 1):
                a, b = _row_span(row_start, u, r, cx - rr, cx + rr)
                cap += b - a
    if cap == 0:
        return 0
    grp = np.empty(cap, np.int64)
    X = np.empty(cap)
    Y = np.empty(cap)
    NX = np.empty(cap)
    NY = np.empty(cap)
    na = 0
    for g in range(G):
        if not want[g]:
            continue
        c = g // 2
        f = g - 2 * c + 1
        cx32 = np.float32(sx[c])
        cy32 = np.float32(sy[c])
        cy = int(sy[c])
        cx = int(sx[c])
        rr = int(math.ceil(R32[c])) + 1
        for r in range(max(cy - rr, 0), min(cy + rr, Hw - 1) + 1):
            a, b = _row_span(row_start, u, r, cx - rr, cx + rr)
            for t in range(a, b):
                if fam[t] != f or core[t]:
                    continue
                dx = qx[t] - cx32
                dy = qy[t] - cy32
                if np.float32(math.sqrt(dx * dx + dy * dy)) <= R32[c]:
                    grp[na] = g
                    X[na] = np.float64(qx[t])
                    Y[na] = np.float64(qy[t])
                    NX[na] = np.float64(nx[t])
                    NY[na] = np.float64(ny[t])
                    na += 1
    # the samples were collected group by group (g rising), each group's in `_fits_of_groups`' order: its runs
    # (decision 0162; the same outputs, and no fit of the groups without samples but one)
    start = np.zeros(G + 1, np.int64)
    for k in range(na):
        start[grp[k] + 1] += 1
    for g in range(G):
        start[g + 1] += start[g]
    c2, d2, r2, n2, neg2, pos2, mn2, mp2, ms2 = _fits_of_runs(start, X, Y, NX, NY, G, sx, sy)
    done = np.zeros(ns, np.bool_)
    for g in range(G):
        if want[g] and n2[g] > cnt[g]:
            cen[g, 0] = c2[g, 0]
            cen[g, 1] = c2[g, 1]
            dr[g, 0] = d2[g, 0]
            dr[g, 1] = d2[g, 1]
            rms[g] = r2[g]
            cnt[g] = n2[g]
            n_neg[g] = neg2[g]
            n_pos[g] = pos2[g]
            m_neg[g] = mn2[g]
            m_pos[g] = mp2[g]
            mean_sin[g] = ms2[g]
            done[g // 2] = True
    return int(done.sum())
