"""`write_simulation`: a simulated case on disk, reproducible without the simulator.

Layout of the output folder (docs/simulator.md):

    frames/000000.png …   camera frames (8- or 16-bit grey PNG), the pattern lit by the projector
    pattern.png           the projector image shown
    truth.npz             Truth arrays (p_proj, depth_cam, normal_proj, object_id, q_proj, lit)
    calibration.json      the true calibration (docs/formats.md)
    rig.toml              camera.device = "replay:frames", projector.port = "sim", the pattern, [sim]
    simulation.json       what was rendered: scene, options, seed, depth range, files
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any, Protocol

import cv2
import numpy as np

from calibration.errors import ConfigError
from calibration.file import CalibrationFile, atomic_write, save_calibration, write_text_atomic
from drivers.sim.presets import SimRig
from drivers.sim.render import RenderOptions
from drivers.sim.world import SimWorld


class PatternLike(Protocol):
    """What write_simulation needs of a pattern (reconstruction.patterns.GridPattern fits; drivers may not
    import reconstruction, so this is structural)."""

    def render(self, width: int, height: int) -> np.ndarray: ...

    def model_dump(self, *, mode: str = ...) -> dict[str, Any]: ...


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    return '"' + str(v).replace("\\", "\\\\").replace('"', '\\"') + '"'


def _imwrite(path: Path, image: np.ndarray) -> None:
    # Atomic: PNG beside the target, then rename (a reader never sees half a frame).
    ok, buf = cv2.imencode(".png", image)
    if not ok:
        raise ConfigError(f"{path}: cannot encode a {image.dtype} {image.shape} image as PNG")
    atomic_write(path, lambda f: f.write(buf.tobytes()))


def simulation_toml(*, rig: SimRig, pattern: PatternLike, options: RenderOptions, seed: int) -> str:
    """rig.toml text for a replay of a simulated case (frames in ./frames, calibration.json beside)."""
    cam = rig.procam.camera
    near, far = rig.depth_range_mm
    lines = [
        f"# Written by `rig simulate` (scene {rig.name!r}). Replays the frames in ./frames with the true",
        "# calibration; [sim] says how they were made, so the case can be rendered again.",
        'calibration = "calibration.json"',
        "",
        "[projector]",
        'port = "sim"',
        "",
        "[camera]",
        'device = "replay:frames"',
        f"width = {cam.width}",
        f"height = {cam.height}",
        "",
        "[sim]",
        f"scene = {_toml_value(rig.name)}",
        'truth = "calibration.json"',
        f"noise_grey = {_toml_value(float(options.noise_grey))}",
        f"ambient = {_toml_value(float(options.ambient))}",
        f"gamma = {_toml_value(float(options.gamma))}",
        f"bit_depth = {options.bit_depth}",
        f"seed = {int(seed)}",
        "",
        "[pattern]",
    ]
    for k, v in pattern.model_dump(mode="json").items():
        lines.append(f"{k} = {_toml_value(v)}")
    lines += [
        "",
        "[reconstruction]",
        f"depth_min_mm = {_toml_value(float(near))}",
        f"depth_max_mm = {_toml_value(float(far))}",
    ]
    return "\n".join(lines) + "\n"


def write_simulation(
    out_dir: str | os.PathLike,
    *,
    rig: SimRig,
    pattern: PatternLike,
    options: RenderOptions,
    seed: int,
    frames: int = 1,
) -> Path:
    """Render `frames` frames of `rig` under `pattern` and write a self-contained case to `out_dir`
    (created if missing; files of the same names are replaced). Returns the folder."""
    if frames < 1:
        raise ConfigError(f"frames must be at least 1, got {frames}")
    out = Path(out_dir)
    (out / "frames").mkdir(parents=True, exist_ok=True)
    proj = rig.procam.projector
    image = np.asarray(pattern.render(proj.width, proj.height))
    world = SimWorld(rig, options=options, seed=seed)
    names = []
    for k in range(frames):
        name = f"frames/{k:06d}.png"
        _imwrite(out / name, world.render(image))
        names.append(name)
    _imwrite(out / "pattern.png", image)
    tmp = out / ".truth.tmp.npz"
    np.savez_compressed(tmp, **world.truth.as_dict())
    os.replace(tmp, out / "truth.npz")
    cal = CalibrationFile.from_procam(
        rig.procam,
        provenance={"source": "rig simulate (the simulator's truth)", "scene": rig.name, "seed": int(seed)},
    )
    save_calibration(cal, out / "calibration.json")
    write_text_atomic(out / "rig.toml", simulation_toml(rig=rig, pattern=pattern, options=options, seed=seed))
    manifest = {
        "scene": rig.name,
        "description": rig.description,
        "seed": int(seed),
        "options": {
            "noise_grey": options.noise_grey,
            "ambient": options.ambient,
            "gamma": options.gamma,
            "bit_depth": options.bit_depth,
            "projector_gain": options.projector_gain,
            "supersample": options.supersample,
        },
        "depth_range_mm": list(rig.depth_range_mm),
        "frames": names,
        "pattern": pattern.model_dump(mode="json"),
        "truth": "truth.npz",
        "calibration": "calibration.json",
    }
    write_text_atomic(out / "simulation.json", json.dumps(manifest, indent=2) + "\n")
    return out
