"""Rerun recordings of scans: the rig geometry, the pattern, every frame; written atomically.

Layout (docs/recording.md): `world` (RDF, mm), `world/projector` and `world/camera` (Transform3D + Pinhole, so the
viewer draws both frusta), `world/projector/pattern`, `world/camera/image` (the raw frame), timelines `frame`
(sequence) and `capture_time` (wall-clock timestamp of the exposure). Reconstruction products are logged by
rig.log_reconstruction.

The stream is saved to `<out>.partial` and renamed to `<out>` when it is closed, on success and on failure alike
(a recording closed after Ctrl-C holds every frame captured so far); a killed process leaves only the .partial file,
never a half file under the final name.
"""

from __future__ import annotations

import json
import os
import time
import uuid
from pathlib import Path

import numpy as np

from calibration.models import Intrinsics, ProCam

APPLICATION_ID = "rig"


def working_point_mm(procam: ProCam) -> float:
    """Depth (projector z, mm) where the two optical axes pass closest: where the rig looks."""
    from reconstruction.geometry import triangulate_rays

    p, _ = triangulate_rays(procam, np.zeros((1, 2)), np.zeros((1, 2)))
    z = float(p[0, 2])
    return z if np.isfinite(z) and z > 0 else max(500.0, 3.0 * procam.baseline_mm)


def default_blueprint(procam: ProCam | None = None):
    """The default layout: 3-D view, camera image with overlays, depth, pattern, statistics, calibration report.

    With the rig's calibration the 3-D view starts behind and above the projector, looking at the working point.
    """
    import rerun.blueprint as rrb

    eye = None
    if procam is not None:
        z = working_point_mm(procam)
        eye = rrb.EyeControls3D(position=[0.0, -0.6 * z, -0.9 * z], look_target=[0.0, 0.0, z], eye_up=[0.0, -1.0, 0.0])
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                rrb.Spatial3DView(name="3-D", origin="/world", eye_controls=eye, line_grid=rrb.LineGrid3D(visible=False)),
                rrb.TimeSeriesView(name="statistics", origin="/stats"),
                row_shares=[3, 1],
            ),
            rrb.Vertical(
                # The depth image has its own view; drawn over the camera image it would tint it.
                rrb.Spatial2DView(name="camera", origin="/world/camera", contents=["$origin/**", "- /world/camera/depth"]),
                rrb.Spatial2DView(name="depth", origin="/world/camera", contents=["/world/camera/depth"]),
                rrb.Tabs(
                    rrb.Spatial2DView(name="pattern", origin="/world/projector"),
                    rrb.TextDocumentView(name="rig", origin="/report"),
                ),
            ),
            column_shares=[3, 2],
        ),
        collapse_panels=True,
    )


def _pinhole(model: Intrinsics, image_plane_distance: float):
    import rerun as rr

    return rr.Pinhole(
        image_from_camera=model.K,
        resolution=[model.width, model.height],
        camera_xyz=rr.ViewCoordinates.RDF,
        image_plane_distance=image_plane_distance,
    )


class Recording:
    """One .rrd file being written. Use as a context manager (or call close(), idempotent)."""

    def __init__(
        self, path: str | os.PathLike, *, application_id: str = APPLICATION_ID, blueprint=None, procam: ProCam | None = None
    ):
        import rerun as rr

        self.path = Path(path)
        self.partial = self.path.with_name(self.path.name + ".partial")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.stream = rr.RecordingStream(application_id, recording_id=uuid.uuid4())
        self.stream.save(self.partial, default_blueprint=blueprint if blueprint is not None else default_blueprint(procam))
        self._closed = False
        # Host monotonic -> wall clock, for the capture_time timeline.
        self._wall_minus_mono = time.time() - time.monotonic()
        self.frames_logged = 0
        self.stream.log("world", rr.ViewCoordinates.RDF, static=True)

    # --- static content --------------------------------------------------------------------------------------
    def log_rig(self, procam: ProCam, *, report: dict | None = None) -> None:
        """Both devices' poses and frusta (static), and the calibration report as text."""
        import rerun as rr

        depth_hint = max(100.0, 0.5 * procam.baseline_mm)
        self.stream.log("world/projector", rr.Transform3D(translation=[0.0, 0.0, 0.0], mat3x3=np.eye(3)), static=True)
        self.stream.log("world/projector", _pinhole(procam.projector, depth_hint), static=True)
        self.stream.log(
            "world/camera", rr.Transform3D(translation=procam.t_proj_cam, mat3x3=procam.R_proj_cam), static=True
        )
        self.stream.log("world/camera", _pinhole(procam.camera, depth_hint), static=True)
        text = "# Rig\n\n" + _rig_markdown(procam, report or {})
        self.stream.log("report", rr.TextDocument(text, media_type=rr.MediaType.MARKDOWN), static=True)

    def log_pattern(self, image: np.ndarray, *, index: int | None = None) -> None:
        """The projector image; static when `index` is None, else on the current frame."""
        import rerun as rr

        self.stream.log("world/projector/pattern", rr.Image(image, color_model="L"), static=index is None)

    # --- per frame ---------------------------------------------------------------------------------------------
    def set_frame(self, index: int, *, timestamp_s: float | None = None) -> None:
        """Select the frame the next logs belong to; timestamp_s is host monotonic time of the exposure."""
        self.stream.set_time("frame", sequence=index)
        if timestamp_s is not None:
            self.stream.set_time("capture_time", timestamp=timestamp_s + self._wall_minus_mono)

    def log_frame(self, index: int, image: np.ndarray, *, timestamp_s: float | None = None) -> None:
        import rerun as rr

        self.set_frame(index, timestamp_s=timestamp_s)
        if image.dtype == np.uint16:
            self.stream.log("world/camera/image", rr.Image(image, color_model="L", datatype=np.uint16))
        elif image.ndim == 3:
            self.stream.log("world/camera/image", rr.Image(image[..., ::-1], color_model="RGB"))  # OpenCV BGR
        else:
            self.stream.log("world/camera/image", rr.Image(image, color_model="L"))
        self.frames_logged += 1

    def log_text(self, entity: str, text: str, *, level: str = "INFO") -> None:
        import rerun as rr

        self.stream.log(entity, rr.TextLog(text, level=level))

    # --- lifecycle ---------------------------------------------------------------------------------------------
    def close(self) -> Path:
        """Write the footer, close the file and move it to its final name (idempotent)."""
        if not self._closed:
            self._closed = True
            self.stream.flush()
            self.stream.disconnect()
            os.replace(self.partial, self.path)
        return self.path

    def __enter__(self) -> "Recording":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def open_recording(
    path: str | os.PathLike, *, procam: ProCam, pattern_image: np.ndarray | None = None, report: dict | None = None
) -> Recording:
    """A new recording with the rig geometry (and the pattern, if given) already logged."""
    rec = Recording(path, procam=procam)
    rec.log_rig(procam, report=report)
    if pattern_image is not None:
        rec.log_pattern(pattern_image)
    return rec


def _rig_markdown(procam: ProCam, report: dict) -> str:
    c, p = procam.camera, procam.projector
    lines = [
        f"- camera: {c.width}×{c.height} px, fx {c.fx:.1f}, fy {c.fy:.1f}, principal point ({c.cx:.1f}, {c.cy:.1f})",
        f"- projector: {p.width}×{p.height} px, fx {p.fx:.1f}, fy {p.fy:.1f}, principal point ({p.cx:.1f}, {p.cy:.1f})",
        f"- baseline: {procam.baseline_mm:.1f} mm; camera centre in the projector frame: "
        + ", ".join(f"{x:.1f}" for x in procam.t_proj_cam)
        + " mm",
    ]
    if report:
        lines += ["", "```json", json.dumps(report, indent=2, default=str), "```"]
    return "\n".join(lines) + "\n"
