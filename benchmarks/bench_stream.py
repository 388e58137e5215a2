"""Does the scan loop keep up with the camera? The reconstruction beside the capture (rig/overlap.py).

    .venv/bin/python -m benchmarks.bench_stream [--frames N]

For each 1280x1024 benchmark scene (noise 2 grey levels, one rendered frame handed over N times from memory),
scans per second of:

- *reconstruction only*: extraction, labelling and triangulation (the issue's in-process time);
- *scan loop*: the scan loop's own parts as `rig scan` runs them: the raw frame logged to a Rerun recording
  (`Recording.log_frame`), extraction, then labelling + triangulation, then the results logged (depth image,
  points, grid overlay, statistics: `rig.acquire.scan_stages`); no device I/O;
- *scan loop with the capture's waits*: the same with the default capture timing of `rig scan` on a real rig
  slept on the capture thread before each scan: the pattern switch's settle time plus one exposure
  (`[camera] settle_ms` 20 + `exposure_ms` 16.667; the trigger's serial round trip left out). Sleeping releases
  the CPU, as waiting for a camera frame does.

each *sequential* (the stages one after the other on the capture thread: `ScanRequest.overlap = False`) and
*overlapped* (each stage on its own thread, `rig.overlap.StagePipeline`, the default).

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
CAPTURE_S = (20.0 + 16.667) / 1000.0  # rig scan's defaults: [camera] settle_ms + exposure_ms
SCENES = ["converged-1280", "converged-1280 noise 4", "converged-1280 pitch 16, 35/125 deg", "converged-1280 De Bruijn"]


def run(scene, image, *, frames: int, overlap: bool, log: bool, capture_s: float, workdir: Path) -> dict:
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
            if capture_s:
                time.sleep(capture_s)  # the pattern switch's settle time and the exposure: the capture waits
            if rec is not None:
                rec.log_frame(k, image, timestamp_s=time.monotonic())
            points += [info["points"] for _, info in stages.submit(Scan(k, k, None, [image]))]
        points += [info["points"] for _, info in stages.drain()]
        elapsed = time.perf_counter() - t0
    return {"fps": frames / elapsed, "scans": len(points), "points": statistics.median(points)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=200, help="scans per run (default 200)")
    args = ap.parse_args()
    cv2.setNumThreads(1)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for scene in bench_scenes(["tabletop"], SCENES, noise_grey=2.0):
            image, _truth = render_scene(scene.procam, scene.scene, scene.pattern, noise_grey=scene.noise_grey)
            kw = dict(frames=args.frames, workdir=Path(tmp))
            r = {}
            for name, log, capture_s in (("rec", False, 0.0), ("loop", True, 0.0), ("cap", True, CAPTURE_S)):
                for overlap in (False, True):
                    r[name, overlap] = run(scene, image, overlap=overlap, log=log, capture_s=capture_s, **kw)
            assert all(x["scans"] == args.frames for x in r.values())
            assert len({x["points"] for x in r.values()}) == 1, "overlap must not change the result"
            rows.append([scene.name, *(f"{r[key]['fps']:.1f}" for key in r), f"{r['rec', False]['points']:.0f}"])
            print(" | ".join(rows[-1]), flush=True)
    lines = [
        "# bench_stream",
        "",
        f"Command: `.venv/bin/python -m benchmarks.bench_stream --frames {args.frames}` "
        "(noise 2 grey levels, cv2.setNumThreads(1), this machine: 2 cores).",
        "Scans per second. *Reconstruction*: extraction, labelling, triangulation. *Scan loop*: also the raw frame and "
        "the results logged to a Rerun recording (depth image, points, grid overlay, statistics), no device I/O. "
        f"*With the capture's waits*: the scan loop plus {1e3 * CAPTURE_S:.1f} ms slept on the capture thread per scan "
        "(rig scan's default settle time and exposure). *seq*: the stages one after the other on the capture thread; "
        "*overlap*: each stage on its own thread (rig/overlap.py, the default).",
        "",
        f"Working tree: {tree_state(['reconstruction', 'rig'])}.",
        "",
    ]
    lines += markdown_table(
        ["scene", "reconstruction, seq", "reconstruction, overlap", "scan loop, seq", "scan loop, overlap",
         "with the capture's waits, seq", "with the capture's waits, overlap", "points per scan"],
        rows,
    )
    write_markdown(OUT, [*lines, ""])
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
