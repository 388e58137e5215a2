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
  pixel of a line's centre, measured across the line, on the drawn part of the line; decision 0101) that have
  a reconstructed point within 1.5 camera px;
- time per stage (ms, median of --repeat rounds, 30 by default, one OpenCV thread), taken after the accuracy
  pass in rounds that run every scene and labeller once each (`time_round_robin`), so that the shared machine's
  slow spells fall on all rows alike; a round takes about half a second, so 30 rounds span long enough for a
  slow spell of a few seconds not to decide the median.
"""

from __future__ import annotations

import argparse
import statistics
import time

import cv2
import numpy as np

from benchmarks._common import (RESULTS, bench_scenes, converged_1280, coverage_lines, line_centre_pixels, markdown_table,
                                render_scene, sample_bilinear, tree_state, write_markdown)
from reconstruction.patterns import GridPattern
from reconstruction.pipeline import ReconstructOptions, reconstruct
from reconstruction.rigmodel import UNLABELLED

OUT = RESULTS / "bench_reconstruction.md"
# converged_1280 was defined here and is still imported from here by scripts outside benchmarks/.
__all__ = ["OUT", "converged_1280", "coverage", "evaluate", "line_pixels", "main", "scenes"]


def scenes(quick: bool, noise: float):
    """(name, procam, scene, pattern, depth range, noise grey levels) of every benchmark scene."""
    presets = ["paper-intermediate"] if quick else ["paper-parallel", "paper-intermediate", "paper-orthogonal", "tabletop"]
    variants = ["converged-1280"]
    if not quick:
        variants += ["converged-1280 noise 4", "converged-1280 pitch 16, 35/125 deg", "converged-1280 De Bruijn"]
    return bench_scenes(presets, variants, noise_grey=noise)


def line_pixels(truth, pattern: GridPattern) -> np.ndarray:
    """The coverage target: `benchmarks._common.line_centre_pixels`."""
    return line_centre_pixels(truth, pattern)


def coverage(truth, pattern: GridPattern, q_cam: np.ndarray) -> float:
    """Share of `line_pixels` with a reconstructed point within 1.5 camera px."""
    return coverage_lines(truth, pattern, q_cam, radius_px=1.5)


def evaluate(image, truth, procam, pattern, depth_range, labeller: str) -> dict:
    """Accuracy, labels and coverage of one reconstruction (times: `time_round_robin`)."""
    opts = ReconstructOptions(labeller=labeller, depth_min_mm=depth_range[0], depth_max_mm=depth_range[1])
    res = reconstruct(image, procam, pattern, options=opts)
    lab = res.junction_labels
    ok = lab[:, 0] != UNLABELLED
    # float32 samples: the table's figures have always been computed with them
    qp = sample_bilinear(truth.q_proj, res.junctions_cam[ok], dtype=np.float32)
    d = np.linalg.norm(qp - pattern.junction_uv(lab[ok, 0], lab[ok, 1]), axis=1)
    known = np.isfinite(d)
    p_true = sample_bilinear(truth.p_proj, res.q_cam, dtype=np.float32)
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
        "warnings": res.warnings,
        "left_out": res.stats["junctions_left_out"],
        "split": res.stats.get("components_split", 0),
        "size": f"{image.shape[1]}x{image.shape[0]}",
    }


def time_round_robin(jobs: list, repeat: int) -> list[dict]:
    """Median stage times (ms) of each job (image, procam, pattern, options), over `repeat` rounds that each run
    every job once: a slow spell of the shared machine falls on all scenes alike instead of on the one being
    timed (decision 0088's benchmark round)."""
    runs: list[list[dict]] = [[] for _ in jobs]
    for _ in range(repeat):
        for k, (image, procam, pattern, opts) in enumerate(jobs):
            runs[k].append(reconstruct(image, procam, pattern, options=opts).stats["ms"])
    return [{key: statistics.median(r[key] for r in rk) for key in ("extract", "label", "triangulate", "total")} for rk in runs]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="one paper scene and the 1280x1024 rig only")
    ap.add_argument("--repeat", type=int, default=30, help="timing rounds over all rows (median per row)")
    ap.add_argument("--noise", type=float, default=2.0)
    args = ap.parse_args()
    cv2.setNumThreads(1)
    rows = []
    jobs = []
    for name, procam, scene, pattern, dr, noise in scenes(args.quick, args.noise):
        t0 = time.perf_counter()
        img, truth = render_scene(procam, scene, pattern, noise_grey=noise, seed=0)
        print(f"{name}: rendered in {time.perf_counter() - t0:.1f} s", flush=True)
        for labeller in ("epipolar", "paper"):
            r = evaluate(img, truth, procam, pattern, dr, labeller)
            r["noise"] = noise
            rows.append((name, labeller, r))
            jobs.append((img, procam, pattern, ReconstructOptions(labeller=labeller, depth_min_mm=dr[0], depth_max_mm=dr[1])))
            print(name, labeller, {k: v for k, v in r.items() if k != "warnings"}, flush=True)
        del truth
    for (name, labeller, r), ms in zip(rows, time_round_robin(jobs, args.repeat)):
        r["ms"] = ms
        print(name, labeller, "ms", {k: round(v, 2) for k, v in ms.items()}, flush=True)
    lines = [
        "# bench_reconstruction",
        "",
        f"Command: `.venv/bin/python -m benchmarks.bench_reconstruction{' --quick' if args.quick else ''} --repeat {args.repeat}`"
        f" (noise {args.noise} grey levels, cv2.setNumThreads(1), this machine; times: medians of {args.repeat} rounds over all rows).",
        "Relative error: |p − p_true| / |p_true| in %; >1 %: share of points more than 1 % off (mislabelled);",
        "label ok: labelled junctions within 2 projector px of the true junction; coverage: lit line-centre pixels with a point within 1.5 px.",
        "",
        f"Working tree: {tree_state(['reconstruction'])}.",
        "",
    ]
    lines += markdown_table(
        ["scene", "camera", "noise", "labeller", "junctions found", "labelled", "label ok", "points", "median %", "p99 %",
         ">1 % share", "coverage %", "extract ms", "label ms", "triangulate ms", "total ms"],
        [[name, r["size"], f"{r['noise']:g}", labeller, f"{r['found']}", f"{r['labelled']}", f"{100 * r['label_ok']:.1f} %",
          f"{r['points']}", f"{r['median']:.4f}", f"{r['p99']:.3f}", f"{r['over1']:.2f}", f"{r['coverage']:.1f}",
          f"{r['ms']['extract']:.1f}", f"{r['ms']['label']:.1f}", f"{r['ms']['triangulate']:.1f}", f"{r['ms']['total']:.1f}"]
         for name, labeller, r in rows])
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
    warned = [f"- {name}: {w}" for name, labeller, r in rows if labeller == "epipolar" for w in r["warnings"]]
    lines.extend(warned or ["- none"])
    write_markdown(OUT, [*lines, ""])
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
