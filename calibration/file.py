"""The calibration file (`calibration.json`, format_version 1): one pydantic model, atomic writes.

The format is documented in docs/formats.md. Every problem is reported as one CalibrationFileError whose
message names the file and the key, e.g. ``calibration.json: camera.K: expected a 3x3 matrix, got 2 rows``.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path
from typing import Any, BinaryIO, Callable, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, ValidationError, field_validator, model_validator

from calibration.errors import CalibrationFileError
from calibration.models import Intrinsics, ProCam

FORMAT_VERSION = 1


def _matrix(value: Any, rows: int, cols: int) -> list[list[float]]:
    if not isinstance(value, (list, tuple)) or len(value) != rows:
        got = f"{len(value)} rows" if isinstance(value, (list, tuple)) else type(value).__name__
        raise ValueError(f"expected a {rows}x{cols} matrix, got {got}")
    out = []
    for r in value:
        if not isinstance(r, (list, tuple)) or len(r) != cols:
            raise ValueError(f"expected a {rows}x{cols} matrix, got a row {r!r}")
        out.append([float(x) for x in r])
    if not np.all(np.isfinite(out)):
        raise ValueError("contains a non-finite number")
    return out


class DeviceCalibration(BaseModel):
    """Intrinsics of one device (camera or projector)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    width: int
    height: int
    K: list[list[float]]
    dist: list[float] = [0.0, 0.0, 0.0, 0.0, 0.0]

    @field_validator("width", "height")
    @classmethod
    def _positive(cls, v: int) -> int:
        if v <= 0:
            raise ValueError(f"must be a positive number of pixels, got {v}")
        return v

    @field_validator("K", mode="before")
    @classmethod
    def _k(cls, v: Any) -> list[list[float]]:
        K = _matrix(v, 3, 3)
        if K[2] != [0.0, 0.0, 1.0] or K[1][0] != 0.0 or K[0][0] <= 0 or K[1][1] <= 0:
            raise ValueError("expected [[fx, s, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0")
        return K

    @field_validator("dist", mode="before")
    @classmethod
    def _dist(cls, v: Any) -> list[float]:
        if not isinstance(v, (list, tuple)) or len(v) not in (0, 4, 5, 8, 12, 14):
            n = len(v) if isinstance(v, (list, tuple)) else type(v).__name__
            raise ValueError(f"expected 4, 5, 8, 12 or 14 OpenCV distortion coefficients [k1, k2, p1, p2, k3, …], got {n}")
        return [float(x) for x in v]

    def to_intrinsics(self) -> Intrinsics:
        return Intrinsics(self.width, self.height, np.array(self.K), np.array(self.dist))

    @classmethod
    def from_intrinsics(cls, m: Intrinsics) -> "DeviceCalibration":
        return cls(width=m.width, height=m.height, K=m.K.tolist(), dist=m.dist.tolist())


class CalibrationFile(BaseModel):
    """The whole file. `projector`, `R` and `t` are absent in a camera-only calibration."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    format_version: Literal[1]
    camera: DeviceCalibration
    projector: DeviceCalibration | None = None
    R: list[list[float]] | None = None
    t: list[float] | None = None
    quality: dict[str, Any] = {}
    provenance: dict[str, Any] = {}

    @field_validator("R", mode="before")
    @classmethod
    def _r(cls, v: Any) -> Any:
        if v is None:
            return v
        R = np.array(_matrix(v, 3, 3))
        if not np.allclose(R.T @ R, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
            raise ValueError("expected a rotation matrix (orthonormal, determinant +1)")
        return R.tolist()

    @field_validator("t", mode="before")
    @classmethod
    def _t(cls, v: Any) -> Any:
        if v is None:
            return v
        if not isinstance(v, (list, tuple)) or len(v) != 3:
            raise ValueError("expected [tx, ty, tz] in millimetres")
        t = [float(x) for x in v]
        if not np.all(np.isfinite(t)):
            raise ValueError("contains a non-finite number")
        return t

    @model_validator(mode="after")
    def _complete(self) -> "CalibrationFile":
        parts = {"projector": self.projector, "R": self.R, "t": self.t}
        present = [k for k, v in parts.items() if v is not None]
        if present and len(present) != 3:
            missing = [k for k in parts if k not in present]
            raise ValueError(f"has {', '.join(present)} but not {', '.join(missing)}: a camera–projector calibration needs all three")
        return self

    @property
    def has_projector(self) -> bool:
        return self.projector is not None

    def to_procam(self, *, source: str = "calibration") -> ProCam:
        """The camera–projector model; CalibrationFileError if this is a camera-only file."""
        if self.projector is None or self.R is None or self.t is None:
            raise CalibrationFileError(
                f"{source}: has only the camera part; this command needs the projector and the pose "
                "(run `rig calibrate procam …` or `rig calibrate` to make a full calibration)"
            )
        return ProCam(self.camera.to_intrinsics(), self.projector.to_intrinsics(), np.array(self.R), np.array(self.t))

    @classmethod
    def from_procam(cls, rig: ProCam, *, quality: dict | None = None, provenance: dict | None = None) -> "CalibrationFile":
        return cls(
            format_version=FORMAT_VERSION,
            camera=DeviceCalibration.from_intrinsics(rig.camera),
            projector=DeviceCalibration.from_intrinsics(rig.projector),
            R=rig.R_proj_cam.tolist(),
            t=rig.t_proj_cam.tolist(),
            quality=quality or {},
            provenance=provenance or {},
        )


def _first_error(e: ValidationError) -> str:
    err = e.errors()[0]
    loc = ".".join(str(x) for x in err["loc"] if not str(x).startswith("function-after")) or "(top level)"
    kind = err["type"]
    if kind == "missing":
        return f"{loc}: missing (see docs/formats.md)"
    if kind == "extra_forbidden":
        return f"{loc}: unknown key (see docs/formats.md for the allowed keys)"
    if kind == "literal_error" and loc == "format_version":
        return f"format_version: this version of rig reads format_version 1, got {err.get('input')!r}"
    msg = err["msg"].removeprefix("Value error, ")
    return f"{loc}: {msg}"


def parse_calibration(data: Any, *, source: str = "calibration") -> CalibrationFile:
    """Validate an already-parsed JSON object."""
    if not isinstance(data, dict):
        raise CalibrationFileError(f"{source}: expected a JSON object at the top level, got {type(data).__name__}")
    try:
        return CalibrationFile.model_validate(data)
    except ValidationError as e:
        raise CalibrationFileError(f"{source}: {_first_error(e)}") from e


def read_text(path: Path, *, error: type[Exception], missing: str) -> str:
    """A UTF-8 file's text; a missing or unreadable file is one `error` naming the path (`missing`: the hint)."""
    try:
        return path.read_text(encoding="utf-8")
    except FileNotFoundError as e:
        raise error(f"{path}: {missing}") from e
    except OSError as e:
        raise error(f"{path}: cannot read: {e.strerror}") from e


def load_calibration(path: str | os.PathLike) -> CalibrationFile:
    """Read and validate a calibration file; every failure is one CalibrationFileError naming the problem."""
    path = Path(path)
    text = read_text(path, error=CalibrationFileError, missing="no such calibration file (make one with `rig calibrate`)")
    try:
        data = json.loads(text)
    except json.JSONDecodeError as e:
        raise CalibrationFileError(f"{path}: not valid JSON (line {e.lineno}, column {e.colno}: {e.msg})") from e
    return parse_calibration(data, source=str(path))


def atomic_write(path: str | os.PathLike, write: Callable[[BinaryIO], None]) -> None:
    """Write a file atomically: `write(f)` fills a temporary file beside it, which is fsynced and renamed.

    A crash leaves no half file under the final name. The file gets the usual permissions (0666 minus umask).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def write_text_atomic(path: str | os.PathLike, text: str) -> None:
    """Write a UTF-8 text file atomically (see atomic_write)."""
    data = text.encode("utf-8")
    atomic_write(path, lambda f: f.write(data))


def save_calibration(cal: CalibrationFile, path: str | os.PathLike) -> None:
    """Write the calibration file atomically, human-readable (indented JSON, one matrix row per line)."""
    write_text_atomic(path, dumps_calibration(cal))


def dumps_calibration(cal: CalibrationFile) -> str:
    data = cal.model_dump(exclude_none=True)
    text = json.dumps(data, indent=2)
    # Keep matrix rows and short vectors on one line each: easier to read and to diff.
    import re

    def _squash(m: re.Match) -> str:
        return "[" + ", ".join(x.strip() for x in m.group(1).split(",")) + "]"

    text = re.sub(r"\[\s*((?:-?[\d.eE+-]+\s*,\s*)*-?[\d.eE+-]+)\s*\]", _squash, text)
    return text + "\n"
