"""Label the pieces of two lines that cross where nothing else is labelled (decision 0139).

On a face that nothing else labels (an object lit by only a few lines: the paper presets' pyramid and arrow,
whose faces are dim and lit obliquely, their lines wide), the lines cross once or twice and extraction keeps no
junction there (a wide, dim crossing: too few ring samples, decisions 0068, 0129), and decision 0092's piece
junctions need a component of three nodes. The pieces stay unlabelled although the crossing, with the working
volume, names both lines.

For every crossing of unlabelled pieces:

1. **Crossing.** Each end of an unlabelled piece of at least `min_samples` samples has an end line: the total
   least-squares line of its samples between `trim_px` and 3·`trim_px` from the end (the crossing's light pulls
   the first ones, decision 0059; all within 3·`trim_px` on a piece too short for that). An end of family 1 and an
   end of family 2 meet where their end lines cross, ahead of both ends, within `reach_px` (half a crossing's gap);
   the estimates closer than `merge_px` are one node, at their mean. A node is kept when every end line passes
   within `lateral_px` of it, each family has one or two ends there, a family with two has them on two pieces on
   opposite sides, at least one family runs through (an X; with `t_nodes` also a T whose stem is the other family:
   the pyramid's crossing on paper-intermediate has an arm extraction lost), and no end belongs to two nodes.
2. **Families.** The cyclic order of (epipolar direction, i-line, j-line) at the node is the rig's
   (`acute_crossings.expected_order_sign`, decision 0083: every lit, visible surface shows it): a piece given
   the wrong family (where both families turn towards the epipolar direction) swaps it.
3. **Candidates.** The working volume names, per family, the lines the node's pieces can lie on: the integers in
   the intersection of their samples' stretches (decision 0128's, widened by `tol_px`). A candidate junction
   (i, j) of those must lie in the pattern, triangulate (camera ray and projector ray) inside the volume, and put
   the pieces' samples, on its sheet, inside the volume (both over `check_samples` samples a piece, evenly spaced:
   fewer samples admit a superset). The true junction always passes.
4. **Choice.** Among the candidates, the epipolar residual r of the node (projector px) decides as for a lone
   found junction (decision 0134): s = r², σ² = max(s1, σ0², ρ²) (σ0 the epipolar floor, ρ the larger RMS of
   the node's end-line fits, camera px: arms that are not straight bound how well the node is placed), accepted
   when (s2 − s1)/σ² ≥ `min_llr` and s2 ≥ `min_rms_ratio`²·σ² (a lone candidate: s2 = ∞).
5. **Pieces.** The node's pieces take i (family 1) and j (family 2) where every accepted node at a piece agrees;
   their samples within `trim_px` of an end at an accepted node stay unlabelled, as in decision 0128 (gap filling
   reaches them where both sides are labelled), and within `free_end_trim`·`trim_px` of a free end (a silhouette,
   a shadow: the cut line's ridge is pulled there; with 1σ, one point 1.3 % off on unseen seed 109). The samples
   next to a node become seeds, so that decision 0084's far-end check examines the rest of the piece as for a
   found junction's.
6. **Free ends.** A piece that runs across a depth edge onto a collinear line of another surface takes a line it
   is not on (unseen seed 125: 7 points 26 % off). At an end at no accepted node, the crossing with another piece's
   end line of the other family (ahead of both within `reach_px`) counts when it is a crossing of two lines — the
   piece's own line goes on beyond it (an end of its family facing back, its end line through it) or the other
   family's line runs through it (ends on both sides) — and it must then land, triangulated on the piece's sheet k,
   within `cross_tol_px` projector px of a line of the other family inside the volume (decision 0066's check);
   otherwise the piece stays unlabelled (`far_end_check`).

Why this is not one-sided evidence (decisions 0049, 0089): nothing is carried from a labelled neighbour; the
crossing is labelled from its own epipolar line, like a found lone junction, and its pieces are those a found
junction there would seed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from reconstruction.acute_crossings import epipolar_dir_cam, expected_order_sign, order_sign
from reconstruction.depth_range_labels import _k_stretches_meet, index_stretch
from reconstruction.geometry import depth_cam, epipolar_lines, triangulate_rays
from reconstruction._jit import njit
from reconstruction._label_kernels import _union_find_join
from reconstruction.trace_ends import mean_shift_split
from reconstruction.rigmodel import RigModel, _k_cam_bilinear, _k_sheet_depth


@dataclass(frozen=True)
class LoneCrossingOptions:
    """enabled: the step runs (`TraceOptions.lone_crossings`). min_samples: the shortest piece used. min_llr,
    min_rms_ratio: the ambiguity test of `label_epipolar` (25, 1.5). merge_share: node estimates closer than this share of the junction step are one
    node. opposite_deg: a family's two ends at a node point apart within this of 180°. t_nodes: a node where
    one family has a single end (a T whose stem is that family) is kept too. check_samples: the samples per piece
    (evenly spaced, both ends included) whose stretches and sheet depths are checked. free_end_trim: the samples
    within this many `trim_px` of a piece's end at no accepted node stay unlabelled. node_end_trim: the same at an
    end at an accepted node. far_end_check, cross_tol_px: step 6. far_end_split, far_split_step: a piece whose far end
    fails step 6 keeps its label out to a ridge-brightness step of this share, or whole at a T (step 6b, `_far_split`;
    needs the ridge; the share is `TraceOptions.max_ridge_step`, the trace cut's)."""

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
    far_end_split: bool = True
    far_split_step: float = 0.15


@njit
def _fit_end(q, sid, ts, a, b, p, e, trim_px, ends, pts, dirs, rms, ok):
    """`_k_end_lines` for end e (0: start, 1: stop) of the piece p at positions a … b − 1 (its end samples
    already in `ends`): the end line's point, outward direction and fit RMS, ok[2·p + e] when at least 2 samples fit."""
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
        return
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
            _fit_end(q, sid, ts, a, b, p, e, trim_px, ends, pts, dirs, rms, ok)
    return pts, dirs, rms, ends, ok


@njit
def _meet_ahead(pts, dirs, ends, a, b, sin_min, lateral_px, reach_px):
    """Where end lines a and b (point pts, unit direction dirs, end sample ends) cross: (True, x, y) when they meet at
    an angle of more than asin(sin_min) and the crossing lies ahead of both ends, from −lateral_px to reach_px along
    each end's direction; (False, 0, 0) otherwise."""
    den = dirs[a, 0] * dirs[b, 1] - dirs[a, 1] * dirs[b, 0]
    if abs(den) <= sin_min:
        return False, 0.0, 0.0
    wx = pts[b, 0] - pts[a, 0]
    wy = pts[b, 1] - pts[a, 1]
    s = (wx * dirs[b, 1] - wy * dirs[b, 0]) / den
    x = pts[a, 0] + s * dirs[a, 0]
    y = pts[a, 1] + s * dirs[a, 1]
    ha = (x - ends[a, 0]) * dirs[a, 0] + (y - ends[a, 1]) * dirs[a, 1]
    hb = (x - ends[b, 0]) * dirs[b, 0] + (y - ends[b, 1]) * dirs[b, 1]
    if ha < -lateral_px or ha > reach_px or hb < -lateral_px or hb > reach_px:
        return False, 0.0, 0.0
    return True, x, y


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
            hit, x, y = _meet_ahead(pts, dirs, ends, a, b, sin_min, lateral_px, reach_px)
            if not hit:
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
def _k_nodes(A, B, X, e_pt, e_dir, e_piece, e_fam, n_e, merge_px, lateral_px, cos_opp, t_nodes):
    """Step 1's nodes from the crossings (A, B, X) of `_k_crossings`, in one pass: the estimates within merge_px
    linked (single linkage; a node is numbered by its lowest estimate), the node at their mean, and the node's
    ends of each family. Returns the node count N, xn (N, 2), bad (N,) (an end at two nodes, an end line beyond
    lateral_px, a family with no end or more than two, two ends of one piece or not on opposite sides, no family
    with two ends; without t_nodes also a family with one end), and per node and family (column f − 1) its first
    and second end (e0, e1; −1: none)."""
    m = X.shape[0]
    r2 = merge_px * merge_px
    parent = np.arange(m)
    for i in range(m):
        for j in range(i + 1, m):
            dx = X[i, 0] - X[j, 0]
            dy = X[i, 1] - X[j, 1]
            if dx * dx + dy * dy <= r2:
                _union_find_join(parent, i, j)
    for i in range(m):  # a parent is never larger than its child: in this order one pass reaches the roots
        parent[i] = parent[parent[i]]
    node_id = np.full(m, -1, np.int64)
    N = 0
    for i in range(m):
        if parent[i] == i:
            node_id[i] = N
            N += 1
    node_of = np.empty(m, np.int64)
    for i in range(m):
        node_of[i] = node_id[parent[i]]
    xn = np.zeros((N, 2))
    cnt = np.zeros(N)
    for i in range(m):
        xn[node_of[i], 0] += X[i, 0]
        xn[node_of[i], 1] += X[i, 1]
        cnt[node_of[i]] += 1.0
    for k in range(N):
        xn[k, 0] = xn[k, 0] / cnt[k]
        xn[k, 1] = xn[k, 1] / cnt[k]
    # the node's ends, each once, sorted by node and end
    keys = np.empty(2 * m, np.int64)
    for i in range(m):
        keys[i] = node_of[i] * n_e + A[i]
        keys[m + i] = node_of[i] * n_e + B[i]
    keys = np.sort(keys)
    nu = 0
    for i in range(2 * m):
        if i == 0 or keys[i] != keys[i - 1]:
            keys[nu] = keys[i]
            nu += 1
    bad = np.zeros(N, np.bool_)
    per_end = np.zeros(n_e, np.int64)
    for u in range(nu):
        per_end[keys[u] % n_e] += 1
    c = np.zeros((N, 2), np.int64)
    e0 = np.full((N, 2), -1, np.int64)
    e1 = np.full((N, 2), -1, np.int64)
    for u in range(nu):
        k = keys[u] // n_e
        e = keys[u] % n_e
        if per_end[e] > 1:
            bad[k] = True
        rx = xn[k, 0] - e_pt[e, 0]
        ry = xn[k, 1] - e_pt[e, 1]
        if abs(rx * e_dir[e, 1] - ry * e_dir[e, 0]) > lateral_px:
            bad[k] = True
        f = e_fam[e] - 1
        if c[k, f] == 0:
            e0[k, f] = e
        elif c[k, f] == 1:
            e1[k, f] = e
        c[k, f] += 1
    for k in range(N):
        n_two = 0
        for f in range(2):
            ck = c[k, f]
            if ck == 0 or ck > 2 or (ck == 1 and not t_nodes):
                bad[k] = True
            if ck == 2:
                n_two += 1
                a = e0[k, f]
                b = e1[k, f]
                if e_piece[a] == e_piece[b] or e_dir[a, 0] * e_dir[b, 0] + e_dir[a, 1] * e_dir[b, 1] > -cos_opp:
                    bad[k] = True
            else:
                e1[k, f] = -1
                if ck != 1:
                    e0[k, f] = -1
        if n_two < 1:
            bad[k] = True
    return N, xn, bad, e0, e1


@njit
def _k_open_pieces(piece, sid, index, min_samples):
    """The pieces of the traces (piece (n,) non-decreasing, numbered 0 … n_p − 1): their first and past-the-end
    positions, and the open ones (no sample labelled, at least min_samples samples)."""
    n = piece.shape[0]
    n_p = 1
    for s in range(1, n):
        if piece[s] != piece[s - 1]:
            n_p += 1
    starts = np.empty(n_p, np.int64)
    stops = np.empty(n_p, np.int64)
    open_mask = np.zeros(n_p, np.bool_)
    p = 0
    starts[0] = 0
    for s in range(1, n + 1):
        if s == n or piece[s] != piece[s - 1]:
            stops[p] = s
            p += 1
            if s < n:
                starts[p] = s
    for p in range(n_p):
        if stops[p] - starts[p] < min_samples:
            continue
        lab = False
        for s in range(starts[p], stops[p]):
            if np.isfinite(index[sid[s]]):
                lab = True
                break
        open_mask[p] = not lab
    return starts, stops, open_mask


@njit
def _end_radius(q, sid, ts, a, b, e, trim_px):
    """The largest distance from the end sample of end e (0: start, 1: stop) of the piece at positions a … b − 1 to
    a sample within 3·trim_px of it along the piece (every sample `_fit_end` can use)."""
    ex = q[sid[a], 0] if e == 0 else q[sid[b - 1], 0]
    ey = q[sid[a], 1] if e == 0 else q[sid[b - 1], 1]
    r2 = 0.0
    for k in range(b - a):
        pos = a + k if e == 0 else b - 1 - k
        d = ts[pos] - ts[a] if e == 0 else ts[b - 1] - ts[pos]
        if d > 3.0 * trim_px:
            break
        dd = (q[sid[pos], 0] - ex) ** 2 + (q[sid[pos], 1] - ey) ** 2
        if dd > r2:
            r2 = dd
    return np.sqrt(r2)


@njit
def _k_far_ends(free, e_fam, e_piece, q, sid, ts, starts, stops, long_mask, done, pts, dirs, rms, ends, ok, trim_px, reach_px,
                lateral_px, merge_px, cos_opp, sin_min, own_line):
    """Step 6's crossings, as decision 0139's `_k_free_end_crossings` (kept in the tests' reference) computed them
    over every long piece's end line: for each free end, the nearest crossing X with a usable end line of the other
    family and whether it counts (X (m, 2), ok (m,)). Here the end lines of the long pieces (long_mask) are fitted
    only where read: `done` marks the ends whose fit (pts, dirs, rms, ok; updated in place) is already there; the
    other family's ends only within 2·reach_px, the own family's only where the other family's line does not run
    through X, and not those that cannot reach X (decision 0142's bound). on (m,): the free end's own line goes on
    beyond X (an end of its family facing back, its end line through X); with own_line also where the other family's
    line runs through X (step 6b), else only where it does not."""
    m = free.shape[0]
    n = e_fam.shape[0]
    X = np.full((m, 2), np.nan)
    okf = np.zeros(m, np.bool_)
    on = np.zeros(m, np.bool_)
    xs = np.empty((n, 2))
    ids = np.empty(n, np.int64)
    rad = np.full(n, -1.0)
    for u in range(m):
        a = free[u]
        fa = e_fam[a]
        cnt = 0
        best = -1
        bd = np.inf
        for b in range(n):
            if e_fam[b] == fa or not long_mask[e_piece[b]]:
                continue
            dx = ends[a, 0] - ends[b, 0]
            dy = ends[a, 1] - ends[b, 1]
            if dx * dx + dy * dy > 4.0 * reach_px * reach_px:
                continue
            if not done[b]:
                p = e_piece[b]
                _fit_end(q, sid, ts, starts[p], stops[p], p, b - 2 * p, trim_px, ends, pts, dirs, rms, ok)
                done[b] = True
            if not ok[b]:
                continue
            hit, x, y = _meet_ahead(pts, dirs, ends, a, b, sin_min, lateral_px, reach_px)
            if not hit:
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
        if through:
            okf[u] = True
            if not own_line:
                continue
        goes_on = False
        for g in range(n):
            if e_fam[g] != fa or e_piece[g] == e_piece[a] or not long_mask[e_piece[g]]:
                continue
            if not done[g]:
                p = e_piece[g]
                # an end line through X (lat <= lateral_px) whose end is ahead within reach_px puts X within
                # lateral_px + max(lateral_px, reach_px) + 2·R of the end sample, R the radius about it of the samples
                # the fit can use (their mean is within R of it): farther ends are skipped unfitted
                if rad[g] < 0.0:
                    rad[g] = _end_radius(q, sid, ts, starts[p], stops[p], g - 2 * p, trim_px)
                if np.sqrt((x - ends[g, 0]) ** 2 + (y - ends[g, 1]) ** 2) > lateral_px + max(lateral_px, reach_px) + 2.0 * rad[g] + 1e-6:
                    continue
                _fit_end(q, sid, ts, starts[p], stops[p], p, g - 2 * p, trim_px, ends, pts, dirs, rms, ok)
                done[g] = True
            if not ok[g]:
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
        on[u] = goes_on
        okf[u] = okf[u] or goes_on
    return X, okf, on


def _far_split(ridge, sid, a, b, side, min_step, goes_on, min_samples):
    """Step 6b for the piece at trace positions a … b − 1 (its other end at an accepted node) whose far end, side
    (0: start, 1: stop), fails step 6: (side, the position its labelled part ends before (side 1) or starts at
    (side 0)), or None (the piece stays unlabelled). The ridge brightness's maximum-likelihood step along the piece
    (`trace_ends.mean_shift_split`, decision 0132) is the depth edge where the two sides' means differ by at least
    min_step of the brighter (an edge the piece shows: the piece keeps the node's side); without such a step, a
    piece whose own line goes on beyond the far crossing (goes_on: an X there names another line) stays
    unlabelled, and one whose line ends there (a T: the other family's line runs across the end, in front of it
    or beyond a shadow's edge) keeps its whole length. The kept part needs min_samples samples."""
    r = np.ascontiguousarray(ridge[sid[a:b]], np.float64)
    s = int(mean_shift_split(r))
    if s < 1:
        return None
    m0 = float(r[:s].mean())
    m1 = float(r[s:].mean())
    if abs(m1 - m0) >= min_step * max(m0, m1, 1e-9):
        at = a + s
        return (side, at) if (at - a if side == 1 else b - at) >= min_samples else None
    if goes_on:
        return None
    return side, (b if side == 1 else a)


@njit
def _k_label_pieces(pp, kk, at_node, starts, stops, ts, sid, index, seed, has_seed, t_node, t_free, trim_px):
    """Step 5 for the pieces pp (ascending) with their one index kk: every sample farther than t_node (an end at
    an accepted node, at_node[2·piece + side]) or t_free (a free end) from the piece's ends and not labelled takes
    kk in index; with has_seed, those within 2·trim_px past the trim of an end at a node take it in seed first.
    Returns the count of samples labelled."""
    total = 0
    for u in range(pp.shape[0]):
        p = pp[u]
        a = starts[p]
        b = stops[p]
        k = kk[u]
        n0 = at_node[2 * p]
        n1 = at_node[2 * p + 1]
        t0 = t_node if n0 else t_free
        t1 = t_node if n1 else t_free
        ta = ts[a]
        tb = ts[b - 1]
        if has_seed:
            for s in range(a, b):
                inner = (ts[s] - ta >= t0) and (tb - ts[s] >= t1)
                near = False
                if n0 and ts[s] - ta >= t0 and ts[s] - ta <= t0 + 2.0 * trim_px:
                    near = True
                if n1 and tb - ts[s] >= t1 and tb - ts[s] <= t1 + 2.0 * trim_px:
                    near = True
                if near and inner and not np.isfinite(index[sid[s]]):
                    seed[sid[s]] = k
        for s in range(a, b):
            if (ts[s] - ta >= t0) and (tb - ts[s] >= t1) and not np.isfinite(index[sid[s]]):
                index[sid[s]] = k
                total += 1
    return total


@njit
def _before(a, b):
    """a sorts before b in NumPy's order of floats (NaN last)."""
    if a != a:
        return False
    if b != b:
        return True
    return a < b


@njit
def _nan_max(a, b):
    """np.maximum of two floats (NaN when either is)."""
    if a != a or b != b:
        return np.nan
    return a if a >= b else b


@njit
def _k_check_choice(c_start, ci, cj, res, adm, g_start, g_size, qs, fs, index_min, span, z0, z1, sheet, rho, nf2, min_llr, rr2):
    """Steps 3 (the sheet checks) and 4 (the choice) per node k, whose candidates are c_start[k] … c_start[k+1] − 1
    (ci, cj, residual res, adm: inside the volume): in the order of res (stable, NaN last) each candidate's two
    groups (2·k + f − 1: rows g_start … g_start + g_size of qs, fs) checked on its sheet inside the volume
    (`RigModel.sheet_depth`'s kernel, `sheet` its table arguments; each (group, line) once) until two pass: the
    best two admissible candidates, all the choice reads. Returns (ok, accept (K,), b1 (K,)); ok False when a
    pixel lies outside the camera table (the caller takes the NumPy path)."""
    K = c_start.shape[0] - 1
    accept = np.zeros(K, np.bool_)
    b1 = np.full(K, -1, np.int64)
    state = np.zeros(2 * K * span, np.int8)  # per (group, line): 0 not checked, 1 inside the volume, 2 not
    order = np.empty(c_start[K] - c_start[0], np.int64)
    for k in range(K):
        m = 0
        for c in range(c_start[k], c_start[k + 1]):
            if not adm[c]:
                continue
            # stable insertion by residual
            u = m
            while u > 0 and _before(res[c], res[order[u - 1]]):
                order[u] = order[u - 1]
                u -= 1
            order[u] = c
            m += 1
        n_ok = 0
        c1 = -1
        c2 = -1
        for r in range(m):
            c = order[r]
            good = True
            for f in range(2):
                g = 2 * k + f
                key = g * span + ((ci[c] if f == 0 else cj[c]) - index_min)
                if state[key] == 0:
                    a = g_start[g]
                    nr = g_size[g]
                    z = np.empty(nr)
                    idx = np.full(nr, (ci[c] if f == 0 else cj[c]), np.int64)
                    if not _k_sheet_depth(qs[a : a + nr], fs[a : a + nr], idx, *sheet, z):
                        return False, accept, b1
                    st = 1
                    for s in range(nr):
                        if not (z[s] >= z0 and z[s] <= z1):
                            st = 2
                            break
                    state[key] = st
                if state[key] != 1:
                    good = False
                    break
            if good:
                n_ok += 1
                if n_ok == 1:
                    c1 = c
                else:
                    c2 = c
                    break
        if n_ok == 0:
            continue
        b1[k] = c1
        s1 = res[c1] * res[c1]
        s2 = res[c2] * res[c2] if n_ok > 1 else np.inf
        sig2 = _nan_max(_nan_max(s1, nf2), rho[k] * rho[k])
        accept[k] = ((s2 - s1) / sig2 >= min_llr) and (s2 >= rr2 * sig2)
    return True, accept, b1


@njit
def _k_group_samples(g_e0, g_e1, e_piece, starts, stops, sid, q, check_samples, tab, inv_step):
    """Step 3's samples per group g (2·node + f − 1; its pieces: the end g_e0[g]'s, then g_e1[g]'s when ≥ 0): at most
    check_samples a piece, evenly spaced from end to end. Returns ok (False: a pixel outside the camera table; the
    caller takes the NumPy path), their pixels qs (M, 2), normalised coordinates xy (M, 2) (`RigModel.cam_normalised`'s
    table), family fs (M,), and each group's first row and row count."""
    G = g_e0.shape[0]
    g_start = np.empty(G, np.int64)
    g_size = np.zeros(G, np.int64)
    M = 0
    for g in range(G):
        for u in range(2):
            e = g_e0[g] if u == 0 else g_e1[g]
            if e >= 0:
                p = e_piece[e]
                M += min(stops[p] - starts[p], check_samples)
    qs = np.empty((M, 2))
    fs = np.empty(M, np.int64)
    r = 0
    for g in range(G):
        g_start[g] = r
        for u in range(2):
            e = g_e0[g] if u == 0 else g_e1[g]
            if e < 0:
                continue
            p = e_piece[e]
            full = stops[p] - starts[p]
            sz = min(full, check_samples)
            step = (full - 1) / max(sz - 1, 1)
            for k in range(sz):
                s = sid[starts[p] + int(np.rint(k * step))]
                qs[r, 0] = q[s, 0]
                qs[r, 1] = q[s, 1]
                fs[r] = g % 2 + 1
                r += 1
        g_size[g] = r - g_start[g]
    xy = np.empty((M, 2))
    inside = np.empty(M, np.bool_)
    _k_cam_bilinear(qs, tab, inv_step, xy, inside)
    for n in range(M):
        if not inside[n]:
            return False, qs, xy, fs, g_start, g_size
    return True, qs, xy, fs, g_start, g_size


def _unique(a: np.ndarray) -> np.ndarray:
    """np.unique of an integer array by a sort (NumPy 2's hash-based unique is slow on these small arrays)."""
    a = np.sort(a, kind="stable")
    return a[np.r_[True, a[1:] != a[:-1]]] if len(a) else a


def label_lone_crossings(q, fam, sid, piece, ts, index, *, model: RigModel, depth_range_mm, trim_px: float, reach_px: float,
                         lateral_px: float, tol_px: float, noise_floor_px: float,
                         options: LoneCrossingOptions = LoneCrossingOptions(), seed: np.ndarray | None = None,
                         ridge: np.ndarray | None = None, debug: dict | None = None) -> dict:
    """Label the pieces at crossings of unlabelled pieces (module doc). q (P, 2), fam (P,), index (P,) (NaN: none;
    written in place); the traces as `labelling.label_samples` builds them: sid (n,), piece (n,) non-decreasing, ts
    (n,) position along the piece (px). seed (P,) int (`labelling.label_samples`' junction seeds, UNLABELLED where
    none; None: not written): the labelled samples within 2·trim_px past the trim of an end at an accepted node
    become seeds with the piece's index. ridge (P,): the ridge brightness at the samples (`labelling._ridge_brightness`;
    None: step 6b off). Returns counts."""
    stats = {"nodes": 0, "nodes_labelled": 0, "samples": 0}
    n = len(piece)
    if n == 0:
        return stats
    q = np.asarray(q, np.float64)
    fam = np.asarray(fam)
    piece = np.asarray(piece, np.intp)
    sid = np.asarray(sid, np.intp)
    ts = np.asarray(ts, np.float64)
    starts, stops, open_mask = _k_open_pieces(piece, sid, index, int(options.min_samples))
    n_p = len(starts)
    if open_mask.sum() < 3:
        return stats
    starts64, stops64 = starts, stops
    e_pt, e_dir, e_rms, e_end, ok = _k_end_lines(q, sid, ts, starts64, stops64, open_mask, float(trim_px))
    e_all = np.flatnonzero(ok)
    e_piece = np.arange(2 * n_p, dtype=np.int64) // 2
    e_fam = np.asarray(fam[sid[starts]], np.int64)[e_piece]
    if debug is not None:
        debug.update(e_end=e_end[e_all], e_fam=e_fam[e_all], e_dir=e_dir[e_all], e_piece=e_piece[e_all], e_pt=e_pt[e_all])
    # 1. pairs of ends of the two families near each other, and where their end lines cross
    A, B, X = _k_crossings(e_all[e_fam[e_all] == 1], e_all[e_fam[e_all] == 2], e_pt, e_dir, e_end, float(reach_px), float(lateral_px),
                           float(np.sin(np.deg2rad(10.0))))
    if len(A) == 0:
        return stats
    # nodes: single linkage of the estimates within merge_px, their ends, the shape tests (one compiled pass)
    merge_px = options.merge_share * model.junction_step_cam_px
    cos_opp = np.cos(np.deg2rad(options.opposite_deg))
    N, xn, bad, fe0, fe1 = _k_nodes(A, B, X, e_pt, e_dir, e_piece, e_fam, 2 * n_p, float(merge_px), float(lateral_px), float(cos_opp),
                                    bool(options.t_nodes))
    first = {f: (fe0[:, f - 1], fe1[:, f - 1]) for f in (1, 2)}
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
    G = 2 * K
    tol_g = np.tile(tol, K)
    proj = model.procam.projector
    # at most `check_samples` samples a piece, evenly spaced from end to end (the stretches' intersection and the
    # volume test over fewer samples admit a superset of the lines: never fewer candidates, never the truth out)
    compiled = False
    if model.cam_xy_table is not None and proj.dist.size <= 5:
        # one compiled pass for the samples, then decision 0128's compiled stretches, intersected per group
        compiled, qs, xy_s, f_all, g_start, g_size = _k_group_samples(g_e0.astype(np.int64), g_e1.astype(np.int64), e_piece, starts64, stops64,
                                                                     sid, q, int(options.check_samples), model.cam_xy_table,
                                                                     1.0 / model.cam_table_px)
    if compiled:
        pat = model.pattern
        dist = np.zeros(5)
        dist[: min(5, proj.dist.size)] = np.asarray(proj.dist, np.float64).ravel()[:5]
        lo_g, hi_g = _k_group_stretches(
            xy_s, g_start, g_start + g_size,
            np.ascontiguousarray(model.procam.R_proj_cam, np.float64), np.ascontiguousarray(model.procam.t_proj_cam, np.float64), z0, z1,
            np.ascontiguousarray(proj.K, np.float64), dist, bool(proj.has_distortion), float(pat.centre_px[0]), float(pat.centre_px[1]),
            np.array([pat.n1, pat.n2], np.float64), np.ascontiguousarray(model.line_offsets_px, np.float64), int(model.index_min))
        miss = ~np.isfinite(lo_g) & (lo_g > 0)
    else:
        # the NumPy path (the reference the kernels are tested against)
        has1 = g_e1 >= 0
        gp = np.concatenate([np.arange(2 * K), np.flatnonzero(has1)])
        pc = np.concatenate([e_piece[g_e0], e_piece[g_e1[has1]]])
        # all samples of the nodes' pieces, one stretch computation
        og = np.argsort(gp, kind="stable")
        gp, pc = gp[og], pc[og]
        full = stops[pc] - starts[pc]
        sz = np.minimum(full, options.check_samples)
        rk = np.arange(sz.sum()) - np.repeat(np.cumsum(sz) - sz, sz)
        step = np.repeat((full - 1) / np.maximum(sz - 1, 1), sz)
        pos = np.repeat(starts[pc], sz) + np.rint(rk * step).astype(np.intp)
        grp = np.repeat(gp, sz)
        s_all = sid[pos]
        f_all = (grp % 2 + 1).astype(np.intp)
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
        g_start = np.searchsorted(grp, np.arange(G))
        g_size = np.searchsorted(grp, np.arange(G), side="right") - g_start
        qs = q[s_all]
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
    # ρ: the larger end-line RMS at the node (camera px)
    rho = np.zeros(K)
    for x in (g_e0, g_e1):
        ex = np.maximum(x, 0)
        v = np.where(x >= 0, e_rms[ex], 0.0)
        rho = np.maximum(rho, np.maximum(v[0::2], v[1::2]))
    # every sample of the node's pieces of family f, on sheet k, inside the volume (decision 0128's step 4): checked
    # for each node's candidates in the order of their residual until two pass (only the best two admissible
    # candidates decide); then the choice (step 4). One compiled pass where `RigModel.sheet_depth` takes its kernel.
    span = model.index_max - model.index_min + 1
    compiled = False
    if debug is None and model.cam_xy_table is not None and proj.dist.size <= 5:
        sheet = (model.cam_xy_table, 1.0 / model.cam_table_px, model.procam.R_proj_cam, model.procam.t_proj_cam, model.index_min,
                 model.sheet_nodes, 1 if proj.has_distortion else 0, *model._sheet_kernel_tables)
        compiled, accept, b1 = _k_check_choice(np.r_[0, np.cumsum(tot)].astype(np.int64), ci.astype(np.int64), cj.astype(np.int64), res, adm,
                                               g_start.astype(np.int64), g_size.astype(np.int64), np.ascontiguousarray(qs),
                                               f_all.astype(np.int64), int(model.index_min), int(span), z0, z1, sheet, rho,
                                               float(noise_floor_px**2), float(options.min_llr), float(options.min_rms_ratio**2))
    if not compiled:
        # the NumPy path (the reference the kernel is tested against): the 4 best first, the rest only where those
        # 4 do not hold two admissible ones
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
            zs = model.sheet_depth(qs[rows_s], f_all[rows_s], kk[rows_c])
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
    cut_at: dict = {}  # step 6b: piece -> the trace position its kept part ends before (far end at stop) or starts at
    if proposals and options.far_end_check:
        # the end lines of every piece long enough (labelled ones too): the lines a free end may cross; fitted
        # where read (the open pieces' are step 1's)
        long_mask = stops - starts >= options.min_samples
        fr_e, fr_p = [], []
        for p_ in sorted(proposals):
            if len(proposals[p_]) != 1:
                continue
            for e in (2 * p_, 2 * p_ + 1):
                if e not in at_node and ok[e]:
                    fr_e.append(e)
                    fr_p.append(p_)
        if fr_e:
            fr_e = np.array(fr_e, np.int64)
            done = np.repeat(open_mask, 2)
            split = options.far_end_split and ridge is not None and len(ridge) == len(q)
            Xf, okf, onf = _k_far_ends(fr_e, e_fam, e_piece, q, sid, ts, starts64, stops64, long_mask, done, e_pt, e_dir, e_rms, e_end, ok,
                                       float(trim_px), float(reach_px), float(lateral_px), float(merge_px), float(cos_opp),
                                       float(np.sin(np.deg2rad(10.0))), bool(split))
            if okf.any():
                sel = np.flatnonzero(okf)
                ff = e_fam[fr_e[sel]]
                kf = np.array([next(iter(proposals[fr_p[i]])) for i in sel.tolist()])
                _, zf, _, dist_f = model.sheet_check(Xf[sel], ff, kf)
                bad_far = ~((dist_f <= options.cross_tol_px) & (zf >= z0) & (zf <= z1))
                if debug is not None:
                    debug["far"] = [(Xf[i], int(ff[t]), int(kf[t]), float(dist_f[t]), float(zf[t]), bool(bad_far[t]), int(fr_p[i]), int(fr_e[i]), bool(onf[i])) for t, i in enumerate(sel.tolist())]
                for t in np.flatnonzero(bad_far).tolist():
                    p_, e_ = fr_p[sel[t]], int(fr_e[sel[t]])
                    stats["pieces_far_end"] = stats.get("pieces_far_end", 0) + 1
                    cut = None
                    if split and p_ not in cut_at and (e_ ^ 1) in at_node:
                        cut = _far_split(ridge, sid, int(starts[p_]), int(stops[p_]), e_ % 2, float(options.far_split_step),
                                         bool(onf[sel[t]]), int(options.min_samples))
                    if cut is None:
                        proposals[p_] = set()
                        cut_at.pop(p_, None)
                    else:
                        cut_at[p_] = cut
                        stats["pieces_far_split"] = stats.get("pieces_far_split", 0) + 1
    # 5. the pieces whose accepted nodes agree, without their samples within trim_px of either end (an end at no
    # accepted node is free (a silhouette, a shadow, another crossing): the cut line's ridge is pulled over the
    # smoothing kernel's reach there, `free_end_trim` smoothing scales); the labelled samples next to a node are
    # the piece's seeds, as a found junction's would be: the stretch beyond them is then checked at its far end
    # like any seeded piece's (decision 0084: a piece that runs across a depth edge onto a collinear line of
    # another surface)
    pp, kp = [], []
    for p_ in sorted(proposals):
        ks = proposals[p_]
        if len(ks) != 1:
            if len(ks) > 1:
                stats["pieces_conflicting"] = stats.get("pieces_conflicting", 0) + 1
            continue
        pp.append(p_)
        kp.append(next(iter(ks)))
    if pp:
        at_mask = np.zeros(2 * n_p, np.bool_)
        at_mask[list(at_node)] = True
        if cut_at:
            # step 6b: the cut pieces end (start) at their edge, a free end there
            starts64, stops64 = starts64.copy(), stops64.copy()
            for p_, (side, at) in cut_at.items():
                if side == 1:
                    stops64[p_] = at
                else:
                    starts64[p_] = at
        stats["samples"] += int(_k_label_pieces(np.array(pp, np.int64), np.array(kp, np.int64), at_mask, starts64, stops64, ts, sid, index,
                                                seed if seed is not None else np.zeros(1, np.int64), seed is not None,
                                                float(options.node_end_trim * trim_px), float(options.free_end_trim * trim_px),
                                                float(trim_px)))
    return stats
