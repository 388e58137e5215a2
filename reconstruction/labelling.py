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

import math
from dataclasses import dataclass, field, replace
from functools import lru_cache

import cv2
import numpy as np
from scipy.spatial import cKDTree

from reconstruction import _ambiguity_kernels as _ak
from reconstruction import _epipolar_loop as _el
from reconstruction import _label_kernels as _k
from reconstruction.ambiguity_guard import Guard
from reconstruction.continuation import continue_lines, crossing_gap_px
from reconstruction.depth_range_labels import label_pieces as label_depth_range_pieces
from reconstruction.edge_cuts import edge_misfits
from reconstruction.extraction import GridObservation
from reconstruction.geometry import camera_rays_proj, epipolar_lines, paper_epipolar_mb
from reconstruction.piece_junctions import label_piece_junctions
from reconstruction.lone_crossings import LoneCrossingOptions, label_lone_crossings
from reconstruction.piece_seeds import seed_one_sided
from reconstruction.surface_labels import label_from_surface
from reconstruction.limb_lines import label_beside_lines
from reconstruction.residual_clusters import elevated_pieces, kept_adjacency
from reconstruction.rigmodel import UNLABELLED, RigModel
from reconstruction.seed_brightness import spread_checked_seeds
from reconstruction.trace_ends import cut_facing_ends, cut_far_ends

_NO_RIDGE = np.zeros(0, np.float32)  # spread_checked_seeds without the check (decision 0150)
# label_samples' seeds are int32 (decision 0150): the sentinel must be one
assert np.iinfo(np.int32).min <= UNLABELLED <= np.iinfo(np.int32).max


@dataclass(frozen=True)
class LabelOptions:
    """Options of the default labeller (docs/reconstruction.md, "Default labeller").

    depth_min_mm, depth_max_mm: working volume (camera-frame z); the pipeline sets them from its own options.
    min_inside_fraction: share of a component's junctions that must triangulate inside it for an offset to
        be admissible; afterwards every labelled junction must be inside it on its own.
    residual_cap_px: residuals are capped here in the offset score (robust to a few bad junctions).
    noise_floor_px: smallest junction noise (projector px RMS) the ambiguity test assumes: the epipolar error the
        calibration may leave (decision 0110; `rig` sets it from rig.toml or the calibration's stereo RMS).
    ambiguity_chi2: the best offset must beat the runner-up by M·(s2 − s1)/σ² ≥ this (log-likelihood ratio × 2).
    min_rms_ratio: and its RMS residual must be this many times smaller than the runner-up's (σ floored):
        systematic calibration error shifts every junction alike and is not noise.
    neighbour_noise: a component that fails that ratio is judged again with the independent part of its junctions'
        noise (half the mean squared difference of graph neighbours' signed residuals) taken out of both scores:
        noise that neighbours do not share averages away and is not the shared error the ratio guards against
        (decision 0122).
    frame_retry_limit: an ambiguous component is judged again on its best offset's inliers; their limit is at most
        max(outlier_sigma·σ̂_frame, max_residual_px), σ̂_frame the robust residual scale of the junctions the first
        round accepted: a component whose own scale is inflated by wrong relative labels (half its junctions a
        line off) would otherwise count every junction an inlier (decision 0123).
    cut_misfit_edges: where `skip_edges` reads an ambiguous component's edges, an edge whose residual jump no step
        along its own line explains is cut: it joins another line or surface (`edge_cuts`, decision 0130). The jump
        must exceed max(outlier_sigma·σ̂_Δ, max_residual_px) (σ̂_Δ = τ / skip_tol_sigma) for every k in
        1 … skip_max_steps, across the edge and between the local medians of its two ends' neighbourhoods; pieces
        it cuts off need min_split_component junctions. Needs `skip_edges`.
    skip_edges_accepted: `skip_edges` on the components the first round accepted too (decision 0146): an edge that
        skips missed crossings in an accepted component leaves a minority of its junctions a line off within the
        outlier limit (unseen seed 156); with the accepted offset its step is read as for an ambiguous component, and
        where one changes the component's labels are taken back and its pieces labelled again (0130's cuts are not
        made there). The jump tolerance τ is then computed on every frame with at least 20 accepted edges. Off: it
        re-steps right edges of accepted components on unseen 132, 126, 116 (decision 0146, measured, not merged).
    ill_posed_at_floor: the rig's labelling margin is judged "ill-posed" (the frame's warning, `rig check`) below
        min_rms_ratio × noise_floor_px, the runner-up miss this test needs (decision 0130); False: below the fixed
        0.1 px of decision 0004.
    candidate_band_px: offsets are proposed by pattern junctions this close to a reference junction's
        epipolar line. candidate_refs: how many reference junctions per component.
    outlier_sigma, max_residual_px: after the offset is chosen, a junction farther from its epipolar line
        than max(outlier_sigma·σ̂, max_residual_px) (σ̂: the component's robust residual scale) is an outlier:
        its edges are cut and what they joined is labelled again on its own (a bad edge joins two surfaces).
    min_split_component: pieces split off as outliers need this many junctions to be labelled again.
    max_split_rounds: how often a component may be split.
    min_component: components with fewer junctions are left out.
    lone_arm_floor: a component of one junction is judged with the smaller of its arms' fit RMS (camera px) as the
        noise floor of the ambiguity test as well (decision 0134): it cannot measure its own noise, and arms that
        depart from straight lines (aliased lines beside it, an acute crossing) bound how well its position is known.
    residual_clusters, cluster_factor, cluster_floor_px, cluster_min: a connected group of at least cluster_min
        junctions whose local median residual exceeds max(cluster_factor·σ̂, cluster_floor_px) is taken out like
        outliers, and of the rest the connected pieces no larger than that group are labelled again on their own
        (a part joined across a depth edge by a lattice vector that runs nearly along the epipolar lines;
        `residual_clusters`, decision 0108).
    compiled_loop: the per-component work loop (the choice, re-steps, inlier retry, clusters and splits) in one compiled
        call (`_epipolar_loop.work_loop`, decision 0161); False: the Python loop it reproduces bit for bit (the reference).
    """

    depth_min_mm: float = 100.0
    depth_max_mm: float = 10000.0
    min_inside_fraction: float = 0.9
    residual_cap_px: float = 1.0
    noise_floor_px: float = 0.1
    ambiguity_chi2: float = 25.0
    min_rms_ratio: float = 1.5
    neighbour_noise: bool = True
    frame_retry_limit: bool = True
    skip_edges: bool = True
    skip_edges_accepted: bool = False
    ill_posed_at_floor: bool = True
    cut_misfit_edges: bool = True
    skip_max_steps: int = 6
    skip_tol_sigma: float = 4.0
    candidate_band_px: float = 4.0
    candidate_refs: int = 5
    outlier_sigma: float = 6.0
    max_residual_px: float = 0.3
    min_split_component: int = 3
    max_split_rounds: int = 3
    min_component: int = 1
    lone_arm_floor: bool = True
    residual_clusters: bool = True
    cluster_factor: float = 3.0
    cluster_floor_px: float = 0.075
    cluster_min: int = 3
    compiled_loop: bool = True

    def __post_init__(self) -> None:
        # the ambiguity test divides by noise_floor_px² (compiled: a zero would give inf/NaN silently)
        for name in ("noise_floor_px", "residual_cap_px", "candidate_band_px", "max_residual_px", "cluster_factor", "cluster_floor_px"):
            if not getattr(self, name) > 0:
                raise ValueError(f"LabelOptions.{name} = {getattr(self, name)}: must be > 0")
        if not self.skip_max_steps >= 2 or not self.skip_tol_sigma > 0:
            raise ValueError(f"LabelOptions: skip_max_steps ({self.skip_max_steps}) must be >= 2 and skip_tol_sigma ({self.skip_tol_sigma}) > 0")
        if not self.cluster_min >= 1:
            raise ValueError(f"LabelOptions.cluster_min = {self.cluster_min}: must be >= 1")
        if not self.depth_max_mm > self.depth_min_mm:
            raise ValueError(f"LabelOptions: depth_max_mm ({self.depth_max_mm}) must be greater than depth_min_mm ({self.depth_min_mm})")


#: reasons a junction is left out by the default labeller (keys of stats["junctions_left_out"])
LEFT_OUT_REASONS = (
    "ambiguous",
    "no_admissible_offset",
    "component_too_small",
    "residual_too_large",
    "out_of_depth_range",
    "split_too_small",
)


@dataclass(frozen=True, eq=False)
class Labels:
    """labels (M, 2) int (i, j), UNLABELLED where none; residual (M,) epipolar distance of the label
    (projector px, NaN if unlabelled); component (M,) component id (−1: isolated); stats: counts."""

    labels: np.ndarray
    residual: np.ndarray
    component: np.ndarray
    stats: dict = field(default_factory=dict)
    ambiguous_best: np.ndarray | None = None  # (M, 2): junctions of components of at least 3 left out as ambiguous,
    # their labels under the component's best offset (UNLABELLED elsewhere; decision 0141's guard); None: not recorded
    ambiguous_labels: np.ndarray | None = None  # (M, 2): the same for components of any size (decision 0147's report)


def clean_edges(n_junctions: int, edges: np.ndarray, delta: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """Remove the edges that contradict the labels propagated along a spanning tree (twice).

    edges (E, 2) junction ids a → b; delta (E, 2) the (i, j) change from a to b. Every edge touching an
    endpoint of a contradicting edge is dropped (cheap and conservative). Returns the kept edges, their
    deltas and the number removed. Compiled (`_label_kernels.clean_edges`).
    """
    edges = np.asarray(edges, np.int64).reshape(-1, 2)
    delta = np.asarray(delta, np.int64).reshape(-1, 2)
    keep, removed = _k.clean_edges(int(n_junctions), *_edge_arrays(edges, delta), 2)
    return edges[keep], delta[keep], int(removed)


def relative_labels(n_junctions: int, edges: np.ndarray, delta: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """Integer labels relative to one root per connected component, from the graph edges.

    edges (E, 2) junction ids a → b; delta (E, 2) the (i, j) change from a to b. Edges that contradict
    the labels propagated along a spanning tree are removed first (`clean_edges`).
    Returns rel (M, 2), component (M,), number of contradicting edges removed.
    """
    edges, delta, removed = clean_edges(n_junctions, edges, delta)
    rel, comp = _propagate(n_junctions, edges, delta)
    return rel, comp, removed


def _edge_arrays(edges: np.ndarray, delta: np.ndarray):
    """a, b (E,) intp and the delta's columns (E,) int64, contiguous, for the graph kernels."""
    return (np.ascontiguousarray(edges[:, 0], np.intp), np.ascontiguousarray(edges[:, 1], np.intp),
            np.ascontiguousarray(delta[:, 0], np.int64), np.ascontiguousarray(delta[:, 1], np.int64))


def _propagate(n: int, edges: np.ndarray, delta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Labels relative to the lowest-numbered junction of each component, summed along a breadth-first
    spanning tree, and the component ids (numbered by their lowest junction). The tree is the one scipy's
    `breadth_first_order` builds (decision 0067); a compiled walk (`_label_kernels.propagate`)."""
    edges = np.asarray(edges, np.int64).reshape(-1, 2)
    delta = np.asarray(delta, np.int64).reshape(-1, 2)
    return _k.propagate(int(n), *_edge_arrays(edges, delta), np.ones(len(edges), np.bool_))


def _epipolar_residual_px(model: RigModel, lines: np.ndarray, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """|l · (x, y, 1)| in projector px for lines (..., 3) and labels (...) inside the pattern."""
    xy = model.xy_junction[i - model.index_min, j - model.index_min]
    return np.abs(lines[..., 0] * xy[..., 0] + lines[..., 1] * xy[..., 1] + lines[..., 2]) * model.fx_proj


def _groups(comp: np.ndarray) -> list[np.ndarray]:
    """Member index arrays of each component id in `comp` (ids in any order), by increasing id, members in
    increasing order. Ids ≥ 0 (as `_propagate` numbers them): a compiled counting sort (decision 0087)."""
    comp = np.asarray(comp)
    order, bounds = _k.group_order(np.ascontiguousarray(comp, np.int64)) if len(comp) else (comp, comp)
    if len(bounds) == 0:
        order = np.argsort(comp, kind="stable")
        bounds = np.flatnonzero(np.diff(np.concatenate([[-1], comp[order], [-2]])))
    return [order[bounds[k] : bounds[k + 1]] for k in range(len(bounds) - 1)]


def _group_bounds(comp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`_groups` as one array: order (M,) intp, the members of every group by increasing id, and bounds (G + 1,)
    intp, group g being order[bounds[g]:bounds[g + 1]] (the same groups in the same order)."""
    comp = np.asarray(comp)
    order, bounds = _k.group_order(np.ascontiguousarray(comp, np.int64)) if len(comp) else (np.zeros(0, np.intp), np.zeros(1, np.intp))
    if len(bounds) == 0:
        order = np.argsort(comp, kind="stable")
        bounds = np.flatnonzero(np.diff(np.concatenate([[-1], comp[order], [-2]])))
    return order, bounds


@dataclass
class _Choice:
    """The outcome of scoring one component's offsets."""

    reason: str | None  # None: accepted; else a LEFT_OUT_REASONS key
    labels: np.ndarray | None = None  # (m, 2)
    residual: np.ndarray | None = None  # (m,) projector px
    inside: np.ndarray | None = None  # (m,) bool, inside the depth range
    rms: tuple[float, float] = (float("nan"), float("nan"))  # best, runner-up
    limit: float | None = None  # the outlier limit, when the inlier retry decided (decision 0123)


def _choose_offset(
    model: RigModel, rel: np.ndarray, ln: np.ndarray, xy_cam: np.ndarray, options: LabelOptions, stats: dict, *, _inlier_retry: bool = True,
    members: np.ndarray | None = None, graph: _Graph | None = None, retry_limit_px: float = math.inf, restep=None,
) -> _Choice:
    """Score every admissible integer offset of one component (relative labels rel (m, 2), epipolar lines
    ln (m, 3), normalised camera points xy_cam (m, 2)) and apply the range and ambiguity tests. members (m,) the
    component's junction ids and graph `_Graph` (the kept edges), both or neither: for the noise split of
    decision 0122 (`_choice_of`); retry_limit_px: the inlier retry's limit at most this (decision 0123); restep: see
    `_choice_of`."""
    rel = np.ascontiguousarray(rel, np.int64)
    ln = np.ascontiguousarray(ln, np.float64)
    xy_cam = np.ascontiguousarray(xy_cam, np.float64)
    cap2 = options.residual_cap_px**2
    # Candidate offsets (pattern junctions near the epipolar lines of a few reference junctions), the
    # admissible ones (labels nearly all inside the pattern; the few outside, shifted by a bad edge, become
    # outliers below) and their scores (`_label_kernels.offset_scores`); the walk down the ranking (its 16
    # best) until two offsets put the surface inside the working volume (`offset_depth_walk`, decision 0078;
    # formerly chunks of 4 through `offset_points` and NumPy's `depth_cam`, with the same results); the best
    # one's residuals (`offset_residuals`): one compiled call (`offset_choice`, decision 0087), with the candidate
    # scan by blocks of the pattern's junctions (`offset_choice_b`, as `offset_choice_groups`; decisions 0124, 0127).
    status, n_fail, ok, s1, s2, n_eff, off_best, r_full, inside = _k.offset_choice_b(
        rel, ln, xy_cam, model.xy_junction, _junction_blocks(model.xy_junction), _k._BLOCK, int(model.index_min), int(model.index_max),
        float(model.fx_proj),
        int(options.candidate_refs), float(options.candidate_band_px), float(options.min_inside_fraction), float(cap2),
        model.procam.R_proj_cam, model.procam.t_proj_cam, float(options.depth_min_mm), float(options.depth_max_mm))
    return _choice_of(model, rel, ln, xy_cam, options, stats, _inlier_retry, status, n_fail, ok, s1, s2, n_eff, off_best, r_full, inside,
                      members=members, graph=graph, retry_limit_px=retry_limit_px, restep=restep)


_BLOCKS: dict = {}  # id(xy_junction) -> (xy_junction, its blocks)


def _junction_blocks(xy_junction: np.ndarray) -> np.ndarray:
    """`_label_kernels.junction_blocks(xy_junction, _BLOCK)`, kept per pattern table (a rig model's `xy_junction`,
    read-only) so that `_choose_offset` does not bound the blocks again on every call."""
    hit = _BLOCKS.get(id(xy_junction))
    if hit is None or hit[0] is not xy_junction:
        if len(_BLOCKS) >= 16:
            _BLOCKS.clear()
        hit = _BLOCKS[id(xy_junction)] = (xy_junction, _k.junction_blocks(xy_junction, _k._BLOCK))
    return hit[1]


class _Graph:
    """The kept edges' adjacency (`residual_clusters.kept_adjacency`), built on first use, and a work array pos
    (M,) intp all −1, for `_ambiguity_kernels.neighbour_noise2`."""

    def __init__(self, n: int, a: np.ndarray, b: np.ndarray, keep: np.ndarray):
        self._args = (int(n), a, b, keep)
        self._adj = None

    def adjacency(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        if self._adj is None:
            n = self._args[0]
            self._adj = (*kept_adjacency(*self._args), np.full(n, -1, np.intp))
        return self._adj


def _shared_error_test(model, rel, ln, off_best, s1, s2, n_eff, options, members, graph) -> bool:
    """Decision 0122: the ambiguity test with the independent junction noise σn² (`neighbour_noise2` under the
    best offset) taken out of both scores for the ratio condition: s2 − σn² ≥ min_rms_ratio²·max(s1 − σn², σ0²);
    the likelihood condition M·(s2 − s1)/max(s1, σ0²) ≥ ambiguity_chi2 unchanged. False without the graph."""
    if graph is None or members is None or rel is None or not options.neighbour_noise:
        return False
    sigma2 = max(s1, options.noise_floor_px**2)
    if n_eff * (s2 - s1) / sigma2 < options.ambiguity_chi2:
        return False
    start, nbr, pos = graph.adjacency()
    noise2, n_edges = _ak.neighbour_noise2(np.ascontiguousarray(members, np.intp), np.ascontiguousarray(rel, np.int64),
                                           int(off_best[0]), int(off_best[1]), np.ascontiguousarray(ln, np.float64), model.xy_junction,
                                           int(model.index_min), int(model.index_max), float(model.fx_proj), start, nbr, pos,
                                           float(options.residual_cap_px**2))
    if n_edges == 0 or not math.isfinite(noise2):
        return False
    return s2 - noise2 >= options.min_rms_ratio**2 * max(s1 - noise2, options.noise_floor_px**2)


def _choice_of(model, rel, ln, xy_cam, options, stats, _inlier_retry, status, n_fail, ok, s1, s2, n_eff, off_best, r_full, inside,
               limit=None, members=None, graph=None, retry_limit_px=math.inf, restep=None) -> _Choice:
    """`_choose_offset`'s tests on `offset_choice`'s results (limit: `_outlier_limit(r_full)` when known; members,
    graph, retry_limit_px: see `_choose_offset`). restep: called with the best offset (2,) when the component fails
    the ambiguity test, before the inlier retry; True means its edges changed (decision 0125): the outcome is then
    "restepped" and the caller labels it again."""
    if status != 0:
        if status >= 2:
            stats["out_of_pattern"] += 1
        return _Choice("no_admissible_offset")
    stats["out_of_depth_range"] += int(n_fail)
    if not ok:
        return _Choice("no_admissible_offset")
    s1 = float(s1)
    s2 = float(s2)
    sigma2 = max(s1, options.noise_floor_px**2)
    rms = (math.sqrt(s1), math.sqrt(s2))
    lab = rel + off_best
    if (n_eff * (s2 - s1) / sigma2 < options.ambiguity_chi2 or s2 < options.min_rms_ratio**2 * sigma2) and _shared_error_test(
            model, rel, ln, off_best, s1, s2, n_eff, options, members, graph):
        stats["ambiguity_noise_split"] = stats.get("ambiguity_noise_split", 0) + 1
    elif n_eff * (s2 - s1) / sigma2 < options.ambiguity_chi2 or s2 < options.min_rms_ratio**2 * sigma2:
        # A component that mixes two surfaces (a bad edge) looks ambiguous as a whole: each offset fits one
        # part. Judge the best offset on its own inliers; if it wins there, the rest is split off later. First, edges
        # that skip missed crossings take the steps the epipolar geometry names under the best offset (decision 0125).
        if restep is not None and restep(np.asarray(off_best)):
            return _Choice("restepped")
        lim = min(_outlier_limit(r_full, options) if limit is None else limit, retry_limit_px)
        inl = np.isfinite(r_full) & (r_full <= lim)
        if not _inlier_retry or inl.all() or inl.sum() < options.min_split_component:
            return _Choice("ambiguous", lab, rms=rms)  # the best offset's labels: decision 0141's guard reads them
        sub = _choose_offset(model, rel[inl], ln[inl], xy_cam[inl], options, stats, _inlier_retry=False,
                             members=None if members is None else members[inl], graph=graph)
        if sub.reason is not None or not np.array_equal(sub.labels[0] - rel[inl][0], lab[0] - rel[0]):
            return _Choice("ambiguous", lab, rms=rms)
        return _Choice(None, lab, r_full, inside, rms, limit=lim)  # the inliers' limit: the same unless tightened
    return _Choice(None, lab, r_full, inside, rms)


def _frame_retry_limit(residual: np.ndarray, options: LabelOptions, *, min_junctions: int = 20) -> float:
    """Decision 0123: `_outlier_limit` of the residuals (M,) (projector px, NaN where none) of the junctions the first
    round accepted: the frame's own junction noise, which a component with many wrong relative labels cannot
    inflate. inf when switched off or with fewer than min_junctions accepted junctions."""
    if not options.frame_retry_limit or int(np.isfinite(residual).sum()) < min_junctions:
        return math.inf
    return _outlier_limit(residual, options)


def _edge_jump_tol(model: RigModel, lines: np.ndarray, labels: np.ndarray, comp: np.ndarray, a: np.ndarray, b: np.ndarray,
                   keep: np.ndarray, options: LabelOptions, *, min_edges: int = 20) -> float:
    """Decision 0125: skip_tol_sigma·σ̂_Δ, σ̂_Δ = 1.4826·median |r_b − r_a| over the kept edges a → b (a, b (E,) junction
    ids, keep (E,) bool) whose ends are labelled in one component (labels (M, 2), comp (M,)), r the signed epipolar
    residual of the label (projector px; lines (M, 3)); compiled (`_ambiguity_kernels.edge_jump_median`). inf with
    fewer than min_edges such edges (the re-step is off)."""
    med, n = _ak.edge_jump_median(a, b, keep, np.ascontiguousarray(comp, np.int64), labels, lines, model.xy_junction,
                                  int(model.index_min), float(model.fx_proj), UNLABELLED)
    if n < min_edges:
        return math.inf
    return options.skip_tol_sigma * 1.4826 * float(med)


def _lone_arm_floor(obs, order, bounds, g_written, g_s1, g_s2, g_neff, labels, residual, options: LabelOptions) -> np.ndarray | None:
    """Decision 0134: a first-round component of one junction (no edge) that the compiled call accepted is judged
    again with σ² = max(s1, noise_floor_px², ρ²), ρ the smaller of its two arms' fit RMS (obs.junction_rms, camera px):
    a lone junction cannot measure its own noise, and arms that depart from straight lines (unresolved or aliased
    lines beside it, an acute crossing) bound how well its position is known. Those that fail the ambiguity test
    with it are unwritten (labels, residual cleared in place); not those whose runner-up is at the residual cap (the
    capped score cannot weigh a margin beyond it). Returns (G,) bool, the groups unwritten, or None."""
    rms = getattr(obs, "junction_rms", None)
    if not options.lone_arm_floor or rms is None or len(rms) != len(order) or len(bounds) < 2:
        return None
    sizes = np.diff(bounds)
    # a runner-up at the residual cap (≥ residual_cap_px off its epipolar line) is beyond what the capped scores can
    # weigh against ρ: those stay as the compiled call judged them
    g = np.flatnonzero((sizes == 1) & g_written.astype(np.bool_) & (np.asarray(g_s2, np.float64) < options.residual_cap_px**2))
    if len(g) == 0:
        return None
    k = order[bounds[g]]
    rho = np.min(np.asarray(rms, np.float64)[k], axis=1)
    s1 = np.asarray(g_s1, np.float64)[g]
    s2 = np.asarray(g_s2, np.float64)[g]
    n_eff = np.asarray(g_neff, np.float64)[g]
    sigma2 = np.maximum(np.maximum(s1, options.noise_floor_px**2), np.where(np.isfinite(rho), rho, 0.0) ** 2)
    fail = (n_eff * (s2 - s1) / sigma2 < options.ambiguity_chi2) | (s2 < options.min_rms_ratio**2 * sigma2)
    if not fail.any():
        return None
    out = np.zeros(len(bounds) - 1, np.bool_)
    out[g[fail]] = True
    labels[k[fail]] = UNLABELLED
    residual[k[fail]] = np.nan
    return out


def _outlier_limit(r: np.ndarray, options: LabelOptions) -> float:
    """max(outlier_sigma·σ̂, max_residual_px), σ̂ = 1.4826·median|r| (half-normal: median |r| = 0.674 σ)."""
    med = float(_k.median_finite(np.ascontiguousarray(r, np.float64)))
    sigma_hat = 1.4826 * med if np.isfinite(med) else np.inf
    return max(options.outlier_sigma * sigma_hat, options.max_residual_px)


# `_epipolar_loop.work_loop`'s counts: (stats key, index), always present / present when not zero (as the Python loop adds them)
_LOOP_STATS = (("components_labelled", _el.S_LABELLED), ("ambiguous", _el.S_AMBIGUOUS), ("out_of_pattern", _el.S_OUT_OF_PATTERN),
               ("out_of_depth_range", _el.S_OUT_OF_DEPTH), ("too_small", _el.S_TOO_SMALL), ("components_split", _el.S_SPLIT),
               ("junctions_residual_clusters", _el.S_CLUSTERS))
_LOOP_STATS_WHEN_ANY = (("edges_restepped", _el.S_EDGES_RESTEPPED), ("components_restepped", _el.S_COMPONENTS_RESTEPPED),
                        ("components_restepped_accepted", _el.S_RESTEPPED_ACCEPTED), ("ambiguity_noise_split", _el.S_NOISE_SPLIT),
                        ("edges_cut", _el.S_EDGES_CUT))
assert LEFT_OUT_REASONS == ("ambiguous", "no_admissible_offset", "component_too_small", "residual_too_large", "out_of_depth_range",
                            "split_too_small")  # _epipolar_loop's L_* order


def label_epipolar(obs: GridObservation, model: RigModel, xy_cam: np.ndarray, *, options: LabelOptions = LabelOptions()) -> Labels:
    """The default labeller: one offset per connected component, split at outliers (module doc).

    xy_cam: (M, 2) normalised camera coordinates of obs.q_junction. stats["junctions_left_out"] counts the
    junctions left out by reason (LEFT_OUT_REASONS); stats["components_split"] the components cut at
    outlier junctions; stats["ambiguity_noise_split"] (when any) the components accepted by decision 0122's test;
    stats["edges_restepped"] and stats["components_restepped"] (when any) the edges given another step and the components
    labelled again for it (decision 0125).

    Speed (decisions 0067, 0078, 0087): the graph walk (`clean_edges`, `_propagate`), the components' groups,
    each component's candidate offsets, scores, depth walk and residuals (`offset_choice`: one call) and the
    inliers' writes are compiled; per component Python applies the ambiguity and split tests.
    """
    M = len(obs.q_junction)
    labels = np.full((M, 2), UNLABELLED, np.int64)
    amb_best = np.full((M, 2), UNLABELLED, np.int64)  # ambiguous components' best-offset labels (decision 0141)
    amb_all = np.full((M, 2), UNLABELLED, np.int64)  # the same for every size (decision 0147's report)
    residual = np.full(M, np.nan)
    stats = {"components": 0, "components_labelled": 0, "ambiguous": 0, "out_of_pattern": 0, "out_of_depth_range": 0,
             "too_small": 0, "components_split": 0, "contradicting_edges": 0, "junctions_left_out": {}}
    left = dict.fromkeys(LEFT_OUT_REASONS, 0)
    if M == 0:
        stats["junctions_left_out"] = left
        return Labels(labels, residual, np.zeros(0, np.int64), stats)
    # `clean_edges` then `_propagate` on the kept edges, with the edge arrays made once: the walk takes the kept
    # edges in their order (`propagate`'s keep), as it took the filtered copy (decision 0096)
    edges_all = np.asarray(obs.edges, np.int64).reshape(-1, 2)
    delta_all = obs_delta = np.asarray(obs.edge_delta, np.int64).reshape(-1, 2)
    e_arrays = _edge_arrays(edges_all, delta_all)
    keep, removed, rel, comp = _k.clean_edges_walk(int(M), *e_arrays, 2)  # the walk on the kept edges (decision 0158)
    stats["contradicting_edges"] = int(removed)
    edges = delta = None  # the kept edges, made when a component is split
    # `epipolar_lines`, its cross product and scaling compiled (decision 0094)
    lines = _k.epipolar_from_rays(camera_rays_proj(model.procam, xy_cam), model.t_proj_cam_c)
    component = comp.copy()
    next_id = int(comp.max()) + 1 if M else 0
    groups = _group_bounds(comp)
    stats["components"] = len(groups[1]) - 1
    # The first round's offsets of every component in one compiled call (decision 0096): the same gathers and
    # `offset_choice` per component as `_choose_offset`, the accepted ones' outlier limits, and the components
    # that pass the ambiguity test written as `write_component` writes them (labels are written only to a
    # component's own members, so the order of the writes does not matter).
    order, bounds = groups
    g_status, g_fail, g_ok, g_s1, g_s2, g_neff, g_off, g_limit, g_r, g_in, g_written, g_bad, g_nbad = _k.offset_choice_groups(
        order, bounds, int(options.min_component), rel, lines, np.ascontiguousarray(xy_cam, np.float64), model.xy_junction,
        int(model.index_min), int(model.index_max), float(model.fx_proj), int(options.candidate_refs),
        float(options.candidate_band_px), float(options.min_inside_fraction), float(options.residual_cap_px**2),
        model.procam.R_proj_cam, model.procam.t_proj_cam, float(options.depth_min_mm), float(options.depth_max_mm),
        float(options.outlier_sigma), float(options.max_residual_px), float(options.noise_floor_px**2),
        float(options.ambiguity_chi2), float(options.min_rms_ratio**2), labels, residual)
    lone_rejected = _lone_arm_floor(obs, order, bounds, g_written, g_s1, g_s2, g_neff, labels, residual, options)  # decision 0134
    graph = _Graph(int(M), e_arrays[0], e_arrays[1], keep)  # the kept edges, for decision 0122's noise split
    retry_limit = _frame_retry_limit(residual, options)  # decision 0123
    # Groups of junctions off their epipolar lines together (decision 0108): taken out like outliers.
    clusters = None
    stats["junctions_residual_clusters"] = 0
    if options.residual_clusters:
        adj: list = []
        pos = np.full(M, -1, np.intp)

        def _clusters(members, bad, n_bad):
            if not adj:
                adj.extend(graph.adjacency()[:2])
            out, added = elevated_pieces(members, residual, bad, adj[0], adj[1], pos, float(options.cluster_factor),
                                         float(options.cluster_floor_px), int(options.cluster_min))
            if added == 0:
                return bad, n_bad
            newly = members[out & ~bad]
            labels[newly] = UNLABELLED
            residual[newly] = np.nan
            stats["junctions_residual_clusters"] += int(added)
            return out, n_bad + int(added)

        clusters = _clusters

    # Edges that skip crossings (decision 0125): the tolerance of the residual jump across an edge, from the kept
    # edges of the components the first round wrote; only when a component may come out ambiguous.
    skip_tol = math.inf
    if options.skip_edges and (options.skip_edges_accepted or bool((g_ok.astype(np.bool_) & ~g_written.astype(np.bool_)).any())):
        skip_tol = _edge_jump_tol(model, lines, labels, comp, e_arrays[0], e_arrays[1], keep, options)

    restep_pos = np.full(M, -1, np.intp)  # `component_edge_steps`' work space

    def _restep(members, off, cut_ok=True):
        """Decision 0125: give the component's edges the steps the epipolar geometry names under offset off, and cut
        those no step explains (decision 0130); (the re-propagated pieces, whether an edge was cut), or None when no
        edge changes."""
        nonlocal delta_all, edges
        # the component's kept edges, their ends' positions and their steps: one compiled call (decision 0127)
        off = np.asarray(off, np.int64)
        sel, pa, pb, k = _ak.component_edge_steps(np.ascontiguousarray(members, np.intp), restep_pos, keep, edges_all, delta_all, rel,
                                                  int(off[0]), int(off[1]), lines, model.xy_junction, int(model.index_min),
                                                  int(model.index_max), float(model.fx_proj), int(options.skip_max_steps), float(skip_tol))
        if len(sel) == 0:
            return None
        changed = k != 1
        # edges no step along their line explains: cut (decision 0130)
        cut = np.zeros(len(sel), np.bool_)
        if options.cut_misfit_edges and cut_ok:
            start, nbr, pos = graph.adjacency()
            # the jump must be an outlier as a junction's residual is (decision 0044's max(6σ̂, 0.3 px), with the
            # frame's neighbour scale σ̂_Δ = τ / skip_tol_sigma), and no step along the line may fit within it
            cut_tol = max(options.outlier_sigma / options.skip_tol_sigma * float(skip_tol), options.max_residual_px)
            step_args = (pa, pb, np.ascontiguousarray(delta_all[sel, 0]), np.ascontiguousarray(delta_all[sel, 1]),
                         np.ascontiguousarray(rel[members] + off), np.ascontiguousarray(lines[members]), model.xy_junction,
                         int(model.index_min), int(model.index_max), float(model.fx_proj), int(options.skip_max_steps))
            cut = edge_misfits(*step_args, float(cut_tol), np.ascontiguousarray(members, np.intp), start, nbr, pos) & ~changed
        any_changed = bool(changed.any())
        if not any_changed and not cut.any():
            return None
        sub_e = np.column_stack([pa, pb])  # (made only past the return above: decision 0158)
        if any_changed:
            if delta_all is obs_delta:
                delta_all = delta_all.copy()
            delta_all[sel[changed]] *= k[changed, None]
            stats["edges_restepped"] = stats.get("edges_restepped", 0) + int(changed.sum())
        edges = None  # the split's kept edges are made again with the new steps and without the cut edges
        if cut.any():
            stats["edges_cut"] = stats.get("edges_cut", 0) + int(cut.sum())
            keep[sel[cut]] = False
            sel, sub_e = sel[~cut], sub_e[~cut]
        sub_arrays = _edge_arrays(sub_e, delta_all[sel])
        keep_s, _, sub_rel, sub_comp = _k.clean_edges_walk(len(members), *sub_arrays, 2)
        keep[sel[~keep_s]] = False
        rel[members] = sub_rel
        return [members[p] for p in _groups(sub_comp)], bool(cut.any())

    if options.compiled_loop:
        # the work loop below in one compiled call (decision 0161): the same steps, kernels and outputs
        st, lf, next_id = _el.work_loop(
            order, bounds, g_status, g_fail, g_ok, g_s1, g_s2, g_neff, g_off, g_limit, g_r, g_in, g_written, g_bad, g_nbad,
            lone_rejected if lone_rejected is not None else np.zeros(0, np.bool_), lone_rejected is not None, rel, lines,
            np.ascontiguousarray(xy_cam, np.float64), model.xy_junction, _junction_blocks(model.xy_junction), _k._BLOCK,
            int(model.index_min), int(model.index_max), float(model.fx_proj), int(options.candidate_refs),
            float(options.candidate_band_px), float(options.min_inside_fraction), float(options.residual_cap_px**2),
            model.procam.R_proj_cam, model.procam.t_proj_cam, float(options.depth_min_mm), float(options.depth_max_mm), keep,
            np.ascontiguousarray(edges_all), delta_all.copy(), e_arrays[0], e_arrays[1], labels, residual, amb_best, amb_all,
            component, next_id, float(skip_tol), float(retry_limit), int(options.min_component), int(options.min_split_component),
            int(options.max_split_rounds), float(options.outlier_sigma), float(options.max_residual_px), float(options.noise_floor_px**2),
            float(options.ambiguity_chi2), float(options.min_rms_ratio**2), bool(options.neighbour_noise), bool(options.skip_edges_accepted),
            bool(options.cut_misfit_edges), int(options.skip_max_steps), float(options.skip_tol_sigma), bool(options.residual_clusters),
            float(options.cluster_factor), float(options.cluster_floor_px), int(options.cluster_min), int(UNLABELLED))
        for key, k in _LOOP_STATS:
            stats[key] += int(st[k])
        for key, k in _LOOP_STATS_WHEN_ANY:
            if st[k] > 0:
                stats[key] = int(st[k])
        for k, reason in enumerate(LEFT_OUT_REASONS):
            left[reason] += int(lf[k])
        stats["junctions_left_out"] = left
        return Labels(labels, residual, component, stats, amb_best, amb_all)

    # The reference (LabelOptions.compiled_loop=False). Work list: (members, split round, first-round group or −1, edges may
    # be re-stepped). Pieces split off are relabelled on their own.
    work = [(order[bounds[g] : bounds[g + 1]], 0, g, True) for g in range(len(bounds) - 1)]
    while work:
        members, rounds, g, may_restep = work.pop()
        m = len(members)
        if rounds == 0 and m < options.min_component:
            left["component_too_small"] += m
            stats["too_small"] += 1
            continue
        if rounds > 0 and m < options.min_split_component:
            left["split_too_small"] += m
            continue
        limit = None
        pieces_box: list = []
        restep = None
        if may_restep and math.isfinite(skip_tol):
            def _restep_component(off, members=members, pieces_box=pieces_box):
                out = _restep(members, off)
                if out is not None:
                    pieces_box.append(out)
                return out is not None

            restep = _restep_component
        if g >= 0 and lone_rejected is not None and lone_rejected[g]:
            # a lone junction whose arms' fit leaves its position too uncertain for its margin (decision 0134)
            left["ambiguous"] += m
            stats["ambiguous"] += 1
            continue
        if (g >= 0 and g_written[g] and options.skip_edges_accepted and restep is not None
                and (out_acc := _restep(members, np.asarray(g_off[g]), cut_ok=False)) is not None):
            # an accepted component with edges that skip missed crossings under its offset (decision 0146: decision
            # 0125's re-step on accepted components, without 0130's cuts): its labels are taken back and the pieces
            # labelled again with the new steps
            labels[members] = UNLABELLED
            residual[members] = np.nan
            stats["components_restepped"] = stats.get("components_restepped", 0) + 1
            stats["components_restepped_accepted"] = stats.get("components_restepped_accepted", 0) + 1
            pieces, _ = out_acc
            for p in pieces:
                component[p] = next_id
                next_id += 1
                work.append((p, rounds, -1, False))
            continue
        if g >= 0 and g_written[g]:
            # accepted and written in the compiled call (`_choice_of`'s path without the retry)
            stats["out_of_depth_range"] += int(g_fail[g])
            stats["components_labelled"] += 1
            n_bad = int(g_nbad[g])
            b0, b1 = bounds[g], bounds[g + 1]
            bad, inside_m = g_bad[b0:b1], g_in[b0:b1]
            if clusters is not None and m >= 2 * options.cluster_min:
                bad, n_bad = clusters(members, bad, n_bad)
            if n_bad == 0:
                continue
        elif g >= 0:
            b0, b1 = bounds[g], bounds[g + 1]
            ok_g = bool(g_ok[g])
            ch = _choice_of(model, rel[members] if ok_g else None, lines[members] if ok_g else None, xy_cam[members] if ok_g else None,
                            options, stats, True, int(g_status[g]), g_fail[g], ok_g, g_s1[g], g_s2[g], int(g_neff[g]),
                            g_off[g], g_r[b0:b1] if ok_g else None, g_in[b0:b1] if ok_g else None, g_limit[g], members=members, graph=graph,
                            retry_limit_px=retry_limit, restep=restep)
            limit = float(g_limit[g])
        else:
            ch = _choose_offset(model, rel[members], lines[members], xy_cam[members], options, stats, members=members, graph=graph,
                                retry_limit_px=retry_limit, restep=restep)
        if not (g >= 0 and g_written[g]):
            if ch.reason == "restepped":
                # labelled again with the new steps (once): pieces the re-propagation separates on their own
                stats["components_restepped"] = stats.get("components_restepped", 0) + 1
                pieces, any_cut = pieces_box[0]
                for p in pieces:
                    if any_cut and len(p) < options.min_split_component:
                        # cut off by edges no step explains (decision 0130): a split piece, as outliers' are
                        left["split_too_small"] += len(p)
                        continue
                    component[p] = next_id
                    next_id += 1
                    work.append((p, rounds, -1, False))
                continue
            if ch.reason is not None:
                left[ch.reason] += m
                if ch.reason == "ambiguous":
                    stats["ambiguous"] += 1
                    if ch.labels is not None:
                        amb_all[members] = ch.labels  # decision 0147
                    if ch.labels is not None and m >= options.min_split_component:
                        amb_best[members] = ch.labels  # decision 0141
                continue
            r = ch.residual
            # the inliers (finite residual within the outlier limit, inside the depth range) take their labels:
            # one compiled pass (decision 0087)
            if ch.limit is not None:
                limit = ch.limit if limit is None else min(limit, ch.limit)
            bad, n_bad = _k.write_component(members, ch.labels, r, ch.inside, float(_outlier_limit(r, options)) if limit is None else limit,
                                            labels, residual)
            inside_m = ch.inside
            stats["components_labelled"] += 1
            if clusters is not None and m >= 2 * options.cluster_min:
                bad, n_bad = clusters(members, bad, n_bad)
            if n_bad == 0:
                continue
        # Outliers: cut their edges to the inliers; what they hold together is labelled again on its own.
        outl = members[bad]
        if rounds >= options.max_split_rounds:
            left["residual_too_large"] += int((bad & inside_m).sum())
            left["out_of_depth_range"] += int((bad & ~inside_m).sum())
            continue
        stats["components_split"] += 1
        if edges is None:
            edges, delta = edges_all[keep], delta_all[keep]
        # edges between two outliers, renumbered by the outliers' sorted order (a lookup table, not np.isin)
        srt = np.sort(outl)
        pos_of = np.full(M, -1, np.intp)
        pos_of[srt] = np.arange(len(srt))
        sel = (pos_of[edges[:, 0]] >= 0) & (pos_of[edges[:, 1]] >= 0)
        sub_e = pos_of[edges[sel]].reshape(-1, 2)
        outl = srt
        sub_rel, sub_comp = _propagate(len(outl), sub_e, delta[sel])
        rel[outl] = sub_rel
        for g in _groups(sub_comp):
            component[outl[g]] = next_id
            next_id += 1
            work.append((outl[g], rounds + 1, -1, True))
    stats["junctions_left_out"] = left
    return Labels(labels, residual, component, stats, amb_best, amb_all)


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


def triangle_shape(pattern, gap_i: float, gap_j: float) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 2 generalised: offsets h, v (3,) of the vertices (i, j), (i+1, j), (i+1, j+1) from the base
    vertex, when line i+1 is gap_i after line i and line j+1 gap_j after line j (projector px). For the
    uniform grid (gap_i = gap_j = p) this is the paper's h = (0, p/(n2−n1), 0), v = (0, n2·p/(n2−n1), p)."""
    n1, n2 = pattern.n1, pattern.n2
    d = n2 - n1
    h = np.array([0.0, gap_i / d, (gap_i - gap_j) / d])
    v = np.array([0.0, n2 * gap_i / d, (n2 * gap_i - n1 * gap_j) / d])
    return h, v


def _paper_uniform(pat, model: RigModel, m: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The paper's base point and snap on the uniform grid: base points (T, 2) and labels (T, 2)."""
    p, n1, n2 = pat.pitch_px, pat.n1, pat.n2
    h, v = triangle_shape(pat, p, p)
    base = solve_base_point(m, b, h, v)
    # Snap: nearest junction of the (uniform) grid whose triangle lies inside the pattern.
    with np.errstate(invalid="ignore"):
        fi = (base[:, 1] - n1 * base[:, 0]) / p
        fj = (base[:, 1] - n2 * base[:, 0]) / p
    best = np.full((len(m), 2), UNLABELLED, np.int64)
    bestd = np.full(len(m), np.inf)
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
    return base, best


def _paper_general(pat, model: RigModel, m: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The paper's method on a grid whose spacings vary (De Bruijn): the triangle's shape depends on the
    two gaps after its base lines, so the 2×2 system is solved once per distinct shape, each base point
    is snapped to the nearest base junction of a triangle of that shape, and the nearest snap over all
    shapes wins. Returns base points (T, 2) of the winning shape and labels (T, 2)."""
    idx = pat.indices
    gi = np.round(np.diff(pat.offsets_px(1)), 6)
    gj = np.round(np.diff(pat.offsets_px(2)), 6)
    T = len(m)
    best = np.full((T, 2), UNLABELLED, np.int64)
    bestd = np.full(T, np.inf)
    base_best = np.full((T, 2), np.nan)
    for a in np.unique(gi).tolist():
        for c in np.unique(gj).tolist():
            I = idx[:-1][gi == a]
            J = idx[:-1][gj == c]
            if len(I) == 0 or len(J) == 0:
                continue
            II, JJ = np.meshgrid(I, J, indexing="ij")
            xy = pat.junction_xy(II.ravel(), JJ.ravel())
            h, v = triangle_shape(pat, a, c)
            base = solve_base_point(m, b, h, v)
            ok = np.isfinite(base).all(axis=1)
            if not ok.any():
                continue
            dist, k = cKDTree(xy).query(base[ok])
            rows = np.flatnonzero(ok)
            better = dist < bestd[rows]
            r = rows[better]
            best[r, 0] = II.ravel()[k[better]]
            best[r, 1] = JJ.ravel()[k[better]]
            bestd[r] = dist[better]
            base_best[r] = base[r]
    return base_best, best


def label_paper(obs: GridObservation, model: RigModel, xy_cam: np.ndarray) -> Labels:
    """The paper's labeller (module doc). Works in the paper's projector-plane coordinates: undistorted
    projector pixels relative to the pattern centre (X = f_x·x + c_x − c_u, Y = f_y·y + c_y − c_v).
    With De Bruijn spacing the triangle's shape (Eq. 2) depends on its gaps: one 2×2 solve per shape, the
    nearest snap over all shapes wins (`_paper_general`)."""
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
    if pat.spacing == "uniform":
        base, best = _paper_uniform(pat, model, m_px[tris], b_px[tris])
    else:
        base, best = _paper_general(pat, model, m_px[tris], b_px[tris])
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


# --- line samples ---------------------------------------------------------------------------------------


@dataclass(frozen=True)
class TraceOptions:
    """How line samples inherit the index of their line from labelled junctions (docs/reconstruction.md,
    "Line samples").

    mix_sigma: samples closer than this many smoothing scales σ to a sample of the other family are in the
        crossing's mixing zone: the two lines' profiles overlap and the ridge is pulled towards the crossing.
        Near a labelled junction, on its fitted line, they are moved onto that line (`snap_mixing`);
        elsewhere they are dropped.
    link_px: samples of one family closer than this (and in neighbouring pixels) are linked on a trace.
    lateral_px: linked samples may be at most this far apart across the line (measured against the line's
        direction on each side of the link). Along one light plane the depth is a function of the image
        position across the line (∂z/∂n, see the doc), so a trace that jumps across a depth edge jumps
        sideways in the image: this is the depth-continuity test.
    direction_px: the line's direction on each side of a link is the chord to the sample this many samples
        away along the trace.
    max_turn_deg: the two sides' directions may differ by at most this: a line on a smooth surface bends
        gently, a ridge that runs off along a shadow or occlusion edge (half a line cut off) turns sharply.
    seed_lateral_px: a sample near a labelled junction takes the junction's index for its family only if
        it lies this close to the junction's fitted line of that family.
    snap_mixing: move mixing-zone samples near a labelled junction onto its fitted line (else drop them).
    max_profile_drop: a labelled sample is dropped when the image at it is darker than the brightest point
        within half a line width across the line by more than this share of the line's contrast (the
        brightest inner point minus the darker of the two points one line width away; image 3×3
        box-filtered). The smoothed ridge of a line that an occluding edge half hides sits on the edge,
        off the line's light (decision 0050). 0 turns the test off; it needs the image.
    cross_pieces: label unseeded pieces from the crossings at both ends (decision 0052): the crossing with
        a labelled line m of the other family, triangulated on m's light sheet, must project within
        cross_residual_px (projector px) of one line of the piece's family, inside the depth range, and both
        ends must name the same line; cross_rounds rounds (labelled pieces become neighbours); pieces of at
        least cross_min_samples samples; neighbours within cross_radius junction steps of the piece's end;
        the samples within cross_trim_sigma·σ of the piece's ends are left out (pulled by the crossing).
    cross_both_ends: off, one end suffices (measured: wrong indices on tabletop; do not turn off).
    fill_gaps: fill a crossing's gap between two labelled pieces of one line with the same index that face
        each other (samples moved onto the chord between the anchors, fill_anchor samples inside the ends).
    max_ridge_step: cut a trace where the image brightness at consecutive samples changes by more than
        this share (an occluding edge where another surface's line continues this one); 0: off.
    seed_brightness: a labelled junction's seeds on one trace piece whose median ridge brightness differs from the
        median over all the junction's seeds of that family by more than seed_brightness_share of the larger are
        taken back before the seeds spread: the piece lies beyond a depth edge at the junction, on another surface whose line
        continues the junction's in the image (decision 0146, `reconstruction.seed_brightness`).
    continue_lines: carry a labelled piece's index to the pieces that continue its line across crossings
        where no junction was labelled (`reconstruction.continuation`, decision 0066); continue_reach: the
        longest gap, in junction steps; continue_lateral_px: the facing ends' largest sideways offset
        (camera px, per sampling step); continue_tol_px: the crossings at a continued piece's ends,
        triangulated on its light sheet, must lie this close to a line of the other family (projector px).
        The reach is at least a crossing's gap (`continuation.crossing_gap_px`: mixing zone and trims on
        both sides, at crossings down to continue_gap_deg in the image; 0: the junction-step share only),
        and the facing ends' tangents must meet at the gap's middle within continue_lateral_px (decision 0072).
    cross_rounds_after: rounds of the crossing pieces after the continuation (continued pieces are labelled
        neighbours too; the same check, decision 0074); 0: none.
    far_end_check: a seeded piece's stretch past its outermost seed loses its label when the crossing at
        that end, with a labelled line of the other family, names another line of the piece's family (the
        crossing check above, cross_radius and cross_residual_px): the trace ran across a depth edge onto a
        collinear line of another surface (decision 0084, `reconstruction.trace_ends`).
    far_end_mean_shift: with far_end_check, the depth edge inside such a stretch is put at the ridge
        brightness's maximum-likelihood step (every sample on its side of the split counts) instead of its
        largest step between two consecutive samples, which sensor noise wins over an edge the smoothing
        spreads over a few samples (decision 0132, `trace_ends.unlabel_stretches_ml`).
    from_segments: build the trace pieces from extraction's segments (`GridObservation.segment_linked`:
        ordered along each segment's fitted line, joined where segment ends, or a kept sample outside every
        segment, lie within link_px of one another, then cut by the rules above) instead of linking the
        samples again (decision 0085); observations without `segment_linked` are linked again.
    piece_seeds: label a piece that a crossing with a labelled line names at one end when the crossing at
        its other end, on the piece's light sheet, lands on the next line of the other family
        (`reconstruction.piece_seeds`, decision 0089). Off by default since decision 0131: on the unseen scenes it
        adds a few dozen points per frame, and on some (seeds 134, 147, 166) most of those are a line off.
    piece_junctions: build junctions at the crossings of pieces where extraction found none and label them as
        found ones (`reconstruction.piece_junctions`, decision 0092).
    surface_labels: label a piece whose index the labelled surface around it predicts: a plane fit of the
        labelled samples' depths within surface_radius junction steps beyond the piece's half extent, with
        neighbours on all sides of the piece and a residual far below one sheet step; surface_rounds rounds
        (`reconstruction.surface_labels`, decision 0093).
    beside_lines: label a piece beside a labelled line of its family k_n with k_n ± 1 when its two crossings, the
        middles of the gaps the mixing zone cuts, land on consecutive lines of the other family on its own sheet
        within cross_residual_px for one of the two and miss by twice that for the other, the neighbour in the same
        cell (`reconstruction.limb_lines`, decision 0103: compressed bands at a limb).
    beside_lines_ends: with beside_lines, the samples its trim leaves at an end of a piece it labelled whose
        facing piece stays unlabelled take the piece's line (no gap filling reaches them; decision 0106).
    t_nodes: piece_junctions' nodes with one family through (T's) join its graph; the through line's pieces
        at a T are labelled only at the pattern's rim (`reconstruction.t_nodes`, decision 0098).
    depth_range_labels: label a piece without a labelled sample whose samples' rays, inside the working volume,
        cross exactly one line of its family and none of the other family (`reconstruction.depth_range_labels`,
        decision 0128); each ray's stretch is widened by depth_range_tol times the epipolar noise floor
        (`LabelOptions.noise_floor_px`), pieces of at least cross_min_samples samples; the samples within
        cross_trim_sigma·σ of a piece's ends stay unlabelled (gap filling reaches them). Runs before the crossing
        searches, so that the pieces it labels seed them like junction-labelled ones.
    ambiguity_guard: after every labelling step, a labelled sample on the line of a junction whose component
        `label_epipolar` left out as ambiguous (within the seed radius and seed_lateral_px, as a seed) must carry that
        junction's index under the component's best offset; otherwise its piece loses its label
        (`reconstruction.ambiguity_guard`, decision 0141: a line continued across a depth edge by a lattice vector
        along the epipolar lines). Needs `label_samples(..., ambiguous_labels=)`; it only ever removes labels.
    ambiguity_guard_protect_seeded: the samples labelled by the labelled junctions' seeds (step 4, before any other
        step) are neither read nor unlabelled by the guard: an accepted component outranks an ambiguous one's best.
    lone_crossings: label the pieces at a crossing of unlabelled pieces (an X, or a T) from the crossing's own epipolar
        residual among the junctions the working volume leaves for its pieces, judged as a lone found junction
        (`reconstruction.lone_crossings`, decision 0139); runs after the piece junctions.
    lone_far_split: a lone crossing's piece whose free far end fails its crossing check (decision 0139's step 6)
        keeps its label from the node out to the likeliest ridge-brightness step (the depth edge, decision 0132)
        instead of losing it whole (decision 0164).
    frame_through: in the piece junctions' X test and T stems, a family with one end at a node (inside the frame by
        one cell) whose line leaves the camera frame within the continuation's reach past it runs through it: the
        frame is no edge of the surface (decision 0143).
    piece_junction_min_nodes: the smallest component of the piece junctions' X nodes given to `label_epipolar` (with
        a label_options); a component of two only where one node lies at the frame and the two lie
        2·(mix_sigma + cross_trim_sigma)·σ + one cell apart (decision 0143; 3: decision 0092's rule).
    """

    mix_sigma: float = 2.0
    link_px: float = 1.6
    lateral_px: float = 0.5
    direction_px: float = 3.0
    max_turn_deg: float = 10.0
    seed_lateral_px: float = 1.0
    snap_mixing: bool = True
    max_profile_drop: float = 0.15
    cross_pieces: bool = True
    cross_both_ends: bool = True
    cross_rounds: int = 3
    cross_min_samples: int = 4
    cross_radius: float = 0.6
    cross_residual_px: float = 1.0
    cross_trim_sigma: float = 1.0
    fill_gaps: bool = True
    max_ridge_step: float = 0.15
    seed_brightness: bool = True  # decision 0146: a junction's seeds on a piece off its seeds' brightness are taken back
    seed_brightness_share: float = 0.2  # decision 0146: how far off (share of the larger median)
    fill_anchor: int = 3
    continue_lines: bool = True
    continue_reach: float = 0.6
    continue_lateral_px: float = 1.0
    continue_tol_px: float = 1.0
    continue_gap_deg: float = 45.0
    cross_rounds_after: int = 1
    far_end_check: bool = True
    far_end_mean_shift: bool = True
    from_segments: bool = True
    piece_seeds: bool = False  # decision 0131: off (on unseen scenes its few points are often wrong; decision 0089 measured it small)
    piece_junctions: bool = True
    piece_junction_min_nodes: int = 2
    frame_through: bool = True
    surface_labels: bool = True
    surface_rounds: int = 3
    surface_radius: float = 1.0
    t_nodes: bool = True
    beside_lines: bool = True
    beside_lines_ends: bool = True
    depth_range_labels: bool = True
    depth_range_tol: float = 3.0
    ambiguity_guard: bool = True
    ambiguity_guard_protect_seeded: bool = True
    lone_crossings: bool = True
    lone_far_split: bool = True


@dataclass(frozen=True, eq=False)
class SampleLabels:
    """index (P,) float: the line index of each sample in its own family (NaN: none); q (P, 2): the
    position to triangulate (the sample's own, or moved onto a labelled junction's fitted line in the
    mixing zone); junction (P,) int: the labelled junction whose index the sample took (−1: none);
    stats: counts."""

    index: np.ndarray
    q: np.ndarray
    junction: np.ndarray
    stats: dict = field(default_factory=dict)


def profile_drop(image: np.ndarray, q: np.ndarray, tangent: np.ndarray, width_px: float) -> np.ndarray:
    """How far the image at each sample falls below its line's brightest point, as a share of contrast.

    image (H, W) grey; q (N, 2) camera px; tangent (N, 2) unit line directions; width_px: the line's
    width in the camera. With the image 3×3 box-filtered and read bilinearly at q + d·n (n ⟂ tangent):
    inner = max over d ∈ {0, ±w/4, ±w/2}, outer = min over d = ±w, returns (inner − I(q)) /
    max(inner − outer, 1) (N,). About 0 on a line's ridge; large where the smoothed ridge sits on an
    occluding edge that hides half the line (the image at q is the occluder, not the line).
    """
    n = len(q)
    if n == 0:
        return np.zeros(0)
    return _profile_drop_box3(_box3(image), q, tangent, width_px)


def _profile_drop_traces(img: np.ndarray, q: np.ndarray, sid: np.ndarray, tangent: np.ndarray, pos: np.ndarray,
                         width_px: float, ridge: np.ndarray | None = None) -> np.ndarray:
    """profile_drop on the box-filtered image (`_box3`) at trace positions pos (samples q[sid[pos]], tangents
    tangent[pos]); for uint8 images one compiled pass with cv2.remap's arithmetic
    (`_label_kernels.profile_drop_u8`, decision 0067), reusing `_ridge_brightness(img, q)` when given."""
    if img.dtype == np.uint8 and img.ndim == 2:
        have = ridge is not None
        return _k.profile_drop_u8(img, q, sid, np.ascontiguousarray(tangent, np.float64), np.ascontiguousarray(pos, np.intp),
                                  float(width_px), ridge if have else np.zeros(0, np.float32), have)
    return _profile_drop_box3(img, q[sid[pos]], tangent[pos], width_px)


def _profile_drop_box3(img: np.ndarray, q: np.ndarray, tangent: np.ndarray, width_px: float) -> np.ndarray:
    """profile_drop on the already box-filtered image (`_box3`), through cv2.remap."""
    n = len(q)
    if n == 0:
        return np.zeros(0)
    d = np.array([0.0, -0.25, 0.25, -0.5, 0.5, -1.0, 1.0], np.float32) * np.float32(width_px)
    nrm = np.column_stack([-tangent[:, 1], tangent[:, 0]]).astype(np.float32)
    qf = q.astype(np.float32)
    mx = (qf[None, :, 0] + d[:, None] * nrm[None, :, 0]).ravel()  # probe-major (7, n): fast reductions
    my = (qf[None, :, 1] + d[:, None] * nrm[None, :, 1]).ravel()
    # remap wants maps smaller than 32767 in both directions: lay the probes out in rows of 4096
    m = len(mx)
    cols = 4096
    rows = -(-m // cols)
    pad = rows * cols - m
    mx = np.concatenate([mx, np.zeros(pad, np.float32)]).reshape(rows, cols)
    my = np.concatenate([my, np.zeros(pad, np.float32)]).reshape(rows, cols)
    v = cv2.remap(img, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).ravel()[:m]
    v = v.reshape(len(d), n).astype(np.float32)
    inner = np.maximum(np.maximum(np.maximum(v[0], v[1]), np.maximum(v[2], v[3])), v[4])
    outer = np.minimum(v[5], v[6])
    return (inner - v[0]) / np.maximum(inner - outer, 1.0)


def _nearest_within(q: np.ndarray, pts: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """For points q (N, 2): the index of the nearest of pts (M, 2) within `radius` (−1: none) and its
    distance. Buckets pts in cells `radius` wide; each point looks at the 3×3 cells around its own (one
    entry per cell is enough when pts are more than radius·√2 apart, as junctions are). Compiled
    (`_label_kernels.nearest_within_cells`)."""
    return _k.nearest_within_cells(np.ascontiguousarray(q, np.float64).reshape(-1, 2),
                                   np.ascontiguousarray(pts, np.float64).reshape(-1, 2), float(radius))


@lru_cache(maxsize=8)
def _disk_offsets(rad: int) -> tuple[np.ndarray, np.ndarray]:
    """The (row, column) offsets (intp) of the pixels of cv2's elliptic structuring element of radius rad (the
    mixing zone's disk), in np.nonzero's order; cached (decision 0087)."""
    dr, dc = np.nonzero(cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * rad + 1, 2 * rad + 1)))
    dr, dc = (dr - rad).astype(np.intp), (dc - rad).astype(np.intp)
    dr.setflags(write=False)  # cached and shared between threads
    dc.setflags(write=False)
    return dr, dc


_SIN_20 = float(np.sin(np.deg2rad(20)))  # the crossing searches' smallest crossing angle


def _crossing_seeds(q, fam, sid, piece, ts_all, tangent, index, seed_jid, model: RigModel, depth_range_mm,
                    radius_px: float, trim_px: float, options: TraceOptions, grid: tuple | None = None,
                    rounds: int | None = None, state: dict | None = None) -> int:
    """Label unseeded trace pieces from the crossings at their ends (TraceOptions.cross_pieces).

    Every piece ends at a crossing's gap (the mixing zone is cut out of the traces). Where a labelled
    sample of the other family (index m) lies near a piece's end, the crossing c is the intersection of
    the two samples' tangent lines; the camera ray of c meets light sheet m at a point whose projector
    position must lie on a line of the piece's family: its index k is the piece's, and the distance to
    that line's centre is the crossing's epipolar residual (≤ cross_residual_px), the point inside the depth
    range. A piece is labelled only if both its ends give the same k (`cross_both_ends`). Repeated
    `cross_rounds` times, newly labelled pieces serving as the next round's neighbours. Writes index and
    seed_jid (sample ids, in place); returns the number of samples labelled. grid: `_sample_grid` with
    cells at least radius_px wide (built here when not given). rounds: instead of options.cross_rounds.
    """
    n_pieces = int(piece[-1]) + 1 if len(piece) else 0
    if n_pieces == 0:
        return 0
    if grid is None:
        grid = _sample_grid(q, (fam == 1) | (fam == 2), sid, radius_px, fam)
    total = 0
    labelled_none = np.zeros(0, np.bool_)
    sin_min = _SIN_20
    # Each piece end's nearest labelled sample of the other family, its crossing's line and junction, kept
    # from round to round ([side·n_pieces + piece]), and which samples were labelled when they were found:
    # labels are only added (here, by the continuation, by nothing else in between), so later an end's
    # nearest candidate changes only where a sample labelled since is nearer; only those ends are searched
    # and checked again (decision 0078; the same results as a full search every round). `state` carries
    # this from the rounds before the continuation to the round after it (same grid, radius and options).
    st = {} if state is None else state
    if not st or len(st["bd"]) != 2 * n_pieces:
        st.clear()
        st.update(bd=np.full(2 * n_pieces, np.inf), bk=np.full(2 * n_pieces, -1, np.intp),
                  k_end=np.full(2 * n_pieces, UNLABELLED, np.int64), jid_end=np.full(2 * n_pieces, -1, np.int64), seen=None)
    for _ in range(options.cross_rounds if rounds is None else rounds):
        # which samples carry an index now, and those labelled since the search before (decision 0087)
        labelled_now, new_s = _k.newly_labelled(index, st["seen"] if st["seen"] is not None else labelled_none, st["seen"] is not None)
        if st["seen"] is None:
            todo, e, te, sign, fe, first, last = _k.cross_round_ends(q, sid, piece, tangent, fam, index, n_pieces,
                                                                    int(options.cross_min_samples))
            st["first"], st["last"] = first, last
        else:
            # the pieces to do: those of the search before without a sample labelled since
            first, last = st["first"], st["last"]
            todo, e, te, sign, fe = _k.cross_round_ends_after(st["todo"], new_s, grid[7], piece, first, last, q, sid, tangent, fam)
        nt = len(todo)
        if nt == 0:
            break
        # (the per-end state's gathers and scatters at rows todo, todo + n_pieces, and the rows to search
        # again, compiled: decision 0087)
        if st["seen"] is None:  # every end (redo = 0 .. 2·nt − 1)
            bd, bk = _k.crossing_nearest(e, fe, q, fam, index, True, float(radius_px), *grid)
            redo = np.arange(2 * nt)
            k_end = np.full(2 * nt, UNLABELLED, np.int64)
            jid_end = np.full(2 * nt, -1, np.int64)
            o, c = _k.crossing_test(e, te, sign, bk, q, sid, tangent, float(radius_px), sin_min)
        else:
            bd, bk, k_end, jid_end = _k.round_state_gather(todo, n_pieces, st["bd"], st["bk"], st["k_end"], st["jid_end"])
            changed = _k.crossing_nearest_update(e, fe, q, fam, grid[7], new_s, float(radius_px), bd, bk)
            redo, e_r, te_r, sign_r, bk_r = _k.redo_rows(changed, e, te, sign, bk, k_end, jid_end, UNLABELLED)
            o, c = _k.crossing_test(e_r, te_r, sign_r, bk_r, q, sid, tangent, float(radius_px), sin_min)
        # the ends with a crossing (their labelled sample's line m), checked on light sheet m: the nearest line
        # of the piece's family, its distance and the depth; the passing ones give their end that line and
        # junction (gathers and writes compiled, decision 0087)
        sel, o_sel, c_sel, f_other, m = _k.crossing_hits(o, c, redo, True, fe, index, sid)
        if len(sel):
            _, z, kk, res = model.sheet_check(c_sel, f_other, m)
            _k.crossing_hits_write(sel, o_sel, kk, res, z, float(options.cross_residual_px), float(depth_range_mm[0]),
                                   float(depth_range_mm[1]), k_end, jid_end, seed_jid, sid)
        _k.round_state_scatter(todo, n_pieces, bd, bk, k_end, jid_end, st["bd"], st["bk"], st["k_end"], st["jid_end"])
        st["seen"] = labelled_now
        st["todo"] = todo
        # the pieces' ends next to the crossings are left out: the other line's profile pulls the ridge
        taken, written = _k.cross_round_write(todo, k_end, jid_end, bool(options.cross_both_ends), UNLABELLED, first, last,
                                              ts_all, sid, float(trim_px), index, seed_jid)
        if taken == 0 or written == 0:
            # no sample changed (pieces taken but shorter than the trims write nothing): the next round would
            # see the same index and repeat this one exactly (decision 0078)
            break
        total += int(written)
    return total


def _sample_grid(q: np.ndarray, valid: np.ndarray, sid: np.ndarray, cell_px: float, fam: np.ndarray | None = None,
                 prep: SamplePrep | None = None, pos_of: np.ndarray | None = None) -> tuple:
    """The bucket grid of the valid samples in cells cell_px wide that the crossing searches share, with
    each sample's trace position (`_label_kernels.sample_grid`): (x0, y0, cell, gw, gh, start, items, pos_of).
    With fam (P,): each cell's items split by family (`_label_kernels.sample_grid_split`, decision 0090),
    taken from prep.grids when the extraction stage built it on this cell (decision 0115; prep must be
    these samples' and valid prep.valid). pos_of: `_label_kernels.positions_of(len(q), sid)` when the caller has it
    (decision 0140)."""
    if fam is None:
        x0, y0, gw, gh, start, items, pos_of = _k.sample_grid(q, valid, sid, float(cell_px))
    else:
        g = None if prep is None else prep.grids.get(("valid", float(cell_px)))
        if g is None:
            g = _k.sample_grid_cells(q, valid, fam, float(cell_px))
        x0, y0, gw, gh, start, items = g
        if pos_of is None:
            pos_of = _k.positions_of(len(q), sid)
    return float(x0), float(y0), float(cell_px), int(gw), int(gh), start, items, pos_of


def _fill_gaps(q, fam, sid, piece, tangent, index, seed_jid, q_out, candidates, reach_px: float, options: TraceOptions,
               lab_pos: np.ndarray | None = None) -> int:
    """Fill the gaps at crossings between two labelled pieces of one line (TraceOptions.fill_gaps).

    The samples of a crossing's gap (mixing zone, or trimmed from a crossing-labelled piece's end) lie
    where the other line's profile pulls the ridge sideways. A candidate (sample ids) of family f is
    filled only when it lies between the ends of two labelled pieces of family f that carry the same
    index and face each other across the gap (each end at most 2·reach_px away): the line is seen on both
    sides of the crossing with one index, so the gap is that line's. (A gap next to one labelled piece
    only, e.g. at an occluding edge where the background's lines run past, stays empty: checked against
    simulator truth.) The sample is moved onto the chord between the two anchors (the labelled samples
    `fill_anchor` samples inside each end) if it lies within seed_lateral_px of it. Writes index,
    seed_jid and q_out in place; returns the number of samples filled. Compiled (`_label_kernels.fill_gaps`).
    lab_pos: the trace positions whose sample carries an index (np.flatnonzero(np.isfinite(index[sid]))) when
    the caller has them (decision 0115); None: found here."""
    if lab_pos is not None:
        return int(_k.fill_gaps_at(q, fam, sid, piece, tangent, index, seed_jid, q_out, np.ascontiguousarray(candidates, np.intp),
                                   float(reach_px), int(options.fill_anchor), float(options.seed_lateral_px),
                                   np.ascontiguousarray(lab_pos, np.intp)))
    return int(_k.fill_gaps(q, fam, sid, piece, tangent, index, seed_jid, q_out, np.ascontiguousarray(candidates, np.intp),
                            float(reach_px), int(options.fill_anchor), float(options.seed_lateral_px)))


def _box3(image: np.ndarray) -> np.ndarray:
    """The image as grey (uint8, uint16 or float32), 3×3 box-filtered (cv2.blur)."""
    img = np.asarray(image)
    if img.ndim == 3:
        from reconstruction.extraction import to_grey_float

        img = to_grey_float(img)
    if img.dtype not in (np.uint8, np.uint16, np.float32):
        img = img.astype(np.float32)
    return cv2.blur(img, (3, 3))


def _ridge_brightness(img: np.ndarray, q: np.ndarray) -> np.ndarray:
    """The 3×3 box-filtered image (`_box3`) at samples q (N, 2), bilinear (N,) float32: cv2.remap's values
    (NaN positions read at (0, 0)); for uint8 images a compiled read with OpenCV's arithmetic
    (`_label_kernels.ridge_brightness_u8`, decision 0067)."""
    if img.dtype == np.uint8 and img.ndim == 2:
        return _k.ridge_brightness_u8(img, np.ascontiguousarray(q, np.float64).reshape(-1, 2))
    m = len(q)
    cols = 4096
    rows = max(1, -(-m // cols))
    pad = rows * cols - m
    qf = np.nan_to_num(q.astype(np.float32))
    mx = np.concatenate([qf[:, 0], np.zeros(pad, np.float32)]).reshape(rows, cols)
    my = np.concatenate([qf[:, 1], np.zeros(pad, np.float32)]).reshape(rows, cols)
    return cv2.remap(img, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).ravel()[:m].astype(np.float32)


def _nearest_seed(piece: np.ndarray, t: np.ndarray, has: np.ndarray) -> np.ndarray:
    """For positions in sorted trace order (piece non-decreasing, t the position along it), the position of
    the nearest seed (has) on the same piece, or −1 (the earlier seed on a tie). Compiled."""
    return _k.nearest_seed(np.ascontiguousarray(piece), np.ascontiguousarray(t, np.float64), np.ascontiguousarray(has, np.bool_))


@dataclass(frozen=True, eq=False)
class SamplePrep:
    """What `label_samples` measures on the samples and the image before any label is known (decision 0107):
    computed by `prepare_samples`, in the pipeline's extraction stage.

    cell: the extraction's sampling step (camera px, 1 or 2); valid (P,) bool, r, c (P,) the samples' cells on
    a grid of that step padded by 2 (H, W cells; `_label_kernels.sample_cells`), n_valid; near_other (P,) bool:
    the mixing zone, within mix_sigma·σ of a sample of the other family (a disk on that grid); blurred: the
    image 3×3 box-filtered (`_box3`, None without an image); ridge (P,) float32: blurred at the samples
    (`_ridge_brightness`, None without an image or with max_ridge_step 0). key: what it was computed for
    (P, σ, mix_sigma, whether the ridge was read, the image's id). grids: bucket grids of the samples that need
    no label either, built in the same stage (decision 0115): ("valid", cell) the valid samples' grid split by
    family (`_label_kernels.sample_grid_cells`, `trace_grid_cell_px`), ("family", cell) every sample's
    (`crossing_fill.family_grid`); read-only, looked up by the stage that needs them and built there when
    absent. traces: the trace pieces and what follows from them alone (`TracePrep`, decision 0140; None: built by
    label_samples)."""

    cell: int
    valid: np.ndarray
    r: np.ndarray
    c: np.ndarray
    H: int
    W: int
    n_valid: int
    near_other: np.ndarray | None
    blurred: np.ndarray | None
    ridge: np.ndarray | None
    key: tuple
    grids: dict = field(default_factory=dict)
    traces: TracePrep | None = None

    def check(self, n_samples: int, sigma_px: float, options: TraceOptions, image: np.ndarray | None) -> None:
        """ValueError unless this was prepared for these samples, σ, options and image."""
        want = _prep_key(n_samples, sigma_px, options, image)
        if want != self.key:
            raise ValueError(f"label_samples: prep was computed for (samples, sigma_px, mix_sigma, ridge, image) = {self.key[:4]}, "
                             f"not {want[:4]} (or for another image); pass the prepare_samples result of this frame and options, or None")


@dataclass(frozen=True, eq=False)
class TracePrep:
    """`label_samples`' trace pieces, built before any label is known (decision 0140): the pieces are linked from the
    kept samples, and those are the valid samples outside the mixing zone (`_label_kernels.kept_samples`); a seed
    in the mixing zone is snapped and labelled on its own, never linked. So the pieces, and what is computed from
    them and the image alone, need no label.

    key: the options they were built with (`_trace_key`). k_idx (K,) the kept samples, n_mix the valid samples in
    the mixing zone; order, piece, ts, tangent: `_label_kernels.traces_from_segments` (or `traces_of`) on k_idx;
    sid = k_idx[order]; pos_of (P,) each sample's trace position (`_label_kernels.positions_of`, None: not built);
    drop (n,) float32 the cut-profile measure at every trace position (`_profile_drop_traces`, None: not built) for
    line width drop_width_px. Read-only: the label stage reads them and writes none of them."""

    key: tuple
    k_idx: np.ndarray
    n_mix: int
    order: np.ndarray
    piece: np.ndarray
    ts: np.ndarray
    tangent: np.ndarray
    sid: np.ndarray
    pos_of: np.ndarray | None = None
    drop: np.ndarray | None = None
    drop_width_px: float | None = None


def _trace_key(options: TraceOptions) -> tuple:
    """The options the trace pieces depend on (besides the samples, σ, mix_sigma and the ridge: `_prep_key`)."""
    return (bool(options.from_segments), float(options.link_px), float(options.lateral_px), float(options.max_turn_deg),
            float(options.direction_px), float(options.max_ridge_step))


def _trace_pieces(obs: GridObservation, q: np.ndarray, fam: np.ndarray, k_idx: np.ndarray, cell: int, r, c, H, W,
                  ridge: np.ndarray | None, options: TraceOptions) -> tuple:
    """Step 3's linking: the trace pieces of the kept samples k_idx (order, piece, ts, tangent), from extraction's
    segments (decision 0085) or by linking the samples again."""
    P = len(q)
    use_ridge = ridge is not None and options.max_ridge_step > 0
    seg_linked = getattr(obs, "segment_linked", None)
    if options.from_segments and seg_linked is not None and len(seg_linked) == P:
        # one linking: extraction's segments, ordered along their fitted lines and cut (decision 0085)
        return _k.traces_from_segments(
            q, fam, np.asarray(seg_linked, np.int64), np.ascontiguousarray(obs.segment_centre, np.float64).reshape(-1, 2),
            np.ascontiguousarray(obs.segment_dir, np.float64).reshape(-1, 2), k_idx, float(options.link_px * cell),
            float(options.lateral_px), float(np.cos(np.deg2rad(options.max_turn_deg))), max(1, int(round(options.direction_px))),
            ridge if use_ridge else np.zeros(0, np.float32), np.float32(options.max_ridge_step), use_ridge)
    return _k.traces_of(
        q, fam, r, c, k_idx.astype(np.intp), int(H), int(W), float(options.link_px * cell), float(options.lateral_px),
        float(np.cos(np.deg2rad(options.max_turn_deg))), max(1, int(round(options.direction_px))),
        ridge if use_ridge else np.zeros(0, np.float32), np.float32(options.max_ridge_step), use_ridge)


def _prepare_traces(obs: GridObservation, q: np.ndarray, fam: np.ndarray, cell: int, valid, near_other, r, c, H, W,
                    blurred, ridge, options: TraceOptions, line_width_px: float | None) -> TracePrep:
    """`TracePrep` of these samples (decision 0140): the kept samples, their pieces, every position's trace
    position and, with line_width_px and an image (and max_profile_drop > 0), the cut-profile measure at every
    trace position."""
    # the kept samples need no seed (`_label_kernels.kept_samples` only counts the seeds among them)
    k_idx, n_mix, _ = _k.kept_samples(valid, near_other, np.full(len(q), UNLABELLED, np.int64), UNLABELLED)
    if len(k_idx):
        order, piece, ts, tangent = _trace_pieces(obs, q, fam, k_idx, cell, r, c, H, W, ridge, options)
    else:  # nothing kept: label_samples builds no pieces either
        order, piece, ts, tangent = np.zeros(0, np.intp), np.zeros(0, np.int64), np.zeros(0), np.zeros((0, 2))
    sid = k_idx[order]
    pos_of = _k.positions_of(len(q), sid)
    drop = None
    width = None
    if blurred is not None and line_width_px and options.max_profile_drop > 0 and len(sid):
        width = float(line_width_px)
        drop = _profile_drop_traces(blurred, q, sid, tangent, np.arange(len(sid), dtype=np.intp), width, ridge)
    return TracePrep(_trace_key(options), k_idx, int(n_mix), order, piece, ts, tangent, sid, pos_of, drop, width)


def _prep_key(n_samples: int, sigma_px: float, options: TraceOptions, image: np.ndarray | None) -> tuple:
    return (int(n_samples), float(sigma_px), float(options.mix_sigma), image is not None and options.max_ridge_step > 0,
            None if image is None else id(image))


def prepare_samples(obs: GridObservation, *, sigma_px: float, options: TraceOptions = TraceOptions(),
                    image: np.ndarray | None = None, grid_cell_px: float | None = None, traces: bool = False,
                    line_width_px: float | None = None, family_cell_px: float | None = None) -> SamplePrep:
    """`label_samples`' measurements that need no label (SamplePrep): the samples' cells, the mixing zone, the
    box-filtered image and the ridge brightness at the samples. Same arguments as label_samples; grid_cell_px
    (`trace_grid_cell_px(model, options)`): the valid samples' bucket grid on that cell too (SamplePrep.grids,
    decision 0115; None: built by label_samples). traces: the trace pieces too (SamplePrep.traces, decision 0140),
    with line_width_px (label_samples' own) the cut-profile measure at every trace position. family_cell_px
    (`crossing_fill.fill_grid_cell_px`): every sample's grid by family on that cell too (SamplePrep.grids[("family",
    cell)], `crossing_fill.family_grid`), built with the valid samples' grid in one kernel when both are asked for
    (`_label_kernels.sample_grid_cells_two`, decision 0156)."""
    q = np.ascontiguousarray(np.asarray(obs.q, np.float64).reshape(-1, 2))
    fam = np.ascontiguousarray(np.asarray(obs.family).reshape(-1), np.intp)
    key = _prep_key(len(q), sigma_px, options, image)
    # Grid of cells of the extraction's sampling step (padded so that neighbour lookups never wrap): samples
    # from a half-resolution working image lie about 2 px apart and would never be neighbours on the
    # camera's pixel grid (decision 0066).
    cell = max(1, int(obs.stats.get("scale", 1)))
    valid, r, c, H, W, n_valid = _k.sample_cells(q, fam, float(cell), 2)
    if n_valid == 0:
        prep = SamplePrep(cell, valid, r, c, int(H), int(W), 0, None, None, None, key)
        if family_cell_px is not None:
            prep.grids[("family", float(family_cell_px))] = _family_grid_of(q, fam, float(family_cell_px))
        return prep
    rad = max(1, int(round(options.mix_sigma * sigma_px / cell)))
    near_other = _k.mixing_zone(r, c, fam, valid, int(H), int(W), *_disk_offsets(rad))
    blurred = _box3(image) if image is not None else None
    ridge = _ridge_brightness(blurred, q) if image is not None and options.max_ridge_step > 0 else None
    tp = None
    if traces:
        tp = _prepare_traces(obs, q, fam, cell, valid, near_other, r, c, H, W, blurred, ridge, options, line_width_px)
    prep = SamplePrep(cell, valid, r, c, int(H), int(W), int(n_valid), near_other, blurred, ridge, key, traces=tp)
    if grid_cell_px is not None and family_cell_px is not None:
        # both grids in one kernel: valid is the set `_family_grid` keeps (family 1 or 2, finite position)
        g, gf = _k.sample_grid_cells_two(q, valid, fam, float(grid_cell_px), float(family_cell_px))
        prep.grids[("valid", float(grid_cell_px))] = g
        prep.grids[("family", float(family_cell_px))] = gf
    elif grid_cell_px is not None:
        prep.grids[("valid", float(grid_cell_px))] = _k.sample_grid_cells(q, valid, fam, float(grid_cell_px))
    elif family_cell_px is not None:
        prep.grids[("family", float(family_cell_px))] = _family_grid_of(q, fam, float(family_cell_px))
    return prep


def _family_grid_of(q: np.ndarray, fam: np.ndarray, cell_px: float) -> tuple:
    """`crossing_fill.family_grid` (imported here: crossing_fill is not imported by this module otherwise)."""
    from reconstruction.crossing_fill import family_grid

    return family_grid(q, fam, cell_px)


def trace_grid_cell_px(model: RigModel, options: TraceOptions) -> float | None:
    """The cell of the bucket grid the label stage's crossing searches share (camera px), None when
    `label_samples` builds none (no crossing pieces and no continuation)."""
    if not (options.cross_pieces or options.continue_lines):
        return None
    return float(model.junction_step_cam_px * max(options.cross_radius, options.continue_reach))


def label_samples(
    obs: GridObservation,
    junction_labels: np.ndarray,
    *,
    sigma_px: float,
    seed_radius_px: float,
    options: TraceOptions = TraceOptions(),
    model: RigModel | None = None,
    depth_range_mm: tuple[float, float] = (0.0, np.inf),
    image: np.ndarray | None = None,
    line_width_px: float | None = None,
    prep: SamplePrep | None = None,
    label_options: LabelOptions | None = None,
    ambiguous_labels: np.ndarray | None = None,
) -> SampleLabels:
    """Give every line sample the index of its line, following the visible trace of the line from the
    labelled junctions on it.

    Samples of one family are linked into trace pieces (extraction's segments, joined where their ends lie
    within `link_px` of one another, split where consecutive samples lie farther apart, decision 0085; or,
    with `from_segments` off, neighbours within `link_px`), cut where the line
    jumps sideways by more than `lateral_px` or turns by more than `max_turn_deg`; samples near a labelled
    junction, on the junction's fitted line, are seeds carrying the junction's index; every sample takes
    the index of the nearest seed along its piece. A piece therefore carries the index from a labelled
    junction through unlabelled crossings' gaps only where its samples stay linked, out to the image
    border, a shadow or an occlusion. Pieces whose seeds disagree (two lines joined, or a wrong junction
    label) are split between the seeds; pieces without seeds stay unlabelled (never guessed). Samples in
    a crossing's mixing zone are moved onto a labelled junction's fitted line or dropped.

    junction_labels (M, 2) int, UNLABELLED where none. sigma_px: the extraction's smoothing scale.
    seed_radius_px: how far from a junction its seeds may lie (camera px). model, depth_range_mm: for
    the crossing pieces (`cross_pieces`, skipped without a model). image, line_width_px: for the cut-profile test
    (`max_profile_drop`, skipped without them). prep: `prepare_samples(obs, sigma_px=sigma_px, options=options,
    image=image)` when the caller computed it already (the pipeline does, in the extraction stage; decision
    0107); None: computed here. label_options: the frame's `LabelOptions` (the pipeline passes its own), used with
    min_component 3 to label decision 0092's piece junctions (None: LabelOptions(min_component=3)), so that
    settings such as the epipolar floor (decision 0110) reach them too. ambiguous_labels (M, 2): the best-offset labels
    of the junctions `label_epipolar` left out as ambiguous (`Labels.ambiguous_best`; UNLABELLED elsewhere): with
    `ambiguity_guard`, after every labelling step a piece labelled otherwise on such a junction's line loses its
    label (decision 0141, `reconstruction.ambiguity_guard`); None: no guard. Order: seeds and traces, crossing pieces, continuation, one more crossing
    round (`cross_rounds_after`), cut profiles, gap filling.

    Speed: the per-sample steps (valid samples and their cells, mixing zone, seeds, trace linking and
    cutting, the nearest seed, the crossing search at piece ends, the continuation, gap candidates and
    gap filling) are compiled loops (`reconstruction._label_kernels`, `_continuation_kernels`, decisions
    0064, 0067 and 0070: the mixing zone as bit rows, components ordered by an insertion sort, libm's hypot
    inlined, each cell's seed candidates listed once); one bucket grid of the valid samples per frame serves
    every crossing search. The image is box-filtered once with OpenCV; a uint8 image is then read in
    compiled passes that repeat cv2.remap's arithmetic (other types through cv2.remap). Light sheets and
    projections stay with `RigModel`. Times: benchmarks/results/bench_reconstruction.md.
    """
    q = np.asarray(obs.q, np.float64).reshape(-1, 2)
    # the families (int8), index (NaN; float32 inside, the integer line indices exact, returned as float64: decision 0150),
    # q_out (a copy of q), seed_jid (−1) and seed (UNLABELLED): one pass
    fam, index, q_out, seed_jid, seed = _k.label_arrays(q, np.asarray(obs.family).reshape(-1), UNLABELLED)
    P = len(q)
    stats = {"samples": P, "mixing_zone": 0, "snapped_to_junction_line": 0, "seeds": 0, "seed_conflicts": 0, "traces": 0,
             "traces_seeded": 0, "traces_conflicting": 0, "samples_labelled": 0, "samples_unseeded": 0, "cut_profile": 0}
    if prep is None:
        prep = prepare_samples(obs, sigma_px=sigma_px, options=options, image=image)
    else:
        prep.check(P, sigma_px, options, image)
    cell = prep.cell
    valid = prep.valid
    if prep.n_valid == 0:
        return SampleLabels(index.astype(np.float64), q_out, seed_jid.astype(np.int64), stats)
    # 1. The mixing zone (prepare_samples).
    near_other = prep.near_other
    # 2. Seeds: samples near a labelled junction, on its fitted line of their family.
    lab = np.asarray(junction_labels, np.int64).reshape(-1, 2)
    labelled = np.flatnonzero(lab[:, 0] != UNLABELLED)
    if len(labelled):
        jdir = np.ascontiguousarray(obs.junction_dir, np.float64).reshape(-1, 2, 2)
        n_snap = _k.junction_seeds(q, fam, valid, near_other, np.ascontiguousarray(obs.q_junction, np.float64).reshape(-1, 2),
                                   labelled, lab, jdir, float(seed_radius_px), float(options.seed_lateral_px),
                                   bool(options.snap_mixing), UNLABELLED, seed, seed_jid, q_out, index)
        if options.snap_mixing:
            stats["snapped_to_junction_line"] = int(n_snap)
    # the kept samples (outside the mixing zone) and the two counts, in one pass (decision 0087); the kept samples and
    # their trace pieces need no label and may come from the extraction stage (decision 0140)
    tp = prep.traces if prep.traces is not None and prep.traces.key == _trace_key(options) else None
    if tp is None:
        k_idx, n_mix, n_seeds = _k.kept_samples(valid, near_other, seed, UNLABELLED)
    else:
        k_idx, n_mix = tp.k_idx, tp.n_mix
        n_seeds = _k.seeds_among(k_idx, seed, UNLABELLED)
    stats["mixing_zone"] = int(n_mix) - stats["snapped_to_junction_line"]
    stats["seeds"] = int(n_seeds)
    # 3. Trace pieces and the nearest seed along each.
    ridge = prep.ridge
    blurred = prep.blurred
    r, c, H, W = prep.r, prep.c, prep.H, prep.W
    if len(k_idx):
        if tp is None:
            order, piece, ts, tangent = _trace_pieces(obs, q, fam, k_idx, cell, r, c, H, W, ridge, options)
            sid = k_idx[order]
        else:
            order, piece, ts, tangent, sid = tp.order, tp.piece, tp.ts, tp.tangent, tp.sid
        stats["traces"] = int(piece[-1]) + 1
        # a junction's seeds on a piece of another surface, beyond a depth edge at the junction, taken back (decision
        # 0146), and the seeds spread along the pieces: one pass over the positions (decision 0150)
        check = bool(options.seed_brightness and ridge is not None and len(ridge) == P)
        got, n_seeded, n_conflicting, n_off = spread_checked_seeds(
            sid, piece, ts, fam, seed, seed_jid, index, ridge if check else _NO_RIDGE, float(options.seed_brightness_share),
            check, UNLABELLED)
        if check:
            stats["seeds_off_brightness"] = int(n_off)
        stats["traces_seeded"] = int(n_seeded)
        stats["traces_conflicting"] = int(n_conflicting)
        guard = None
        if options.ambiguity_guard and ambiguous_labels is not None and len(ambiguous_labels) == len(lab):
            # sample labels an ambiguous junction component rules out (decision 0141): checked after every step
            guard = Guard(q, fam, valid, obs.q_junction, obs.junction_dir, ambiguous_labels, float(seed_radius_px),
                          float(options.seed_lateral_px), index if options.ambiguity_guard_protect_seeded else None)
            if len(guard.pair_s) == 0:
                guard = None

        def _guard() -> None:
            if guard is not None:
                guard(index, seed_jid, piece, sid)

        _guard()
        grid = None
        if model is not None and (options.cross_pieces or options.continue_lines):
            # the continuation's reach: a share of the junction step, and at least a crossing's gap (decision 0072)
            reach_cont = options.continue_reach * model.junction_step_cam_px
            if options.continue_gap_deg > 0:
                reach_cont = max(reach_cont, cell + crossing_gap_px(sigma_px, mix_sigma=options.mix_sigma, trim_sigma=options.cross_trim_sigma,
                                                                     min_angle_deg=options.continue_gap_deg))
            grid = _sample_grid(q, valid, sid, trace_grid_cell_px(model, options), fam, prep,
                                pos_of=None if tp is None else tp.pos_of)
        noise_floor = (label_options or LabelOptions()).noise_floor_px
        if options.depth_range_labels and model is not None:
            # pieces the working volume alone names (decision 0128)
            stats["samples_depth_range"] = label_depth_range_pieces(
                model, q, fam, sid, piece, ts, index, depth_range_mm, tol_px=options.depth_range_tol * noise_floor,
                min_samples=options.cross_min_samples, trim_px=options.cross_trim_sigma * sigma_px)
            _guard()
        cross_state: dict = {}  # the crossing searches' results, carried to the round after the continuation
        if options.cross_pieces and model is not None:
            stats["samples_from_crossings"] = _crossing_seeds(
                q, fam, sid, piece, ts, tangent, index, seed_jid, model, depth_range_mm,
                options.cross_radius * model.junction_step_cam_px, options.cross_trim_sigma * sigma_px, options, grid,
                state=cross_state)
            _guard()
        if options.continue_lines and model is not None:
            cont = continue_lines(q, fam, sid, piece, ts, tangent, index, seed_jid, valid, model=model, depth_range_mm=depth_range_mm,
                                  reach_px=reach_cont, check_radius_px=options.continue_reach * model.junction_step_cam_px,
                                  lateral_px=options.continue_lateral_px * cell, tol_px=options.continue_tol_px,
                                  anchor=options.fill_anchor, trim_px=options.cross_trim_sigma * sigma_px, grid=grid)
            stats["samples_continued"] = cont["samples"]
            stats["pieces_continuation_failed"] = cont["pieces_failed"]
            _guard()
            if options.cross_pieces and options.cross_rounds_after and cont["samples"]:
                # the continued pieces are labelled neighbours too: the crossings with them label the
                # pieces across (decision 0074), with the same check
                stats["samples_from_crossings_after"] = _crossing_seeds(
                    q, fam, sid, piece, ts, tangent, index, seed_jid, model, depth_range_mm,
                    options.cross_radius * model.junction_step_cam_px, options.cross_trim_sigma * sigma_px,
                    options, grid, rounds=options.cross_rounds_after, state=cross_state)
                _guard()
        if options.piece_seeds and options.cross_pieces and model is not None and grid is not None:
            # pieces one labelled crossing names and the next crossing confirms on their own sheet (decision 0089)
            ps = seed_one_sided(q, fam, sid, piece, ts, tangent, index, seed_jid, model=model, depth_range_mm=depth_range_mm,
                                radius_px=options.cross_radius * model.junction_step_cam_px, grid=grid,
                                trim_px=options.cross_trim_sigma * sigma_px, tol_px=options.cross_residual_px,
                                min_samples=options.cross_min_samples, anchor=options.fill_anchor)
            stats["samples_piece_seeds"] = ps["samples"]
            _guard()
        if options.piece_junctions and options.cross_pieces and model is not None and grid is not None:
            # junctions at the crossings of pieces where extraction found none (decision 0092)
            pj = label_piece_junctions(q, fam, sid, piece, ts, tangent, index, seed_jid, model=model, depth_range_mm=depth_range_mm,
                                       radius_px=options.cross_radius * model.junction_step_cam_px, grid=grid,
                                       q_junction=obs.q_junction, junction_labels=lab, trim_px=options.cross_trim_sigma * sigma_px,
                                       anchor=options.fill_anchor,
                                       reach_px=0.5 * (cell + crossing_gap_px(sigma_px, mix_sigma=options.mix_sigma, trim_sigma=options.cross_trim_sigma,
                                                                              min_angle_deg=options.continue_gap_deg or 45.0)),
                                       lateral_px=options.seed_lateral_px * cell, q_out=q_out, t_nodes=options.t_nodes,
                                       label_options=None if label_options is None else replace(label_options, min_component=options.piece_junction_min_nodes),
                                       frame_through=options.frame_through, frame_margin_px=float(cell),
                                       pair_min_px=2.0 * (options.mix_sigma + options.cross_trim_sigma) * sigma_px + cell)
            stats["samples_piece_junctions"] = pj["samples"]
            _guard()
        if options.lone_crossings and model is not None:
            # the pieces at a crossing of unlabelled pieces that the crossing's epipolar line names (decision 0139)
            lc = label_lone_crossings(q, fam, sid, piece, ts, index, model=model, depth_range_mm=depth_range_mm,
                                      trim_px=options.cross_trim_sigma * sigma_px,
                                      reach_px=0.5 * (cell + crossing_gap_px(sigma_px, mix_sigma=options.mix_sigma, trim_sigma=options.cross_trim_sigma,
                                                                             min_angle_deg=options.continue_gap_deg or 45.0)),
                                      lateral_px=options.seed_lateral_px * cell, tol_px=options.depth_range_tol * noise_floor,
                                      noise_floor_px=noise_floor, seed=seed, ridge=ridge,
                                      options=LoneCrossingOptions(far_end_split=options.lone_far_split, far_split_step=options.max_ridge_step))
            stats["samples_lone_crossings"] = lc["samples"]
            _guard()
        if options.surface_labels and options.cross_pieces and model is not None and grid is not None:
            # pieces inside a labelled surface that predicts their index (decision 0093)
            sf = label_from_surface(q, fam, sid, piece, ts, index, seed_jid, model=model, depth_range_mm=depth_range_mm,
                                    grid=grid, fit_radius_px=options.surface_radius * model.junction_step_cam_px,
                                    trim_px=options.cross_trim_sigma * sigma_px, min_samples=options.cross_min_samples,
                                    rounds=options.surface_rounds)
            stats["samples_surface_labels"] = sf["samples"]
            _guard()
        if options.beside_lines and options.cross_pieces and model is not None and grid is not None:
            # pieces beside a labelled line of their family, confirmed at both crossings on their sheet (decision 0103)
            bl = label_beside_lines(q, fam, sid, piece, ts, tangent, index, seed_jid, model=model, depth_range_mm=depth_range_mm,
                                    grid=grid, sigma_px=sigma_px, mix_sigma=options.mix_sigma,
                                    reach_px=cell + crossing_gap_px(sigma_px, mix_sigma=options.mix_sigma, trim_sigma=options.cross_trim_sigma,
                                                                    min_angle_deg=options.continue_gap_deg or 45.0),
                                    across_px=model.junction_step_cam_px, trim_px=options.cross_trim_sigma * sigma_px,
                                    tol_px=options.cross_residual_px, lateral_px=options.seed_lateral_px * cell,
                                    min_samples=options.cross_min_samples, anchor=options.fill_anchor, ends=options.beside_lines_ends)
            stats["samples_beside_lines"] = bl["samples"]
            _guard()
        if options.far_end_check and model is not None and grid is not None:
            # a seeded trace that ran across a depth edge onto a collinear line of another surface: the
            # crossing at its far end names another line (decision 0084, `reconstruction.trace_ends`)
            stats["samples_far_end_cut"] = cut_far_ends(q, fam, sid, piece, tangent, seed, index, seed_jid, model, depth_range_mm,
                                                        options.cross_radius * model.junction_step_cam_px,
                                                        options.cross_residual_px, grid, UNLABELLED, options.cross_min_samples,
                                                        options.seed_lateral_px * cell, ridge,
                                                        mean_shift=options.far_end_mean_shift)
            # a labelled end running into a collinear line of its family with another index (0084, round 4b)
            stats["samples_facing_cut"] = cut_facing_ends(q, fam, sid, piece, tangent, index, seed_jid, obs.q_junction, grid,
                                                          reach_px=cell + crossing_gap_px(sigma_px, mix_sigma=options.mix_sigma, trim_sigma=options.cross_trim_sigma,
                                                                                          min_angle_deg=options.continue_gap_deg or 45.0),
                                                          lateral_px=options.seed_lateral_px * cell, ridge=ridge)
        lab_pos = None  # the labelled trace positions when known (decision 0115)
        do_cut = bool(image is not None and line_width_px and options.max_profile_drop > 0)
        cand = None
        if ((options.cross_pieces or options.continue_lines) and model is not None and tp is not None and tp.drop is not None
                and tp.drop_width_px == float(line_width_px or 0.0) and tp.drop.dtype == np.float32 and len(tp.drop) == len(sid)):
            # the labelled positions, the cut profile (every trace position's measure from the extraction stage, decision
            # 0140) and the gap candidates in one compiled pass (decision 0157)
            lab_pos, n_unseeded, cut_samples, cand = _k.cut_and_gap_candidates(
                index, sid, piece, valid, tp.drop, np.float32(options.max_profile_drop), do_cut, bool(options.fill_gaps))
            stats["samples_unseeded"] = int(n_unseeded)
            if do_cut:
                stats["cut_profile"] = int(len(cut_samples))
        else:
            if (options.cross_pieces or options.continue_lines) and model is not None:
                g, n_unseeded = _k.labelled_positions(index, sid)  # (decision 0087)
                lab_pos = g
            else:
                g = np.flatnonzero(got)
                n_unseeded = len(got) - len(g)
            stats["samples_unseeded"] = int(n_unseeded)
            cut_samples = np.zeros(0, np.intp)
            if do_cut:
                if tp is not None and tp.drop is not None and tp.drop_width_px == float(line_width_px):
                    drop = tp.drop[g]  # every trace position's, measured in the extraction stage (decision 0140)
                else:
                    drop = _profile_drop_traces(blurred, q, sid, tangent, g, float(line_width_px), ridge)
                cut = drop > options.max_profile_drop
                cut_samples = sid[g[cut]]
                index[cut_samples] = np.nan
                stats["cut_profile"] = int(len(cut_samples))
                if lab_pos is not None:
                    lab_pos = g[~cut]
        if options.fill_gaps:
            # gap samples: the mixing zone, and the unlabelled ends of labelled pieces
            if cand is None:
                cand = _k.gap_candidates(valid, index, sid, piece, cut_samples)
            reach = (options.mix_sigma + options.cross_trim_sigma) * sigma_px + 2.0
            stats["samples_gap_filled"] = _fill_gaps(q, fam, sid, piece, tangent, index, seed_jid, q_out, cand, reach, options, lab_pos)
        _guard()
        if guard is not None:
            stats["samples_ambiguity_guard"] = guard.n
    # junction −1 where no index, the result's float64 index and int64 junctions: one pass (decision 0157)
    index_out, jid_out, n_lab = _k.labels_out(index, seed_jid)
    stats["samples_labelled"] = int(n_lab)
    return SampleLabels(index_out, q_out, jid_out, stats)
