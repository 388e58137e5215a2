"""Grid extraction: sub-pixel line centres, the two line families, junctions and their connectivity.

One camera image in, a `GridObservation` out (camera pixels, (u, v), pixel (0, 0) = centre of the
top-left pixel). The method (docs/reconstruction.md, decisions 0040, 0041, 0055–0059, 0068, 0077):

1. Smoothing with a Gaussian of σ = 0.4 × the line width the calibration predicts (one separable float32
   filter over the image; lines wider than ~6 px are processed at half resolution after `cv2.pyrDown`).
   Candidates: pixels where the discrete Laplacian is clearly negative (a bright ridge or crossing).
2. At candidates only, the Hessian's most negative eigenvector is the line normal n; Steger's sub-pixel
   offset t = −(∇I · n) / (nᵀ H n) moves the sample onto the ridge; a pixel is kept when the ridge
   passes through its square (non-maximum suppression across the line, one sample per pixel along it).
   Anisotropic pixels are line samples; pixels where both eigenvalues are clearly negative are crossing
   candidates (two bright lines crossing make a blob; λ2 < −0.25·|λ1| on the full-resolution path, which
   admits crossings down to ~53° in the image, decision 0068; −λ2 above 5 deviations of its own noise, the
   noise of one second derivative, decision 0129).
3. Each sample's line direction is compared with the two families' directions predicted from the
   calibration (`RigModel.dir_cam`): the closer one names the family.
4. Junctions: the crossing candidates' local maxima (non-maximum suppression on a grid of cells; two closer
   than the core radius merged into one, decision 0129), each sample assigned to the nearest one (a Voronoi
   partition on that grid). Around each, a straight line is fitted to each family's samples outside the
   core, outliers trimmed, and the junction is the intersection of the two fits. A junction is kept only
   if both lines run *through* it (samples on both sides): T- and L-shapes are occlusion or shadow
   boundaries, or the pattern's rim.
5. Segments: samples outside the junction cores are linked to neighbours within 2 px that lie on the same
   line (same family, parallel normals, small offset across the line) and the links' connected components
   are the segments; kinks and gaps (depth edges, shadows) break them. A segment whose two ends reach two
   different junctions and whose samples lie on the chord between them is an edge of the graph. Samples
   within two smoothing scales of an end that reaches no crossing (a line cut by a silhouette or shadow)
   leave their segment: the cut bends the ridge there (decision 0059).

Speed (decisions 0062, 0063, 0069, 0079, 0087, 0091, 0155): for an 8-bit image whose width is a multiple of 16 and
a kernel of at most 15 taps the smoothing is a numba kernel computing OpenCV's `sepFilter2D` bits (its FMA order), in
the same walk as the ridge pass below, its column pass two rows at a time and its rows in a ring of 16 (no full
working image, `smooth_ridges_ring_u8`, decision 0155); otherwise it is one OpenCV call into a per-thread working
image. Every per-pixel and per-sample step is a numba kernel (`reconstruction/_extract_kernels.py`): one walk
over the image for the Laplacian test (a vectorised loop per row, candidates collected branch-free) that
computes the Hessian, eigenvector and Steger offset of the candidates in blocks that LLVM vectorises as
soon as a block's rows have been scanned (row-major, so sample order is the scan order; outputs in
per-thread arrays), one branch-free pass for the albedo test and the families,
nearest-candidate lookups on coarse grids, linking with 4 probes per sample on a window of sample-id rows
and a union-find, the line fits, end walks, arms, trims and chord tests as loops over samples or segments,
the per-junction tests and the duplicates in one pass each (decision 0079); the noise estimate of an
8-bit image is a histogram kernel; the edges' index steps, the kept candidates and junctions are one pass each
(decision 0087), per-frame constants cached. The kernels compute what the NumPy
passes they replaced did, in the same float widths and order. Times per stage: see
benchmarks/results/bench_extraction.md.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np

from reconstruction import _extract_kernels as _k
from reconstruction import unsuppressed_seeds as _us
from reconstruction.crossing_candidates import merge_within, remap_grid
from reconstruction.corner_junctions import corner_candidates, corner_kinds, dark_beyond
from reconstruction.junction_arms import retry_trimmed_arms
from reconstruction.acute_recentre import acute_retry, recentre_acute
from reconstruction.rigmodel import RigModel
from reconstruction.crossing_pull import unpull_samples, untilted_dirs


@dataclass(frozen=True)
class ExtractOptions:
    """sigma_px: Gaussian smoothing (camera px) before the derivatives; None: from the line width the
        calibration predicts in the camera (`sigma_for`).
    threshold_sigma: a ridge must be this many noise standard deviations strong.
    min_relative_strength: and at least this fraction of the strongest ridges nearby (uneven albedo).
    anisotropy: a line sample's second eigenvalue may be at most this fraction of the first (below:
        a spot or a crossing).
    crossing_anisotropy: a pixel is a crossing candidate when its second eigenvalue is below −this fraction
        of the first (two lines crossing at angle θ give tan²(θ/2): 1 at 90°, 0.33 at 60°, 0.25 at 53°;
        foreshortened surfaces make crossings acute in the image). Full-resolution path only; the
        half-resolution path (wide lines) uses `anisotropy` (decision 0068).
    crossing_strength: a crossing candidate's weaker eigenvalue must reach this fraction of the strongest
        ridges nearby.
    family_margin: |cos| difference needed between the two predicted families.
    max_segment_rms_px: an edge's samples must lie within this RMS distance of the chord between its
        junctions (camera px).
    max_junction_offset_px: the fitted intersection may be this far from the crossing candidate
        (camera px, at least a third of the junction core).
    max_arm_turn_deg: a junction's fitted line may differ from its samples' own directions by this much
        on average (more: the line jumps sideways at the crossing, a depth edge).
    free_end_trim_sigma: samples within this many smoothing scales of a segment end that reaches no
        crossing are left out of their segment (the cut line's ridge is biased there); 0: keep them.
    arm_free_end_trim: a candidate whose arms are bent (crooked, jump, turn) is fitted again without the
        samples within `free_end_trim_sigma` smoothing scales of a free segment end (a silhouette or shadow
        cuts the line there); kept if those arms are straight and run through it (decision 0077).
    arm_short_share: with `arm_free_end_trim`, a candidate still bent after that refit is fitted once more
        on its arm samples within this share of the arm radius (at least the attach radius + 1), free ends
        trimmed too; kept on the same terms (decision 0077, round 4b); 0: off.
    downsample_sigma_px: smoothing scales at or above this are computed on a half-resolution image
        (wide lines; the samples are still about two camera pixels apart).
    shared_arms: where crossings along a line are only a few px apart (the other family's lines compressed by
        a surface seen obliquely), a candidate short of ring samples that sits in a row of such crossings (two
        opposite neighbours at one spacing) is counted again with the ring samples it shares with them, and an
        arm with fewer than 3 samples is fitted again from every sample of its family near the candidate outside
        the crossings' cores (decision 0120). Full-resolution path only.
    crossing_eigen_noise: a crossing candidate's weaker curvature −λ2 must be `threshold_sigma` standard
        deviations of the noise of that one eigenvalue strong (about 0.6 of the Laplacian's noise, the noise of a
        second derivative along one direction: `_second_derivative_noise_gain`) instead of the Laplacian's; off: the
        Laplacian's, as a line sample's strength (decision 0129). Full-resolution path only.
    merge_close_candidates: crossing candidates closer than the core radius to each other (two maxima of one
        elongated crossing blob, which would split its ring samples) are one candidate, at their score-weighted
        mean position (`crossing_candidates.merge_within`, decision 0129).
    acute_recentre: a candidate that fails only the through or the off-centre test, whose arms' intersection lies
        off it along the bisector of the acute crossing angle θ (within the tolerance × sin 45° / sin(θ/2), the
        elongation of the crossing blob; across it within the tolerance), is judged again with its sides counted
        from that intersection (`acute_recentre.py`, decision 0133). Off by default (the lead's call: the junctions it
        adds are right, but the label stage mislabels one on seed 133, 0.043 → 0.177 % of its points more than 1 %
        off, for coverage gains of 0–1 point); off: every test relative to the candidate.
    corner_junctions: a candidate rejected only because one family ends at it (a T, straight arms) is kept as
        a junction (`corner_junctions.py`; stats["junction_corner"] says which). Off: measured not to pay
        (decision 0102). corner_dark: with it, only T's whose stem's missing side is dark (no lit lines there).
    unsuppressed_seeds: a crossing-score maximum whose ring test fails (no crossing: a wide line's own blob, a spot)
        suppresses no weaker maximum: the maxima its blob hid are looked for again in its 3×3 cells and kept as
        candidates where their own ring holds both families and no crossing is within the attachment reach
        (`unsuppressed_seeds.py`, decision 0152; on by default since decision 0153). Off: every maximum suppresses
        its 3×3 cells.
    unsuppressed_past_blob: with unsuppressed_seeds, the samples of a released blob's line within the attachment
        reach of the blob on its far side from the new candidate it released are no line samples (family 0 in the
        observation): the blob is light that is neither one line's ridge nor a crossing, and where it lies at a
        depth edge the new crossing's label would run through it onto another surface's line collinear with its own
        (`unsuppressed_seeds.past_blobs`, decision 0153; stats["samples_past_blob"]). Off: they are kept.
    crossing_pull: a sample a kept junction's arm holds is moved back by the first-order pull of the other
        family's line (its blurred profile adds a slope across the sample's ridge next to the crossing;
        `crossing_pull.py`, decision 0154), computed from the junction's two fitted lines; samples closer than
        crossing_pull_min_sigma·σ to the other line (where the two ridges merge) are not moved. The moved positions
        are `GridObservation.q_unpulled`, which the pipeline triangulates; `q` stays the ridge centres the label stage
        works on unless crossing_pull_in_labels (measured: a few labels change, decision 0154). Off: no q_unpulled.
    """

    sigma_px: float | None = None
    threshold_sigma: float = 5.0
    min_relative_strength: float = 0.15
    anisotropy: float = 0.5
    crossing_anisotropy: float = 0.25
    crossing_strength: float = 0.03
    family_margin: float = 0.15
    max_segment_rms_px: float = 0.6
    max_junction_offset_px: float = 1.5
    downsample_sigma_px: float = 2.6
    max_arm_turn_deg: float = 9.0
    free_end_trim_sigma: float = 2.0
    arm_free_end_trim: bool = True
    arm_short_share: float = 0.5
    corner_junctions: bool = False
    corner_dark: bool = True
    shared_arms: bool = True
    crossing_eigen_noise: bool = True
    merge_close_candidates: bool = True
    acute_recentre: bool = False
    unsuppressed_seeds: bool = True
    unsuppressed_past_blob: bool = True
    crossing_pull: bool = True
    crossing_pull_min_sigma: float = 1.0
    crossing_pull_in_labels: bool = False
    crossing_pull_untilt: bool = False
    debug: bool = False


@dataclass(frozen=True, eq=False)
class GridObservation:
    """What extraction found in one image.

    Samples (P): q (P, 2) sub-pixel line centres; family (P,) 1 = i-line, 2 = j-line (0: no line sample, decision 0153); segment (P,) the
        segment id or −1 (−1 too for samples a kept junction holds); junction (P,) the kept junction whose
        arms hold the sample, or −1; strength (P,) the ridge's curvature (grey levels / px²).
    Junctions (M): q_junction (M, 2); junction_dir (M, 2, 2) fitted directions of the i- and j-line;
        junction_rms (M, 2) RMS distance (px) of each family's arm samples from its fitted line.
    Segments (S): segment_family (S,), segment_ends (S, 2) junction ids (−1 = none), segment_rms (S,)
        straight-line fit RMS (px), segment_centre (S, 2) and segment_dir (S, 2) of that fit.
    Edges (E): edges (E, 2) junction ids a → b, edge_family (E,), edge_delta (E, 2) the change of (i, j)
        from a to b (±1 in the index of the other family), edge_segment (E,).
    stats: counts, reasons and `ms` (time per stage).
    segment_linked (P,) int: the segment each sample was linked into before kept junctions, free-end trims
        and biased crossings took samples out of it (−1: a crossing's core or a single sample); the label
        stage's trace pieces are built from it (decision 0085). None where an observation was made without.
    q_unpulled (P, 2) or None: q with the other line's pull next to a crossing taken out (`ExtractOptions.crossing_pull`,
        decision 0154); the pipeline triangulates the line samples the label stage left where they were from it.
    """

    q: np.ndarray
    family: np.ndarray
    segment: np.ndarray
    junction: np.ndarray
    strength: np.ndarray
    q_junction: np.ndarray
    junction_dir: np.ndarray
    segment_family: np.ndarray
    segment_ends: np.ndarray
    segment_rms: np.ndarray
    segment_centre: np.ndarray
    segment_dir: np.ndarray
    edges: np.ndarray
    edge_family: np.ndarray
    edge_delta: np.ndarray
    edge_segment: np.ndarray
    stats: dict
    junction_rms: np.ndarray | None = None
    segment_linked: np.ndarray | None = None
    q_unpulled: np.ndarray | None = None


def to_grey_float(image: np.ndarray) -> np.ndarray:
    """(H, W) or (H, W, 3) uint8/uint16/float image -> (H, W) float32 on the 8-bit scale."""
    img = np.asarray(image)
    if img.ndim == 3:
        if img.shape[2] == 1:
            img = img[:, :, 0]
        else:
            img = img[:, :, :3].astype(np.float32) @ np.array([0.114, 0.587, 0.299], np.float32)  # BGR weights
    if img.dtype == np.uint16:
        return img.astype(np.float32) * np.float32(255.0 / 65535.0)
    return img.astype(np.float32, copy=False)


def image_noise_grey(img: np.ndarray) -> float:
    """Standard deviation (grey levels) of the sensor noise: the median absolute response to the 3×3
    operator [[1,−2,1],[−2,4,−2],[1,−2,1]] (which cancels planes and is 6σ for white noise; Immerkær 1996),
    on up to ~64 k pixels (row blocks spread over the image). The median keeps lines and edges from
    inflating it."""
    H, W = img.shape
    rows = max(3, min(H, 65536 // max(W, 1)))
    if rows < H:
        # blocks of 4 rows (3x3 needs neighbours), evenly spaced
        starts = _noise_row_starts(H, rows)
        if img.dtype == np.uint8 and W >= 3:  # integer responses: the same median from a kernel (0079)
            return float(_k.noise_median_u8(img, starts, True)) / (0.6745 * 6.0)
        img = np.concatenate([img[s : s + 4] for s in starts])
    elif img.dtype == np.uint8 and H >= 3 and W >= 3:
        return float(_k.noise_median_u8(img, np.zeros(0, np.intp), False)) / (0.6745 * 6.0)
    k = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32)
    r = cv2.filter2D(img.astype(np.float32, copy=False), cv2.CV_32F, k, borderType=cv2.BORDER_REFLECT)
    if rows < H:
        r = r.reshape(-1, 4, W)[:, 1:3, 1:-1]
    else:
        r = r[1:-1, 1:-1]
    a = np.abs(r).ravel()
    return float(np.partition(a, len(a) // 2)[len(a) // 2]) / (0.6745 * 6.0)


@lru_cache(maxsize=16)
def _noise_row_starts(H: int, rows: int) -> np.ndarray:
    """The first rows of `image_noise_grey`'s blocks of 4 (intp), per image height (cached: decision 0087)."""
    starts = np.linspace(0, H - 4, max(1, rows // 4)).astype(np.intp)
    starts.setflags(write=False)
    return starts


def _clip(x: float, lo: float, hi: float) -> float:
    """float(np.clip(x, lo, hi)) for Python floats, without NumPy's scalar overhead: min(max(x, lo), hi) (the
    same value, NaN included; hi when lo > hi, as np.clip)."""
    return float(min(max(x, lo), hi))


def sigma_for(model: RigModel, options: ExtractOptions) -> float:
    """The smoothing scale: given, or 0.4 × the predicted line width in the camera (at least 1 px).

    A bright bar of width w smoothed by σ ≥ w/(2√3) has a single ridge at its centre (Steger 1998)."""
    if options.sigma_px is not None:
        return float(options.sigma_px)
    return _clip(0.4 * model.line_width_cam_px, 1.0, 8.0)


@lru_cache(maxsize=16)
def _gauss_kernel(sigma: float) -> np.ndarray:
    r = max(1, int(np.ceil(3.5 * sigma)))
    k = cv2.getGaussianKernel(2 * r + 1, sigma, cv2.CV_32F)
    k.setflags(write=False)  # cached and shared between threads (decision 0087)
    return k


_workspace = threading.local()  # per thread: the full-resolution working image, reused between frames


def _work_buffer(shape: tuple[int, int]) -> np.ndarray:
    """A float32 buffer of `shape` owned by the calling thread (a fresh image-sized array per frame would be
    page-faulted in by the filter every time; decision 0063). Only `extract_grid`'s working image uses it."""
    buf = getattr(_workspace, "G", None)
    if buf is None or buf.shape != shape:
        buf = np.empty(shape, np.float32)
        _workspace.G = buf
    return buf


_RING_WALK = True  # the fused walk without the full working image (decision 0155; False: `smooth_ridges_u8`, as before)


def _ridges(G: np.ndarray, thr_lap, thr, neg_aniso, neg_cross, thr_cross=np.float32(-1.0), *,
            image: np.ndarray | None = None, taps: tuple = ()) -> tuple:
    """`_extract_kernels.ridge_pass` with its outputs in arrays owned by the calling thread (views of them
    are returned; `albedo_and_families` copies what it keeps, so nothing returned by `extract_grid` refers
    to them). The arrays start at 1/16 of the image's pixels and double when a frame needs more (decision
    0091). image, taps: smooth the 8-bit `image` into G in the same walk (`smooth_ridges_u8`; only where
    `_fused_smoothing` allows it)."""
    H, W = G.shape
    most = max(H - 2, 0) * max(W - 2, 0)  # every inner pixel
    bufs = getattr(_workspace, "ridge", None)
    cap = max(min(4096, most), (H * W) // 16) if bufs is None else len(bufs[0])
    while True:
        if bufs is None or len(bufs[0]) < cap:
            i64, f32 = np.int64, np.float32
            bufs = tuple(np.empty(cap, t) for t in (i64, i64, f32, f32, f32, f32, f32, i64, i64, f32))
            _workspace.ridge = bufs
        if image is not None and _RING_WALK:  # the working image kept as a ring of rows only (decision 0155)
            n, m, mx = _k.smooth_ridges_ring_u8(image, taps, thr_lap, thr, neg_aniso, neg_cross, *bufs, thr_cross)
        elif image is not None:
            n, m, mx = _k.smooth_ridges_u8(image, taps, G, thr_lap, thr, neg_aniso, neg_cross, *bufs, thr_cross)
        else:
            n, m, mx = _k.ridge_pass_into(G, thr_lap, thr, neg_aniso, neg_cross, *bufs, thr_cross)
        if m >= 0:
            break
        cap = min(2 * cap, most)
    u, v, ox, oy, nx, ny, st, xu, xv, xs = bufs
    return n, u[:m], v[:m], ox[:m], oy[:m], nx[:m], ny[:m], st[:m], xu[:mx], xv[:mx], xs[:mx]


@lru_cache(maxsize=16)
def _gauss_taps(sigma: float) -> tuple:
    """`_gauss_kernel(sigma)` as a tuple of float32 scalars (the form `_extract_kernels.gauss_u8` takes)."""
    return tuple(np.float32(x) for x in _gauss_kernel(sigma).ravel())


_GAUSS_WIDTH_STEP = 16  # gauss_u8 equals OpenCV's filter where its SIMD loops cover every column (decision 0091)


def _fused_smoothing(src: np.ndarray, sigma: float) -> bool:
    """Whether the full-resolution working image of `src` comes from `_extract_kernels.gauss_u8` (or its
    fused form with the ridge pass) rather than OpenCV: an 8-bit (H, W) image whose width is a multiple of
    16, a kernel of at most GAUSS_MAX_TAPS taps, both sides longer than its radius (decision 0091)."""
    if src.ndim != 2 or src.dtype != np.uint8:
        return False
    n_taps = len(_gauss_taps(sigma))
    H, W = src.shape
    return n_taps <= _k.GAUSS_MAX_TAPS and W % _GAUSS_WIDTH_STEP == 0 and min(H, W) > n_taps // 2


def _smooth(image: np.ndarray, sigma: float, scale: int, *, out: np.ndarray | None = None) -> np.ndarray:
    """The working image: Gaussian-smoothed float32 (H, W), or at half resolution (scale 2: pixel k of
    the result is full-resolution pixel 2k) with the same total smoothing. out: (H, W) float32 to write
    the full-resolution result into (scale 1 only). An 8-bit image whose width is a multiple of 16, with a
    kernel of at most `_extract_kernels.GAUSS_MAX_TAPS` taps, is filtered by `_extract_kernels.gauss_u8`
    (the same bits as OpenCV's `sepFilter2D`, ~10–20 % faster; decision 0091), anything else by OpenCV."""
    img = np.asarray(image)
    if scale == 1:
        src = img if (img.ndim == 2 and img.dtype == np.uint8) else to_grey_float(img)
        k = _gauss_kernel(sigma)
        if out is not None:
            if _fused_smoothing(src, sigma):
                _k.gauss_u8(np.ascontiguousarray(src), _gauss_taps(sigma), out)
                return out
            return cv2.sepFilter2D(src, cv2.CV_32F, k, k, dst=out, borderType=cv2.BORDER_REFLECT)
        return cv2.sepFilter2D(src, cv2.CV_32F, k, k, borderType=cv2.BORDER_REFLECT)
    half = cv2.pyrDown(to_grey_float(img))  # [1 4 6 4 1]/16: σ = 1 full-resolution px, then every 2nd pixel
    sc = float(np.sqrt(max(sigma**2 - 1.0, 0.25))) / 2
    k = _gauss_kernel(sc)
    return cv2.sepFilter2D(half, cv2.CV_32F, k, k, borderType=cv2.BORDER_REFLECT)


@lru_cache(maxsize=16)
def _laplacian_noise_gain(sigma: float, scale: int) -> float:
    """Std of the working image's discrete Laplacian per unit std of white pixel noise (numerically,
    by pushing single-pixel impulses through the same filters)."""
    n = 2 * (int(np.ceil(4 * sigma)) + 8)
    acc = 0.0
    for dy in range(scale):
        for dx in range(scale):
            delta = np.zeros((n, n), np.float32)
            delta[n // 2 + dy, n // 2 + dx] = 1
            resp = cv2.Laplacian(_smooth(delta, sigma, scale), cv2.CV_32F, ksize=1)
            acc += float((resp.astype(np.float64) ** 2).sum())
    # one impulse per phase of the decimation grid: the sum of their squared responses is the variance
    return float(np.sqrt(acc))


@lru_cache(maxsize=16)
def _second_derivative_noise_gain(sigma: float, scale: int) -> float:
    """Std of the working image's second difference along one axis ([1, −2, 1]) per unit std of white pixel
    noise (as `_laplacian_noise_gain`). The smoothed noise is isotropic, so this is the noise of the second
    derivative along any direction, to first order that of the weaker Hessian eigenvalue on a line or at a
    crossing (about 0.6 × the Laplacian's; decision 0129)."""
    n = 2 * (int(np.ceil(4 * sigma)) + 8)
    k = np.array([[1.0, -2.0, 1.0]], np.float32)
    acc = 0.0
    for dy in range(scale):
        for dx in range(scale):
            delta = np.zeros((n, n), np.float32)
            delta[n // 2 + dy, n // 2 + dx] = 1
            resp = cv2.filter2D(_smooth(delta, sigma, scale), cv2.CV_32F, k, borderType=cv2.BORDER_REFLECT)
            acc += float((resp.astype(np.float64) ** 2).sum())
    return float(np.sqrt(acc))


_PAD = 16  # margin (cells) of the lookup grids
_GRID_NARROW = True  # int16 lookup grids where the ids fit (decision 0155; False: int32 throughout, as before)
_INT16_IDS = 32767  # ids 0 … 32766 and −1 fit in an int16

_dir_f32: tuple = (None, None)  # (model.dir_cam, its float32 (gh·gw, 4) copy): the last rig's


def _dir_cam_f32(model: RigModel) -> np.ndarray:
    """model.dir_cam as the families kernel reads it, float32 (gh·gw, 4), converted once per rig (the model's
    table is read-only; decision 0087). The pair is replaced as one tuple, so threads never mix two rigs."""
    global _dir_f32
    src, conv = _dir_f32
    if src is not model.dir_cam:
        conv = np.ascontiguousarray(model.dir_cam.reshape(-1, 4), np.float32)
        conv.setflags(write=False)
        _dir_f32 = (model.dir_cam, conv)
    return conv


def extract_grid(image: np.ndarray, model: RigModel, *, options: ExtractOptions = ExtractOptions()) -> GridObservation:
    """Find line samples, families, junctions and the segment graph in one camera image (see module doc).

    image: (H, W) or (H, W, 3) uint8, uint16 or float (8-bit scale) camera image.
    """
    t0 = time.perf_counter()
    ms: dict[str, float] = {}
    sigma = sigma_for(model, options)
    scale = 2 if sigma >= options.downsample_sigma_px else 1
    img = np.asarray(image)
    if img.ndim == 3 or img.dtype != np.uint8:
        img = to_grey_float(img)
    noise_grey = image_noise_grey(img)
    noise = max(noise_grey, 0.5) * _laplacian_noise_gain(round(sigma, 3), scale)
    thr = options.threshold_sigma * noise
    thr_cross = thr
    if options.crossing_eigen_noise and scale == 1:  # −λ2 against its own noise, not the Laplacian's (0129)
        thr_cross = options.threshold_sigma * max(noise_grey, 0.5) * _second_derivative_noise_gain(round(sigma, 3), scale)
    ridge_thr = (np.float32(-0.5 * thr), np.float32(thr), np.float32(-options.anisotropy),
                 np.float32(-(options.crossing_anisotropy if scale == 1 else options.anisotropy)), np.float32(thr_cross))
    if scale == 1 and _fused_smoothing(img, sigma):
        # --- 1–2. smoothing, ridge candidates and Steger samples in one walk (decision 0091; ms["smooth"]
        # holds both, ms["ridges"] is 0)
        G = _work_buffer(img.shape[:2])
        n_cand, u, v, ox, oy, nx, ny, strength, xu, xv, xs = _ridges(
            G, *ridge_thr, image=np.ascontiguousarray(img), taps=_gauss_taps(sigma))
        t1 = time.perf_counter()
        ms["smooth"] = 1e3 * (t1 - t0)
    else:
        G = _smooth(img, sigma, scale, out=_work_buffer(img.shape[:2]) if scale == 1 else None)
        t1 = time.perf_counter()
        ms["smooth"] = 1e3 * (t1 - t0)
        # --- 1–2. ridge candidates and Steger samples ----------------------------------------------------
        n_cand, u, v, ox, oy, nx, ny, strength, xu, xv, xs = _ridges(np.ascontiguousarray(G, np.float32), *ridge_thr)
    Hw, Ww = G.shape
    s_w = sigma / scale  # smoothing in working pixels (approximately, for the geometry below)
    stats: dict = {
        "ridge_candidates": int(n_cand),
        "noise_laplacian": noise,
        "noise_grey": noise_grey,
        "sigma_px": sigma,
        "scale": scale,
    }
    t2 = time.perf_counter()
    ms["ridges"] = 1e3 * (t2 - t1)

    # --- uneven albedo: demand a fraction of the locally strongest ridge (3x3 cells of 16 px) ------------
    # --- 3. families from the predicted directions -------------------------------------------------------
    # (the model's coarse direction grid, looked up at the nearest cell; the line direction is (−ny, nx))
    gh_d, gw_d = model.dir_cam.shape[:2]
    u, v, ox, oy, nx, ny, strength, fam, qx32, qy32, xu, xv, xs = _k.albedo_and_families(
        u, v, ox, oy, nx, ny, strength, xu, xv, xs, Hw, Ww,
        np.float32(options.min_relative_strength), np.float32(options.crossing_strength),
        _dir_cam_f32(model), gh_d, gw_d, float(model.cell_px / scale),
        np.float32(options.family_margin),
    )  # fmt: skip
    # float32 sample coordinates (working px), one array per coordinate for the hot loops
    nx32, ny32 = nx, ny
    q, strength64 = _k.samples_f64(qx32, qy32, strength)
    P = len(q)
    stats["samples"] = int(P)
    t3 = time.perf_counter()
    ms["families"] = 1e3 * (t3 - t2)
    row_start = _k.row_starts(v, Hw)  # the samples of each working row (they are in scan order)

    # --- 4a. crossing candidates: local maxima of the weaker curvature ------------------------------------
    step = model.junction_step_cam_px / scale  # predicted junction spacing along a line, working px
    cell = float(max(1.5, 0.2 * step))
    r0 = _clip(1.6 * s_w + 0.5, 1.5, 0.3 * step)  # core: the crossing biases the ridge there
    r_att = float(min(r0 + 1.5 * s_w + 2.0, 0.45 * step + 1.0))  # a line reaching this close meets the crossing
    R = float(max(0.6 * step, r_att + 1.0))  # arms (further bounded by the neighbouring junctions)
    gh, gw = int(Hw / cell) + 1, int(Ww / cell) + 1
    if options.unsuppressed_seeds:  # the cells' maxima kept for the second look (0152)
        seed, cell_max = _k.crossing_seeds_max(xu, xv, xs, cell, gh, gw)
    else:
        seed = _k.crossing_seeds(xu, xv, xs, cell, gh, gw)
    if options.debug:
        stats["debug_xpix"] = (xu * scale, xv * scale, xs)
    seeds, seed_score = _k.ordered_seeds(xu, xv, xs, seed)  # weakest first: the strongest seed wins overlaps below
    stats["junction_candidates"] = int(len(seeds))
    stats["junction_radius_px"] = R * scale
    stats["junction_core_px"] = r0 * scale
    reasons = {"too_few_samples": 0, "not_through": 0, "parallel": 0, "off_centre": 0, "crooked": 0, "duplicate": 0}

    cs = 2.0  # cell of the lookup grids below (working px)
    inv_cs = np.float32(1 / cs)
    gsh2 = (int(Hw / cs) + 2, int(Ww / cs) + 2)

    # one buffer for both lookup grids; int16 while every id it can hold fits (decision 0155: half the memory the
    # stamps fill and the lookups read; the same values)
    narrow = _GRID_NARROW and 2 * len(xs) < _INT16_IDS
    grid = np.empty((gsh2[0] + 2 * _PAD, gsh2[1] + 2 * _PAD), np.int16 if narrow else np.int32)

    def stamp(centres: np.ndarray, radius: float) -> np.ndarray:
        c = np.ascontiguousarray(centres, np.float64).reshape(-1, 2)
        _k.stamp(c[:, 0].copy(), c[:, 1].copy(), float(radius), cs, grid, _PAD)
        return grid

    def look_dist(grid: np.ndarray, px: np.ndarray, py: np.ndarray, centres: np.ndarray, rmax: float):
        c32 = np.asarray(centres, np.float32).reshape(-1, 2)
        return _k.look_dist(grid, px, py, inv_cs, _PAD, c32[:, 0].copy(), c32[:, 1].copy(), np.float32(rmax))

    # sub-pixel candidates: the score-weighted centroid of the crossing pixels around each maximum (a
    # crossing is point-symmetric, so is its blob)
    seed_grid = stamp(seeds, r_att + 1.5)
    if len(seeds):
        # over the core and one smoothing scale more: on wide flat-topped lines the weaker curvature
        # peaks near the corners of the crossing, the blob as a whole is centred (decision 0058)
        seeds = _k.centroids(seed_grid, xu, xv, xs, seeds[:, 0].copy(), seeds[:, 1].copy(), cs, _PAD, max(r0 + s_w, 1.5))
        if options.merge_close_candidates:  # two maxima of one crossing's blob are one candidate (0129)
            keep_m, remap_m, mx_, my_, n_merged = merge_within(seeds[:, 0].copy(), seeds[:, 1].copy(), seed_score, r0)
            stats["junction_candidates_merged"] = int(n_merged)
            if n_merged:
                seeds = np.column_stack([mx_, my_])
                seed_score = seed_score[keep_m]
                remap_grid(seed_grid, remap_m)

    if options.debug:
        stats["debug_raw_candidates"] = seeds * scale
    # samples near each candidate; a candidate is a crossing only where both families come close
    spacing = np.zeros(len(seeds))  # per kept candidate: the spacing of its row of compressed crossings, 0: none
    past_blob = None  # samples of a released blob's line past it (0153): not line samples
    if len(seeds) and P:
        near, dist = look_dist(seed_grid, qx32, qy32, seeds, r_att)
        n_ring = _k.ring_counts(near, dist, fam, np.float32(r0), len(seeds))
        if options.unsuppressed_seeds:  # a maximum that is no crossing suppresses nothing (0152)
            # a line's own blob: one family only, about one sample per px of the ring on both sides of it
            ids, masked = _us.unsuppressed_seeds(xu, xv, xs, seed, cell, cell_max, seeds[:, 0].copy(), seeds[:, 1].copy(),
                                                 n_ring, float(max(r0 + s_w, 1.5)), float(r_att - r0))
            n_new = 0
            if len(ids):
                pos, sc_new = _us.new_candidates(
                    ids, xu, xv, xs, masked, float(max(r0 + s_w, 1.5)), seeds[:, 0].copy(), seeds[:, 1].copy(), n_ring,
                    float(r0), float(r_att), qx32, qy32, fam, near, dist, row_start, 0, Hw)
                n_new = len(pos)
                if n_new:
                    n_old = len(seeds)
                    n_ring_old = n_ring  # the rings the blobs were judged by (relook moves counts)
                    seeds = np.concatenate([seeds, pos])
                    seed_score = np.concatenate([seed_score, sc_new])
                    n_ring = np.concatenate([n_ring, np.zeros((n_new, 2), n_ring.dtype)])
                    _us.stamp_more(seeds[:, 0].copy(), seeds[:, 1].copy(), n_old, r_att + 1.5, cs, seed_grid, _PAD)
                    s32n = np.asarray(seeds, np.float32)
                    _us.relook(seed_grid, qx32, qy32, inv_cs, _PAD, s32n[:, 0].copy(), s32n[:, 1].copy(), n_old,
                               np.float32(r_att), r_att + 1.5 + 2 * cs, np.float32(r0), fam, near, dist, n_ring, row_start, 0, Hw)
                    if options.unsuppressed_past_blob:  # the released blob's line past it is not used (0153)
                        past_blob = np.zeros(P, np.bool_)
                        stats["samples_past_blob"] = int(_us.past_blobs(
                            seeds[:, 0].copy(), seeds[:, 1].copy(), n_old, n_ring_old, float(r_att - r0),
                            float(2.0 * cell + max(r0 + s_w, 1.5)) * math.sqrt(2.0), float(r_att), qx32, qy32, fam,
                            row_start, 0, Hw, past_blob))
            stats["junction_candidates_unsuppressed"] = int(n_new)
            if options.debug:
                stats["debug_raw_candidates"] = seeds * scale
        if options.debug:
            stats["debug_ring_own"] = n_ring
        if options.shared_arms and scale == 1:  # crossings a few px apart share their ring samples (0120)
            s32 = np.asarray(seeds, np.float32).reshape(-1, 2)
            spacing_raw = _k.compressed_spacing(n_ring, seeds[:, 0].copy(), seeds[:, 1].copy(), r0, r_att)
            n_ring = _k.shared_ring_counts(n_ring, spacing_raw, s32[:, 0].copy(), s32[:, 1].copy(), qx32, qy32, fam, dist,
                                           row_start, u, np.float32(r0), np.float32(r_att))
        if options.debug:
            stats["debug_ring"] = n_ring
        # the kept candidates (≥ 2 ring samples of each family), renumbered, and their coordinates as the
        # kernels below read them: one pass (decision 0087)
        remap_seed, seeds, seed_score, seeds_x, seeds_y, seeds_x32, seeds_y32, n_few = _k.keep_crossings(n_ring, seeds, seed_score)
        reasons["too_few_samples"] = int(n_few)
        core = _k.crossing_cores(near, dist, remap_seed, np.float32(r0))  # samples within r0 of a kept one
        if options.shared_arms and scale == 1:
            spacing = np.zeros(len(seeds))
            spacing[remap_seed[remap_seed >= 0]] = spacing_raw[remap_seed >= 0]
    else:
        remap_seed = np.arange(len(seeds))
        core = np.zeros(P, bool)
        seeds_x, seeds_y = seeds[:, 0].copy(), seeds[:, 1].copy()
        seeds_x32, seeds_y32 = seeds_x.astype(np.float32), seeds_y.astype(np.float32)
    ns = len(seeds)

    # --- 5a. segments: link samples outside the crossings' cores along their line -------------------------
    # each sample looks ahead along its own line: one and two steps along the dominant axis of its
    # tangent, the two pixels across that the line can reach (4 probes instead of the 12 of a 5x3 window)
    seg, S = _k.link_segments(u, v, core, qx32, qy32, nx32, ny32, fam, Hw, Ww)
    sidx, sg, seg_family = _k.segment_lists(seg, fam, S)
    seg_cen, seg_dir, seg_rms, _ = _k.line_fit(sg, sidx, qx32, qy32, S)
    stats["segments"] = int(S)

    # --- 5b. segment ends: the crossing each end reaches ---------------------------------------------------
    sproj, smin, smax = _k.segment_extents(sidx, sg, qx32, qy32, seg_cen, seg_dir, S)
    if S and ns:
        # walk from each end outwards; the first candidate within `r_side` of the walk is the one it reaches
        r_side = 1.5 + 0.75 * s_w
        probes = np.arange(0.0, r_att + 0.5, 0.75)
        # a free end running into a line of the other family is a T (rim, occlusion, shadow edge):
        # remember where, the ridge of that line is biased there
        seg_seed, t_ids = _k.end_walks(
            sidx, sg, sproj, smin, smax, qx32, qy32, nx32, ny32, fam, seg_family, seg_dir, probes, Hw, Ww,
            seed_grid, remap_seed, inv_cs, _PAD, seeds_x, seeds_y, seeds_x32, seeds_y32, np.float32(r_side), r_att + r_side, row_start, u, core,
        )  # fmt: skip
        t_points = q[t_ids]
    else:
        seg_seed = np.full((S, 2), -1, np.int64)
        t_points = np.zeros((0, 2))

    # --- 4b. junctions: line fits on the arms (the segments reaching a crossing), intersected -------------
    if S and ns:
        arm_of = _k.arms(sidx, sg, sproj, smin, smax, seg_seed, qx32, qy32, seeds_x32, seeds_y32, np.float32(R), P)
    else:
        arm_of = np.full(P, -1, np.intp)
    corner = None
    if not ns:
        valid = np.zeros(ns, bool)
        qj = np.full((ns, 2), np.nan)
        rms_j = np.zeros((ns, 2))
    else:
        cen, dr, rms, cnt, n_neg, n_pos, m_neg, m_pos, mean_sin = _k.junction_fits(arm_of, fam, qx32, qy32, nx32, ny32, seeds_x, seeds_y, ns)
        if options.arm_free_end_trim and options.free_end_trim_sigma > 0:
            # bent arms: fitted again without the samples next to a free segment end, where a silhouette or
            # a shadow cuts the line and its ridge bends (decision 0077); the fits are replaced in place
            stats["junctions_arms_trimmed"] = retry_trimmed_arms(
                (cen, dr, rms, cnt, n_neg, n_pos, m_neg, m_pos, mean_sin), arm_of, (sidx, sg, sproj, smin, smax, seg_seed),
                options.free_end_trim_sigma * s_w, (fam, qx32, qy32, nx32, ny32), (seeds_x, seeds_y),
                rms_tol=options.max_segment_rms_px / scale, sin_tol=float(np.sin(np.deg2rad(options.max_arm_turn_deg))),
                r_short=max(options.arm_short_share * R, r_att + 1.0) if options.arm_short_share > 0 else 0.0)
        if options.shared_arms and scale == 1:  # arms of one or two samples: the samples around it (0120)
            stats["junctions_shared_arms"] = _k.shared_arm_fits(
                (cen, dr, rms, cnt, n_neg, n_pos, m_neg, m_pos, mean_sin), core, row_start, u, fam,
                qx32, qy32, nx32, ny32, seeds_x, seeds_y, np.maximum(R, 1.5 * spacing).astype(np.float32))
        # in one kernel (decision 0079), in this order, each reason counting the candidates still valid:
        # a line that jumps sideways at the crossing (a depth edge: two surfaces' lines meeting) is no
        # crossing: compare the mean signed offsets from the fit on both sides; and with few samples the
        # fit turns to absorb such a jump: the samples' own directions (across-line normals) then
        # disagree with the fitted direction. Then too few samples; a line not running through (no
        # samples on one side); the two fits parallel; their intersection qj off the candidate (or not
        # finite); an arm crooked (RMS) or jumping.
        valid, qj, jump, par, offc, cross, counts = _k.junction_verdicts(
            cen, dr, rms, cnt, n_neg, n_pos, m_neg, m_pos, mean_sin, seeds_x, seeds_y, options.max_segment_rms_px / scale,
            float(np.sin(np.deg2rad(options.max_arm_turn_deg))), max(options.max_junction_offset_px / scale, 0.5 * r0 + 0.5),
            options.max_segment_rms_px / scale,
        )  # fmt: skip
        if options.acute_recentre:  # acute crossings: sides from the arms' intersection, not the blob (0133)
            off_tol = max(options.max_junction_offset_px / scale, 0.5 * r0 + 0.5)
            retry, mx, my = acute_retry(valid, cnt, n_neg, n_pos, par, offc, qj, dr, seeds_x, seeds_y, off_tol)
            n_re = 0
            if retry.any():
                fits = (cen, dr, rms, cnt, n_neg, n_pos, m_neg, m_pos, mean_sin)
                ok = recentre_acute(fits, _k.junction_fits(arm_of, fam, qx32, qy32, nx32, ny32, mx, my, ns), retry)
                if ok.any():
                    valid, qj, jump, par, offc, cross, counts = _k.junction_verdicts(
                        cen, dr, rms, cnt, n_neg, n_pos, m_neg, m_pos, mean_sin, np.where(ok, mx, seeds_x), np.where(ok, my, seeds_y),
                        options.max_segment_rms_px / scale, float(np.sin(np.deg2rad(options.max_arm_turn_deg))), off_tol,
                        options.max_segment_rms_px / scale,
                    )  # fmt: skip
                    n_re = int((ok & valid).sum())
            stats["junctions_recentred"] = n_re
        if options.corner_junctions:  # T's: one family through, straight arms (decision 0102)
            corner = corner_candidates(valid, cnt, n_neg, n_pos, rms, jump, par, offc, qj, options.max_segment_rms_px / scale)
            if options.corner_dark:
                stats["corners_not_dark"] = dark_beyond(corner, qj, dr, n_neg, n_pos, qx32, qy32, r0 + s_w + 1.0, step, 0.5 * step, 2)
            valid |= corner
        reasons["too_few_samples"] += int(counts[0])
        reasons["not_through"] = int(counts[1])
        reasons["parallel"] = int(counts[2])
        reasons["off_centre"] = int(counts[3])
        reasons["crooked"] = int(counts[4])
        n_neg, n_pos = n_neg.reshape(ns, 2), n_pos.reshape(ns, 2)
        dr = dr.reshape(ns, 2, 2)
        rms = rms.reshape(ns, 2)
        cnt = cnt.reshape(ns, 2)
        rms_j = rms
        # two candidates on one crossing converge to one intersection: keep the stronger
        reasons["duplicate"] = int(_k.drop_duplicates(valid, qj, seed_score))
        if options.debug:
            stats["debug_fit"] = {"dr": dr * 1.0, "cnt": cnt, "n_neg": n_neg, "n_pos": n_pos, "rms": rms, "qj": qj * scale, "jump": jump, "jump_off": np.abs(m_neg - m_pos).reshape(ns, 2) * scale, "mean_sin": mean_sin.reshape(ns, 2), "offc": offc, "par": par, "cross": cross}
    stats["junctions_rejected"] = reasons
    if options.debug:
        stats["debug_seg"] = seg
        stats["debug_seg_seed"] = seg_seed
        stats["debug_core"] = core
        stats["debug_candidates"] = seeds * scale
        stats["debug_valid"] = valid.copy()
        stats["debug_arm_of"] = arm_of.copy()
    if ns:  # the kept junctions' ids, positions, fitted i- and j-line directions, RMS (px); the segments' ends
        new_id, q_junction, junction_dir, junction_rms, segment_ends = _k.kept_junctions(valid, qj, dr, rms_j, scale, seg_seed)
    else:
        new_id = np.full(1, -1, np.int64)
        q_junction, junction_dir, junction_rms = qj[valid], np.zeros((0, 2, 2)), np.zeros((0, 2))
        segment_ends = new_id[seg_seed]
    M = len(q_junction)
    stats["junctions"] = M
    if corner is not None:
        stats["junction_corner"] = corner_kinds(corner & valid, n_neg.reshape(-1), n_pos.reshape(-1), new_id, M)
    # samples a kept junction holds are reported with it, not with their segment; near a rejected
    # crossing (T- and L-shapes: the pattern's rim, occlusions) the other line's light biases the ridge,
    # so samples there are left out of their segment
    sample_junction, seg_out = _k.junction_sample_ids(arm_of, new_id, seg)
    if S and options.free_end_trim_sigma > 0:
        # a line cut by a silhouette or a shadow edge is half a bar there: its ridge bends away from the true
        # centre within about one smoothing scale of the cut; samples that close to a free end (one that
        # reaches no crossing) are left out of their segment (decision 0059)
        d_trim = options.free_end_trim_sigma * s_w
        n_near = _k.trim_free_ends(seg_out, sidx, sg, sproj, smin, smax, seg_seed, sample_junction, d_trim)
        stats["end_trimmed_samples"] = n_near
    biased = np.concatenate([seeds[~valid], t_points])
    if len(biased) and P:
        r_bias = r0 + s_w
        b32 = np.asarray(biased, np.float32).reshape(-1, 2)
        if grid.dtype == np.int16 and len(biased) >= _INT16_IDS:
            grid = np.empty(grid.shape, np.int32)
        stats["biased_samples"] = _k.leave_near(
            stamp(biased, r_bias), qx32, qy32, inv_cs, _PAD, b32[:, 0].copy(), b32[:, 1].copy(), np.float32(r_bias), sample_junction, seg_out
        )  # fmt: skip
    t4 = time.perf_counter()
    ms["junctions+segments"] = 1e3 * (t4 - t3)

    # --- edges: two ends on two junctions, straight along the chord --------------------------------------
    # (a candidate edge: both ends on two different junctions; the samples' distances from the chord)
    cand, rms_ch, max_ch = _k.chord_stats_ends(seg, segment_ends, q_junction, qx32, qy32, S)
    tol = options.max_segment_rms_px / scale
    # the straight ones (RMS and maximum distance from the chord), their junctions, midpoints and lengths
    sid, a_j, b_j, fam_s, mid, dq, elen, n_crooked = _k.edge_candidates(
        cand, rms_ch, max_ch, tol, 3 * tol + 0.5, segment_ends, seg_family, q_junction, scale
    )
    stats["segments_crooked"] = int(n_crooked)
    # index change along the edge, from the predicted camera->projector Jacobian at its midpoint (the model's
    # coarse grid, nearest cell): the sign of the step across the other family's lines; along a j-line i
    # changes, along an i-line j. A crossing nobody detected lets a segment run on to the next junction: an
    # edge about twice as long as its neighbour along the same line (at either end) skipped one; dropped.
    # One kernel (`edge_steps`, decision 0087: formerly `RigModel.lookup`, einsum and NumPy steps).
    edges, edge_family, edge_delta, edge_segment, n_skip = _k.edge_steps(
        sid, a_j, b_j, fam_s, mid, dq, elen, model.J_proj_cam, float(model.cell_px), float(model.pattern.n1),
        float(model.pattern.n2), M)
    stats["edges_skipping"] = int(n_skip)
    stats["edges"] = int(len(edges))
    q_out = q if scale == 1 else q * scale
    q_unpulled = None
    if options.crossing_pull and M:  # the other line's pull on the samples the junctions' arms hold (0154)
        dirs = junction_dir
        if options.crossing_pull_untilt:  # development option (0154's open lead): the fits' tilt taken out first
            dirs = untilted_dirs(q_out, fam, sample_junction, q_junction * scale, junction_dir, sigma,
                                 model.line_width_cam_px, options.crossing_pull_min_sigma)
        q_unpulled, stats["samples_unpulled"] = unpull_samples(
            q_out, fam, sample_junction, q_junction * scale, dirs, sigma, model.line_width_cam_px,
            options.crossing_pull_min_sigma)
        if options.crossing_pull_in_labels:
            q_out = q_unpulled
    t5 = time.perf_counter()
    ms["edges"] = 1e3 * (t5 - t4)
    ms["total"] = 1e3 * (t5 - t0)
    stats["ms"] = ms

    return GridObservation(
        q=q_out,
        family=fam if past_blob is None else np.where(past_blob, 0, fam).astype(fam.dtype),
        segment=seg_out,
        junction=sample_junction,
        strength=strength64,
        q_junction=q_junction * scale,
        junction_dir=junction_dir,
        segment_family=seg_family,
        segment_ends=segment_ends,
        segment_rms=seg_rms * scale,
        segment_centre=seg_cen * scale,
        segment_dir=seg_dir,
        edges=edges,
        edge_family=edge_family,
        edge_delta=edge_delta,
        edge_segment=edge_segment,
        stats=stats,
        junction_rms=junction_rms,
        segment_linked=seg,
        q_unpulled=q_unpulled,
    )
