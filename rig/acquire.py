"""The acquisition loop: show/trigger → acknowledgement → settle → grab → verify → write raw → process → log.

Orchestration only; every device call goes through the protocols in drivers.base. Memory stays constant over any
number of frames (nothing is kept after a frame is logged). Ctrl-C stops cleanly: the frames captured so far stay on
disk and the recording is closed properly.
"""

from __future__ import annotations

import contextlib
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from calibration.errors import DeviceError, RigError
from calibration.file import CalibrationFile, dumps_calibration
from rig.config import RigConfig, config_to_toml


@dataclass(frozen=True)
class ScanRequest:
    """What `rig scan` was asked for. Products named with `ply`/`depth` get a _NNNNNN suffix when frames > 1."""

    out: Path
    frames: int = 1
    record: Path | None = None
    ply: Path | None = None
    depth: Path | None = None
    reconstruct: bool = True


@dataclass
class ScanSummary:
    out: Path
    frames_requested: int
    frames_captured: int = 0
    points_total: int = 0
    interrupted: bool = False
    error: str | None = None
    record: Path | None = None
    reconstructed: bool = False
    warnings: list[str] = field(default_factory=list)
    calibration_source: str = ""


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


def run_scan(
    cfg: RigConfig,
    request: ScanRequest,
    *,
    on_frame: Callable[[int, dict], None] | None = None,
) -> ScanSummary:
    """Scan `request.frames` frames on the configured rig; returns the summary (also on Ctrl-C).

    Device and protocol errors propagate after everything captured so far is closed and kept; the summary of
    what was kept is attached to the exception as `e.summary`.
    """
    from rig.recording import open_recording
    from rig.registry import open_rig

    summary = ScanSummary(out=request.out, frames_requested=request.frames, record=request.record)
    with contextlib.ExitStack() as stack:
        capture = None
        transcript = None
        if request.record is not None:
            from rig.capture import CaptureWriter

            capture = CaptureWriter(
                request.record,
                header={
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
        problem = cfg.pattern.fits(procam.projector.width, procam.projector.height)
        if problem:
            from calibration.errors import ConfigError

            raise ConfigError(f"[pattern]: {problem}")
        pattern_image = cfg.pattern.render(procam.projector.width, procam.projector.height)
        rig.projector.load([pattern_image])
        devices = {"projector": rig.projector.describe(), "camera": rig.camera.describe()}
        if capture is not None:
            capture.header["devices"] = devices
            capture.header["calibration_source"] = rig.calibration_source
            capture.write_pattern(0, pattern_image)
            (capture.dir / "calibration.json").write_text(dumps_calibration(CalibrationFile.from_procam(procam)))

        recon = _reconstructor(cfg, procam) if request.reconstruct else None
        summary.reconstructed = recon is not None
        rec = stack.enter_context(
            open_recording(request.out, procam=procam, pattern_image=pattern_image,
                           report={"calibration": rig.calibration_source, "devices": devices})
        )
        settle_s = cfg.camera.settle_ms / 1000.0
        timeout_s = cfg.camera.timeout_ms / 1000.0
        try:
            for n in range(request.frames):
                shown = rig.projector.show(0)
                frame = grab_verified(rig.camera, shown, settle_s=settle_s, timeout_s=timeout_s)
                meta = {"device_time_us": shown.device_time_us, "exposure_ms": cfg.camera.exposure_ms}
                # Raw data first: on disk (and in the recording) before anything can fail on it.
                if capture is not None:
                    capture.write_frame(frame.image, pattern=shown.index, timestamp_s=frame.timestamp_s, **meta)
                rec.log_frame(n, frame.image, timestamp_s=frame.timestamp_s)
                summary.frames_captured += 1
                info: dict = {"frame": n}
                if recon is not None:
                    info.update(recon(rec, frame.image, n, request))
                    summary.points_total += info.get("points", 0)
                    for w in info.get("warnings", []):
                        summary.warnings.append(f"frame {n}: {w}")
                if on_frame is not None:
                    on_frame(n, info)
        except KeyboardInterrupt:
            summary.interrupted = True
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


def _reconstructor(cfg: RigConfig, procam) -> Callable | None:
    """A per-frame function reconstructing and logging one frame, or None while reconstruction is unavailable."""
    try:
        from reconstruction.pipeline import ReconstructOptions, reconstruct
        from rig.log_reconstruction import log_reconstruction
    except ImportError:
        return None
    from rig.registry import working_volume

    depth_min_mm, depth_max_mm = working_volume(cfg)
    options = ReconstructOptions(
        labeller=cfg.reconstruction.labeller, depth_min_mm=depth_min_mm, depth_max_mm=depth_max_mm
    )

    def run(rec, image: np.ndarray, n: int, request: ScanRequest) -> dict:
        t0 = time.perf_counter()
        result = reconstruct(image, procam, cfg.pattern, options=options)
        ms = (time.perf_counter() - t0) * 1000.0
        log_reconstruction(rec.stream, result)
        save_products(result, ply=_numbered(request.ply, n, request.frames), depth=_numbered(request.depth, n, request.frames))
        return {"points": int(len(result.points_proj)), "ms": ms, "warnings": list(result.warnings)}

    return run
