"""Does the scan loop keep up with a 60 fps camera? The reconstruction beside the capture (rig/overlap.py).

    .venv/bin/python -m benchmarks.bench_stream [--frames N] [--fps F]

For each 1280x1024 benchmark scene (noise 2 grey levels, one rendered frame handed over N times from memory):

- *scan loop*: the scan loop's own parts as `rig scan` runs them: the raw frame logged to a Rerun recording
  (`Recording.log_frame`), extraction, then labelling + triangulation + the results logged (depth image, points,
  grid overlay, statistics: `rig.acquire.scan_stages`); no device I/O (a camera delivers frames by DMA; the
  trigger's serial round trip and the settle time are waits, not CPU);
- *reconstruction only*: extraction, labelling and triangulation (the issue's in-process time);

each *sequential* (both stages one after the other on one thread: `ScanRequest.overlap = False`) and *overlapped*
(each stage on its own thread, `rig.overlap.StagePipeline`, the default: extraction; labelling +
triangulation; for the scan loop also the results' logging), as fast as they go; and the
reconstruction overlapped with frames handed over at F frames/s (a camera's clock): how many scans had to wait
for room (a camera at that rate waited on) and how far behind its clock the run ended.

cv2.setNumThreads(1), as in every benchmark. Writes benchmarks/results/bench_stream.md.
"""

from __future__ import annotations

import argparse
import contextlib
import statistics
import tempfile
import time
from pathlib import Path

import cv2

from benchmarks._common import RESULTS, bench_scenes, markdown_table, render_scene, tree_state, write_markdown

OUT = RESULTS / "bench_stream.md"
SCENES = ["converged-1280", "converged-1280 noise 4", "converged-1280 pitch 16, 35/125 deg", "converged-1280 De Bruijn"]


def run(scene, image, *, frames: int, overlap: bool, fps: float | None, log: bool, workdir: Path) -> dict:
    """One run of `frames` scans of `image`: the scan loop's logging and reconstruction stages (log), or the two
    reconstruction stages alone (not log)."""
    from reconstruction.pipeline import ReconstructOptions, extract_frame, finish_frame
    from rig.acquire import InlineStages, Scan, ScanMode, ScanRequest, scan_stages
    from rig.overlap import StagePipeline
    from rig.recording import Recording

    options = ReconstructOptions(depth_min_mm=scene.depth_range_mm[0], depth_max_mm=scene.depth_range_mm[1])
    mode = ScanMode("grid", [], [0], lambda images: extract_frame(images[0], scene.procam, scene.pattern, options=options),
                    finish_frame)
    out = workdir / f"{'overlap' if overlap else 'seq'}.rrd"
    with contextlib.ExitStack() as stack:
        if log:
            rec = stack.enter_context(Recording(out, procam=scene.procam))
            steps = scan_stages(mode, rec, ScanRequest(out=out, frames=frames, overlap=overlap))
        else:
            rec = None
            steps = (lambda scan: mode.prepare(scan.images), lambda state: (0, {"points": finish_frame(state).n_points}))
        InlineStages(*steps).submit(Scan(0, 0, None, [image]))  # warm-up: compiled kernels loaded, rig model built
        stages = StagePipeline(*steps) if overlap else InlineStages(*steps)
        stack.callback(stages.close)
        points = []
        t0 = time.perf_counter()
        for k in range(frames):
            if fps:
                delay = t0 + k / fps - time.perf_counter()
                if delay > 0:
                    time.sleep(delay)
            if rec is not None:
                rec.log_frame(k, image, timestamp_s=time.monotonic())
            points += [info["points"] for _, info in stages.submit(Scan(k, k, None, [image]))]
        points += [info["points"] for _, info in stages.drain()]
        elapsed = time.perf_counter() - t0
    behind = max(0.0, elapsed - frames / fps) if fps else 0.0
    return {"fps": frames / elapsed, "waits": stages.waits, "wait_ms": 1e3 * stages.wait_s, "behind_ms": 1e3 * behind,
            "scans": len(points), "points": statistics.median(points)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=300, help="scans per run (default 300)")
    ap.add_argument("--fps", type=float, default=60.0, help="the camera's frame rate of the paced run (default 60)")
    args = ap.parse_args()
    cv2.setNumThreads(1)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for scene in bench_scenes(["tabletop"], SCENES, noise_grey=2.0):
            image, _truth = render_scene(scene.procam, scene.scene, scene.pattern, noise_grey=scene.noise_grey)
            kw = dict(frames=args.frames, workdir=Path(tmp))
            r = {
                "seq": run(scene, image, overlap=False, fps=None, log=True, **kw),
                "ovl": run(scene, image, overlap=True, fps=None, log=True, **kw),
                "seq_rec": run(scene, image, overlap=False, fps=None, log=False, **kw),
                "ovl_rec": run(scene, image, overlap=True, fps=None, log=False, **kw),
                "paced_rec": run(scene, image, overlap=True, fps=args.fps, log=False, **kw),
            }
            assert all(x["scans"] == args.frames for x in r.values())
            assert len({x["points"] for x in r.values()}) == 1, "overlap must not change the result"
            p = r["paced_rec"]
            rows.append([scene.name, f"{r['seq']['fps']:.1f}", f"{r['ovl']['fps']:.1f}", f"{r['seq_rec']['fps']:.1f}",
                         f"{r['ovl_rec']['fps']:.1f}", f"{p['waits']} of {args.frames}", f"{p['wait_ms']:.0f}",
                         f"{p['behind_ms']:.0f}", f"{r['seq']['points']:.0f}"])
            print(" | ".join(rows[-1]), flush=True)
    lines = [
        "# bench_stream",
        "",
        f"Command: `.venv/bin/python -m benchmarks.bench_stream --frames {args.frames} --fps {args.fps:g}` "
        "(noise 2 grey levels, cv2.setNumThreads(1), this machine: 2 cores).",
        "*Scan loop*: per scan the raw frame logged to a Rerun recording, extraction, labelling, triangulation and the "
        "results logged (depth image, points, grid overlay, statistics: rig.acquire.scan_stages), no device I/O. "
        "*Reconstruction only*: extraction, labelling and triangulation (the issue's in-process time). *Sequential*: "
        "both stages one after the other on one thread; *overlapped*: each stage on its own thread (rig/overlap.py; the scan loop's logging is a third stage). "
        f"*At {args.fps:g}/s*: overlapped, one frame handed over every 1/{args.fps:g} s: the scans that had to wait for "
        "room (a camera at that rate waited on), their total wait, and how far behind the camera's clock the run ended.",
        "",
        f"Working tree: {tree_state(['reconstruction', 'rig'])}.",
        "",
    ]
    lines += markdown_table(
        ["scene", "scan loop, sequential (scans/s)", "scan loop, overlapped (scans/s)", "reconstruction only, sequential",
         "reconstruction only, overlapped", f"reconstruction only at {args.fps:g}/s: scans that waited", "waited (ms)",
         "behind at the end (ms)", "points per scan"],
        rows,
    )
    write_markdown(OUT, [*lines, ""])
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
