"""The one place where configuration values become devices.

`"sim"`, `"replay:DIR"`, a device path or a pyserial URL are resolved here and nowhere else (no `if mock:`
branches elsewhere). Everything is opened in an ExitStack, so every exit path stops the projector and releases
the devices.
"""

from __future__ import annotations

import contextlib
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

from calibration.errors import ConfigError, DeviceError
from calibration.file import load_calibration
from calibration.models import ProCam
from drivers.base import Camera, Projector
from rig.config import RigConfig


@dataclass
class OpenRig:
    """The opened devices and the calibration used to reconstruct."""

    projector: Projector
    camera: Camera
    procam: ProCam
    calibration_source: str
    sim: object | None = None  # the SimWorld when the camera is simulated
    notes: list[str] = field(default_factory=list)


def resolve_procam(cfg: RigConfig) -> tuple[ProCam, str]:
    """The calibration to reconstruct with, and where it came from.

    `calibration` in rig.toml wins; without it, the simulated rig uses its own truth (`[sim] truth`, else the
    preset's); a real rig without a calibration is a ConfigError naming the fix.
    """
    if cfg.calibration is not None:
        cal = load_calibration(cfg.calibration)
        return cal.to_procam(source=str(cfg.calibration)), str(cfg.calibration)
    if cfg.camera.device == "sim":
        sim_rig = sim_rig_from_config(cfg)
        src = str(cfg.sim.truth) if cfg.sim.truth else f"the simulated rig's truth (scene {cfg.sim.scene!r})"
        return sim_rig.procam, src
    raise ConfigError(
        f"{cfg.source or 'configuration'}: no `calibration = \"…\"` for this rig; run `rig calibrate` and point "
        "rig.toml at the file it writes"
    )


def sim_rig_from_config(cfg: RigConfig):
    """The simulated rig named by `[sim]` (scene preset, optionally built with the `truth` calibration)."""
    from drivers.sim import preset

    truth = None
    if cfg.sim.truth is not None:
        truth = load_calibration(cfg.sim.truth).to_procam(source=str(cfg.sim.truth))
    return preset(cfg.sim.scene, truth=truth)


def working_volume(cfg: RigConfig) -> tuple[float, float]:
    """(depth_min_mm, depth_max_mm) for labelling: rig.toml's values; where absent, the simulated scene's depth
    range when the camera is simulated, else 100 and 10000 mm."""
    lo, hi = cfg.reconstruction.depth_min_mm, cfg.reconstruction.depth_max_mm
    if lo is not None and hi is not None:
        return lo, hi
    default = (100.0, 10000.0)
    if cfg.camera.device == "sim":
        default = tuple(float(x) for x in sim_rig_from_config(cfg).depth_range_mm)
    lo = default[0] if lo is None else lo
    hi = default[1] if hi is None else hi
    if hi <= lo:
        raise ConfigError(f"{cfg.source or 'configuration'}: [reconstruction] depth_max_mm ({hi}) must exceed depth_min_mm ({lo})")
    return lo, hi


def epipolar_floor_px(cfg: RigConfig) -> float:
    """The labeller's noise floor (`LabelOptions.noise_floor_px`, projector px): rig.toml's
    `[reconstruction] epipolar_floor_px`; where absent, the calibration file's stereo RMS (`quality.stereo_rms_px`,
    written by `rig calibrate`) if it is larger than the default, else the default (decision 0110). A calibration
    that reprojects with 0.3 px RMS cannot tell two offsets apart that differ by less on the epipolar lines."""
    from reconstruction.labelling import LabelOptions

    if cfg.reconstruction.epipolar_floor_px is not None:
        return float(cfg.reconstruction.epipolar_floor_px)
    floor = LabelOptions().noise_floor_px
    if cfg.calibration is not None:
        rms = load_calibration(cfg.calibration).quality.get("stereo_rms_px")
        if isinstance(rms, (int, float)) and math.isfinite(rms) and rms > floor:
            floor = float(rms)
    return floor


def reconstruct_options(cfg: RigConfig, *, labeller: str | None = None):
    """The ReconstructOptions rig.toml asks for: labeller (or the override), working volume, epipolar floor, the
    sample points' precision limit (decision 0131)."""
    import dataclasses

    from reconstruction.pipeline import ReconstructOptions

    depth_min_mm, depth_max_mm = working_volume(cfg)
    options = ReconstructOptions(labeller=labeller or cfg.reconstruction.labeller, depth_min_mm=depth_min_mm, depth_max_mm=depth_max_mm)
    sheet = dataclasses.replace(options.sheet_precision, max_error_pct=cfg.reconstruction.max_sample_error_pct)
    return dataclasses.replace(options, label=dataclasses.replace(options.label, noise_floor_px=epipolar_floor_px(cfg)),
                               sheet_precision=sheet)


def render_options(cfg: RigConfig):
    from drivers.sim import RenderOptions

    return RenderOptions(
        noise_grey=cfg.sim.noise_grey, ambient=cfg.sim.ambient, gamma=cfg.sim.gamma, bit_depth=cfg.sim.bit_depth
    )


@contextlib.contextmanager
def open_rig(cfg: RigConfig, *, transcript: Path | None = None) -> Iterator[OpenRig]:
    """Open projector and camera as configured; closes both (projector stopped first) on every exit path."""
    procam, source = resolve_procam(cfg)
    with contextlib.ExitStack() as stack:
        world = None
        if cfg.camera.device == "sim" or cfg.projector.port == "sim":
            from drivers.sim import SimWorld

            world = SimWorld(sim_rig_from_config(cfg), options=render_options(cfg), seed=cfg.sim.seed)
        writer = None
        if transcript is not None and cfg.projector.port != "sim":
            from drivers.serial import TranscriptWriter

            writer = TranscriptWriter(transcript)
            stack.callback(writer.close)  # after the projector is closed (ExitStack unwinds in reverse)
        projector = stack.enter_context(_open_projector(cfg, world=world, transcript=writer))
        if world is not None and cfg.camera.device == "sim":
            world.geometry  # ray-cast now, once the projector answered, not inside the first grab's deadline  # noqa: B018
        camera = stack.enter_context(_open_camera(cfg, world=world, projector=projector))
        if (camera.width, camera.height) != (procam.camera.width, procam.camera.height):
            raise ConfigError(
                f"the camera delivers {camera.width}x{camera.height} frames but the calibration ({source}) is for "
                f"{procam.camera.width}x{procam.camera.height}; set [camera] width/height to match or recalibrate"
            )
        yield OpenRig(projector=projector, camera=camera, procam=procam, calibration_source=source, sim=world)


def _open_projector(cfg: RigConfig, *, world, transcript):
    port = cfg.projector.port
    if port == "sim":
        from drivers.sim import SimProjector

        return SimProjector(world)
    from drivers.serial import SerialProjector, open_transport

    def reopen():
        return open_transport(port, baudrate=cfg.projector.baudrate)

    proj = SerialProjector(
        reopen(),
        timeout_s=cfg.projector.timeout_ms / 1000.0,
        retries=cfg.projector.retries,
        reopen=reopen,
        transcript=transcript,
    )
    try:
        proj.hello()
    except DeviceError as e:
        proj.close()
        raise type(e)(
            f"{e} — no trigger board answered the handshake: check that its firmware speaks docs/protocol.md, "
            f"the baud rate ([projector] baudrate = {cfg.projector.baudrate}) and the cable"
        ) from e
    except BaseException:
        proj.close()
        raise
    return proj


def _open_camera(cfg: RigConfig, *, world, projector: Projector):
    dev = cfg.camera.device
    if dev == "sim":
        from drivers.sim import SimCamera

        return SimCamera(world, source=projector)
    if dev.startswith("replay:"):
        from drivers.replay import ReplayCamera

        return ReplayCamera(Path(dev[len("replay:") :]))
    from drivers.v4l2 import CameraSettings, V4L2Camera, open_v4l2_capture

    settings = CameraSettings.from_config(cfg.camera)
    return V4L2Camera(open_v4l2_capture(dev), settings, name=dev)
