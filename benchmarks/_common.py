"""What the benchmark scripts share: truth sampling, scoring against the simulator's truth, the benchmark scenes,
and the markdown they write. Private (leading underscore): benchmarks/run_all.py does not run it.

- Truth sampling and scores: `sample_bilinear`, `relative_errors`, `line_centre_pixels` (the coverage target),
  `across_line_scale`, `coverage_lines`, `covered_share`,
  `evaluate_grid` / `GridScore` / `pooled` (the definitions that paper.py, sweep.py and modes.py report).
- Scenes: `converged_1280` (the 1280x1024 rig of bench_extraction and bench_reconstruction), `bench_scenes`
  (simulator presets and `converged-1280` variants as `BenchScene`s), `render_scene` (image plus truth, seeded),
  `sweep_procam` (the placement sweep's camera, also used by modes.py).
- Output: `fmt`, `markdown_table`, `write_markdown`, `tree_state` (the "Working tree:" provenance), `pyplot` and
  `save_figure` for the PNG figures.

Frames, units and pixel conventions: CONVENTIONS.md (q_cam in camera pixels, (u, v), pixel centres at integers;
points in the projector frame, mm).
"""

from __future__ import annotations

import subprocess
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, NamedTuple

import cv2
import numpy as np

from calibration.models import Intrinsics, ProCam, look_at

if TYPE_CHECKING:  # imported where used, so that scripts that only write tables do not load the pipeline
    from reconstruction.patterns import GridPattern
    from reconstruction.pipeline import Reconstruction

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
LABEL_TOL_PX = 2.0  # a junction label is correct when its pattern junction is this close to the true projector pixel


# --- truth sampling and scores -----------------------------------------------------------------------------------
def sample_bilinear(a: np.ndarray, q: np.ndarray, *, dtype: type = np.float64) -> np.ndarray:
    """a (H, W[, C]) sampled bilinearly at sub-pixel camera positions q (N, 2) (u, v): (N, C) of `dtype`;
    NaN outside the image or next to a NaN of a.

    The interpolation is OpenCV's (remap on float32), so the values are float32 ones whatever `dtype` is;
    `dtype=np.float32` keeps them float32 for callers whose arithmetic was float32."""
    if len(q) == 0:
        return np.zeros((0, a.shape[2] if a.ndim == 3 else 1), dtype)
    # OpenCV's remap takes maps of fewer than 32767 rows: lay the points out 1024 to a row.
    n = len(q)
    rows = -(-n // 1024)
    m = np.full((rows * 1024, 2), -10.0, np.float32)
    m[:n] = q
    m = m.reshape(rows, 1024, 2)
    out = cv2.remap(np.asarray(a, np.float32), m[..., 0], m[..., 1], cv2.INTER_LINEAR, borderValue=np.nan)
    return out.reshape(rows * 1024, -1)[:n].astype(dtype, copy=False)


def covered_share(target: np.ndarray, q_cam: np.ndarray, *, radius_px: float = 1.5) -> float:
    """Share of the True pixels of target (H, W) that have a point of q_cam (N, 2) (u, v), rounded to its pixel,
    within radius_px (Euclidean distance transform); NaN when target is empty."""
    if not target.any():
        return float("nan")
    mask = np.full(target.shape, 255, np.uint8)
    if len(q_cam):
        c = np.clip(np.rint(q_cam[:, 0]).astype(int), 0, target.shape[1] - 1)
        r = np.clip(np.rint(q_cam[:, 1]).astype(int), 0, target.shape[0] - 1)
        mask[r, c] = 0
    dist = cv2.distanceTransform(mask, cv2.DIST_L2, 3)
    return float((dist[target] <= radius_px).mean())


def relative_errors(points_proj: np.ndarray, q_cam: np.ndarray, truth) -> np.ndarray:
    """|p − p_true| / |p_true| (fraction) for every point whose true surface point is known (bilinear at q_cam)."""
    p_true = sample_bilinear(truth.p_proj, q_cam)
    ok = np.all(np.isfinite(p_true), axis=1)
    p = np.asarray(points_proj, np.float64)[ok]
    return np.linalg.norm(p - p_true[ok], axis=1) / np.linalg.norm(p_true[ok], axis=1)


def projector_px_per_camera_px(q_proj: np.ndarray) -> np.ndarray:
    """(H, W): the local scale of the truth's projector map q_proj (H, W, 2), projector px per camera px (the
    larger of the two image axes).

    One-sided differences, the smaller of the two per axis: at a depth edge the pixel's own surface is on one
    side, and a central difference across the edge would make a silhouette pixel look "near" every line
    (decision 0075). NaN where neither side is on a surface."""
    q = np.asarray(q_proj, np.float64)
    out = None
    for axis in (0, 1):
        d = np.linalg.norm(np.diff(q, axis=axis), axis=2)
        pad_f = [(0, 1), (0, 0)] if axis == 0 else [(0, 0), (0, 1)]
        pad_b = [(1, 0), (0, 0)] if axis == 0 else [(0, 0), (1, 0)]
        s = np.fmin(np.pad(d, pad_f, constant_values=np.nan), np.pad(d, pad_b, constant_values=np.nan))
        out = s if out is None else np.fmax(out, s)
    return out


def across_line_scale(s: np.ndarray) -> np.ndarray:
    """(H, W): |grad s| in units of s per camera px, for a field s (H, W) such as a line family's across-line
    projector coordinate: how many projector px one camera px moves across that family's lines.

    Per axis the one-sided difference of smaller magnitude (sign kept), as in `projector_px_per_camera_px`: at a
    depth edge the pixel's own surface is on one side of it (decision 0075). NaN where neither side is on a
    surface."""
    g = []
    for axis in (0, 1):
        d = np.diff(s, axis=axis)
        pad_f = [(0, 1), (0, 0)] if axis == 0 else [(0, 0), (0, 1)]
        pad_b = [(1, 0), (0, 0)] if axis == 0 else [(0, 0), (1, 0)]
        fw = np.pad(d, pad_f, constant_values=np.nan)
        bw = np.pad(d, pad_b, constant_values=np.nan)
        g.append(np.where(np.isnan(fw) | (np.abs(bw) < np.abs(fw)), bw, fw))
    return np.hypot(g[0], g[1])


def line_centre_pixels(truth, pattern: GridPattern) -> np.ndarray:
    """(H, W) bool: the visible, lit camera pixels on the centre of a drawn line of the pattern (the coverage
    target).

    A pixel counts when the projector pixel it sees (truth.q_proj) lies within half a camera pixel of a line's
    centre, measured across that line (the projector distance over `across_line_scale` of the family's
    across-line coordinate: a band one camera pixel wide whatever the local foreshortening, decision 0101),
    inside the part of the line the pattern draws (between its first and last crossing, see
    GridPattern.render), and the projector lights it (truth.lit). Uniform and De Bruijn spacings alike:
    distances are measured with the pattern's own offsets."""
    q = truth.q_proj.astype(np.float64)
    x = q[..., 0] - pattern.centre_px[0]
    y = q[..., 1] - pattern.centre_px[1]
    on_surface = np.isfinite(projector_px_per_camera_px(q))
    near = np.zeros(x.shape, bool)
    half = 0.5 * pattern.line_width_px
    s = {}
    for fam, n in ((1, pattern.n1), (2, pattern.n2)):
        s[fam] = (y - n * x) / np.hypot(1, n)  # distance-like coordinate across family fam (projector px)
    with np.errstate(invalid="ignore"):
        for fam, n in ((1, pattern.n1), (2, pattern.n2)):
            other, n_o = (2, pattern.n2) if fam == 1 else (1, pattern.n1)
            offs = pattern.offsets_px(fam) / np.hypot(1, n)
            k = np.clip(np.searchsorted(offs, np.nan_to_num(s[fam])), 1, len(offs) - 1)
            d = np.minimum(np.abs(s[fam] - offs[k - 1]), np.abs(s[fam] - offs[k]))
            offs_o = pattern.offsets_px(other) / np.hypot(1, n_o)
            inside = (s[other] >= offs_o[0] - half) & (s[other] <= offs_o[-1] + half)
            near |= (d <= 0.5 * across_line_scale(s[fam])) & inside
        return near & truth.lit & on_surface


def coverage_lines(truth, pattern: GridPattern, q_cam: np.ndarray, *, radius_px: float = 1.5) -> float:
    """Share of `line_centre_pixels` that have a point of q_cam within radius_px (the benchmarks' coverage)."""
    return covered_share(line_centre_pixels(truth, pattern), q_cam, radius_px=radius_px)


@dataclass
class GridScore:
    """One reconstruction scored against the truth. rel: relative errors (fraction) of every point."""

    found: int
    labelled: int
    correct: int
    points: int
    coverage: float
    ms: float
    rel: np.ndarray = field(repr=False)

    @property
    def labelled_share(self) -> float:
        return self.labelled / self.found if self.found else float("nan")

    @property
    def correct_share(self) -> float:
        return self.correct / self.labelled if self.labelled else float("nan")


def evaluate_grid(result: Reconstruction, truth, pattern: GridPattern) -> GridScore:
    """Score one reconstruction: labels within LABEL_TOL_PX of the true projector pixel, relative errors of
    every point, coverage_lines, total time."""
    from reconstruction.rigmodel import UNLABELLED

    lab = result.junction_labels
    ok = lab[:, 0] != UNLABELLED
    qp = sample_bilinear(truth.q_proj, result.junctions_cam[ok])
    d = np.linalg.norm(qp - pattern.junction_uv(lab[ok, 0], lab[ok, 1]), axis=1)
    return GridScore(
        found=int(len(lab)),
        labelled=int(ok.sum()),
        correct=int((d <= LABEL_TOL_PX).sum()),
        points=result.n_points,
        coverage=coverage_lines(truth, pattern, result.q_cam),
        ms=float(result.stats["ms"]["total"]),
        rel=relative_errors(result.points_proj, result.q_cam, truth),
    )


def pooled(scores: list[GridScore]) -> dict:
    """Scores of several frames pooled: error percentiles over all points, shares over all junctions."""
    rel = np.concatenate([s.rel for s in scores]) * 100 if scores else np.zeros(0)
    found = sum(s.found for s in scores)
    labelled = sum(s.labelled for s in scores)
    correct = sum(s.correct for s in scores)
    return {
        "found": found / max(len(scores), 1),
        "labelled_pct": 100 * labelled / found if found else float("nan"),
        "correct_pct": 100 * correct / labelled if labelled else float("nan"),
        "points": sum(s.points for s in scores) / max(len(scores), 1),
        "median_pct": float(np.median(rel)) if len(rel) else float("nan"),
        "p99_pct": float(np.percentile(rel, 99)) if len(rel) else float("nan"),
        "over1_pct": float((rel > 1).mean() * 100) if len(rel) else float("nan"),
        "coverage_pct": 100 * float(np.nanmean([s.coverage for s in scores])) if scores else float("nan"),
        "ms": float(np.median([s.ms for s in scores])) if scores else float("nan"),
    }


# --- scenes ------------------------------------------------------------------------------------------------------
def converged_1280(*, pitch_px: float = 22.0, alpha1_deg: float = 30.0, alpha2_deg: float = 120.0, spacing: str = "uniform"):
    """A well-posed 1280x1024 rig with lens distortion on both devices: a tilted plane, a sphere, a box.

    Returns (procam, scene, pattern, depth range (min, max) in mm)."""
    from drivers.sim import Box, Plane, Scene, Sphere
    from reconstruction.patterns import GridPattern

    cam = Intrinsics(1280, 1024, np.array([[1800.0, 0, 639.5], [0, 1800.0, 511.5], [0, 0, 1]]), np.array([-0.06, 0.05, 0, 0, 0]))
    prj = Intrinsics(1024, 768, np.array([[1500.0, 0, 511.5], [0, 1500.0, 383.5], [0, 0, 1]]), np.array([0.02, 0, 0, 0, 0]))
    t = np.array([220.0, 90.0, 60.0])
    procam = ProCam(cam, prj, look_at(t, np.array([0, 0, 900.0])), t)
    scene = Scene(objects=[
        Plane(np.array([0, 0, 1000.0]), np.array([0.1, -0.25, -1.0])),
        Sphere(np.array([40.0, 20.0, 850.0]), 110.0),
        Box((-150.0, 80.0, 900.0), (120.0, 120.0, 120.0), np.eye(3)),
    ])
    lines = int(2 * (330.0 // pitch_px) + 1)
    pattern = GridPattern(pitch_px=pitch_px, lines=lines, centre_px=(511.5, 383.5), line_width_px=3.0,
                          alpha1_deg=alpha1_deg, alpha2_deg=alpha2_deg, spacing=spacing)
    return procam, scene, pattern, (600.0, 1400.0)


#: The `converged-1280` variants by name: converged_1280's keywords, and the sensor noise in grey levels
#: (None: the run's --noise).
CONVERGED_VARIANTS: dict[str, tuple[dict, float | None]] = {
    "converged-1280": ({}, None),
    "converged-1280 noise 4": ({}, 4.0),
    "converged-1280 pitch 16, 35/125 deg": ({"pitch_px": 16.0, "alpha1_deg": 35.0, "alpha2_deg": 125.0}, None),
    "converged-1280 De Bruijn": ({"spacing": "debruijn"}, None),
}


class BenchScene(NamedTuple):
    """One benchmark scene; unpacks as (name, procam, scene, pattern, depth_range_mm, noise_grey)."""

    name: str
    procam: ProCam
    scene: object  # drivers.sim.Scene
    pattern: GridPattern
    depth_range_mm: tuple[float, float]
    noise_grey: float


def bench_scenes(presets: Sequence[str], variants: Sequence[str], *, noise_grey: float) -> list[BenchScene]:
    """The simulator presets named in `presets` (default GridPattern, the preset's depth range), then the
    CONVERGED_VARIANTS named in `variants`, in that order; noise_grey unless the variant fixes its own."""
    from drivers.sim import preset
    from reconstruction.patterns import GridPattern

    out = []
    for name in presets:
        rig = preset(name)
        out.append(BenchScene(name, rig.procam, rig.scene, GridPattern(), rig.depth_range_mm, noise_grey))
    for name in variants:
        kw, noise = CONVERGED_VARIANTS[name]
        procam, scene, pattern, depth_range = converged_1280(**kw)
        out.append(BenchScene(name, procam, scene, pattern, depth_range, noise_grey if noise is None else noise))
    return out


def render_scene(procam: ProCam, scene, pattern: GridPattern, *, noise_grey: float, seed: int = 0):
    """The camera image of `pattern` on `scene` and the simulator's truth: (image (H, W) uint8, drivers.sim.Truth).
    Default render options but for the sensor noise (grey levels); the noise generator is seeded with `seed`."""
    from drivers.sim import RenderOptions, render

    return render(procam, scene, pattern.render(procam.projector.width, procam.projector.height),
                  options=RenderOptions(noise_grey=noise_grey), rng=np.random.default_rng(seed))


SWEEP_TARGET_MM = np.array([0.0, 0.0, 850.0])  # the tabletop's centre, projector frame


def sweep_procam(baseline_mm: float, angle_deg: float) -> ProCam:
    """The tabletop projector with a 640x512 camera (f = 2300 px, no distortion) `baseline_mm` from it in its x-y
    plane, in direction `angle_deg` from +x towards −y (90 = above), aimed at SWEEP_TARGET_MM."""
    from drivers.sim.presets import tabletop_procam

    projector = tabletop_procam().projector
    camera = Intrinsics(640, 512, np.array([[2300.0, 0.0, 319.5], [0.0, 2300.0, 255.5], [0.0, 0.0, 1.0]]))
    a = np.deg2rad(angle_deg)
    t = baseline_mm * np.array([np.cos(a), -np.sin(a), 0.0])
    return ProCam(camera, projector, look_at(t, SWEEP_TARGET_MM), t)


# --- output ------------------------------------------------------------------------------------------------------
def fmt(x: float, digits: int = 2) -> str:
    """x with `digits` decimals; an en dash for NaN or infinity."""
    return "–" if not np.isfinite(x) else f"{x:.{digits}f}"


def markdown_table(header: Sequence[str], rows: Iterable[Sequence[str]], *, align: str | None = None) -> list[str]:
    """The lines of a markdown table: header, rule, one line per row of already formatted cells.

    align: one letter per column, "l" (rule `---`) or "r" (`---:`); None: all "l"."""
    rule = ["---:" if a == "r" else "---" for a in (align or "l" * len(header))]
    if len(rule) != len(header):
        raise ValueError(f"markdown_table: align has {len(rule)} letters for {len(header)} columns; give one per column")
    return ["| " + " | ".join(header) + " |", "|" + "|".join(rule) + "|", *("| " + " | ".join(r) + " |" for r in rows)]


def write_markdown(path: Path, lines: Sequence[str]) -> None:
    """Write lines joined by newlines (UTF-8) to path, making its folder. End `lines` with "" for a final newline."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines), encoding="utf-8")


def pyplot():
    """matplotlib.pyplot on the Agg backend (files only, no display), imported on first use."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig, path: Path, *, rect: tuple[float, float, float, float] | None = None) -> None:
    """Lay fig out tightly (within `rect`, figure fractions, when given), save it at 110 dpi, and close it."""
    fig.tight_layout(rect=rect)
    fig.savefig(path, dpi=110)
    pyplot().close(fig)


def tree_state(paths: Sequence[str]) -> str:
    """Which of `paths` (relative to the repository) differ from the last commit, for a results file's
    "Working tree:" line: "commit abc1234, clean", "commit abc1234, with uncommitted changes to a, b", or
    "unknown (no git)"."""
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, check=True,
                              cwd=ROOT).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--", *paths], capture_output=True, text=True, check=True,
                               cwd=ROOT).stdout.split("\n")
    except (OSError, subprocess.CalledProcessError):
        return "unknown (no git)"
    mod = [ln[3:] for ln in dirty if ln.strip()]
    return f"commit {head}" + (f", with uncommitted changes to {', '.join(mod)}" if mod else ", clean")
