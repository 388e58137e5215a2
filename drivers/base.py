"""One small interface per device kind: only the verbs the scan loop needs.

Every implementation (serial board, V4L2 camera, emulator, replay, simulator) is a context manager with an
idempotent `close()`; nothing relies on `__del__`. Times are host `time.monotonic()` seconds.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol, Sequence, runtime_checkable

import numpy as np


@dataclass(frozen=True)
class Shown:
    """What a projector reports after switching to a pattern and firing the camera trigger.

    index: the pattern shown. host_time_s: host monotonic time when the switch was acknowledged (frames
    exposed before this moment plus the settle time show the previous pattern). device_time_us: the
    device's own timestamp of the trigger, if it has a clock (None otherwise).
    """

    index: int
    host_time_s: float
    device_time_us: int | None = None


@dataclass(frozen=True)
class Frame:
    """One camera frame. image: (H, W) uint8 or uint16, or (H, W, 3). timestamp_s: host monotonic time at
    which the exposure ended (for V4L2: the kernel buffer timestamp mapped to the monotonic clock)."""

    image: np.ndarray
    timestamp_s: float
    sequence: int = 0
    meta: dict = field(default_factory=dict)


@runtime_checkable
class Projector(Protocol):
    """A projector with a pattern trigger.

    `load(patterns)` stores the pattern images (each (H, W) uint8 at the projector's resolution) in order;
    `show(i)` switches to pattern i and fires the camera trigger, returning once the device acknowledged;
    `showing` is the image currently projected as far as the host knows (None: dark / safe state);
    `stop()` puts the projector in its safe state (idempotent); `close()` stops and releases the device
    (idempotent).
    """

    def load(self, patterns: Sequence[np.ndarray]) -> None: ...

    def show(self, index: int) -> Shown: ...

    @property
    def showing(self) -> np.ndarray | None: ...

    def stop(self) -> None: ...

    def close(self) -> None: ...

    def describe(self) -> dict: ...


@runtime_checkable
class Camera(Protocol):
    """A camera delivering frames on demand.

    `width`, `height`: frame size in pixels. `grab(after_s=…, timeout_s=…)` returns the first frame whose
    timestamp is later than `after_s` (host monotonic seconds), discarding stale ones, or raises
    DeviceTimeout after `timeout_s`. `close()` is idempotent.
    """

    @property
    def width(self) -> int: ...

    @property
    def height(self) -> int: ...

    def grab(self, *, after_s: float, timeout_s: float) -> Frame: ...

    def close(self) -> None: ...

    def describe(self) -> dict: ...
