"""Reconstruction accuracy, coverage, labelling and speed on simulated scenes with ground truth.

    .venv/bin/python -m benchmarks.bench_reconstruction [--quick] [--repeat N]

Scenes: the simulator's presets (the paper's three camera configurations at 758x570, the 1280x1024
tabletop rig) and a well-posed 1280x1024 rig with lens distortion on both devices (`converged-1280`),
also with 4 grey levels of noise, with a second pitch and angle pair, and with De Bruijn spacing; sensor
noise 2 grey levels unless the name says otherwise. Both labellers run on the same images. Writes
benchmarks/results/bench_reconstruction.md.

Metrics (per scene and labeller):
- junctions found / labelled, and label success: labelled junctions whose true projector pixel is within
  2 projector px of the labelled pattern junction;
- relative 3-D error of every point: |p − p_true| / |p_true| (p_true: the true surface point seen through
  the same sub-pixel camera position, bilinear), median, 99th percentile, share above 1 % (mislabelled);
- coverage: share of the visible, lit line-centre pixels (true projector position within half a camera
  pixel of a line's centre, on the drawn part of the line) that have a reconstructed point within 1.5
  camera px;
- time per stage (ms, median of --repeat runs, one OpenCV thread).
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import cv2
import numpy as np

from calibration.models import Intrinsics, ProCam, look_at
from reconstruction.patterns import GridPattern
from reconstruction.pipeline import ReconstructOptions, reconstruct
from reconstruction.rigmodel import UNLABELLED

OUT = Path(__file__).resolve().parent / "results" / "bench_reconstruction.md"


def _sample(a: np.ndarray, q: np.ndarray) -> np.ndarray:
    if len(q) == 0:
        return np.zeros((0, a.shape[2] if a.ndim == 3 else 1))
    m = q.astype(np.float32).reshape(-1, 1, 2)
    return cv2.remap(a.astype(np.float32), m[..., 0], m[..., 1], cv2.INTER_LINEAR, borderValue=np.nan).reshape(len(q), -1)


def converged_1280(*, pitch_px: float = 22.0, alpha1_deg: float = 30.0, alpha2_deg: float = 120.0, spacing: str = "uniform"):
    """A well-posed 1280x1024 rig with lens distortion on both devices: a tilted plane, a sphere, a box."""
    from drivers.sim import Plane, Scene, Sphere, Box

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


def scenes(quick: bool, noise: float):
    """(name, procam, scene, pattern, depth range, noise grey levels) of every benchmark scene."""
    from drivers.sim import preset

    out = []
    names = ["paper-parallel", "paper-intermediate", "paper-orthogonal", "tabletop"]
    if quick:
        names = ["paper-intermediate"]
    for name in names:
        rig = preset(name)
        out.append((name, rig.procam, rig.scene, GridPattern(), rig.depth_range_mm, noise))
    variants = [("converged-1280", {}, noise)]
    if not quick:
        variants += [
            ("converged-1280 noise 4", {}, 4.0),
            ("converged-1280 pitch 16, 35/125 deg", {"pitch_px": 16.0, "alpha1_deg": 35.0, "alpha2_deg": 125.0}, noise),
            ("converged-1280 De Bruijn", {"spacing": "debruijn"}, noise),
        ]
    for name, kw, nz in variants:
        procam, scene, pattern, dr = converged_1280(**kw)
        out.append((name, procam, scene, pattern, dr, nz))
    return out


def line_pixels(truth, pattern: GridPattern) -> np.ndarray:
    """(H, W) bool: visible, lit camera pixels on the centre of a drawn line of the pattern.

    A pixel counts when the projector pixel it sees (truth.q_proj) lies within half a camera pixel (in
    projector px, from the truth's own local scale) of a line's centre, and inside the part of the line that
    the pattern draws (between its first and last crossing, see GridPattern.render), and the projector
    lights it (truth.lit)."""
    q = truth.q_proj.astype(np.float64)
    x = q[..., 0] - pattern.centre_px[0]
    y = q[..., 1] - pattern.centre_px[1]
    # projector px per camera px (local), from the truth's own gradient
    gu = np.linalg.norm(np.gradient(q, axis=1), axis=2)
    gv = np.linalg.norm(np.gradient(q, axis=0), axis=2)
    scale = np.maximum(gu, gv)
    near = np.zeros(x.shape, bool)
    half = 0.5 * pattern.line_width_px
    s = {}
    for fam, n in ((1, pattern.n1), (2, pattern.n2)):
        s[fam] = (y - n * x) / np.hypot(1, n)  # signed distance-like coordinate across family fam
    for fam, n in ((1, pattern.n1), (2, pattern.n2)):
        other, n_o = (2, pattern.n2) if fam == 1 else (1, pattern.n1)
        offs = pattern.offsets_px(fam) / np.hypot(1, n)
        k = np.clip(np.searchsorted(offs, s[fam]), 1, len(offs) - 1)
        d = np.minimum(np.abs(s[fam] - offs[k - 1]), np.abs(s[fam] - offs[k]))
        offs_o = pattern.offsets_px(other) / np.hypot(1, n_o)
        inside = (s[other] >= offs_o[0] - half) & (s[other] <= offs_o[-1] + half)
        near |= (d <= 0.5 * scale) & inside
    with np.errstate(invalid="ignore"):
        return near & truth.lit & np.isfinite(scale)


def coverage(truth, pattern: GridPattern, q_cam: np.ndarray) -> float:
    """Share of `line_pixels` with a reconstructed point within 1.5 camera px."""
    target = line_pixels(truth, pattern)
    if not target.any():
        return float("nan")
    mask = np.full(target.shape, 255, np.uint8)
    c = np.clip(np.rint(q_cam[:, 0]).astype(int), 0, target.shape[1] - 1)
    r = np.clip(np.rint(q_cam[:, 1]).astype(int), 0, target.shape[0] - 1)
    mask[r, c] = 0
    dist = cv2.distanceTransform(mask, cv2.DIST_L2, 3)
    return float((dist[target] <= 1.5).mean())


def evaluate(image, truth, procam, pattern, depth_range, labeller: str, repeat: int) -> dict:
    opts = ReconstructOptions(labeller=labeller, depth_min_mm=depth_range[0], depth_max_mm=depth_range[1])
    reconstruct(image, procam, pattern, options=opts)  # warm the per-rig cache
    runs = []
    for _ in range(repeat):
        res = reconstruct(image, procam, pattern, options=opts)
        runs.append(res.stats["ms"])
    ms = {k: statistics.median(r[k] for r in runs) for k in ("extract", "label", "triangulate", "total")}
    lab = res.junction_labels
    ok = lab[:, 0] != UNLABELLED
    qp = _sample(truth.q_proj, res.junctions_cam[ok].astype(np.float64))
    d = np.linalg.norm(qp - pattern.junction_uv(lab[ok, 0], lab[ok, 1]), axis=1)
    known = np.isfinite(d)
    p_true = _sample(truth.p_proj, res.q_cam.astype(np.float64))
    good = np.isfinite(p_true).all(axis=1)
    rel = np.linalg.norm(res.points_proj[good] - p_true[good], axis=1) / np.linalg.norm(p_true[good], axis=1) * 100
    return {
        "found": res.stats["junctions_found"],
        "labelled": int(ok.sum()),
        "label_ok": float((d[known] <= 2.0).mean()) if known.any() else float("nan"),
        "points": res.n_points,
        "median": float(np.median(rel)) if len(rel) else float("nan"),
        "p99": float(np.percentile(rel, 99)) if len(rel) else float("nan"),
        "over1": float((rel > 1).mean() * 100) if len(rel) else float("nan"),
        "coverage": coverage(truth, pattern, res.q_cam) * 100,
        "ms": ms,
        "warnings": res.warnings,
        "left_out": res.stats["junctions_left_out"],
        "split": res.stats.get("components_split", 0),
        "size": f"{image.shape[1]}x{image.shape[0]}",
    }


def _tree_state() -> str:
    """Which reconstruction sources differ from the last commit (the table measures the working tree)."""
    import subprocess

    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--", "reconstruction"], capture_output=True, text=True, check=True).stdout.split("\n")
    except (OSError, subprocess.CalledProcessError):
        return "unknown (no git)"
    mod = [ln[3:] for ln in dirty if ln.strip()]
    return f"commit {head}" + (f", with uncommitted changes to {', '.join(mod)}" if mod else ", clean")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="one paper scene and the 1280x1024 rig only")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--noise", type=float, default=2.0)
    args = ap.parse_args()
    cv2.setNumThreads(1)
    from drivers.sim import RenderOptions, render

    rows = []
    for name, procam, scene, pattern, dr, noise in scenes(args.quick, args.noise):
        t0 = time.perf_counter()
        img, truth = render(procam, scene, pattern.render(procam.projector.width, procam.projector.height),
                            options=RenderOptions(noise_grey=noise), rng=np.random.default_rng(0))
        print(f"{name}: rendered in {time.perf_counter() - t0:.1f} s", flush=True)
        for labeller in ("epipolar", "paper"):
            r = evaluate(img, truth, procam, pattern, dr, labeller, args.repeat)
            r["noise"] = noise
            rows.append((name, labeller, r))
            print(name, labeller, {k: v for k, v in r.items() if k != "warnings"}, flush=True)
    lines = [
        "# bench_reconstruction",
        "",
        f"Command: `.venv/bin/python -m benchmarks.bench_reconstruction{' --quick' if args.quick else ''} --repeat {args.repeat}`"
        f" (noise {args.noise} grey levels, cv2.setNumThreads(1), this machine).",
        "Relative error: |p − p_true| / |p_true| in %; >1 %: share of points more than 1 % off (mislabelled);",
        "label ok: labelled junctions within 2 projector px of the true junction; coverage: lit line-centre pixels with a point within 1.5 px.",
        "",
        f"Working tree: {_tree_state()}.",
        "",
        "| scene | camera | noise | labeller | junctions found | labelled | label ok | points | median % | p99 % | >1 % share | coverage % | extract ms | label ms | triangulate ms | total ms |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, labeller, r in rows:
        m = r["ms"]
        lines.append(
            f"| {name} | {r['size']} | {r['noise']:g} | {labeller} | {r['found']} | {r['labelled']} | {100 * r['label_ok']:.1f} % | {r['points']} | "
            f"{r['median']:.4f} | {r['p99']:.3f} | {r['over1']:.2f} | {r['coverage']:.1f} | {m['extract']:.1f} | {m['label']:.1f} | "
            f"{m['triangulate']:.1f} | {m['total']:.1f} |"
        )
    lines.append("")
    lines.append("Junctions left out per scene (epipolar labeller), by reason:")
    lines.append("")
    for name, labeller, r in rows:
        if labeller == "epipolar":
            lo = {k: v for k, v in r["left_out"].items() if v}
            lines.append(f"- {name}: {lo or 'none'}; components split at outliers: {r['split']}")
    lines.append("")
    lines.append("Warnings per scene (epipolar labeller):")
    lines.append("")
    for name, labeller, r in rows:
        if labeller == "epipolar":
            for w in r["warnings"]:
                lines.append(f"- {name}: {w}")
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text("\n".join(lines) + "\n")
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
