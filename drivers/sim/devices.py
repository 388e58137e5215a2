"""Simulated projector and camera: the same interfaces (drivers.base) as the real devices.

The camera renders the shared SimWorld lit by whatever its `source` projector is showing; the source can
be the SimProjector or any other Projector (e.g. the serial driver talking to the firmware emulator), so
the trigger path can be real while the optics are simulated.
"""

from __future__ import annotations

import time
from typing import Sequence

import numpy as np

from calibration.errors import DeviceError, DeviceTimeout
from drivers.base import Frame, Projector, Shown
from drivers.sim.world import SimWorld


class SimProjector:
    """A projector that "shows" images into a SimWorld. Implements drivers.base.Projector."""

    def __init__(self, world: SimWorld) -> None:
        self._world = world
        proj = world.procam.projector
        self._size = (proj.width, proj.height)
        self._patterns: list[np.ndarray] = []
        self._showing: np.ndarray | None = None
        self._index: int | None = None
        self._closed = False

    @property
    def width(self) -> int:
        return self._size[0]

    @property
    def height(self) -> int:
        return self._size[1]

    def _check_open(self) -> None:
        if self._closed:
            raise DeviceError("the simulated projector is closed")

    def load(self, patterns: Sequence[np.ndarray]) -> None:
        """Store the pattern images ((H, W) at the projector's resolution) in order."""
        self._check_open()
        stored = []
        for k, p in enumerate(patterns):
            a = np.array(p, copy=True)
            if a.shape[:2] != (self.height, self.width):
                raise DeviceError(
                    f"pattern {k} is {a.shape[1] if a.ndim > 1 else '?'}x{a.shape[0]} (WxH) but the simulated projector "
                    f"is {self.width}x{self.height}: render patterns at the projector's resolution"
                )
            a.setflags(write=False)
            stored.append(a)
        self._patterns = stored
        self._showing = None
        self._index = None

    def show(self, index: int) -> Shown:
        """Switch to pattern `index` (instantly) and report the switch time."""
        self._check_open()
        if not 0 <= index < len(self._patterns):
            raise DeviceError(f"pattern {index} is not loaded ({len(self._patterns)} loaded; call load() first)")
        self._showing = self._patterns[index]
        self._index = index
        return Shown(index=index, host_time_s=time.monotonic(), device_time_us=None)

    @property
    def showing(self) -> np.ndarray | None:
        return self._showing

    def stop(self) -> None:
        """Dark (the safe state). Idempotent."""
        self._showing = None
        self._index = None

    def close(self) -> None:
        """Stop and release. Idempotent."""
        self.stop()
        self._closed = True

    def describe(self) -> dict:
        return {
            "kind": "sim",
            "scene": self._world.rig.name,
            "width": self.width,
            "height": self.height,
            "patterns": len(self._patterns),
            "showing": self._index,
        }

    def __enter__(self) -> "SimProjector":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class SimCamera:
    """A camera that renders the SimWorld lit by `source.showing`. Implements drivers.base.Camera."""

    def __init__(self, world: SimWorld, *, source: Projector) -> None:
        self._world = world
        self._source = source
        self._sequence = 0
        self._closed = False

    @property
    def width(self) -> int:
        return self._world.procam.camera.width

    @property
    def height(self) -> int:
        return self._world.procam.camera.height

    def grab(self, *, after_s: float, timeout_s: float) -> Frame:
        """Render a frame of what the source shows now. Frames are made on demand, so the first one is
        fresh; if `after_s` lies in the future the camera waits for it (DeviceTimeout if that is more than
        `timeout_s` away)."""
        if self._closed:
            raise DeviceError("the simulated camera is closed")
        wait_s = after_s - time.monotonic()
        if wait_s > timeout_s:
            raise DeviceTimeout(
                f"no frame after t = {after_s:.3f} s within {timeout_s:.3f} s (the simulated camera would have to wait {wait_s:.3f} s)"
            )
        if wait_s >= 0:
            time.sleep(wait_s + 1e-4)
        image = self._world.render(self._source.showing)
        self._sequence += 1
        return Frame(image=image, timestamp_s=time.monotonic(), sequence=self._sequence, meta={"simulated": True, "scene": self._world.rig.name})

    def close(self) -> None:
        """Idempotent."""
        self._closed = True

    def describe(self) -> dict:
        o = self._world.options
        return {
            "kind": "sim",
            "scene": self._world.rig.name,
            "width": self.width,
            "height": self.height,
            "bit_depth": o.bit_depth,
            "noise_grey": o.noise_grey,
            "supersample": o.supersample,
            "seed": self._world.seed,
        }

    def __enter__(self) -> "SimCamera":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
