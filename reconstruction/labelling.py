"""Labelling: which pattern junction (i, j) each image junction is.

Two labellers on the same `GridObservation` graph:

- `label_paper`: the paper's three-point method. Every triangle of connected junctions
  (i, j), (i+1, j), (i+1, j+1) gives three epipolar lines y = m·x + b on the projector plane (Eq. 3); the
  base point (x0, y0) minimising the squared distances of the three vertices to their lines solves the
  2×2 normal equations (Eq. 6–7, `solve_base_point`), and is snapped to the nearest grid junction.
  Junctions take the majority label of the triangles they belong to. No other check.
- `label_epipolar` (default): one unknown integer offset per connected component. The graph gives the
  relative labels; every admissible offset is scored by the robust mean squared epipolar distance of all
  the component's junctions (projector px); offsets that put labels outside the pattern or the surface
  outside the working depth range are discarded; the best is accepted only if it beats the runner-up by
  a clear margin (a likelihood-ratio test), otherwise the component is left out as ambiguous.

Derivations and the ambiguity test: docs/reconstruction.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import breadth_first_order, connected_components

from reconstruction.extraction import GridObservation
from reconstruction.geometry import depth_cam, epipolar_lines, paper_epipolar_mb, triangulate_rays
from reconstruction.rigmodel import UNLABELLED, RigModel


@dataclass(frozen=True)
class LabelOptions:
    """depth_min_mm, depth_max_mm: working volume (camera-frame z). min_inside_fraction: share of a
    component's junctions that must triangulate inside it. residual_cap_px: residuals are capped here
    (robust score). noise_floor_px: smallest junction noise assumed by the ambiguity test. ambiguity_chi2:
    the best offset must beat the runner-up by this much (M·Δscore/σ²). candidate_band_px: offsets are
    proposed by pattern junctions this close to a reference junction's epipolar line. max_residual_px:
    an accepted component's junctions farther than this from their epipolar line are left out.
    min_component: components with fewer junctions are left out."""

    depth_min_mm: float = 100.0
    depth_max_mm: float = 10000.0
    min_inside_fraction: float = 0.9
    residual_cap_px: float = 3.0
    noise_floor_px: float = 0.15
    ambiguity_chi2: float = 25.0
    candidate_band_px: float = 4.0
    max_residual_px: float = 3.0
    min_component: int = 1


@dataclass(frozen=True, eq=False)
class Labels:
    """labels (M, 2) int (i, j), UNLABELLED where none; residual (M,) epipolar distance of the label
    (projector px, NaN if unlabelled); component (M,) component id (−1: isolated); stats: counts."""

    labels: np.ndarray
    residual: np.ndarray
    component: np.ndarray
    stats: dict = field(default_factory=dict)


def relative_labels(n_junctions: int, edges: np.ndarray, delta: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """Integer labels relative to one root per connected component, from the graph edges.

    edges (E, 2) junction ids a → b; delta (E, 2) the (i, j) change from a to b. Edges that contradict
    the labels propagated along a spanning tree are removed and the components recomputed (once).
    Returns rel (M, 2), component (M,), number of contradicting edges removed.
    """
    removed = 0
    for _ in range(2):
        rel, comp = _propagate(n_junctions, edges, delta)
        if len(edges) == 0:
            break
        bad = np.any(rel[edges[:, 1]] - rel[edges[:, 0]] != delta, axis=1)
        if not bad.any():
            break
        # Drop every edge that touches a contradiction's endpoints (cheap and conservative).
        nodes = np.unique(edges[bad].ravel())
        touch = np.isin(edges[:, 0], nodes) | np.isin(edges[:, 1], nodes)
        removed += int(touch.sum())
        edges, delta = edges[~touch], delta[~touch]
    return rel, comp, removed


def _propagate(n: int, edges: np.ndarray, delta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    rel = np.zeros((n, 2), np.int64)
    if n == 0:
        return rel, np.zeros(0, np.int64)
    a, b = edges[:, 0], edges[:, 1]
    g = coo_matrix((np.ones(len(a)), (a, b)), shape=(n, n)).tocsr()
    ncomp, comp = connected_components(g, directed=False)
    # Delta lookup for both directions.
    dmap: dict[tuple[int, int], tuple[int, int]] = {}
    for (x, y), (di, dj) in zip(edges.tolist(), delta.tolist()):
        dmap[(x, y)] = (di, dj)
        dmap[(y, x)] = (-di, -dj)
    seen = np.zeros(ncomp, bool)
    for root in range(n):
        c = comp[root]
        if seen[c]:
            continue
        seen[c] = True
        order, pred = breadth_first_order(g, root, directed=False, return_predecessors=True)
        for node in order[1:].tolist():
            p = int(pred[node])
            di, dj = dmap[(p, node)]
            rel[node, 0] = rel[p, 0] + di
            rel[node, 1] = rel[p, 1] + dj
    return rel, comp.astype(np.int64)


def _epipolar_residual_px(model: RigModel, lines: np.ndarray, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """|l · (x, y, 1)| in projector px for lines (..., 3) and labels (...) inside the pattern."""
    xy = model.xy_junction[i - model.index_min, j - model.index_min]
    return np.abs(lines[..., 0] * xy[..., 0] + lines[..., 1] * xy[..., 1] + lines[..., 2]) * model.fx_proj


def label_epipolar(obs: GridObservation, model: RigModel, xy_cam: np.ndarray, *, options: LabelOptions = LabelOptions()) -> Labels:
    """The default labeller: one offset per connected component (module doc). xy_cam: (M, 2) normalised
    camera coordinates of obs.q_junction."""
    M = len(obs.q_junction)
    labels = np.full((M, 2), UNLABELLED, np.int64)
    residual = np.full(M, np.nan)
    stats = {"components": 0, "components_labelled": 0, "ambiguous": 0, "out_of_pattern": 0,
             "out_of_depth_range": 0, "too_small": 0, "junctions_left_out": {}, "contradicting_edges": 0}
    left = {"ambiguous": 0, "no_admissible_offset": 0, "component_too_small": 0, "residual_too_large": 0}
    if M == 0:
        stats["junctions_left_out"] = left
        return Labels(labels, residual, np.zeros(0, np.int64), stats)
    rel, comp, removed = relative_labels(M, obs.edges, obs.edge_delta)
    stats["contradicting_edges"] = removed
    lines = epipolar_lines(model.procam, xy_cam)
    L = model.index_max - model.index_min + 1
    cap2 = options.residual_cap_px**2
    # Components, largest first.
    order = np.argsort(comp, kind="stable")
    bounds = np.flatnonzero(np.diff(np.concatenate([[-1], comp[order], [-2]])))
    groups = [order[bounds[k] : bounds[k + 1]] for k in range(len(bounds) - 1)]
    stats["components"] = len(groups)
    for members in groups:
        m = len(members)
        if m < options.min_component:
            left["component_too_small"] += m
            stats["too_small"] += 1
            continue
        a = rel[members]
        ln = lines[members]
        ok_line = np.isfinite(ln).all(axis=1)
        if not ok_line.any():
            left["no_admissible_offset"] += m
            continue
        # Admissible offsets keep every label inside the pattern.
        lo_i = model.index_min - a[:, 0].min()
        hi_i = model.index_max - a[:, 0].max()
        lo_j = model.index_min - a[:, 1].min()
        hi_j = model.index_max - a[:, 1].max()
        if lo_i > hi_i or lo_j > hi_j:
            left["no_admissible_offset"] += m
            stats["out_of_pattern"] += 1
            continue
        # Candidate offsets: pattern junctions near the epipolar lines of a few reference junctions.
        refs = np.flatnonzero(ok_line)
        refs = refs[np.linspace(0, len(refs) - 1, min(3, len(refs))).astype(int)]
        cands = set()
        xy_all = model.xy_junction.reshape(-1, 2)
        for r in refs:
            d = np.abs(xy_all @ ln[r, :2] + ln[r, 2]) * model.fx_proj
            near = np.flatnonzero(d <= options.candidate_band_px)
            I = near // L + model.index_min - a[r, 0]
            J = near % L + model.index_min - a[r, 1]
            inside = (I >= lo_i) & (I <= hi_i) & (J >= lo_j) & (J <= hi_j)
            cands.update(zip(I[inside].tolist(), J[inside].tolist()))
        if not cands:
            left["no_admissible_offset"] += m
            stats["out_of_pattern"] += 1
            continue
        off = np.array(sorted(cands), np.int64)  # (C, 2)
        ii = a[None, :, 0] + off[:, None, 0]
        jj = a[None, :, 1] + off[:, None, 1]
        res = _epipolar_residual_px(model, ln[None, ok_line], ii[:, ok_line], jj[:, ok_line])
        score = np.minimum(res * res, cap2).mean(axis=1)
        ranked = np.argsort(score)
        # Walk the ranking: the first two offsets that put the surface inside the working volume.
        passing = []
        for c in ranked[: min(len(ranked), 12)]:
            xy_p = model.junction_xy(ii[c], jj[c])
            p, _ = triangulate_rays(model.procam, xy_cam[members], xy_p)
            z = depth_cam(model.procam, p)
            inside = (z >= options.depth_min_mm) & (z <= options.depth_max_mm)
            if inside.mean() >= options.min_inside_fraction:
                passing.append(c)
                if len(passing) == 2:
                    break
            elif not passing:
                stats["out_of_depth_range"] += 1
        if not passing:
            left["no_admissible_offset"] += m
            continue
        best = passing[0]
        s1 = float(score[best])
        s2 = float(score[passing[1]]) if len(passing) > 1 else cap2
        n_eff = int(ok_line.sum())
        sigma2 = max(s1, options.noise_floor_px**2)
        if n_eff * (s2 - s1) / sigma2 < options.ambiguity_chi2:
            left["ambiguous"] += m
            stats["ambiguous"] += 1
            continue
        lab = np.column_stack([ii[best], jj[best]])
        r_full = _epipolar_residual_px(model, ln, lab[:, 0], lab[:, 1])
        good = np.isfinite(r_full) & (r_full <= options.max_residual_px)
        left["residual_too_large"] += int((~good).sum())
        labels[members[good]] = lab[good]
        residual[members[good]] = r_full[good]
        stats["components_labelled"] += 1
    stats["junctions_left_out"] = left
    return Labels(labels, residual, comp, stats)


def solve_base_point(m: np.ndarray, b: np.ndarray, h: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The paper's Eq. 5–7: base points (T, 2) of T triangles.

    m, b (T, 3): epipolar lines y = m·x + b of the three vertices; h, v (3,) or (T, 3): the vertices'
    offsets from the base point (Eq. 2). Minimises Σ d_k², d_k = (K_k + m_k·x0 − y0)/√(m_k²+1),
    K_k = b_k + m_k·h_k − v_k, via the normal equations
    [[a0, −a1], [−a1, a2]] (x0, y0) = (B0, B1), a0 = Σ m²D², a1 = Σ m D², a2 = Σ D², B0 = −Σ m K D²,
    B1 = Σ K D², D² = 1/(m²+1).
    """
    m = np.asarray(m, np.float64)
    b = np.asarray(b, np.float64)
    K = b + m * h - v
    D2 = 1.0 / (m * m + 1.0)
    a0 = (m * m * D2).sum(axis=-1)
    a1 = (m * D2).sum(axis=-1)
    a2 = D2.sum(axis=-1)
    B0 = -(m * K * D2).sum(axis=-1)
    B1 = (K * D2).sum(axis=-1)
    det = a0 * a2 - a1 * a1
    with np.errstate(divide="ignore", invalid="ignore"):
        x0 = (a2 * B0 + a1 * B1) / det
        y0 = (a1 * B0 + a0 * B1) / det
    return np.column_stack([x0, y0])


def find_triangles(obs: GridObservation) -> np.ndarray:
    """Triangles (T, 3) of junction ids p0 = (i, j), p1 = (i+1, j), p2 = (i+1, j+1) joined by segments:
    p0–p1 along the j-line j, p1–p2 along the i-line i+1."""
    e = obs.edges
    d = obs.edge_delta
    if len(e) == 0:
        return np.zeros((0, 3), np.int64)
    # Directed steps: +i along j-lines, +j along i-lines (both directions of each edge).
    src = np.concatenate([e[:, 0], e[:, 1]])
    dst = np.concatenate([e[:, 1], e[:, 0]])
    dd = np.concatenate([d, -d])
    step_i = {s: t for s, t, x in zip(src.tolist(), dst.tolist(), dd.tolist()) if x == [1, 0]}
    step_j = {s: t for s, t, x in zip(src.tolist(), dst.tolist(), dd.tolist()) if x == [0, 1]}
    tris = [(p0, p1, step_j[p1]) for p0, p1 in step_i.items() if p1 in step_j]
    return np.array(tris, np.int64).reshape(-1, 3)


def label_paper(obs: GridObservation, model: RigModel, xy_cam: np.ndarray) -> Labels:
    """The paper's labeller (module doc). Works in the paper's projector-plane coordinates: undistorted
    projector pixels relative to the pattern centre (X = f_x·x + c_x − c_u, Y = f_y·y + c_y − c_v)."""
    M = len(obs.q_junction)
    labels = np.full((M, 2), UNLABELLED, np.int64)
    residual = np.full(M, np.nan)
    tris = find_triangles(obs)
    stats = {"triangles": int(len(tris)), "junctions_left_out": {}, "vote_conflicts": 0}
    if M == 0 or len(tris) == 0:
        stats["junctions_left_out"] = {"not_in_a_triangle": M}
        return Labels(labels, residual, np.full(M, -1, np.int64), stats)
    pat = model.pattern
    proj = model.procam.projector
    m_n, b_n = paper_epipolar_mb(model.procam, xy_cam)
    ox = proj.cx - pat.centre_px[0]
    oy = proj.cy - pat.centre_px[1]
    m_px = m_n * proj.fy / proj.fx
    b_px = proj.fy * b_n - m_px * ox + oy
    p, n1, n2 = pat.pitch_px, pat.n1, pat.n2
    # Eq. 2 for (i, j), (i+1, j), (i+1, j+1): offsets of p1, p2 from p0.
    h = np.array([0.0, p / (n2 - n1), 0.0])
    v = np.array([0.0, n2 * p / (n2 - n1), p])
    base = solve_base_point(m_px[tris], b_px[tris], h, v)
    # Snap: nearest junction of the (uniform) grid whose triangle lies inside the pattern.
    fi = (base[:, 1] - n1 * base[:, 0]) / p
    fj = (base[:, 1] - n2 * base[:, 0]) / p
    best = np.full((len(tris), 2), UNLABELLED, np.int64)
    bestd = np.full(len(tris), np.inf)
    lo, hi = model.index_min, model.index_max - 1
    for di in (0, 1):
        for dj in (0, 1):
            I = np.clip(np.floor(fi) + di, lo, hi)
            J = np.clip(np.floor(fj) + dj, lo, hi)
            I = np.where(np.isfinite(I), I, lo).astype(np.int64)
            J = np.where(np.isfinite(J), J, lo).astype(np.int64)
            xy = pat.junction_xy(I, J)
            dist = np.hypot(xy[:, 0] - base[:, 0], xy[:, 1] - base[:, 1])
            better = dist < bestd
            best[better] = np.column_stack([I, J])[better]
            bestd[better] = dist[better]
    ok = np.isfinite(base).all(axis=1)
    # Votes: junction -> label counts.
    votes: dict[int, dict[tuple[int, int], int]] = {}
    for t, (I, J) in zip(np.flatnonzero(ok).tolist(), best[ok].tolist()):
        for k, (di, dj) in enumerate(((0, 0), (1, 0), (1, 1))):
            jid = int(tris[t, k])
            key = (I + di, J + dj)
            votes.setdefault(jid, {}).setdefault(key, 0)
            votes[jid][key] += 1
    for jid, vv in votes.items():
        if len(vv) > 1:
            stats["vote_conflicts"] += 1
        key = max(vv.items(), key=lambda kv: kv[1])[0]
        labels[jid] = key
    lab = labels[:, 0] != UNLABELLED
    lines = epipolar_lines(model.procam, xy_cam[lab])
    residual[lab] = _epipolar_residual_px(model, lines, labels[lab, 0], labels[lab, 1])
    stats["junctions_left_out"] = {"not_in_a_triangle": int((~lab).sum())}
    return Labels(labels, residual, np.full(M, -1, np.int64), stats)
