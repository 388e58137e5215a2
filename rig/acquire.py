"""The acquisition loop: show/trigger → acknowledgement → settle → grab → verify → write raw → log raw → reconstruct.

Orchestration only; every device call goes through the protocols in drivers.base. The reconstruction of a scan
runs beside the capture of the next ones (rig/overlap.py: extraction, labelling + triangulation, logging, each on
its own thread, in scan order; decision 0088), so the loop waits for it only when the first stage is busy and two
scans are queued before it. Memory stays constant over any number of frames (at most a few scans in flight; nothing
is kept after a scan is logged). Ctrl-C stops cleanly: the frames captured so far stay on disk, the scans already
captured are reconstructed, and the recording is closed properly.
"""

from __future__ import annotations

import contextlib
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from calibration.errors import DeviceError, RigError
from calibration.file import CalibrationFile, dumps_calibration, write_text_atomic
from rig.config import RigConfig, config_to_toml
from rig.overlap import StagePipeline


@dataclass(frozen=True)
class ScanRequest:
    """What `rig scan` was asked for. Products named with `ply`/`depth` get a _NNNNNN suffix when frames > 1."""

    out: Path
    frames: int = 1
    record: Path | None = None
    ply: Path | None = None
    depth: Path | None = None
    reconstruct: bool = True
    pattern: str = "grid"
    overlap: bool = True  # reconstruct beside the capture (False: after each scan, on the calling thread)


@dataclass
class ScanSummary:
    out: Path
    scans_requested: int
    frames_captured: int = 0
    scans_done: int = 0
    points_total: int = 0
    interrupted: bool = False
    error: str | None = None
    record: Path | None = None
    reconstructed: bool = False
    warnings: list[str] = field(default_factory=list)
    calibration_source: str = ""
    capture_waits: int = 0  # scans whose capture waited for the reconstruction to make room
    capture_wait_s: float = 0.0


def _numbered(path: Path | None, index: int, total: int) -> Path | None:
    if path is None or total == 1:
        return path
    return path.with_name(f"{path.stem}_{index:06d}{path.suffix}")


def _black_level(image: np.ndarray) -> float:
    """Brightest grey level in the frame, on an 8-bit scale."""
    peak = float(np.percentile(image[::4, ::4], 99.5))
    return peak / 257.0 if image.dtype == np.uint16 else peak


def grab_verified(camera, shown, *, settle_s: float, timeout_s: float, black_grey: float = 8.0):
    """Grab the first frame exposed after the pattern switch plus the settle time; reject black frames.

    A black frame (lens cap, exposure far too short, projector dark) is grabbed again once, then an error.
    """
    after = shown.host_time_s + settle_s
    for attempt in range(2):
        frame = camera.grab(after_s=after, timeout_s=timeout_s)
        if frame.timestamp_s < after:
            raise DeviceError(
                f"camera returned a frame from {after - frame.timestamp_s:.3f} s before the pattern switch plus settle "
                "time (stale buffer); the driver must drop queued frames"
            )
        if _black_level(frame.image) >= black_grey:
            return frame
        after = frame.timestamp_s
    raise DeviceError(
        "the camera frame is black (99.5th percentile below 8 grey levels): check the lens cap, the exposure "
        "([camera] exposure_ms) and that the projector is on and showing the pattern"
    )


@dataclass(frozen=True)
class ScanMode:
    """What one scan projects and how its frames become a reconstruction.

    patterns: the projector images (pattern ids are their positions); sequence: the pattern ids shown, in
    order, for one scan (one frame each). The reconstruction in two stages (rig/overlap.py runs them, and the
    logging after them, on threads of their own): prepare(images) -> state, finish(state) -> result with
    points_proj, depth_cam, stats, warnings (a reconstruction.pipeline.Reconstruction); both None when the scan
    only captures.
    """

    name: str
    patterns: list
    sequence: list[int]
    prepare: Callable | None
    finish: Callable | None

    @property
    def reconstructs(self) -> bool:
        return self.finish is not None


def scan_mode(cfg: RigConfig, procam, *, pattern: str, reconstruct: bool) -> ScanMode:
    """The grid (one frame per scan) or the Gray-code mode (2·(⌈log2 W⌉ + ⌈log2 H⌉) + 2 frames per scan)."""
    from calibration.errors import ConfigError

    w, h = procam.projector.width, procam.projector.height
    if pattern == "grid":
        problem = cfg.pattern.fits(w, h)
        if problem:
            raise ConfigError(f"[pattern]: {problem}")
        return ScanMode("grid", [cfg.pattern.render(w, h)], [0], *(_grid_stages(cfg, procam) if reconstruct else (None, None)))
    if pattern == "graycode":
        from reconstruction.graycode_depth import graycode_scan_patterns

        patterns = graycode_scan_patterns(w, h)
        return ScanMode(
            "graycode", patterns, list(range(len(patterns))), *(_graycode_stages(cfg, procam) if reconstruct else (None, None))
        )
    raise ConfigError(f"--pattern {pattern!r}: expected 'grid' (single shot) or 'graycode' (dense, static scenes)")


def run_scan(
    cfg: RigConfig,
    request: ScanRequest,
    *,
    on_frame: Callable[[int, dict], None] | None = None,
) -> ScanSummary:
    """Run `request.frames` scans on the configured rig; returns the summary (also on Ctrl-C).

    Each scan shows its mode's pattern sequence, one verified frame per pattern. Device and protocol errors
    propagate after everything captured so far is closed and kept; the summary of what was kept is attached
    to the exception as `e.summary`.
    """
    from rig.recording import open_recording
    from rig.registry import open_rig

    summary = ScanSummary(out=request.out, scans_requested=request.frames, record=request.record)
    with contextlib.ExitStack() as stack:
        capture = None
        transcript = None
        if request.record is not None:
            from rig.capture import CaptureWriter

            capture = CaptureWriter(
                request.record,
                header={
                    "mode": request.pattern,
                    "config": config_to_toml(cfg),
                    "pattern": cfg.pattern.model_dump(mode="json"),
                    "camera": cfg.camera.model_dump(mode="json"),
                },
            )
            stack.callback(lambda: capture.close(complete=summary.error is None and not summary.interrupted,
                                                 summary={"frames": summary.frames_captured,
                                                          "interrupted": summary.interrupted,
                                                          "error": summary.error}))
            transcript = capture.transcript_path
        rig = stack.enter_context(open_rig(cfg, transcript=transcript))
        procam = rig.procam
        summary.calibration_source = rig.calibration_source
        mode = scan_mode(cfg, procam, pattern=request.pattern, reconstruct=request.reconstruct)
        rig.projector.load(mode.patterns)
        devices = {"projector": rig.projector.describe(), "camera": rig.camera.describe()}
        if capture is not None:
            capture.header["devices"] = devices
            capture.header["calibration_source"] = rig.calibration_source
            for k, image in enumerate(mode.patterns):
                capture.write_pattern(k, image)
            write_text_atomic(capture.dir / "calibration.json", dumps_calibration(CalibrationFile.from_procam(procam)))

        summary.reconstructed = mode.reconstructs
        single = len(mode.sequence) == 1
        rec = stack.enter_context(
            open_recording(request.out, procam=procam, pattern_image=mode.patterns[0] if single else None,
                           report={"calibration": rig.calibration_source, "devices": devices, "mode": mode.name})
        )
        stages = None
        if mode.reconstructs:
            steps = scan_stages(mode, rec, request)
            stages = StagePipeline(*steps) if request.overlap else InlineStages(*steps)
            stack.callback(stages.close)  # before the recording closes (ExitStack unwinds in reverse)

        def finished(results: list, *, notify: bool = True) -> None:
            for n_done, info in results:
                summary.points_total += info.get("points", 0)
                summary.warnings.extend(f"scan {n_done}: {w}" for w in info.get("warnings", []))
                summary.scans_done += 1
                if notify and on_frame is not None:
                    on_frame(n_done, info)

        settle_s = cfg.camera.settle_ms / 1000.0
        timeout_s = cfg.camera.timeout_ms / 1000.0
        frame_no = 0
        try:
            try:
                for n in range(request.frames):
                    images = []
                    timestamp_s = None
                    for pattern_id in mode.sequence:
                        shown = rig.projector.show(pattern_id)
                        frame = grab_verified(rig.camera, shown, settle_s=settle_s, timeout_s=timeout_s,
                                              black_grey=8.0 if single else 0.0)
                        meta = {"device_time_us": shown.device_time_us, "exposure_ms": cfg.camera.exposure_ms}
                        # Raw data first: on disk (and in the recording) before anything can fail on it.
                        if capture is not None:
                            capture.write_frame(frame.image, pattern=shown.index, timestamp_s=frame.timestamp_s, **meta)
                        rec.log_frame(frame_no, frame.image, timestamp_s=frame.timestamp_s)
                        if not single:
                            rec.log_pattern(mode.patterns[pattern_id], index=pattern_id)
                        summary.frames_captured += 1
                        timestamp_s = frame.timestamp_s
                        frame_no += 1
                        images.append(frame.image)
                    if stages is None:
                        finished([(n, {"scan": n, "frame": frame_no - 1})])
                    else:
                        finished(stages.submit(Scan(n, frame_no - 1, timestamp_s, images)))
                    del images
            except KeyboardInterrupt:
                summary.interrupted = True
            if stages is not None:
                # the scans already captured are reconstructed before the recording closes; a second Ctrl-C
                # stops waiting (the raw frames are on disk: `rig reconstruct` can redo them)
                try:
                    finished(stages.drain(), notify=not summary.interrupted)
                except KeyboardInterrupt:
                    summary.interrupted = True
                summary.capture_waits, summary.capture_wait_s = stages.waits, stages.wait_s
        except RigError as e:
            summary.error = str(e)
            e.summary = summary  # type: ignore[attr-defined]
            raise
        finally:
            with contextlib.suppress(Exception):
                rig.projector.stop()
    return summary


def save_products(result, *, ply: Path | None, depth: Path | None) -> None:
    """Write a reconstruction's PLY (points + family, i, j, residual per vertex) and depth .npy, atomically."""
    from reconstruction.io import write_depth_npy, write_ply

    if ply is not None:
        lab = result.label
        write_ply(ply, result.points_proj, family=result.family, i=lab[:, 0], j=lab[:, 1], residual=result.residual)
    if depth is not None:
        write_depth_npy(depth, result.depth_cam)


@dataclass
class Scan:
    """One captured scan on its way through the reconstruction: its number, the recording frame (and exposure
    time) its results are logged at, its images."""

    n: int
    frame: int
    timestamp_s: float | None
    images: list


def scan_stages(mode: ScanMode, rec, request: ScanRequest) -> tuple[Callable, ...]:
    """The stages of a scan for rig/overlap.py: the mode's first stage; its second; then the log on the scan's
    own frame (Rerun's time is per thread) and the requested products. The last returns (n, info) for `on_frame`."""
    from rig.log_reconstruction import log_reconstruction

    def first(scan: Scan):
        t0 = time.perf_counter()
        state = mode.prepare(scan.images)
        return scan, state, time.perf_counter() - t0

    def second(item):
        scan, state, s_first = item
        t0 = time.perf_counter()
        result = mode.finish(state)
        return scan, result, s_first + time.perf_counter() - t0

    def third(item) -> tuple[int, dict]:
        scan, result, s_reconstruct = item
        rec.set_frame(scan.frame, timestamp_s=scan.timestamp_s)
        log_reconstruction(rec.stream, result)
        save_products(result, ply=_numbered(request.ply, scan.n, request.frames), depth=_numbered(request.depth, scan.n, request.frames))
        info = {"scan": scan.n, "frame": scan.frame, "points": int(len(result.points_proj)), "ms": 1e3 * s_reconstruct,
                "warnings": list(result.warnings)}
        return scan.n, info

    return first, second, third


class InlineStages:
    """StagePipeline's interface, every stage on the calling thread at submit (ScanRequest.overlap = False)."""

    waits = 0
    wait_s = 0.0

    def __init__(self, *stages: Callable):
        self._stages = stages

    def submit(self, item) -> list:
        for stage in self._stages:
            item = stage(item)
        return [item]

    def drain(self) -> list:
        return []

    def close(self) -> None:
        pass


def _grid_stages(cfg: RigConfig, procam) -> tuple[Callable, Callable]:
    from reconstruction.pipeline import extract_frame, finish_frame

    from rig.registry import reconstruct_options

    options = reconstruct_options(cfg)
    return (lambda images: extract_frame(images[0], procam, cfg.pattern, options=options)), finish_frame


def _graycode_stages(cfg: RigConfig, procam) -> tuple[Callable, Callable]:
    from reconstruction.graycode_depth import GrayCodeOptions, reconstruct_graycode

    from rig.registry import working_volume

    depth_min_mm, depth_max_mm = working_volume(cfg)
    options = GrayCodeOptions(depth_min_mm=depth_min_mm, depth_max_mm=depth_max_mm)
    return (lambda images: images), (lambda images: reconstruct_graycode(images, procam, options=options))
