"""The NumPy reference for tests/reconstruction/test_recon_lone_crossings_kernels.py (decision 0142): reconstruction/lone_crossings.py
as decision 0139 merged it (main e106847), verbatim below this docstring, before its node, far-end and piece stages were
compiled. Not imported by the package."""


from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from reconstruction.acute_crossings import epipolar_dir_cam, expected_order_sign, order_sign
from reconstruction.depth_range_labels import _k_stretches_meet, index_stretch
from reconstruction.geometry import depth_cam, epipolar_lines, triangulate_rays
from reconstruction._jit import njit
from reconstruction.rigmodel import RigModel


@dataclass(frozen=True)
class LoneCrossingOptions:
    """enabled: the step runs (`TraceOptions.lone_crossings`). min_samples: the shortest piece used. min_llr,
    min_rms_ratio: the ambiguity test of `label_epipolar` (25, 1.5). merge_share: node estimates closer than this share of the junction step are one
    node. opposite_deg: a family's two ends at a node point apart within this of 180°. t_nodes: a node where
    one family has a single end (a T whose stem is that family) is kept too. check_samples: the samples per piece
    (evenly spaced, both ends included) whose stretches and sheet depths are checked. free_end_trim: the samples
    within this many `trim_px` of a piece's end at no accepted node stay unlabelled. node_end_trim: the same at an
    end at an accepted node. far_end_check, cross_tol_px: step 6."""

    enabled: bool = True
    min_samples: int = 4
    min_llr: float = 25.0
    min_rms_ratio: float = 1.5
    merge_share: float = 0.25
    opposite_deg: float = 25.0
    t_nodes: bool = True
    check_samples: int = 8
    free_end_trim: float = 3.0
    node_end_trim: float = 1.0
    far_end_check: bool = True
    cross_tol_px: float = 1.0


@njit
def _k_end_lines(q, sid, ts, starts, stops, open_mask, trim_px):
    """Step 1's end lines: per piece and end (e = 2·piece + side) the end line's point, outward direction, fit RMS,
    end sample and whether it is usable (an open piece with at least 2 samples in the fit)."""
    n_p = starts.shape[0]
    pts = np.zeros((2 * n_p, 2))
    dirs = np.zeros((2 * n_p, 2))
    rms = np.zeros(2 * n_p)
    ends = np.zeros((2 * n_p, 2))
    ok = np.zeros(2 * n_p, np.bool_)
    for p in range(n_p):
        a = starts[p]
        b = stops[p]
        ends[2 * p, 0] = q[sid[a], 0]
        ends[2 * p, 1] = q[sid[a], 1]
        ends[2 * p + 1, 0] = q[sid[b - 1], 0]
        ends[2 * p + 1, 1] = q[sid[b - 1], 1]
        if not open_mask[p]:
            continue
        for e in range(2):
            # pass 1: counts and sums of the core (trim … 3·trim from the end) and of everything within 3·trim
            nc = 0
            na = 0
            for k in range(b - a):
                pos = a + k if e == 0 else b - 1 - k
                d = ts[pos] - ts[a] if e == 0 else ts[b - 1] - ts[pos]
                if d > 3.0 * trim_px:
                    break
                na += 1
                if d >= trim_px:
                    nc += 1
            use_core = nc >= 3
            nn = nc if use_core else na
            if nn < 2:
                continue
            sx = 0.0
            sy = 0.0
            for k in range(na):
                pos = a + k if e == 0 else b - 1 - k
                d = ts[pos] - ts[a] if e == 0 else ts[b - 1] - ts[pos]
                if use_core and d < trim_px:
                    continue
                sx += q[sid[pos], 0]
                sy += q[sid[pos], 1]
            mx = sx / nn
            my = sy / nn
            cxx = 0.0
            cyy = 0.0
            cxy = 0.0
            for k in range(na):
                pos = a + k if e == 0 else b - 1 - k
                d = ts[pos] - ts[a] if e == 0 else ts[b - 1] - ts[pos]
                if use_core and d < trim_px:
                    continue
                dx = q[sid[pos], 0] - mx
                dy = q[sid[pos], 1] - my
                cxx += dx * dx
                cyy += dy * dy
                cxy += dx * dy
            cxx /= nn
            cyy /= nn
            cxy /= nn
            ang = 0.5 * np.arctan2(2.0 * cxy, cxx - cyy)
            ux = np.cos(ang)
            uy = np.sin(ang)
            lam = 0.5 * (cxx + cyy) - np.sqrt(0.25 * (cxx - cyy) ** 2 + cxy * cxy)
            i = 2 * p + e
            o = 2 * p + 1 - e
            if (ends[i, 0] - ends[o, 0]) * ux + (ends[i, 1] - ends[o, 1]) * uy < 0:
                ux = -ux
                uy = -uy
            pts[i, 0] = mx
            pts[i, 1] = my
            dirs[i, 0] = ux
            dirs[i, 1] = uy
            rms[i] = np.sqrt(max(lam, 0.0))
            ok[i] = True
    return pts, dirs, rms, ends, ok


@njit
def _k_crossings(e1, e2, pts, dirs, ends, reach_px, lateral_px, sin_min):
    """Every pair of a family-1 end (e1) and a family-2 end (e2) whose end samples lie within 2·reach_px and whose end
    lines cross ahead of both ends (within reach_px; from −lateral_px), at an angle of at least asin(sin_min):
    (A, B, X)."""
    n1 = e1.shape[0]
    n2 = e2.shape[0]
    cap = 64
    A = np.empty(cap, np.int64)
    B = np.empty(cap, np.int64)
    X = np.empty((cap, 2))
    m = 0
    r2 = (2.0 * reach_px) ** 2
    for u in range(n1):
        a = e1[u]
        for v in range(n2):
            b = e2[v]
            dx = ends[a, 0] - ends[b, 0]
            dy = ends[a, 1] - ends[b, 1]
            if dx * dx + dy * dy > r2:
                continue
            den = dirs[a, 0] * dirs[b, 1] - dirs[a, 1] * dirs[b, 0]
            if abs(den) <= sin_min:
                continue
            wx = pts[b, 0] - pts[a, 0]
            wy = pts[b, 1] - pts[a, 1]
            s = (wx * dirs[b, 1] - wy * dirs[b, 0]) / den
            x = pts[a, 0] + s * dirs[a, 0]
            y = pts[a, 1] + s * dirs[a, 1]
            ha = (x - ends[a, 0]) * dirs[a, 0] + (y - ends[a, 1]) * dirs[a, 1]
            hb = (x - ends[b, 0]) * dirs[b, 0] + (y - ends[b, 1]) * dirs[b, 1]
            if ha < -lateral_px or ha > reach_px or hb < -lateral_px or hb > reach_px:
                continue
            if m == cap:
                cap *= 2
                A2 = np.empty(cap, np.int64)
                B2 = np.empty(cap, np.int64)
                X2 = np.empty((cap, 2))
                A2[:m] = A[:m]
                B2[:m] = B[:m]
                X2[:m] = X[:m]
                A, B, X = A2, B2, X2
            A[m] = a
            B[m] = b
            X[m, 0] = x
            X[m, 1] = y
            m += 1
    return A[:m], B[:m], X[:m]


@njit
def _k_group_stretches(xy, g_start, g_stop, R, t, z0, z1, Kp, dist, has_dist, cu, cv, nn, offs, index_min):
    """Per group g (positions g_start[g] … g_stop[g] − 1 of xy; family 1 for even g, 2 for odd): the intersection
    (lo, hi) of its samples' stretches through the working volume (decision 0128's `_k_stretches_meet`, unwidened);
    lo = +inf when a ray misses the projector."""
    G = g_start.shape[0]
    lo = np.empty(G)
    hi = np.empty(G)
    for g in range(G):
        lo[g], hi[g] = _k_stretches_meet(xy, g_start[g], g_stop[g], g % 2 + 1, R, t, z0, z1, Kp, dist, has_dist, cu, cv, nn, offs,
                                         index_min, 0.0)
    return lo, hi


@njit
def _k_free_end_crossings(free, e_fam, usable, e_piece, pts, dirs, ends, reach_px, lateral_px, merge_px, cos_opp, sin_min):
    """Step 6's crossings: for each free end e (free (m,)), the nearest point X where its end line crosses the end
    line of a usable end of the other family, ahead of both within reach_px (from −lateral_px), at an angle of at
    least asin(sin_min); kept (ok) when the piece's own line goes on beyond X (a usable end of its family on another
    piece, facing back, ahead of X within reach_px, its end line within lateral_px of X) or the other family's line
    runs through X (two of its ends crossing e's end line within merge_px of X, pointing apart within the
    opposite cone). Returns X (m, 2) and ok (m,)."""
    m = free.shape[0]
    n = e_fam.shape[0]
    X = np.full((m, 2), np.nan)
    ok = np.zeros(m, np.bool_)
    xs = np.empty((n, 2))
    ids = np.empty(n, np.int64)
    for u in range(m):
        a = free[u]
        fa = e_fam[a]
        cnt = 0
        best = -1
        bd = np.inf
        for b in range(n):
            if not usable[b] or e_fam[b] == fa:
                continue
            dx = ends[a, 0] - ends[b, 0]
            dy = ends[a, 1] - ends[b, 1]
            if dx * dx + dy * dy > 4.0 * reach_px * reach_px:
                continue
            den = dirs[a, 0] * dirs[b, 1] - dirs[a, 1] * dirs[b, 0]
            if abs(den) <= sin_min:
                continue
            wx = pts[b, 0] - pts[a, 0]
            wy = pts[b, 1] - pts[a, 1]
            t = (wx * dirs[b, 1] - wy * dirs[b, 0]) / den
            x = pts[a, 0] + t * dirs[a, 0]
            y = pts[a, 1] + t * dirs[a, 1]
            ha = (x - ends[a, 0]) * dirs[a, 0] + (y - ends[a, 1]) * dirs[a, 1]
            hb = (x - ends[b, 0]) * dirs[b, 0] + (y - ends[b, 1]) * dirs[b, 1]
            if ha < -lateral_px or ha > reach_px or hb < -lateral_px or hb > reach_px:
                continue
            xs[cnt, 0] = x
            xs[cnt, 1] = y
            ids[cnt] = b
            d = (x - ends[a, 0]) ** 2 + (y - ends[a, 1]) ** 2
            if d < bd:
                bd = d
                best = cnt
            cnt += 1
        if best < 0:
            continue
        x = xs[best, 0]
        y = xs[best, 1]
        X[u, 0] = x
        X[u, 1] = y
        through = False
        for i in range(cnt):
            if (xs[i, 0] - x) ** 2 + (xs[i, 1] - y) ** 2 > merge_px * merge_px:
                continue
            for j in range(i + 1, cnt):
                if (xs[j, 0] - x) ** 2 + (xs[j, 1] - y) ** 2 > merge_px * merge_px:
                    continue
                bi = ids[i]
                bj = ids[j]
                if dirs[bi, 0] * dirs[bj, 0] + dirs[bi, 1] * dirs[bj, 1] < -cos_opp:
                    through = True
        goes_on = False
        for g in range(n):
            if not usable[g] or e_fam[g] != fa or e_piece[g] == e_piece[a]:
                continue
            if dirs[g, 0] * dirs[a, 0] + dirs[g, 1] * dirs[a, 1] >= -cos_opp:
                continue
            ahead = (x - ends[g, 0]) * dirs[g, 0] + (y - ends[g, 1]) * dirs[g, 1]
            if ahead < -lateral_px or ahead > reach_px:
                continue
            lat = abs((x - pts[g, 0]) * dirs[g, 1] - (y - pts[g, 1]) * dirs[g, 0])
            if lat <= lateral_px:
                goes_on = True
                break
        ok[u] = through or goes_on
    return X, ok


def _unique(a: np.ndarray) -> np.ndarray:
    """np.unique of an integer array by a sort (NumPy 2's hash-based unique is slow on these small arrays)."""
    a = np.sort(a, kind="stable")
    return a[np.r_[True, a[1:] != a[:-1]]] if len(a) else a


def _components(n: int, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Connected components (ids numbered by their lowest member) of n nodes joined by the pairs (a, b)."""
    parent = np.arange(n)
    for i, j in zip(a.tolist(), b.tolist()):
        while parent[i] != i:
            i = parent[i]
        while parent[j] != j:
            j = parent[j]
        if i != j:
            parent[max(i, j)] = min(i, j)
    for i in range(n):
        parent[i] = parent[parent[i]]
    return parent


def label_lone_crossings(q, fam, sid, piece, ts, index, *, model: RigModel, depth_range_mm, trim_px: float, reach_px: float,
                         lateral_px: float, tol_px: float, noise_floor_px: float,
                         options: LoneCrossingOptions = LoneCrossingOptions(), seed: np.ndarray | None = None,
                         debug: dict | None = None) -> dict:
    """Label the pieces at crossings of unlabelled pieces (module doc). q (P, 2), fam (P,), index (P,) (NaN: none;
    written in place); the traces as `labelling.label_samples` builds them: sid (n,), piece (n,) non-decreasing, ts
    (n,) position along the piece (px). seed (P,) int (`labelling.label_samples`' junction seeds, UNLABELLED where
    none; None: not written): the labelled samples within 2·trim_px past the trim of an end at an accepted node
    become seeds with the piece's index. Returns counts."""
    stats = {"nodes": 0, "nodes_labelled": 0, "samples": 0}
    n = len(piece)
    if n == 0:
        return stats
    q = np.asarray(q, np.float64)
    fam = np.asarray(fam)
    piece = np.asarray(piece, np.intp)
    sid = np.asarray(sid, np.intp)
    ts = np.asarray(ts, np.float64)
    starts = np.flatnonzero(np.r_[True, piece[1:] != piece[:-1]])
    stops = np.r_[starts[1:], n]
    n_p = len(starts)
    lab = np.isfinite(index[sid])
    n_lab = np.bincount(piece, lab, n_p)
    open_mask = (n_lab == 0) & (stops - starts >= options.min_samples)
    if open_mask.sum() < 3:
        return stats
    starts64, stops64 = starts.astype(np.int64), stops.astype(np.int64)
    e_pt, e_dir, e_rms, e_end, ok = _k_end_lines(q, sid, ts, starts64, stops64, open_mask, float(trim_px))
    e_all = np.flatnonzero(ok)
    e_piece = np.arange(2 * n_p) // 2
    e_fam = np.asarray(fam[sid[starts]])[e_piece]
    if debug is not None:
        debug.update(e_end=e_end[e_all], e_fam=e_fam[e_all], e_dir=e_dir[e_all], e_piece=e_piece[e_all], e_pt=e_pt[e_all])
    # 1. pairs of ends of the two families near each other, and where their end lines cross
    A, B, X = _k_crossings(e_all[e_fam[e_all] == 1], e_all[e_fam[e_all] == 2], e_pt, e_dir, e_end, float(reach_px), float(lateral_px),
                           float(np.sin(np.deg2rad(10.0))))
    if len(A) == 0:
        return stats
    # nodes: single linkage of the estimates within merge_px
    m = len(X)
    merge_px = options.merge_share * model.junction_step_cam_px
    cp = cKDTree(X).query_pairs(merge_px, output_type="ndarray")
    comp = _components(m, cp[:, 0], cp[:, 1]) if len(cp) else np.arange(m)
    is_root = np.zeros(m, bool)
    is_root[comp] = True
    N = int(is_root.sum())
    node_of = (np.cumsum(is_root) - 1)[comp]
    cnt = np.bincount(node_of, minlength=N).astype(np.float64)
    xn = np.stack([np.bincount(node_of, X[:, 0], N), np.bincount(node_of, X[:, 1], N)], axis=1) / cnt[:, None]
    # the node's ends (each end once per node)
    ent = _unique(np.concatenate([node_of * (2 * n_p) + A, node_of * (2 * n_p) + B]))
    en_node, en_end = ent // (2 * n_p), ent % (2 * n_p)
    en_fam = e_fam[en_end]
    bad = np.zeros(N, bool)
    # an end at two nodes: neither
    per_end = np.bincount(en_end, minlength=2 * n_p)
    bad[en_node[per_end[en_end] > 1]] = True
    # every end line passes within lateral_px of the node
    r = xn[en_node] - e_pt[en_end]
    lat = np.abs(r[:, 0] * e_dir[en_end, 1] - r[:, 1] * e_dir[en_end, 0])
    bad[en_node[lat > lateral_px]] = True
    # per family: one or two ends; two: of two pieces, on opposite sides
    cos_opp = np.cos(np.deg2rad(options.opposite_deg))
    n_two = np.zeros(N, np.intp)
    first = {}
    for f in (1, 2):
        sel = en_fam == f
        c = np.bincount(en_node[sel], minlength=N)
        bad |= (c == 0) | (c > 2)
        if not options.t_nodes:
            bad |= c == 1
        n_two += c == 2
        nd, ee = en_node[sel], en_end[sel]  # sorted by node (ent is sorted)
        st = np.searchsorted(nd, np.arange(N))
        has2 = c == 2
        e0 = np.where(has2, ee[np.minimum(st, len(ee) - 1)], -1)
        e1 = np.where(has2, ee[np.minimum(st + 1, len(ee) - 1)], -1)
        two = np.flatnonzero(has2)
        bad[two[(e_piece[e0[two]] == e_piece[e1[two]]) | ((e_dir[e0[two]] * e_dir[e1[two]]).sum(1) > -cos_opp)]] = True
        one = c == 1
        e0 = np.where(one, ee[np.minimum(st, len(ee) - 1)], e0)
        first[f] = (e0, e1)
    bad |= n_two < 1
    nodes = np.flatnonzero(~bad)
    stats["nodes"] = int(len(nodes))
    if debug is not None:
        debug["nodes"] = []
    if len(nodes) == 0:
        return stats
    # 2. the epipolar order: i-line and j-line directions through the node
    dfam = {}
    for f in (1, 2):
        e0, e1 = first[f][0][nodes], first[f][1][nodes]
        dfam[f] = e_dir[e0] - np.where((e1 >= 0)[:, None], e_dir[np.maximum(e1, 0)], 0.0)
    exp = expected_order_sign(model, xn[nodes])
    e_ep = epipolar_dir_cam(model, xn[nodes])
    got = order_sign(e_ep, dfam[1], dfam[2])
    if debug is not None:
        debug["sin"] = {tuple(np.round(xn[n_], 0)): [float(abs(np.cross(e_ep[k] / np.linalg.norm(e_ep[k]), dfam[f][k] / np.linalg.norm(dfam[f][k]))))
                                                     for f in (1, 2)] for k, n_ in enumerate(nodes)}
    nodes = nodes[(exp != 0) & (got == exp)]
    if len(nodes) == 0:
        return stats
    # 3. the lines the working volume leaves for each node's pieces
    z0, z1 = float(depth_range_mm[0]), float(depth_range_mm[1])
    tol = tol_px / np.asarray(model.line_spacing_perp_px, np.float64)
    K = len(nodes)
    # per group g = 2·node + (f − 1): its one or two pieces
    g_e0 = np.empty(2 * K, np.intp)
    g_e1 = np.empty(2 * K, np.intp)
    for f in (1, 2):
        g_e0[f - 1 :: 2] = first[f][0][nodes]
        g_e1[f - 1 :: 2] = first[f][1][nodes]
    has1 = g_e1 >= 0
    gp = np.concatenate([np.arange(2 * K), np.flatnonzero(has1)])
    pc = np.concatenate([e_piece[g_e0], e_piece[g_e1[has1]]])
    # all samples of the nodes' pieces, one stretch computation
    og = np.argsort(gp, kind="stable")
    gp, pc = gp[og], pc[og]
    # at most `check_samples` samples a piece, evenly spaced from end to end (the stretches' intersection and the
    # volume test over fewer samples admit a superset of the lines: never fewer candidates, never the truth out)
    full = stops[pc] - starts[pc]
    sz = np.minimum(full, options.check_samples)
    rk = np.arange(sz.sum()) - np.repeat(np.cumsum(sz) - sz, sz)
    step = np.repeat((full - 1) / np.maximum(sz - 1, 1), sz)
    pos = np.repeat(starts[pc], sz) + np.rint(rk * step).astype(np.intp)
    grp = np.repeat(gp, sz)
    s_all = sid[pos]
    f_all = (grp % 2 + 1).astype(np.intp)
    G = 2 * K
    tol_g = np.tile(tol, K)
    proj = model.procam.projector
    if proj.dist.size <= 5:
        # decision 0128's compiled stretches, intersected per group
        g_start = np.searchsorted(grp, np.arange(G))
        g_stop = np.searchsorted(grp, np.arange(G), side="right")
        pat = model.pattern
        dist = np.zeros(5)
        dist[: min(5, proj.dist.size)] = np.asarray(proj.dist, np.float64).ravel()[:5]
        lo_g, hi_g = _k_group_stretches(
            np.ascontiguousarray(model.cam_normalised(q[s_all]), np.float64), g_start.astype(np.int64), g_stop.astype(np.int64),
            np.ascontiguousarray(model.procam.R_proj_cam, np.float64), np.ascontiguousarray(model.procam.t_proj_cam, np.float64), z0, z1,
            np.ascontiguousarray(proj.K, np.float64), dist, bool(proj.has_distortion), float(pat.centre_px[0]), float(pat.centre_px[1]),
            np.array([pat.n1, pat.n2], np.float64), np.ascontiguousarray(model.line_offsets_px, np.float64), int(model.index_min))
        miss = ~np.isfinite(lo_g) & (lo_g > 0)
    else:
        lo, hi = index_stretch(model, q[s_all], f_all, (z0, z1))
        miss = np.bincount(grp, ~(np.isfinite(lo) & np.isfinite(hi)), G) > 0
        lo_g = np.full(G, -np.inf)
        hi_g = np.full(G, np.inf)
        np.maximum.at(lo_g, grp, np.nan_to_num(lo, nan=np.inf))
        np.minimum.at(hi_g, grp, np.nan_to_num(hi, nan=-np.inf))
    k_lo = np.maximum(np.ceil(lo_g - tol_g), model.index_min).astype(np.intp)
    k_hi = np.minimum(np.floor(hi_g + tol_g), model.index_max).astype(np.intp)
    # candidates (i, j) per node: the products of the two ranges
    n_g = np.where(miss, 0, np.maximum(k_hi - k_lo + 1, 0))
    ni, nj = n_g[0::2], n_g[1::2]
    tot = ni * nj
    if tot.sum() == 0:
        return stats
    cn = np.repeat(np.arange(K), tot)
    rr = np.arange(tot.sum()) - np.repeat(np.cumsum(tot) - tot, tot)
    ci = k_lo[0::2][cn] + rr // nj[cn]
    cj = k_lo[1::2][cn] + rr % nj[cn]
    procam = model.procam
    xy_n = model.cam_normalised(xn[nodes])
    xy_p = model.junction_xy(ci, cj)
    p3, _gap = triangulate_rays(procam, xy_n[cn], xy_p)
    zc = depth_cam(procam, p3)
    adm = (zc >= z0) & (zc <= z1)
    ln = epipolar_lines(procam, xy_n)[cn]
    res = np.abs(ln[:, 0] * xy_p[:, 0] + ln[:, 1] * xy_p[:, 1] + ln[:, 2]) * model.fx_proj
    # every sample of the node's pieces of family f, on sheet k, inside the volume (decision 0128's step 4): checked
    # for each node's candidates in the order of their residual, the 4 best first, the rest only where those 4 do not
    # hold two admissible ones (only the best two admissible candidates decide)
    g_start = np.searchsorted(grp, np.arange(G))
    g_size = np.searchsorted(grp, np.arange(G), side="right") - g_start
    span = model.index_max - model.index_min + 1
    state = np.zeros(G * span, np.int8)  # per (group, line): 0 not checked, 1 inside the volume, 2 not

    def check(keys):
        keys = _unique(keys)
        keys = keys[state[keys] == 0]
        if len(keys) == 0:
            return
        g, kk = keys // span, keys % span + model.index_min
        sz_ = g_size[g]
        rows_c = np.repeat(np.arange(len(keys)), sz_)
        rows_s = g_start[g][rows_c] + (np.arange(len(rows_c)) - np.repeat(np.cumsum(sz_) - sz_, sz_))
        zs = model.sheet_depth(q[s_all[rows_s]], f_all[rows_s], kk[rows_c])
        bad_c = np.bincount(rows_c, ~((zs >= z0) & (zs <= z1)), len(keys)) > 0
        state[keys] = np.where(bad_c, 2, 1)

    key_i = (cn * 2 + 0) * span + (ci - model.index_min)
    key_j = (cn * 2 + 1) * span + (cj - model.index_min)
    o = np.lexsort((res, cn))
    o = o[adm[o]]
    rank = np.arange(len(o)) - np.searchsorted(cn[o], cn[o])
    top = o[rank < 4]
    check(np.concatenate([key_i[top], key_j[top]]))
    n_ok = np.bincount(cn[top], (state[key_i[top]] == 1) & (state[key_j[top]] == 1), K)
    rest = o[(rank >= 4) & (n_ok[cn[o]] < 2)]
    check(np.concatenate([key_i[rest], key_j[rest]]))
    adm = np.zeros(len(cn), bool)
    cand = np.concatenate([top, rest])
    adm[cand[(state[key_i[cand]] == 1) & (state[key_j[cand]] == 1)]] = True
    # 4. the choice per node, as for a lone found junction
    o = np.lexsort((res, cn))
    o = o[adm[o]]
    if len(o) == 0:
        return stats
    st1 = np.searchsorted(cn[o], np.arange(K))
    cnt_k = np.bincount(cn[o], minlength=K)
    have = cnt_k > 0
    b1 = o[np.minimum(st1, len(o) - 1)]
    b2 = o[np.minimum(st1 + 1, len(o) - 1)]
    s1 = res[b1] ** 2
    s2 = np.where(cnt_k > 1, res[b2] ** 2, np.inf)
    # ρ: the larger end-line RMS at the node (camera px)
    rho = np.zeros(K)
    for x in (g_e0, g_e1):
        ex = np.maximum(x, 0)
        v = np.where(x >= 0, e_rms[ex], 0.0)
        rho = np.maximum(rho, np.maximum(v[0::2], v[1::2]))
    sig2 = np.maximum(np.maximum(s1, noise_floor_px**2), rho**2)
    with np.errstate(invalid="ignore"):
        accept = have & ((s2 - s1) / sig2 >= options.min_llr) & (s2 >= options.min_rms_ratio**2 * sig2)
    if debug is not None:
        for k in np.flatnonzero(have):
            debug["nodes"].append(dict(xy=xn[nodes[k]], why="ok" if accept[k] else "ambiguous", ij=(int(ci[b1[k]]), int(cj[b1[k]])),
                                       r=np.sqrt([s1[k], s2[k]]), rho=rho[k], n_cand=int(cnt_k[k])))
    stats["nodes_labelled"] = int(accept.sum())
    proposals: dict = {}
    at_node: set = set()  # the ends (2·piece + side) at an accepted node
    for k in np.flatnonzero(accept).tolist():
        for f, kk in ((1, int(ci[b1[k]])), (2, int(cj[b1[k]]))):
            g = 2 * k + f - 1
            for e in (g_e0[g], g_e1[g]):
                if e >= 0:
                    proposals.setdefault(int(e_piece[e]), set()).add(kk)
                    at_node.add(int(e))
    # the far ends: a piece's end at no accepted node that meets a line of the other family (any piece's end line,
    # labelled or not, crossing its end line ahead of both within reach_px) must meet it, on the piece's sheet,
    # within cross_tol_px of a line of the other family inside the volume; a piece that runs across a depth edge onto
    # a collinear line of another surface meets the other family's lines there anywhere (decisions 0066, 0084)
    if proposals and options.far_end_check:
        # the end lines of every piece long enough (labelled ones too): the lines a free end may cross
        long_mask = stops - starts >= options.min_samples
        e_pt, e_dir, e_rms, e_end, ok_any = _k_end_lines(q, sid, ts, starts64, stops64, long_mask, float(trim_px))
        fr_e, fr_p = [], []
        for p_ in sorted(proposals):
            if len(proposals[p_]) != 1:
                continue
            for e in (2 * p_, 2 * p_ + 1):
                if e not in at_node and ok_any[e]:
                    fr_e.append(e)
                    fr_p.append(p_)
        if fr_e:
            fr_e = np.array(fr_e, np.int64)
            Xf, okf = _k_free_end_crossings(fr_e, e_fam.astype(np.int64), ok_any, e_piece.astype(np.int64), e_pt, e_dir, e_end, float(reach_px),
                                            float(lateral_px), float(merge_px), float(cos_opp), float(np.sin(np.deg2rad(10.0))))
            if okf.any():
                sel = np.flatnonzero(okf)
                ff = e_fam[fr_e[sel]]
                kf = np.array([next(iter(proposals[fr_p[i]])) for i in sel.tolist()])
                _, zf, _, dist_f = model.sheet_check(Xf[sel], ff, kf)
                bad_far = ~((dist_f <= options.cross_tol_px) & (zf >= z0) & (zf <= z1))
                if debug is not None:
                    debug["far"] = [(Xf[i], int(ff[t]), int(kf[t]), float(dist_f[t]), float(zf[t]), bool(bad_far[t])) for t, i in enumerate(sel.tolist())]
                for t in np.flatnonzero(bad_far).tolist():
                    proposals[fr_p[sel[t]]] = set()
                    stats["pieces_far_end"] = stats.get("pieces_far_end", 0) + 1
    # 5. the pieces whose accepted nodes agree, without their samples within trim_px of either end
    for p_ in sorted(proposals):
        ks = proposals[p_]
        if len(ks) != 1:
            if len(ks) > 1:
                stats["pieces_conflicting"] = stats.get("pieces_conflicting", 0) + 1
            continue
        a_, b_ = starts[p_], stops[p_]
        t = ts[a_:b_]
        # an end at no accepted node is free (a silhouette, a shadow, another crossing): the cut line's ridge is
        # pulled over the smoothing kernel's reach there, `free_end_trim` smoothing scales
        t0 = options.node_end_trim * trim_px if 2 * p_ in at_node else options.free_end_trim * trim_px
        t1 = options.node_end_trim * trim_px if 2 * p_ + 1 in at_node else options.free_end_trim * trim_px
        inner = (t - t[0] >= t0) & (t[-1] - t >= t1)
        kk = next(iter(ks))
        if seed is not None:
            # the labelled samples next to the node are the piece's seeds, as a found junction's would be: the
            # stretch beyond them is then checked at its far end like any seeded piece's (decision 0084: a piece
            # that runs across a depth edge onto a collinear line of another surface)
            near = np.zeros(len(t), bool)
            if 2 * p_ in at_node:
                near |= (t - t[0] >= t0) & (t - t[0] <= t0 + 2.0 * trim_px)
            if 2 * p_ + 1 in at_node:
                near |= (t[-1] - t >= t1) & (t[-1] - t <= t1 + 2.0 * trim_px)
            sn = sid[a_:b_][near & inner]
            sn = sn[~np.isfinite(index[sn])]
            seed[sn] = kk
        ss = sid[a_:b_][inner]
        ss = ss[~np.isfinite(index[ss])]
        index[ss] = kk
        stats["samples"] += len(ss)
    return stats
