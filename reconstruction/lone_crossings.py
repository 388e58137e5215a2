"""Label the pieces of two lines that cross where nothing else is labelled (decision 0139).

On a face that nothing else labels (an object lit by only a few lines: the paper presets' pyramid and arrow,
whose faces are dim and lit obliquely, their lines wide), the lines cross once or twice and extraction keeps no
junction there (a wide, dim crossing: too few ring samples, decisions 0068, 0129), and decision 0092's piece
junctions need a component of three nodes. The pieces stay unlabelled although the crossing, with the working
volume, names both lines.

For every crossing of unlabelled pieces (each family's line through it on both sides: an X, not a T or an L, which
are silhouettes, shadows or the pattern's rim, decision 0041):

1. **Crossing.** Each end of an unlabelled piece of at least `min_samples` samples has an end line: the total
   least-squares line of its samples between `trim_px` and 3·`trim_px` from the end (the crossing's light pulls
   the first ones, decision 0059). An end of family 1 and an end of family 2 meet where their end lines cross,
   ahead of both ends, within `reach_px` (half a crossing's gap); the estimates closer than `merge_px` are one
   node, at their mean. A node is kept when each family has exactly two ends there, on opposite sides, and every
   end line passes within `lateral_px` of it.
2. **Families.** The cyclic order of (epipolar direction, i-line, j-line) at the node is the rig's
   (`acute_crossings.expected_order_sign`, decision 0083: every lit, visible surface shows it): a piece given
   the wrong family (where both families turn towards the epipolar direction) swaps it.
3. **Candidates.** The working volume names, per family, the lines the node's pieces can lie on: the integers in
   the intersection of their samples' stretches (decision 0128's, widened by `tol_px`). A candidate junction
   (i, j) of those must lie in the pattern, triangulate (camera ray and projector ray) inside the volume, and put
   every sample of the pieces, on its sheet, inside the volume. The true junction always passes.
4. **Choice.** Among the candidates, the epipolar residual r of the node (projector px) decides as for a lone
   found junction (decision 0134): s = r², σ² = max(s1, σ0², ρ²) (σ0 the epipolar floor, ρ the larger RMS of
   the node's end-line fits, camera px: arms that are not straight bound how well the node is placed), accepted
   when (s2 − s1)/σ² ≥ `min_llr` and s2 ≥ `min_rms_ratio`²·σ² (a lone candidate: s2 = ∞).
5. **Pieces.** The node's four pieces take i (family 1) and j (family 2); their samples within `trim_px` of
   either end stay unlabelled, as in decision 0128 (gap filling reaches them where both sides are labelled).

Why this is not one-sided evidence (decisions 0049, 0089): nothing is carried from a labelled neighbour; the
crossing is labelled from its own epipolar line, like a found lone junction, and its pieces are those a found
junction there would seed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from reconstruction.acute_crossings import epipolar_dir_cam, expected_order_sign, order_sign
from reconstruction.depth_range_labels import index_stretch
from reconstruction.geometry import depth_cam, epipolar_lines, triangulate_rays
from reconstruction.rigmodel import RigModel


@dataclass(frozen=True)
class LoneCrossingOptions:
    """enabled: the step runs (`TraceOptions.lone_crossings`). min_samples: the shortest piece used. min_llr,
    min_rms_ratio: the ambiguity test of `label_epipolar` (25, 1.5). merge_share: node estimates closer than this share of the junction step are one
    node. opposite_deg: a family's two ends at a node point apart within this of 180°."""

    enabled: bool = True
    min_samples: int = 4
    min_llr: float = 25.0
    min_rms_ratio: float = 1.5
    merge_share: float = 0.25
    opposite_deg: float = 25.0
    t_nodes: bool = True


def _end_lines(q, sid, ts, a, b, trim_px):
    """The two end lines of the piece at positions a … b − 1: (point (2, 2), outward unit direction (2, 2), fit RMS
    (2,), end sample position (2, 2))."""
    t = ts[a:b]
    p = q[sid[a:b]]
    pts, dirs, rms, ends = np.empty((2, 2)), np.empty((2, 2)), np.empty(2), np.empty((2, 2))
    for e in (0, 1):
        d_end = (t - t[0]) if e == 0 else (t[-1] - t)
        sel = (d_end >= trim_px) & (d_end <= 3.0 * trim_px)
        if sel.sum() < 3:
            sel = np.argsort(d_end)[: min(len(t), 5)]
        x = p[sel]
        c = x.mean(0)
        u, s, vt = np.linalg.svd(x - c, full_matrices=False)
        d = vt[0]
        end = p[0] if e == 0 else p[-1]
        inner = p[-1] if e == 0 else p[0]
        if np.dot(end - inner, d) < 0:
            d = -d
        pts[e], dirs[e], ends[e] = c, d, end
        rms[e] = float(s[1] / np.sqrt(len(x))) if len(s) > 1 else 0.0
    return pts, dirs, rms, ends


def label_lone_crossings(q, fam, sid, piece, ts, index, *, model: RigModel, depth_range_mm, trim_px: float, reach_px: float,
                         lateral_px: float, tol_px: float, noise_floor_px: float,
                         options: LoneCrossingOptions = LoneCrossingOptions(), debug: dict | None = None) -> dict:
    """Label the pieces at crossings of unlabelled pieces (module doc). q (P, 2), fam (P,), index (P,) (NaN: none;
    written in place); the traces as `labelling.label_samples` builds them: sid (n,), piece (n,) non-decreasing, ts
    (n,) position along the piece (px). Returns counts."""
    stats = {"nodes": 0, "nodes_labelled": 0, "samples": 0}
    n = len(piece)
    if n == 0:
        return stats
    q = np.asarray(q, np.float64)
    starts = np.flatnonzero(np.r_[True, piece[1:] != piece[:-1]])
    stops = np.r_[starts[1:], n]
    lab = np.isfinite(index[sid])
    n_lab = np.add.reduceat(lab.astype(np.int64), starts)
    size = stops - starts
    open_p = np.flatnonzero((n_lab == 0) & (size >= options.min_samples))
    if len(open_p) < 4:
        return stats
    # 1. end lines of the open pieces
    E = len(open_p) * 2
    e_pt, e_dir, e_rms, e_end = np.empty((E, 2)), np.empty((E, 2)), np.empty(E), np.empty((E, 2))
    e_piece = np.repeat(open_p, 2)
    e_fam = np.empty(E, np.int64)
    for k, p in enumerate(open_p):
        a, b = starts[p], stops[p]
        pts, dirs, rms, ends = _end_lines(q, sid, ts, a, b, trim_px)
        e_pt[2 * k : 2 * k + 2], e_dir[2 * k : 2 * k + 2], e_rms[2 * k : 2 * k + 2], e_end[2 * k : 2 * k + 2] = pts, dirs, rms, ends
        e_fam[2 * k : 2 * k + 2] = fam[sid[a]]
    if debug is not None:
        debug.update(e_end=e_end.copy(), e_fam=e_fam.copy(), e_dir=e_dir.copy(), e_piece=e_piece.copy(), e_pt=e_pt.copy())
    f1 = np.flatnonzero(e_fam == 1)
    f2 = np.flatnonzero(e_fam == 2)
    if len(f1) < 2 or len(f2) < 2:
        return stats
    # pairs of ends of the two families near each other
    dd = np.linalg.norm(e_end[f1][:, None, :] - e_end[f2][None, :, :], axis=2)
    ia, ib = np.nonzero(dd <= 2.0 * reach_px)
    if len(ia) == 0:
        return stats
    A, B = f1[ia], f2[ib]
    d1, d2 = e_dir[A], e_dir[B]
    den = d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]
    ok = np.abs(den) > np.sin(np.deg2rad(10.0))
    w = e_pt[B] - e_pt[A]
    s_ = np.where(ok, (w[:, 0] * d2[:, 1] - w[:, 1] * d2[:, 0]) / np.where(ok, den, 1.0), 0.0)
    X = e_pt[A] + s_[:, None] * d1
    ahead_a = ((X - e_end[A]) * d1).sum(1)
    ahead_b = ((X - e_end[B]) * d2).sum(1)
    ok &= (ahead_a >= -lateral_px) & (ahead_a <= reach_px) & (ahead_b >= -lateral_px) & (ahead_b <= reach_px)
    A, B, X = A[ok], B[ok], X[ok]
    if len(A) == 0:
        return stats
    # nodes: single linkage of the estimates within merge_px
    merge_px = options.merge_share * model.junction_step_cam_px
    m = len(X)
    parent = np.arange(m)

    def root(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    close = np.linalg.norm(X[:, None] - X[None], axis=2) <= merge_px
    for i, j in zip(*np.nonzero(np.triu(close, 1))):
        ri, rj = root(i), root(j)
        if ri != rj:
            parent[max(ri, rj)] = min(ri, rj)
    comp = np.array([root(i) for i in range(m)])
    cos_opp = np.cos(np.deg2rad(options.opposite_deg))
    nodes = []
    for c in np.unique(comp):
        sel = comp == c
        xn = X[sel].mean(0)
        ends = {1: sorted(set(A[sel].tolist())), 2: sorted(set(B[sel].tolist()))}
        good = True
        n_two = 0
        for f in (1, 2):
            es = ends[f]
            if len(es) == 1 and options.t_nodes:
                continue
            if len(es) != 2 or e_piece[es[0]] == e_piece[es[1]]:
                good = False
                break
            if np.dot(e_dir[es[0]], e_dir[es[1]]) > -cos_opp:
                good = False
                break
            n_two += 1
        good = good and n_two >= 1
        for e in ends[1] + ends[2]:
            r = xn - e_pt[e]
            if abs(r[0] * e_dir[e][1] - r[1] * e_dir[e][0]) > lateral_px:
                good = False
        if debug is not None:
            debug.setdefault("shapes", []).append((xn, ends, good))
        if good:
            nodes.append((xn, ends))
    stats["nodes"] = len(nodes)
    if not nodes:
        return stats
    # an end at two nodes: left to neither
    use = {}
    for k, (_, ends) in enumerate(nodes):
        for f in (1, 2):
            for e in ends[f]:
                use.setdefault(e, set()).add(k)
    proposals: dict = {}  # piece -> set of indices the accepted nodes at it give
    z0, z1 = float(depth_range_mm[0]), float(depth_range_mm[1])
    procam = model.procam
    tol = tol_px / np.asarray(model.line_spacing_perp_px, np.float64)
    if debug is not None:
        debug.setdefault("nodes", [])
    for k, (xn, ends) in enumerate(nodes):
        pieces = {f: [e_piece[e] for e in ends[f]] for f in (1, 2)}
        if any(len(use[e]) > 1 for f in (1, 2) for e in ends[f]):
            if debug is not None:
                debug["nodes"].append(dict(xy=xn, why="end at two nodes"))
            continue
        # 2. the epipolar order
        dir1 = e_dir[ends[1][0]] - (e_dir[ends[1][1]] if len(ends[1]) > 1 else 0.0)
        dir2 = e_dir[ends[2][0]] - (e_dir[ends[2][1]] if len(ends[2]) > 1 else 0.0)
        exp = int(expected_order_sign(model, xn[None])[0])
        e_ep = epipolar_dir_cam(model, xn[None])
        if exp == 0 or int(order_sign(e_ep, dir1[None], dir2[None])[0]) != exp:
            if debug is not None:
                debug["nodes"].append(dict(xy=xn, why="order"))
            continue
        # 3. admissible indices per family
        rng = {}
        pos_f = {}
        for f in (1, 2):
            pos = np.concatenate([np.arange(starts[p], stops[p]) for p in pieces[f]])
            s = sid[pos]
            lo, hi = index_stretch(model, q[s], np.full(len(s), f), (z0, z1))
            if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
                rng[f] = (1, 0)
                continue
            k_lo = int(max(np.ceil(np.max(lo) - tol[f - 1]), model.index_min))
            k_hi = int(min(np.floor(np.min(hi) + tol[f - 1]), model.index_max))
            rng[f] = (k_lo, k_hi)
            pos_f[f] = pos
        if rng[1][0] > rng[1][1] or rng[2][0] > rng[2][1]:
            if debug is not None:
                debug["nodes"].append(dict(xy=xn, why="no range"))
            continue
        ii, jj = np.meshgrid(np.arange(rng[1][0], rng[1][1] + 1), np.arange(rng[2][0], rng[2][1] + 1), indexing="ij")
        ii, jj = ii.ravel(), jj.ravel()
        # every sample on its sheet inside the volume
        okf = {}
        for f, ks in ((1, np.unique(ii)), (2, np.unique(jj))):
            s = sid[pos_f[f]]
            good = []
            for kk in ks:
                z = model.sheet_depth(q[s], np.full(len(s), f), np.full(len(s), kk))
                good.append(bool(np.all((z >= z0) & (z <= z1))))
            okf[f] = dict(zip(ks.tolist(), good))
        keep = np.array([okf[1][a] and okf[2][b] for a, b in zip(ii, jj)], bool)
        ii, jj = ii[keep], jj[keep]
        if len(ii) == 0:
            if debug is not None:
                debug["nodes"].append(dict(xy=xn, why="no sheet in volume"))
            continue
        xy = model.cam_normalised(xn[None])
        xy_p = model.junction_xy(ii, jj)
        p, _gap = triangulate_rays(procam, np.repeat(xy, len(ii), 0), xy_p)
        z = depth_cam(procam, p)
        inside = (z >= z0) & (z <= z1)
        ii, jj, xy_p = ii[inside], jj[inside], xy_p[inside]
        if len(ii) == 0:
            if debug is not None:
                debug["nodes"].append(dict(xy=xn, why="junction outside volume"))
            continue
        ln = epipolar_lines(procam, xy)[0]
        r = np.abs(ln[0] * xy_p[:, 0] + ln[1] * xy_p[:, 1] + ln[2]) * model.fx_proj
        order = np.argsort(r, kind="stable")
        s1 = float(r[order[0]] ** 2)
        s2 = float(r[order[1]] ** 2) if len(order) > 1 else np.inf
        rho = float(max(e_rms[e] for f in (1, 2) for e in ends[f]))
        sig2 = max(s1, noise_floor_px**2, rho**2)
        accept = (s2 - s1) / sig2 >= options.min_llr and s2 >= options.min_rms_ratio**2 * sig2
        if debug is not None:
            debug["nodes"].append(dict(xy=xn, why="ok" if accept else "ambiguous", ij=(int(ii[order[0]]), int(jj[order[0]])),
                                       r=np.sqrt([s1, s2]), rho=rho, n_cand=len(ii), pieces=pieces))
        if not accept:
            continue
        stats["nodes_labelled"] += 1
        lbl = {1: int(ii[order[0]]), 2: int(jj[order[0]])}
        for f in (1, 2):
            for p in pieces[f]:
                proposals.setdefault(p, set()).add(lbl[f])
    # 5. the pieces whose accepted nodes agree, without their samples within trim_px of either end
    for p in sorted(proposals):
        ks = proposals[p]
        if len(ks) != 1:
            stats["pieces_conflicting"] = stats.get("pieces_conflicting", 0) + 1
            continue
        a, b = starts[p], stops[p]
        t = ts[a:b]
        inner = (t - t[0] >= trim_px) & (t[-1] - t >= trim_px)
        s = sid[a:b][inner]
        s = s[~np.isfinite(index[s])]
        index[s] = next(iter(ks))
        stats["samples"] += len(s)
    return stats
