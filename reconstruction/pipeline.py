"""One image of the projected grid in, a metric range map out.

    reconstruct(image, procam, pattern, options=ReconstructOptions()) -> Reconstruction

Stages (docs/reconstruction.md): extraction (`reconstruction.extraction`), labelling
(`reconstruction.labelling`), triangulation: every labelled junction by the closest approach of its
camera ray and projector ray, every line sample by intersecting its camera ray with the light plane of
its labelled line (`reconstruction.geometry`). Lens distortion of both devices is removed at the
boundary (normalised undistorted coordinates throughout).

Speed: the triangulate stage is two numba kernels after the junction rays (decisions 0065, 0071):
`_k_frame_points` takes the labelled line samples from their pixels to the outputs (gather, the rig
model's camera table, the light sheets, the working volume, the depth map, the float32/int32 conversion)
in short passes over flat arrays inside one call, and `_k_segment_overlay` the overlay. The rig model
(tables and the labelling margin behind the ill-posed warning) is built once per rig and cached.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from functools import lru_cache
from typing import Literal

import numpy as np

from calibration.errors import ReconstructionError
from calibration.models import ProCam
from reconstruction.border_fill import BorderFillOptions, with_border
from reconstruction.crossing_fill import CrossingFillOptions, CrossingPoints, fill_crossings, fill_grid_cell_px
from reconstruction.crossing_fill_one_sided import OneSidedFillOptions, with_one_sided
from reconstruction.extraction import ExtractOptions, GridObservation, extract_grid, sigma_for
from reconstruction.crossing_pull import triangulated_positions
from reconstruction.geometry import triangulate_rays
from reconstruction.labelling import (LabelOptions, Labels, SampleLabels, SamplePrep, TraceOptions, label_epipolar, label_paper,
                                      label_samples, prepare_samples, trace_grid_cell_px)
from reconstruction.patterns import GridPattern
from reconstruction._jit import njit
from reconstruction.placement import FIXED_ILL_POSED_PX
from reconstruction.rigmodel import UNLABELLED, RigModel, rig_model
from reconstruction.sheet_precision import SheetPrecisionOptions, across_line_scale, frame_noise_px, imprecise_samples


@dataclass(frozen=True)
class ReconstructOptions:
    """labeller: "epipolar" (default: whole components) or "paper" (the paper's three-point triangles).
    depth_min_mm, depth_max_mm: the working volume (camera-frame z): labels that put the surface
    outside it are rejected, and points outside it are dropped. dense: also triangulate every line sample
    (ray–light-plane), not only the junctions. extract, label: the stages' own options (label's depth
    range is replaced by the one here), trace: how line samples inherit their line's index; crossing:
    points through the crossings' gaps of lines labelled on both sides (decision 0086; default labeller only;
    decision 0092's `trace.piece_junctions` is off with the paper labeller too). traces_in_extraction: the line
    samples' trace pieces and the cut-profile measure along them, which need no label, are built in the extraction
    stage (`extract_frame`, decision 0140) so that the two stages' threads carry similar loads; off: in the label
    stage, as before. The outputs are the same either way. ambiguous_share_warning: when at least this share of the
    frame's junctions is left out as ambiguous (and fewer than the half `left_out_warning` names), warn and name the
    lattice offset the left-out components competed with and whether the rig's geometry explains it (decision 0147;
    0.15: a frame losing more than 1 − the 85 % coverage target; 1 or more: off), when at least
    ambiguous_unrecovered_share of those junctions have no point within a quarter junction step (the later steps
    label many of their lines: unseen seeds 129, 182 lost 2 % and 0 %, 156, 178, 193 44 %, 38 %, 38 %). Reporting
    only: points unchanged."""

    labeller: Literal["epipolar", "paper"] = "epipolar"
    depth_min_mm: float = 100.0
    depth_max_mm: float = 10000.0
    dense: bool = True
    extract: ExtractOptions = ExtractOptions()
    label: LabelOptions = LabelOptions()
    trace: TraceOptions = TraceOptions()
    crossing: CrossingFillOptions = CrossingFillOptions()
    one_sided: OneSidedFillOptions = OneSidedFillOptions()  # decision 0099: a labelled end to its crossing (with `crossing` on)
    border: BorderFillOptions = BorderFillOptions()  # decision 0104: a labelled end to the image border (with `crossing` on)
    sheet_precision: SheetPrecisionOptions = SheetPrecisionOptions()  # decision 0131: samples on sheets along the epipolar lines
    traces_in_extraction: bool = True  # decision 0140: the trace pieces (no label in them) built by extract_frame; outputs identical either way
    ambiguous_share_warning: float = 0.15  # decision 0147: warn and name the competing lattice offset from this share left out as ambiguous
    ambiguous_unrecovered_share: float = 0.25  # decision 0147: ... when this share of them has no point nearby

    def __post_init__(self) -> None:
        if self.labeller not in ("epipolar", "paper"):
            raise ValueError(f"labeller must be 'epipolar' or 'paper', got {self.labeller!r}")
        if not 0 < self.depth_min_mm < self.depth_max_mm:
            raise ValueError(f"need 0 < depth_min_mm < depth_max_mm, got {self.depth_min_mm}, {self.depth_max_mm}")


@dataclass(frozen=True, eq=False)
class Reconstruction:
    """The result of one frame.

    points_proj (N, 3) float32: world (projector) frame, mm. q_cam (N, 2) float32: their camera pixels.
    family (N,) int8: 0 = junction, 1 = i-line sample, 2 = j-line sample.
    label (N, 2) int32: (i, j) for junctions; for line samples the line's index in its family's slot and
        UNLABELLED in the other. residual (N,) float32: epipolar distance of the junction's label in
        projector px (for samples: that of the nearest labelled junction).
    depth_cam (H, W) float32: camera-frame z in mm at the sample's nearest pixel, NaN where nothing.
    junctions_cam (M, 2) float32 and junction_labels (M, 2) int32 (UNLABELLED where none): every junction
        found. segments (S, 2, 2) float32: fitted segments between junctions (for the overlay),
        segment_labelled (S,) bool.
    stats: counts, reasons and per-stage times (ms). warnings: human-readable sentences.
    """

    points_proj: np.ndarray
    q_cam: np.ndarray
    family: np.ndarray
    label: np.ndarray
    residual: np.ndarray
    depth_cam: np.ndarray
    junctions_cam: np.ndarray
    junction_labels: np.ndarray
    segments: np.ndarray
    segment_labelled: np.ndarray
    stats: dict = field(default_factory=dict)
    warnings: list = field(default_factory=list)

    @property
    def n_points(self) -> int:
        return int(len(self.points_proj))


def check_inputs(image: np.ndarray, procam: ProCam, pattern: GridPattern) -> None:
    """ReconstructionError naming the fix if the image, calibration and pattern do not go together."""
    img = np.asarray(image)
    if img.ndim not in (2, 3) or img.size == 0:
        raise ReconstructionError(f"expected a (H, W) or (H, W, 3) image, got an array of shape {img.shape}")
    h, w = img.shape[:2]
    cam = procam.camera
    if (w, h) != (cam.width, cam.height):
        raise ReconstructionError(
            f"the image is {w}x{h} but the calibration's camera is {cam.width}x{cam.height}; "
            "use the calibration made for this camera mode, or set camera.width/height to match it"
        )
    problem = _pattern_problem(pattern, procam.projector.width, procam.projector.height)
    if problem is not None:
        raise ReconstructionError(f"pattern does not fit the projector: {problem}")


@lru_cache(maxsize=32)
def _pattern_problem(pattern: GridPattern, width: int, height: int) -> str | None:
    """pattern.fits, once per pattern and projector size (it is checked on every frame)."""
    return pattern.fits(width, height)


def reconstruct(
    image: np.ndarray, procam: ProCam, pattern: GridPattern, *, options: ReconstructOptions = ReconstructOptions()
) -> Reconstruction:
    """Decode one camera image of `pattern` into points and a camera-frame range map (module doc).

    A frame without a usable grid gives an empty result with a warning; inconsistent inputs raise
    ReconstructionError (`check_inputs`). The same as `finish_frame(extract_frame(...))`.
    """
    return finish_frame(extract_frame(image, procam, pattern, options=options))


@dataclass(frozen=True, eq=False)
class ExtractedFrame:
    """A frame after the extraction stage (`extract_frame`), ready for `finish_frame`: the image, the grid
    observation, the rig model and the options, the stage's times (ms: "model", "extract"), and the samples'
    measurements that need no label (`labelling.prepare_samples`; None without samples or with dense off) and
    the junctions' normalised camera coordinates xy_cam_j (M, 2) (`RigModel.cam_normalised`; None: computed by
    finish_frame)."""

    image: np.ndarray
    obs: GridObservation
    model: RigModel
    options: ReconstructOptions
    ms: dict
    prep: SamplePrep | None = None
    xy_cam_j: np.ndarray | None = None


def extract_frame(
    image: np.ndarray, procam: ProCam, pattern: GridPattern, *, options: ReconstructOptions = ReconstructOptions()
) -> ExtractedFrame:
    """The first stage of `reconstruct`: check the inputs, then grid extraction.

    Split from `finish_frame` so that a stream of frames can run the two stages on two threads at once (the
    scan loop does, rig/overlap.py; decision 0088): each stage's kernels release the GIL. The image must
    not be modified until `finish_frame` has returned (the label stage reads it again)."""
    check_inputs(image, procam, pattern)
    t0 = time.perf_counter()
    model = rig_model(procam, pattern, (float(options.depth_min_mm), float(options.depth_max_mm)))
    t_model = time.perf_counter()
    obs = extract_grid(image, model, options=options.extract)
    prep = None
    if options.dense and len(obs.q):
        # the samples' measurements that need no label (cells, mixing zone, ridge brightness): extraction's
        # work, so that the two threads of a stream carry similar loads (decision 0107); the samples' bucket grid
        # too (decision 0115)
        sigma = _sigma(obs, model, options)
        # the trace pieces and the cut-profile measure along them need no label either (decision 0140)
        # and every sample's grid by family for the crossing fills (decision 0115; built with the other grid, 0156)
        gcell = None
        if options.labeller == "epipolar" and options.crossing.enabled:
            gcell = float(fill_grid_cell_px(sigma, float(_step_px(obs)), options.crossing))
        prep = prepare_samples(obs, sigma_px=sigma, options=options.trace, image=image,
                               grid_cell_px=trace_grid_cell_px(model, options.trace), traces=options.traces_in_extraction,
                               line_width_px=model.line_width_cam_px, family_cell_px=gcell)
    xy_cam_j = model.cam_normalised(obs.q_junction)
    t_extract = time.perf_counter()
    return ExtractedFrame(image, obs, model, options, {"model": 1e3 * (t_model - t0), "extract": 1e3 * (t_extract - t_model)}, prep,
                          xy_cam_j)


def _sigma(obs: GridObservation, model: RigModel, options: ReconstructOptions) -> float:
    """The extraction's smoothing scale σ (camera px) of this frame."""
    return float(obs.stats.get("sigma_px", sigma_for(model, options.extract)))


def _step_px(obs: GridObservation) -> int:
    """The extraction's sampling step (camera px): 1, or 2 on a half-resolution image."""
    return max(1, int(obs.stats.get("scale", 1)))


def finish_frame(frame: ExtractedFrame) -> Reconstruction:
    """The second stage of `reconstruct`: labelling (junctions, then line samples) and triangulation.
    stats["ms"] holds every stage's time, "total" their sum."""
    image, obs, model, options = frame.image, frame.obs, frame.model, frame.options
    t_extract = time.perf_counter()
    xy_cam_j = model.cam_normalised(obs.q_junction) if frame.xy_cam_j is None else frame.xy_cam_j
    lo = None  # the default labeller's options, also for decision 0092's piece junctions
    if options.labeller == "paper":
        lab = label_paper(obs, model, xy_cam_j)
    else:
        lo = options.label
        lo = LabelOptions(**{**lo.__dict__, "depth_min_mm": options.depth_min_mm, "depth_max_mm": options.depth_max_mm})
        lab = label_epipolar(obs, model, xy_cam_j, options=lo)
    # Line samples take their line's index along the trace from a labelled junction (part of labelling).
    sl = None
    if options.dense and (lab.labels[:, 0] != UNLABELLED).any() and len(obs.q):
        sigma = _sigma(obs, model, options)
        seed_r = float(obs.stats.get("junction_radius_px", 0.4 * model.junction_step_cam_px))
        trace = options.trace
        if options.labeller == "paper" and (trace.piece_junctions or trace.depth_range_labels or trace.lone_crossings):
            # decision 0092's junctions at the crossings of pieces are labelled by the default labeller's machinery:
            # the paper labeller's output stays the paper's method (its junctions, extended along the lines); decision
            # 0128's pieces named by the working volume too
            trace = replace(trace, piece_junctions=False, depth_range_labels=False, lone_crossings=False)
        sl = label_samples(obs, lab.labels, sigma_px=sigma, seed_radius_px=seed_r, options=trace, model=model,
                           depth_range_mm=(options.depth_min_mm, options.depth_max_mm), image=image,
                           line_width_px=model.line_width_cam_px, prep=frame.prep, label_options=lo,
                           ambiguous_labels=lab.ambiguous_best)
    cp = None
    if sl is not None and options.labeller == "epipolar" and options.crossing.enabled:
        # points through crossings whose line is labelled on both sides (decision 0086); the paper labeller's
        # output stays the paper's method
        cp = fill_crossings(sl.q, obs.family, sl.index, sl.junction, q_samples=obs.q, family_samples=obs.family,
                            q_junction=obs.q_junction, junction_dir=obs.junction_dir, junction_labels=lab.labels, model=model, sigma_px=sigma,
                            cell_px=float(_step_px(obs)),
                            depth_range_mm=(options.depth_min_mm, options.depth_max_mm), options=options.crossing,
                            grids=None if frame.prep is None else frame.prep.grids)
    if cp is not None and options.one_sided.enabled:
        # points from a labelled line's end up to the crossing that ends it (decision 0099; with 0086's fill only:
        # without it every gap's sides would be ends)
        cp = with_one_sided(cp, sl.q, obs.family, sl.index, sl.junction, q_samples=obs.q, family_samples=obs.family,
                            q_junction=obs.q_junction, junction_labels=lab.labels, model=model, sigma_px=sigma,
                            cell_px=float(_step_px(obs)),
                            depth_range_mm=(options.depth_min_mm, options.depth_max_mm), options=options.one_sided)
    if cp is not None and options.border.enabled:
        # points from a labelled line's end up to the image border (decision 0104)
        cp = with_border(cp, sl.q, obs.family, sl.index, sl.junction, image=image, q_samples=obs.q, family_samples=obs.family,
                         model=model, sigma_px=sigma,
                         cell_px=float(_step_px(obs)),
                         depth_range_mm=(options.depth_min_mm, options.depth_max_mm), options=options.border)
    t_label = time.perf_counter()
    result = _triangulate(image, obs, lab, sl, model, xy_cam_j, options, cp)
    t_tri = time.perf_counter()
    ms = dict(frame.ms)
    ms["label"] = 1e3 * (t_label - t_extract)
    ms["triangulate"] = 1e3 * (t_tri - t_label)
    ms["total"] = ms["model"] + ms["extract"] + ms["label"] + ms["triangulate"]
    result.stats["ms"] = ms
    return result


_LEFT_OUT_WHY = {
    "ambiguous": "another label offset fits almost as well",
    "no_admissible_offset": "no label offset puts them inside the pattern and the working volume",
    "component_too_small": "too few connected junctions to choose an offset",
    "residual_too_large": "they lie too far from their epipolar lines",
    "out_of_depth_range": "their points fall outside the working volume",
    "split_too_small": "what is left after removing outliers is too small",
}


def few_junctions_warning(n_samples: int, n_junctions: int, junction_step_px: float, cell_px: int) -> str | None:
    """The frame's warning when extraction found many line samples but few junctions (None: no warning).

    A grid seen whole gives about 2·step/cell samples per junction (two families, one sample per sampling step
    along each, step: the rig's junction spacing in the camera); the eight benchmark scenes give 1.6–2.6 times that
    (a development script's count), shadows and silhouettes included. Ten times that, with at least 1 000 samples, means crossings were not
    found where lines were: one family's lines too close together in the image (a surface seen at a grazing angle,
    a pitch too fine for the camera). Seen on an unseen scene: 18 378 samples, 5 junctions, no points, no warning."""
    if n_samples < 1000 or n_junctions <= 0:
        return None
    expected = 2.0 * junction_step_px / max(cell_px, 1)
    if n_samples / n_junctions <= 10.0 * expected:
        return None
    return (f"found {n_samples} line samples but only {n_junctions} junctions: the lines' crossings were not found, "
            "probably because one family's lines lie too close together in the image (a surface seen at a grazing "
            "angle, or a pattern pitch too fine for this camera); use a coarser pitch or view the surface less obliquely")


def judged_margin(margin, label: LabelOptions):
    """The rig's labelling margin (`placement.LabellingMargin`) judged against the labeller's own threshold: "ill-posed"
    below min_rms_ratio × noise_floor_px, the miss a runner-up offset needs for `label_epipolar` to accept the best one
    (decision 0130); with `LabelOptions.ill_posed_at_floor` off, decision 0004's fixed 0.1 px."""
    if not label.ill_posed_at_floor:
        return margin.with_floor(FIXED_ILL_POSED_PX, 1.0)
    return margin.with_floor(label.noise_floor_px, label.min_rms_ratio)


def left_out_warning(n_junctions: int, n_labelled: int, left_out: dict, margin) -> str | None:
    """The frame's warning when labelling left out every junction, or most of them as ambiguous (None: no
    warning). Names the main reason; when it is ambiguity and the rig's labelling margin
    (`placement.LabellingMargin`) is "marginal", adds the margin's advice (a tighter depth range, another
    camera direction, De Bruijn spacing), which is the fix; an "ill-posed" margin has a warning of its own."""
    counts = {k: int(v) for k, v in left_out.items() if int(v) > 0}
    n_amb = counts.get("ambiguous", 0)
    if n_labelled > 0 and n_amb <= 0.5 * n_junctions:
        return None
    if n_labelled == 0:
        head = f"found {n_junctions} junctions but could not label any of them"
    else:
        head = f"{n_amb} of {n_junctions} junctions were left out as ambiguous"
    if counts:
        top = max(counts, key=counts.get)
        head += f": {counts[top]} {top.replace('_', ' ')} ({_LEFT_OUT_WHY.get(top, 'see stats: junctions_left_out')})"
        if top == "ambiguous" and margin is not None and margin.verdict == "marginal":
            return f"{head}; {margin.advice()}"
        if top == "ambiguous" and margin is not None and margin.verdict == "ill-posed":
            return f"{head}; the rig's labelling is ill-posed (next warning)"
    return head + " (see stats: junctions_left_out)"


def ambiguous_share_warning(n_junctions: int, lab: Labels, model: RigModel, xy_cam_j, options: ReconstructOptions, stats: dict,
                            q_junction=None, q_points=None) -> str | None:
    """Decision 0147: when at least `options.ambiguous_share_warning` of the frame's junctions were left out as ambiguous,
    and at least `options.ambiguous_unrecovered_share` of those have no point of the result within a quarter junction
    step (q_junction (M, 2) the junctions', q_points (N, 2) the points' camera pixels; the later steps often label the
    lines through them), the lattice offset their components competed with and the rig's miss for it
    (`ambiguous_offsets`); writes stats["ambiguous_offsets"] (left-out junctions per competing vector),
    stats["ambiguous_unrecovered"] and stats["ambiguous_offset"] (the main one's measures). None otherwise, with the
    paper labeller or without recorded labels."""
    n_amb = int(lab.stats.get("junctions_left_out", {}).get("ambiguous", 0))
    if n_junctions == 0 or n_amb < options.ambiguous_share_warning * n_junctions or lab.ambiguous_labels is None:
        return None
    k = np.flatnonzero(lab.ambiguous_labels[:, 0] != UNLABELLED)
    if q_junction is not None and q_points is not None and len(k):
        from scipy.spatial import cKDTree

        if len(q_points):
            d, _ = cKDTree(np.asarray(q_points, np.float64)).query(np.asarray(q_junction, np.float64)[k],
                                                                     distance_upper_bound=0.25 * model.junction_step_cam_px)
            n_open = int((~np.isfinite(d)).sum())
        else:
            n_open = len(k)
        stats["ambiguous_unrecovered"] = n_open
        if n_open < options.ambiguous_unrecovered_share * len(k):
            return None
    from reconstruction.ambiguous_offsets import ambiguity_report, ambiguity_warning

    lo = options.label
    counts, main = ambiguity_report(model, None, xy_cam_j, lab.ambiguous_labels, lab.component,
                                    depth_range_mm=(options.depth_min_mm, options.depth_max_mm), noise_floor_px=lo.noise_floor_px,
                                    min_rms_ratio=lo.min_rms_ratio, chi2=lo.ambiguity_chi2, cap_px=lo.residual_cap_px)
    stats["ambiguous_offsets"] = counts
    if main is not None:
        stats["ambiguous_offset"] = {"vector": list(main.vector), "junctions": main.junctions, "components": main.components,
                                     "median_size": main.median_size, "rms_best_px": main.rms_best, "rms_runner_up_px": main.rms_runner_up,
                                     "rig_miss_px": main.rig_miss_px, "decide_px": main.decide_px, "n_min": main.n_min,
                                     "geometric": bool(main.geometric)}
    return ambiguity_warning(n_junctions, n_amb, main, stats.get("ambiguous_unrecovered"))


def _triangulate(
    image, obs: GridObservation, lab: Labels, sl: SampleLabels | None, model: RigModel, xy_cam_j, options: ReconstructOptions,
    cp: CrossingPoints | None = None,
) -> Reconstruction:
    procam = model.procam
    H, W = np.shape(image)[:2]
    warnings: list[str] = []
    margin = judged_margin(model.margin, options.label)
    labels = lab.labels
    M = len(obs.q_junction)
    jl = np.flatnonzero(labels[:, 0] != UNLABELLED)
    n_j = len(jl)

    # Junctions: closest approach of the camera ray and the projector ray of the labelled junction.
    lj = labels[jl]
    p_j, _gap = triangulate_rays(procam, xy_cam_j[jl], model.junction_xy(lj[:, 0], lj[:, 1]))

    # Line samples (indexed by labelling.label_samples): camera ray ∩ the light sheet of their line. This,
    # the working-volume test of every point, the depth map and the conversion to the outputs are one
    # kernel pass (_k_frame_points), junctions first, then the samples in order.
    family_s = obs.family
    if sl is not None and len(sl.index):
        q_s, index_s, junction_s = sl.q, sl.index, sl.junction
        q_unpulled = getattr(obs, "q_unpulled", None)  # observations built without it (tests): none
        if q_unpulled is not None and q_unpulled is not obs.q:
            # the samples the label stage left at their ridge centre, with the other line's pull next to a
            # crossing taken out (decision 0154); snapped and gap-filled samples keep their positions
            q_s = triangulated_positions(q_s, obs.q, q_unpulled)
        if cp is not None and len(cp.index):
            # the crossing points (decision 0086) after the samples
            q_s = np.concatenate([q_s, cp.q])
            index_s = np.concatenate([index_s, cp.index])
            junction_s = np.concatenate([junction_s, cp.junction])
            family_s = np.concatenate([np.asarray(obs.family), cp.family.astype(np.asarray(obs.family).dtype)])
    else:
        q_s, index_s, junction_s = _EMPTY_Q, _EMPTY_F, _EMPTY_I
    n_max = n_j + len(index_s)
    depth = np.full((H, W), np.nan, np.float32)
    out_p = np.empty((n_max, 3), np.float32)
    out_q = np.empty((n_max, 2), np.float32)
    out_f = np.empty(n_max, np.int8)
    out_l = np.empty((n_max, 2), np.int32)
    out_r = np.empty(n_max, np.float32)
    out_s = np.empty(n_max, np.int64)
    kernel_ok, tables = model.pixel_sheet_tables
    # Rigs the kernel cannot do alone (a projector with more than 5 distortion coefficients), and samples
    # outside the camera table: the sample points come from RigModel.intersect_light_sheets instead.
    p_given = _EMPTY_P if kernel_ok else _sample_points(model, q_s, index_s, family_s)
    z_range = (float(options.depth_min_mm), float(options.depth_max_mm))
    for _ in range(2):
        n_keep, n_keep_j, N, n_outside = _k_frame_points(
            p_j, obs.q_junction, jl, labels, lab.residual, q_s, index_s, family_s, junction_s, p_given, UNLABELLED,
            *tables, *z_range, depth, out_p, out_q, out_f, out_l, out_r, out_s,
        )
        if not n_outside:
            break
        p_given = _sample_points(model, q_s, index_s, family_s)
        depth.fill(np.nan)
    n_imprecise = 0
    if options.labeller == "epipolar" and options.sheet_precision.enabled and n_keep > n_keep_j:
        # decision 0131: sample points whose sheet runs so nearly along the epipolar lines that their depth is
        # not known to the precision asked for are left out (the paper labeller's output stays the paper's method)
        n_keep, n_imprecise = _drop_imprecise(model, lab, options, depth, out_p, out_q, out_f, out_l, out_r, n_keep, n_keep_j,
                                              obs=obs, q_s=q_s, out_s=out_s)

    # Overlay segments: from each segment's fit, between its extreme samples.
    segs, seg_lab = _segment_overlay(obs, lab)

    sample_stats: dict = sl.stats if sl is not None else {}
    stats = {
        "samples": int(len(obs.q)),
        "junctions_found": int(M),
        "junctions_labelled": n_j,
        "junctions_left_out": lab.stats.get("junctions_left_out", {}),
        "junctions_rejected": obs.stats.get("junctions_rejected", {}),
        "segments": int(len(obs.segment_family)),
        "edges": int(len(obs.edges)),
        "components": int(lab.stats.get("components", 0)),
        "components_labelled": int(lab.stats.get("components_labelled", 0)),
        "ambiguous": int(lab.stats.get("ambiguous", 0)),
        "triangles": int(lab.stats.get("triangles", 0)),
        "points": n_keep,
        "points_junctions": n_keep_j,
        "points_dropped_out_of_range": N - n_keep,
        "labelling_margin_px": float(model.margin.margin_px),
        "labeller": options.labeller,
        # the crossing points (decision 0086) are labelled samples too
        "samples_labelled": int(sample_stats.get("samples_labelled", 0)) + (int(len(cp.index)) if cp is not None else 0),
        "samples_left_out": {k: int(sample_stats.get(k, 0)) for k in ("mixing_zone", "samples_unseeded", "cut_profile")},
        "samples_snapped": int(sample_stats.get("snapped_to_junction_line", 0)),
        "samples_from_crossings": int(sample_stats.get("samples_from_crossings", 0)),
        "samples_gap_filled": int(sample_stats.get("samples_gap_filled", 0)),
        "samples_piece_seeds": int(sample_stats.get("samples_piece_seeds", 0)),
        "samples_surface_labels": int(sample_stats.get("samples_surface_labels", 0)),
        "samples_piece_junctions": int(sample_stats.get("samples_piece_junctions", 0)),
        "samples_beside_lines": int(sample_stats.get("samples_beside_lines", 0)),
        "samples_depth_range": int(sample_stats.get("samples_depth_range", 0)),
        "samples_ambiguity_guard": int(sample_stats.get("samples_ambiguity_guard", 0)),  # decision 0141: labels taken back
        "samples_lone_crossings": int(sample_stats.get("samples_lone_crossings", 0)),
        "seeds_off_brightness": int(sample_stats.get("seeds_off_brightness", 0)),  # decision 0146: seeds taken back
        "samples_crossing_filled": int(cp.stats["samples_crossing_filled"]) if cp is not None else 0,
        "samples_one_sided_filled": int(cp.stats.get("samples_one_sided_filled", 0)) if cp is not None else 0,
        "samples_border_filled": int(cp.stats.get("samples_border_filled", 0)) if cp is not None else 0,
        "samples_imprecise": int(n_imprecise),
        "traces_conflicting": int(sample_stats.get("traces_conflicting", 0)),
        "components_split": int(lab.stats.get("components_split", 0)),
        "junctions_residual_clusters": int(lab.stats.get("junctions_residual_clusters", 0)),
    }
    if M == 0:
        warnings.append("no usable grid in this frame (no line crossings found): check exposure, focus and that the pattern is shown")
    else:
        w = few_junctions_warning(len(obs.q), M, model.junction_step_cam_px, _step_px(obs))
        if w:
            warnings.append(w)
        w = left_out_warning(M, n_j, lab.stats.get("junctions_left_out", {}), margin)
        if w:
            warnings.append(w)
        else:
            w = ambiguous_share_warning(M, lab, model, xy_cam_j, options, stats, obs.q_junction, out_q[:n_keep])
            if w:
                warnings.append(w)
    if margin.verdict == "ill-posed":
        # The same measure and threshold as `rig check` (placement.labelling_margin, decision 0065): below the
        # runner-up miss the labeller needs with this frame's epipolar floor (decision 0130).
        warnings.append(f"{margin.advice()} [this rig and working volume {options.depth_min_mm:.0f}–{options.depth_max_mm:.0f} mm]")
    return Reconstruction(
        points_proj=out_p[:n_keep],
        q_cam=out_q[:n_keep],
        family=out_f[:n_keep],
        label=out_l[:n_keep],
        residual=out_r[:n_keep],
        depth_cam=depth,
        junctions_cam=obs.q_junction.astype(np.float32),
        junction_labels=labels.astype(np.int32),
        segments=segs,
        segment_labelled=seg_lab,
        stats=stats,
        warnings=warnings,
    )


def _drop_imprecise(model: RigModel, lab: Labels, options: ReconstructOptions, depth, out_p, out_q, out_f, out_l, out_r,
                    n_keep: int, n_keep_j: int, *, obs: GridObservation | None = None, q_s=None, out_s=None) -> tuple[int, int]:
    """Decision 0131: leave out the sample points (rows n_keep_j … n_keep of the outputs) that
    `sheet_precision.imprecise_samples` flags, with δ = max(the labelled junctions' residual scale, the labeller's
    noise floor) and, with `SheetPrecisionOptions.own_offset` (decision 0151) and obs, q_s (the positions
    triangulated), out_s (each output row's sample in q_s), each sample's own offset from its line's local fit
    where larger (`sheet_precision.own_offsets_px`); the kept rows move up in order and the depth map's pixels of the dropped points are cleared
    (or take the last kept point on that pixel, as the kernel writes them). Returns (kept rows, dropped rows)."""
    pat = model.pattern
    delta = frame_noise_px(lab.residual, options.label.noise_floor_px)
    own = None
    if options.sheet_precision.own_offset and obs is not None and out_s is not None:
        scale = across_line_scale(obs, lab.labels, model.line_offsets_px, model.index_min, float(pat.n1), float(pat.n2), UNLABELLED)
        scale = np.where(np.isfinite(scale), scale, 1.0 / model.cam_per_proj_px)  # too few labelled edges: the rig's scale
        # an offset over half the line's width is off the line's light (a kink, an edge): not its sideways error
        own = (out_s[n_keep_j:n_keep], q_s, obs, scale, 0.5 * float(pat.line_width_px))
    bad = imprecise_samples(np.asarray(model.procam.projector.K, np.float64), model.procam.t_proj_cam, float(pat.n1), float(pat.n2),
                            out_p[n_keep_j:n_keep], out_f[n_keep_j:n_keep], delta, options.sheet_precision, own)
    n_bad = int(bad.sum())
    if n_bad == 0:
        return n_keep, 0
    return _drop_rows(model, depth, bad, out_p, out_q, out_f, out_l, out_r, n_keep, n_keep_j), n_bad


def _drop_rows(model: RigModel, depth, bad, out_p, out_q, out_f, out_l, out_r, n_keep: int, n_keep_j: int) -> int:
    """Remove the sample rows n_keep_j + flatnonzero(bad) from the outputs (the kept rows move up in order) and from
    the depth map: a dropped point's pixel is cleared (NaN), or takes the last kept point on that pixel, as
    `_k_frame_points` writes them. Returns the kept rows. Two compiled passes over the rows (decision 0151's own
    offsets drop a few rows on most frames: the NumPy version, with a full-image mask and five fancy-indexed
    copies, cost ~1.6 ms per 1280×1024 frame)."""
    H, W = depth.shape
    flat = depth.reshape(-1)
    re, pix_re = _k_cleared_pixels(out_q, n_keep, n_keep_j, bad, H, W, flat)
    if len(re):  # kept points on a cleared pixel: written again in order (the last wins)
        R, t = model.procam.R_proj_cam, model.procam.t_proj_cam
        z = (out_p[re].astype(np.float64) - t) @ R[:, 2]
        flat[pix_re] = z
    return _k_compact_rows(bad, n_keep, n_keep_j, out_p, out_q, out_f, out_l, out_r)


@njit
def _k_pixel(qx, qy, H, W):
    """The pixel (row-major id) of position (qx, qy): rounded half to even, clipped to the image."""
    y = min(max(np.rint(np.float64(qy)), 0.0), H - 1.0)
    x = min(max(np.rint(np.float64(qx)), 0.0), W - 1.0)
    return np.int64(y) * W + np.int64(x)


@njit
def _k_cleared_pixels(q, n_keep, n_keep_j, bad, H, W, flat):
    """`_drop_rows`' first pass: the dropped rows' pixels set to NaN in flat (the depth map, row-major); returns the
    kept rows (of 0 … n_keep) whose pixel is one of them, in order, and their pixels."""
    nb = 0
    for r in range(n_keep - n_keep_j):
        if bad[r]:
            nb += 1
    dp = np.empty(nb, np.int64)
    k = 0
    for r in range(n_keep - n_keep_j):
        if bad[r]:
            dp[k] = _k_pixel(q[n_keep_j + r, 0], q[n_keep_j + r, 1], H, W)
            flat[dp[k]] = np.nan
            k += 1
    dp = np.sort(dp)
    re = np.empty(n_keep, np.int64)
    pr = np.empty(n_keep, np.int64)
    m = 0
    for r in range(n_keep):
        if r >= n_keep_j and bad[r - n_keep_j]:
            continue
        p = _k_pixel(q[r, 0], q[r, 1], H, W)
        i = np.searchsorted(dp, p)
        if i < nb and dp[i] == p:
            re[m] = r
            pr[m] = p
            m += 1
    return re[:m], pr[:m]


@njit
def _k_compact_rows(bad, n_keep, n_keep_j, out_p, out_q, out_f, out_l, out_r):
    """`_drop_rows`' second pass: the rows n_keep_j … n_keep that bad does not flag moved up in order; returns the
    kept rows' count."""
    w = n_keep_j
    for r in range(n_keep_j, n_keep):
        if bad[r - n_keep_j]:
            continue
        if w != r:
            for c in range(3):
                out_p[w, c] = out_p[r, c]
            for c in range(2):
                out_q[w, c] = out_q[r, c]
                out_l[w, c] = out_l[r, c]
            out_f[w] = out_f[r]
            out_r[w] = out_r[r]
        w += 1
    return w


_EMPTY_Q = np.zeros((0, 2))
_EMPTY_F = np.zeros(0)
_EMPTY_I = np.zeros(0, np.int64)
_EMPTY_P = np.zeros((0, 3))


def _sample_points(model: RigModel, q: np.ndarray, index: np.ndarray, family: np.ndarray) -> np.ndarray:
    """Points (P, 3) of the samples with a finite line index (NaN for the others) through
    `RigModel.cam_normalised` and `intersect_light_sheets`: the path for what `_k_frame_points` does not do."""
    p = np.full((len(index), 3), np.nan)
    ok = np.isfinite(index)
    if ok.any():
        p[ok] = model.intersect_light_sheets(model.cam_normalised(q[ok]), family[ok], index[ok].astype(np.intp))
    return p


def _segment_overlay(obs: GridObservation, lab: Labels) -> tuple[np.ndarray, np.ndarray]:
    """Segments (S', 2, 2) float32 from each segment's fit between its extreme samples (segments with at
    least two distinct sample positions), and whether either end junction is labelled (S',)."""
    S = len(obs.segment_family)
    if S == 0 or len(obs.q) == 0:
        return np.zeros((0, 2, 2), np.float32), np.zeros(0, bool)
    segs = np.empty((S, 2, 2), np.float32)
    seg_lab = np.empty(S, np.bool_)
    n = _k_segment_overlay(obs.q, obs.segment, obs.segment_centre, obs.segment_dir, obs.segment_ends, lab.labels,
                           UNLABELLED, np.empty(S), np.empty(S), segs, seg_lab)
    return segs[:n], seg_lab[:n]


# --- kernels (decisions 0065, 0071) ----------------------------------------------------------------------------


@njit
def _k_segment_overlay(q, segment, centre, direction, ends, labels, unlabelled, smin, smax, segs, seg_lab):
    """The overlay in one call: smin/smax[k] (scratch, (S,)) the extreme positions s = (q − centre[k])·
    direction[k] of segment k's samples; the segments with smax > smin (finite), in order, to segs (S, 2, 2)
    as centre + s·direction at both extremes, seg_lab: either end junction labelled. Returns the count."""
    S = smin.shape[0]
    for k in range(S):
        smin[k] = np.inf
        smax[k] = -np.inf
    for n in range(q.shape[0]):
        k = segment[n]
        if k < 0:
            continue
        s = (q[n, 0] - centre[k, 0]) * direction[k, 0] + (q[n, 1] - centre[k, 1]) * direction[k, 1]
        if s < smin[k]:
            smin[k] = s
        if s > smax[k]:
            smax[k] = s
    M = labels.shape[0]
    m = 0
    for k in range(S):
        a = smin[k]
        b = smax[k]
        if not (np.isfinite(a) and b > a):
            continue
        for c in range(2):
            segs[m, 0, c] = centre[k, c] + a * direction[k, c]
            segs[m, 1, c] = centre[k, c] + b * direction[k, c]
        e0 = ends[k, 0]
        e1 = ends[k, 1]
        seg_lab[m] = (0 <= e0 < M and labels[e0, 0] != unlabelled) or (0 <= e1 < M and labels[e1, 0] != unlabelled)
        m += 1
    return m


@njit(error_model="numpy")
def _k_frame_points(p_j, q_junction, jl, labels, residual_j, q, index, family, junction, p_given, unlabelled,
                    R, t, index_min, nodes, iterations, cam_tab, inv_step, K_cam,
                    end_n, end_t, chord_n, chord_t, K_proj, dist, centre, n_other, offsets, inv_dx, guess,
                    z_min, z_max, depth, out_p, out_q, out_f, out_l, out_r, out_s):
    """Every point of the frame, in order, from its inputs to the outputs (decision 0071).

    First the labelled junctions jl (points p_j, from `triangulate_rays`), then the line samples with a
    finite index: camera pixel q[n] -> normalised undistorted xy (bilinear in the camera table cam_tab,
    nodes 1/inv_step px apart, as `RigModel.cam_normalised`; the pinhole inverse with K_cam when cam_tab
    is empty) -> the point on the light sheet of line (family[n], int(index[n])) (as
    `RigModel.intersect_light_sheets`: the end plane, then `iterations` times the chord plane where the
    point projects into the projector; tables from `RigModel.pixel_sheet_tables`). If p_given is not
    empty, the sample points are read from it instead. Samples outside the camera table are skipped and
    counted (the caller then passes p_given).

    A point is kept when it is finite and its camera-frame z = R[:, 2]·(p − t) is in [z_min, z_max] mm:
    z goes to its nearest pixel of depth (H, W) (a later point overwrites an earlier one), the point, its
    pixel, family (0 junction, 1/2 line), label (a sample's index in its family's slot, `unlabelled` in
    the other), residual (a sample's: that of the junction it took its index from, junction[n] < 0:
    junction 0's) and source (a sample's row n of q; −1 for a junction: decision 0151) to the outputs. Returns (kept, junctions kept, candidates, outside table).

    The samples go through short passes over flat scratch arrays (gather and camera table; end plane;
    projection; chord search; chord plane; outputs) rather than one loop doing everything per sample: the
    work per sample is one long chain of dependent operations, and a loop body that long stops the
    processor from overlapping samples (decision 0071).
    """
    H, W = depth.shape
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = R[0, 0], R[0, 1], R[0, 2], R[1, 0], R[1, 1], R[1, 2], R[2, 0], R[2, 1], R[2, 2]
    t0, t1, t2 = t[0], t[1], t[2]
    P = index.shape[0]
    sid = np.empty(P, np.int64)  # sample of each candidate
    px = np.empty(P)
    py = np.empty(P)
    pz = np.empty(P)
    given = p_given.shape[0] > 0
    fc = np.empty(0 if given else P, np.int64)  # family − 1, line index − index_min, ray direction
    lc = np.empty(0 if given else P, np.int64)
    dx = np.empty(0 if given else P)
    dy = np.empty(0 if given else P)
    dz = np.empty(0 if given else P)
    exact = cam_tab.shape[0] == 0
    th = cam_tab.shape[0]
    tw = cam_tab.shape[1]
    fx_c, skew_c, cx_c, fy_c, cy_c = K_cam[0, 0], K_cam[0, 1], K_cam[0, 2], K_cam[1, 1], K_cam[1, 2]
    L = end_n.shape[1]
    # Pass 1: the candidates and their normalised camera coordinates (RigModel.cam_normalised), or the
    # given point.
    n_outside = 0
    c = 0
    for n in range(P):
        if not np.isfinite(index[n]):
            continue
        if given:
            sid[c] = n
            px[c] = p_given[n, 0]
            py[c] = p_given[n, 1]
            pz[c] = p_given[n, 2]
            c += 1
            continue
        u = q[n, 0]
        v = q[n, 1]
        if exact:
            yc = (v - cy_c) / fy_c
            xc = (u - cx_c - skew_c * yc) / fx_c
        else:
            gx = u * inv_step
            gy = v * inv_step
            if not (gx >= 0.0 and gy >= 0.0 and gx < tw - 1 and gy < th - 1):
                n_outside += 1
                continue
            x0 = int(gx)
            y0 = int(gy)
            fx_ = gx - x0
            fy_ = gy - y0
            w00 = (1 - fx_) * (1 - fy_)
            w01 = fx_ * (1 - fy_)
            w10 = (1 - fx_) * fy_
            w11 = fx_ * fy_
            xc = cam_tab[y0, x0, 0] * w00 + cam_tab[y0, x0 + 1, 0] * w01 + cam_tab[y0 + 1, x0, 0] * w10 + cam_tab[y0 + 1, x0 + 1, 0] * w11
            yc = cam_tab[y0, x0, 1] * w00 + cam_tab[y0, x0 + 1, 1] * w01 + cam_tab[y0 + 1, x0, 1] * w10 + cam_tab[y0 + 1, x0 + 1, 1] * w11
        sid[c] = n
        fc[c] = family[n] - 1
        lc[c] = min(max(int(index[n]) - index_min, 0), L - 1)
        dx[c] = xc
        dy[c] = yc
        c += 1
    if not given:
        # Pass 2: the ray direction R·(x, y, 1) and the point on the end plane of the line's sheet.
        for a in range(c):
            f = fc[a]
            li = lc[a]
            xc = dx[a]
            yc = dy[a]
            d0 = xc * r00 + yc * r01 + r02
            d1 = xc * r10 + yc * r11 + r12
            d2 = xc * r20 + yc * r21 + r22
            nd = end_n[f, li, 0] * d0 + end_n[f, li, 1] * d1 + end_n[f, li, 2] * d2
            lam = -end_t[f, li] / nd if abs(nd) >= 1e-9 else np.nan
            if not (lam > 0):
                lam = np.nan
            dx[a] = d0
            dy[a] = d1
            dz[a] = d2
            px[a] = t0 + lam * d0
            py[a] = t1 + lam * d1
            pz[a] = t2 + lam * d2
    if not given and iterations > 0:
        s_tmp = np.empty(c)
        row = np.empty(c, np.int64)
        chord_n_rows = chord_n.reshape(-1, 3)
        chord_t_rows = chord_t.reshape(-1)
        k1, k2, p1, p2, k3 = dist[0], dist[1], dist[2], dist[3], dist[4]
        fx, skew, cx, fy, cy = K_proj[0, 0], K_proj[0, 1], K_proj[0, 2], K_proj[1, 1], K_proj[1, 2]
        cu, cv = centre[0], centre[1]
        n_other_1, n_other_2 = n_other[0], n_other[1]
        n_chords = chord_n.shape[2]
        idx_min = float(index_min)
        top = float(n_chords - 1)
        mid = n_chords // 2
        for _ in range(iterations):
            # Pass 3: the offset s = y − n·x (projector px from the pattern centre) of the other family's line
            # through each point's projection (Intrinsics.project, OpenCV's 5-coefficient model; NaN behind).
            for a in range(c):
                z = pz[a]
                x = px[a] / z if z > 0 else np.nan
                y = py[a] / z if z > 0 else np.nan
                r2 = x * x + y * y
                radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
                xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
                yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
                u = fx * xd + skew * yd + cx
                v = fy * yd + cy
                s_tmp[a] = (v - cv) - (n_other_1 if fc[a] == 0 else n_other_2) * (u - cu)
            # Pass 4: the other family's fractional index there (np.interp over its line offsets, the search
            # started from the mean spacing) picks the chord plane (its row in the flat tables).
            for a in range(c):
                f = fc[a]
                o = 1 - f
                s = s_tmp[a]
                if s != s:
                    seg = mid  # the point missed the end plane: the middle chord
                else:
                    if s <= offsets[o, 0]:
                        other = float(index_min)
                    elif s >= offsets[o, L - 1]:
                        other = float(index_min + L - 1)
                    else:
                        lo = min(max(int((s - offsets[o, 0]) * guess[o]), 0), L - 2)
                        while offsets[o, lo] > s:
                            lo -= 1
                        while offsets[o, lo + 1] <= s:
                            lo += 1
                        other = inv_dx[o, lo] * (s - offsets[o, lo]) + float(index_min + lo)
                    seg = int(min(max((other - idx_min) * nodes, 0.0), top))
                row[a] = (f * L + lc[a]) * n_chords + seg
            # Pass 5: the ray meets that chord plane (two short passes overlap better than one long one).
            for a in range(c):
                r = row[a]
                d0 = dx[a]
                d1 = dy[a]
                d2 = dz[a]
                nd = chord_n_rows[r, 0] * d0 + chord_n_rows[r, 1] * d1 + chord_n_rows[r, 2] * d2
                lam = -chord_t_rows[r] / nd if abs(nd) >= 1e-9 else np.nan
                if not (lam > 0):
                    lam = np.nan
                px[a] = t0 + lam * d0
                py[a] = t1 + lam * d1
                pz[a] = t2 + lam * d2
    # Pass 6: the working volume, the depth map and the outputs: junctions, then the samples.
    m = 0
    for a in range(jl.shape[0]):
        x, y, zp = p_j[a, 0], p_j[a, 1], p_j[a, 2]
        if not (np.isfinite(x) and np.isfinite(y) and np.isfinite(zp)):
            continue
        z = (x - t0) * r02 + (y - t1) * r12 + (zp - t2) * r22
        if not (z >= z_min and z <= z_max):
            continue
        jn = jl[a]
        u = q_junction[jn, 0]
        v = q_junction[jn, 1]
        depth[min(max(int(np.rint(v)), 0), H - 1), min(max(int(np.rint(u)), 0), W - 1)] = z
        out_p[m, 0] = x
        out_p[m, 1] = y
        out_p[m, 2] = zp
        out_q[m, 0] = u
        out_q[m, 1] = v
        out_f[m] = 0
        out_l[m, 0] = labels[jn, 0]
        out_l[m, 1] = labels[jn, 1]
        out_r[m] = residual_j[jn]
        out_s[m] = -1
        m += 1
    m_j = m
    for a in range(c):
        x, y, zp = px[a], py[a], pz[a]
        if not (np.isfinite(x) and np.isfinite(y) and np.isfinite(zp)):
            continue
        z = (x - t0) * r02 + (y - t1) * r12 + (zp - t2) * r22
        if not (z >= z_min and z <= z_max):
            continue
        n = sid[a]
        u = q[n, 0]
        v = q[n, 1]
        fam = family[n]
        k = int(index[n])
        depth[min(max(int(np.rint(v)), 0), H - 1), min(max(int(np.rint(u)), 0), W - 1)] = z
        out_p[m, 0] = x
        out_p[m, 1] = y
        out_p[m, 2] = zp
        out_q[m, 0] = u
        out_q[m, 1] = v
        out_f[m] = fam
        out_l[m, 0] = k if fam == 1 else unlabelled
        out_l[m, 1] = k if fam == 2 else unlabelled
        out_r[m] = residual_j[max(junction[n], 0)]
        out_s[m] = n
        m += 1
    return m, m_j, jl.shape[0] + c, n_outside
