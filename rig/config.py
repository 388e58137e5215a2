"""The rig configuration (`rig.toml`): frozen, validated at the edge, paths relative to the file.

With no rig.toml the defaults describe the built-in simulated rig, so `rig scan` works out of the box.
"""

from __future__ import annotations

import os
import tomllib
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from calibration.errors import ConfigError
from calibration.file import read_text
from reconstruction.patterns import GridPattern

_FROZEN = ConfigDict(extra="forbid", frozen=True)


class ProjectorConfig(BaseModel):
    model_config = _FROZEN
    port: str = Field("sim", description='serial device path (/dev/ttyACM0), pyserial URL (socket://…, loop://), or "sim"')
    baudrate: int = Field(115200, gt=0)
    timeout_ms: float = Field(500.0, gt=0, description="deadline of one request before it is retried")
    retries: int = Field(3, ge=0, le=20)


class CameraConfig(BaseModel):
    model_config = _FROZEN
    device: str = Field("sim", description='V4L2 device (/dev/v4l/by-id/…), "replay:DIR" or "sim"')
    width: int | None = Field(None, gt=0, description="None: the calibration's camera width")
    height: int | None = Field(None, gt=0)
    fps: float = Field(30.0, gt=0)
    fourcc: str = Field("GREY", min_length=4, max_length=4)
    exposure_ms: float = Field(16.667, gt=0)
    settle_ms: float = Field(20.0, ge=0, description="time after the pattern switch before a frame counts")
    timeout_ms: float = Field(2000.0, gt=0, description="grab deadline")
    discard: int = Field(3, ge=0, description="frames thrown away after opening")


class SimConfig(BaseModel):
    model_config = _FROZEN
    scene: str = "tabletop"
    truth: Path | None = Field(None, description="calibration file the simulated rig is built with (default: the preset's)")
    noise_grey: float = Field(1.0, ge=0, description="sensor noise, standard deviation in grey levels (8-bit scale)")
    ambient: float = Field(0.05, ge=0, le=1)
    gamma: float = Field(1.0, gt=0)
    bit_depth: Literal[8, 16] = 8
    seed: int = 0


class ReconstructionConfig(BaseModel):
    model_config = _FROZEN
    labeller: Literal["epipolar", "paper"] = "epipolar"
    depth_min_mm: float | None = Field(
        None, gt=0, description="working volume (camera-frame z): nearest surface; None: the simulated scene's, else 100"
    )
    depth_max_mm: float | None = Field(None, gt=0, description="farthest surface; None: the simulated scene's, else 10000")
    epipolar_floor_px: float | None = Field(
        None,
        gt=0,
        description="smallest epipolar error (projector px RMS) the labeller's ambiguity test assumes; None: the "
        "calibration file's stereo RMS where it is larger than 0.1, else 0.1 (decision 0110)",
    )
    max_sample_error_pct: float = Field(
        0.5,
        gt=0,
        description="line-sample points whose predicted depth error (their line nearly along the epipolar lines) "
        "exceeds this % of their distance from the projector are left out; a large value (100) keeps them all "
        "(decision 0131)",
    )

    @model_validator(mode="after")
    def _range(self) -> "ReconstructionConfig":
        if self.depth_min_mm is not None and self.depth_max_mm is not None and self.depth_max_mm <= self.depth_min_mm:
            raise ValueError(f"depth_max_mm ({self.depth_max_mm}) must exceed depth_min_mm ({self.depth_min_mm})")
        return self


class RigConfig(BaseModel):
    """The whole rig.toml. `source` is the file it came from (None: built-in defaults)."""

    model_config = _FROZEN
    calibration: Path | None = Field(None, description="calibration file; None on the simulated rig = its own truth")
    projector: ProjectorConfig = ProjectorConfig()
    camera: CameraConfig = CameraConfig()
    sim: SimConfig = SimConfig()
    pattern: GridPattern = GridPattern()
    reconstruction: ReconstructionConfig = ReconstructionConfig()
    source: Path | None = None

    @property
    def is_simulated(self) -> bool:
        return self.camera.device == "sim" or self.projector.port == "sim"


def _describe(e: ValidationError) -> str:
    err = e.errors()[0]
    loc = ".".join(str(x) for x in err["loc"]) or "(top level)"
    if err["type"] == "missing":
        return f"{loc}: missing"
    if err["type"] == "extra_forbidden":
        return f"{loc}: unknown key (`rig init` writes a commented rig.toml listing every key)"
    return f"{loc}: {err['msg'].removeprefix('Value error, ')}"


def _resolve(base: Path, p: Any) -> Any:
    if p is None or p == "":
        return None
    p = Path(os.path.expanduser(str(p)))
    return p if p.is_absolute() else (base / p)


def config_from_dict(data: dict[str, Any], *, source: Path | None = None) -> RigConfig:
    """Validate a parsed TOML document; relative paths are resolved against the file's folder."""
    base = source.parent if source is not None else Path.cwd()
    data = dict(data)
    if "calibration" in data:
        data["calibration"] = _resolve(base, data["calibration"])
    if isinstance(data.get("sim"), dict) and "truth" in data["sim"]:
        data["sim"] = {**data["sim"], "truth": _resolve(base, data["sim"]["truth"])}
    for section, key in (("camera", "device"), ("projector", "port")):
        sec = data.get(section)
        if isinstance(sec, dict) and isinstance(sec.get(key), str) and sec[key].startswith("replay:"):
            data[section] = {**sec, key: "replay:" + str(_resolve(base, sec[key][len("replay:") :]))}
    data["source"] = source
    try:
        return RigConfig.model_validate(data)
    except ValidationError as e:
        raise ConfigError(f"{source or 'configuration'}: {_describe(e)}") from e


def load_config(path: str | os.PathLike | None) -> RigConfig:
    """Load rig.toml; None gives the built-in simulated rig. One ConfigError line for every problem."""
    if path is None:
        return RigConfig()
    path = Path(path)
    text = read_text(path, error=ConfigError, missing="no such configuration file (write one with `rig init`)")
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{path}: not valid TOML: {e}") from e
    return config_from_dict(data, source=path.resolve())


def config_to_toml(cfg: RigConfig) -> str:
    """The effective configuration as TOML (for `rig config show`)."""
    data = cfg.model_dump(mode="json", exclude={"source"})
    lines: list[str] = []

    def fmt(v: Any) -> str:
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, (int, float)):
            return repr(v)
        if isinstance(v, (list, tuple)):
            return "[" + ", ".join(fmt(x) for x in v) + "]"
        return '"' + str(v).replace("\\", "\\\\").replace('"', '\\"') + '"'

    for k, v in data.items():
        if not isinstance(v, dict):
            lines.append(f"# {k} = (none)" if v is None else f"{k} = {fmt(v)}")
    for k, v in data.items():
        if isinstance(v, dict):
            lines.append(f"\n[{k}]")
            for kk, vv in v.items():
                lines.append(f"# {kk} = (none)" if vv is None else f"{kk} = {fmt(vv)}")
    return "\n".join(lines) + "\n"


TEMPLATE = '''\
# rig.toml: the configuration of one structured-light rig (see README.md and docs/formats.md).
# Paths are relative to this file. Remove a key to get its default.

# The calibration file (`rig calibrate` writes it). Leave it out on the simulated rig: it knows its truth.
# calibration = "calibration.json"

[projector]
port = "sim"            # serial device (/dev/serial/by-id/…), pyserial URL (socket://host:port), or "sim"
baudrate = 115200
timeout_ms = 500.0      # deadline of one request before it is retried
retries = 3             # retries of the same request (same sequence number) before reconnecting

[camera]
device = "sim"          # V4L2 device (/dev/v4l/by-id/…-video-index0), "replay:DIR", or "sim"
# width = 1280          # default: the calibration's camera size
# height = 1024
fps = 30.0
fourcc = "GREY"         # uncompressed mono preferred (GREY, Y16, YUYV); MJPG artefacts hurt decoding
exposure_ms = 16.667    # a multiple of the projector's frame period avoids banding
settle_ms = 20.0        # frames exposed earlier than the pattern switch plus this are stale
timeout_ms = 2000.0     # grab deadline
discard = 3             # frames thrown away after opening

[sim]
scene = "tabletop"      # tabletop, paper-parallel, paper-intermediate, paper-orthogonal (`rig simulate --help`)
# truth = "truth.json"  # the calibration the simulated rig is built with (default: the preset's)
noise_grey = 1.0        # sensor noise, standard deviation in grey levels
ambient = 0.05          # ambient light, fraction of full scale
gamma = 1.0
bit_depth = 8
seed = 0

[pattern]
kind = "grid"
alpha1_deg = 30.0       # i-lines: y = tan(alpha1)·x + i·pitch   (projector pixels, relative to centre_px)
alpha2_deg = 120.0      # j-lines: y = tan(alpha2)·x + j·pitch
pitch_px = 30.0         # vertical spacing between neighbouring lines of one family
lines = 33              # per family, indices -(lines-1)/2 .. +(lines-1)/2
line_width_px = 3.0
centre_px = [511.5, 511.5]
spacing = "uniform"     # or "debruijn"

[reconstruction]
labeller = "epipolar"   # "epipolar" (default: whole components) or "paper" (three-point triangles)
# The working volume (camera-frame z, mm): labels that put the surface outside it are rejected, so a tight range
# makes labelling robust. Default: the simulated scene's depth range, or 100 to 10000 mm on a real rig.
# depth_min_mm = 500.0
# depth_max_mm = 1500.0
# The smallest epipolar error (projector px RMS) the labeller trusts a win against: a component is labelled only if
# the runner-up offset misses its epipolar lines clearly more than that. Default: the calibration's stereo RMS (from
# `rig calibrate`) where it is larger than 0.1 px, else 0.1 px. Raise it if scans show whole surfaces shifted by a line.
# epipolar_floor_px = 0.3
# Line samples on a line that runs nearly along the epipolar lines have imprecise depths; those whose predicted error
# (from the epipolar floor above or the frame's junction noise, whichever is larger) exceeds this % of their distance
# are left out. A larger value keeps more of them (100 keeps them all).
# max_sample_error_pct = 0.5
'''
