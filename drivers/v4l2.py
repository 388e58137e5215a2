"""The camera through OpenCV's V4L2 backend: explicit settings read back, fresh frames only, a grab deadline.

Two pieces, kept apart on purpose (STYLE.md: devices are handed their transport, they never build it):

- `open_v4l2_capture(device)` builds the `cv2.VideoCapture(device, cv2.CAP_V4L2)` and turns "it did not open" into a
  DeviceError naming the device and the fix;
- `V4L2Camera(capture, settings)` is handed any open `cv2.VideoCapture` and implements `drivers.base.Camera` on it.
  Tests hand it a real capture opened on files (an image sequence through CAP_IMAGES, a video through CAP_FFMPEG);
  a setting the backend cannot apply is an error unless it is left at None ("keep").

The hardware pitfalls behind every step are in docs/camera.md; OpenCV's V4L2 backend is
modules/videoio/src/cap_v4l.cpp (property semantics quoted where they matter).
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass
from typing import Any, Callable

import cv2
import numpy as np

from calibration.errors import ConfigError, DeviceError, DeviceTimeout
from drivers.base import Frame

#: Seconds one blocking V4L2 read may wait inside OpenCV (its default is 10 s). OpenCV reads the variable once per
#: process, in whole seconds, the first time a V4L2 read has to wait; `open_v4l2_capture` sets it before the open.
SELECT_TIMEOUT_ENV = "OPENCV_VIDEOIO_V4L_SELECT_TIMEOUT"
DEFAULT_SELECT_TIMEOUT_S = 1

#: Mono pixel formats kept at full bit depth (CAP_PROP_CONVERT_RGB off): FOURCC -> (bytes per pixel, bit depth).
#: Y10/Y12 come as 16-bit little-endian words holding 10 or 12 significant bits; values are not rescaled.
MONO_FORMATS: dict[str, tuple[int, int]] = {
    "GREY": (1, 8),
    "Y8  ": (1, 8),
    "Y800": (1, 8),
    "Y10 ": (2, 10),
    "Y12 ": (2, 12),
    "Y16 ": (2, 16),
}

# V4L2_CID_EXPOSURE_AUTO menu: 0 auto, 1 manual, 2 shutter priority, 3 aperture priority (UVC cameras offer 1 and 3).
_AUTO_EXPOSURE_MANUAL = 1
# V4L2_CID_EXPOSURE_ABSOLUTE is in units of 100 µs.
_EXPOSURE_UNIT_MS = 0.1


def fourcc_code(fourcc: str) -> int:
    """The 32-bit code OpenCV uses for a four-character code ("Y16" is padded to "Y16 ")."""
    s = normalise_fourcc(fourcc)
    return cv2.VideoWriter.fourcc(*s)


def fourcc_text(code: float) -> str:
    """The four characters of a code read back from CAP_PROP_FOURCC ("" when the backend has none)."""
    c = int(code)
    if c <= 0:
        return ""
    chars = [(c >> (8 * i)) & 0xFF for i in range(4)]
    if not all(32 <= ch < 127 for ch in chars):
        return f"0x{c:08x}"
    return "".join(chr(ch) for ch in chars)


def normalise_fourcc(fourcc: str) -> str:
    """Upper-case and pad to four characters; ConfigError for anything else."""
    s = fourcc.upper().ljust(4)
    if len(s) != 4 or not all(32 <= ord(ch) < 127 for ch in s):
        raise ConfigError(f"camera fourcc must be four ASCII characters (like GREY, Y16, YUYV, MJPG), got {fourcc!r}")
    return s


@dataclass(frozen=True)
class CameraSettings:
    """What the camera is asked to do; mirrors `rig.config.CameraConfig` (without importing rig).

    Every device setting may be None ("keep": leave the device as it is); `fourcc="keep"` means the same. A
    setting that is not None must be applied and read back, else V4L2Camera raises DeviceError. File and
    image-sequence captures can change none of them, so tests leave them all at None.

    width, height: frame size in pixels. fps: frames per second (OpenCV's V4L2 backend requests whole numbers).
    fourcc: pixel format, e.g. "GREY", "Y16", "YUYV", "MJPG"; mono formats (MONO_FORMATS) are delivered as (H, W)
    uint8/uint16 at full bit depth, others as OpenCV's (H, W, 3) BGR. exposure_ms: manual exposure (None keeps the
    camera's own exposure control, auto white balance and autofocus as they are). settle_ms: time after a pattern
    switch before a frame counts (the scan loop adds it to `after_s`; the camera only reports it). timeout_ms: the
    default grab deadline. discard: frames thrown away after opening (dark or auto-exposed). buffer_size: V4L2
    buffers (1 = only the newest frame waits; None keeps OpenCV's 4). convert_rgb: OpenCV's CAP_PROP_CONVERT_RGB;
    None switches it off for mono formats and leaves it alone otherwise.
    """

    width: int | None = None
    height: int | None = None
    fps: float | None = None
    fourcc: str | None = None
    exposure_ms: float | None = None
    settle_ms: float = 20.0
    timeout_ms: float = 2000.0
    discard: int = 3
    buffer_size: int | None = 1
    convert_rgb: bool | None = None

    def __post_init__(self) -> None:
        if self.fourcc is not None and self.fourcc.strip().lower() == "keep":
            object.__setattr__(self, "fourcc", None)
        if self.fourcc is not None:
            object.__setattr__(self, "fourcc", normalise_fourcc(self.fourcc))
        for name in ("width", "height", "buffer_size"):
            v = getattr(self, name)
            if v is not None and (int(v) != v or v < 1):
                raise ConfigError(f"camera {name} must be a positive whole number or None, got {v!r}")
        for name in ("fps", "exposure_ms"):
            v = getattr(self, name)
            if v is not None and not v > 0:
                raise ConfigError(f"camera {name} must be positive or None, got {v!r}")
        if self.settle_ms < 0 or not self.timeout_ms > 0 or self.discard < 0:
            raise ConfigError(
                f"camera settle_ms >= 0, timeout_ms > 0 and discard >= 0 are required, got settle_ms={self.settle_ms}, "
                f"timeout_ms={self.timeout_ms}, discard={self.discard}"
            )

    @classmethod
    def keep(cls, **overrides: Any) -> "CameraSettings":
        """Settings that change nothing on the device (for file captures and tests), with `overrides`."""
        base = dict(buffer_size=None, discard=0)
        base.update(overrides)
        return cls(**base)

    @classmethod
    def from_config(cls, config: Any, **overrides: Any) -> "CameraSettings":
        """From any object with CameraConfig's attribute names (duck-typed: drivers never import rig)."""
        names = ("width", "height", "fps", "fourcc", "exposure_ms", "settle_ms", "timeout_ms", "discard")
        values = {n: getattr(config, n) for n in names if hasattr(config, n)}
        values.update(overrides)
        return cls(**values)


def open_v4l2_capture(device: str, *, select_timeout_s: int = DEFAULT_SELECT_TIMEOUT_S) -> cv2.VideoCapture:
    """Open `device` (prefer /dev/v4l/by-id/…-video-index0; a bare number means /dev/videoN) through CAP_V4L2.

    Sets OPENCV_VIDEOIO_V4L_SELECT_TIMEOUT (whole seconds, unless the environment already sets it) before the
    open so that a stalled camera blocks one read for `select_timeout_s`, not OpenCV's 10 s. Returns the open
    capture; DeviceError naming the device and the fix when it does not open.
    """
    os.environ.setdefault(SELECT_TIMEOUT_ENV, str(max(1, int(select_timeout_s))))
    target: str | int = device
    path = device
    if device.isdigit():
        target = int(device)
        path = f"/dev/video{device}"
    if not os.path.exists(path):
        raise DeviceError(
            f"camera {device}: no such device (is the camera plugged in? `rig devices` lists the cameras found)"
        )
    if not os.access(path, os.R_OK | os.W_OK):
        raise DeviceError(
            f"camera {device}: permission denied (add your user to the video group: "
            "`sudo usermod -aG video $USER`, then log in again)"
        )
    cap = cv2.VideoCapture(target, cv2.CAP_V4L2)
    if not cap.isOpened():
        cap.release()
        raise DeviceError(
            f"camera {device}: OpenCV's V4L2 backend cannot open it (is it a capture node? UVC cameras have two: "
            f"use the …-video-index0 one; is another program using it? `fuser -v {path}` shows who)"
        )
    return cap


def decode_raw(raw: np.ndarray, *, fourcc: str, width: int, height: int) -> np.ndarray:
    """A mono frame from the raw buffer OpenCV's V4L2 backend returns with CONVERT_RGB off.

    raw: the bytes as OpenCV hands them over, (1, N) or (N,) uint8 (N may include row padding). Returns (H, W)
    uint8 for 8-bit formats, (H, W) uint16 for Y10/Y12/Y16 (little-endian words, values not rescaled). A frame
    already shaped (H, W) is returned as it is.
    """
    fourcc = normalise_fourcc(fourcc)
    if fourcc not in MONO_FORMATS:
        raise DeviceError(f"cannot decode raw {fourcc!r} frames; mono formats are {', '.join(MONO_FORMATS)}")
    bpp, _ = MONO_FORMATS[fourcc]
    want = np.uint8 if bpp == 1 else np.uint16
    if raw.ndim == 2 and raw.shape == (height, width) and raw.dtype == want:
        return raw
    data = np.ascontiguousarray(raw).reshape(-1).view(np.uint8)
    row = width * bpp
    if data.size < row * height:
        raise DeviceError(
            f"camera delivered a short {fourcc.strip()} frame: {data.size} bytes for {width}x{height} "
            f"({row * height} needed); the USB link may be dropping data (try a lower fps or resolution)"
        )
    stride = data.size // height if data.size % height == 0 else row  # drivers may pad rows (bytesperline)
    rows = data[: stride * height].reshape(height, stride)[:, :row]
    if bpp == 1:
        return rows.copy()
    return np.ascontiguousarray(rows).view("<u2").reshape(height, width).astype(np.uint16, copy=True)


class FrameClock:
    """Maps a capture's frame times (CAP_PROP_POS_MSEC) to host monotonic seconds; refuses times that did not advance.

    Three modes, chosen once:
      "host"   the backend has no frame times (CAP_PROP_POS_MSEC < 0 before the first read, e.g. CAP_IMAGES): the
               host time right after the read is the frame's time.
      "device" the first frame time is within `same_clock_s` of the host clock: the kernel stamped the buffer with
               CLOCK_MONOTONIC (V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC, what uvcvideo does), which is Python's
               time.monotonic(), so it is used unchanged.
      "offset" another clock (a video file's position, CLOCK_REALTIME stamps): host = device + offset, with the offset
               the smallest (host − device) seen so far (the least-delayed frame bounds the latency).

    `stamp` returns None for a frame whose device time is not later than the previous one (V4L2 hands the same
    buffer back after a select() timeout; OpenCV's read() may then still report success).
    """

    def __init__(self, *, has_device_time: bool, same_clock_s: float = 1.0):
        self.mode: str | None = None if has_device_time else "host"
        self.same_clock_s = same_clock_s
        self._last_device_s: float | None = None
        self._offset_s: float | None = None

    def stamp(self, device_ms: float, host_s: float) -> float | None:
        """Host monotonic time of a frame, or None when its device time did not advance."""
        if self.mode == "host":
            return host_s
        device_s = device_ms / 1000.0
        if self._last_device_s is not None and device_s <= self._last_device_s:
            return None
        self._last_device_s = device_s
        if self.mode is None:
            self.mode = "device" if abs(host_s - device_s) < self.same_clock_s else "offset"
        if self.mode == "device":
            return device_s
        gap = host_s - device_s
        self._offset_s = gap if self._offset_s is None else min(self._offset_s, gap)
        return device_s + self._offset_s


class V4L2Camera:
    """`drivers.base.Camera` on an open cv2.VideoCapture (V4L2 for hardware; any backend in tests).

    On construction: FOURCC, then width and height, then fps, each read back (a silent failure is a DeviceError
    naming the wanted and the got value); CONVERT_RGB off for mono formats; buffer size; manual exposure with auto
    white balance and autofocus off; the four format settings verified again (each of them restarts the stream);
    `discard` frames thrown away. `grab(after_s=, timeout_s=)` returns the first frame whose time (see FrameClock)
    is later than `after_s`. The camera owns the capture from here on: `close()` releases it (idempotent).
    """

    def __init__(
        self,
        capture: cv2.VideoCapture,
        settings: CameraSettings,
        *,
        name: str = "",
        clock: Callable[[], float] = time.monotonic,
    ):
        if not capture.isOpened():
            raise DeviceError(f"camera {name or '(unnamed)'}: the capture handed over is not open")
        self._cap = capture
        self.settings = settings
        self._clock = clock
        self._closed = False
        self._sequence = 0
        self.backend = _backend_name(capture)
        self.name = name or f"{self.backend} capture"
        self._applied: dict[str, Any] = {}
        try:
            self._configure()
            self._clock_map = FrameClock(has_device_time=capture.get(cv2.CAP_PROP_POS_MSEC) >= 0)
            self._discard(settings.discard)
        except BaseException:
            self.close()
            raise

    # ----- setup -------------------------------------------------------------------------------------------------

    def _fail(self, setting: str, wanted: Any, got: Any, hint: str = "") -> DeviceError:
        if not hint:
            if self.backend != "V4L2":
                hint = f"the {self.backend} backend cannot change it; leave camera {setting} unset (None/\"keep\")"
            else:
                hint = "the camera does not offer it; `rig devices` (or v4l2-ctl --list-formats-ext) lists what it does"
        return DeviceError(f"camera {self.name}: {setting} is {got}, wanted {wanted} ({hint})")

    def _set(self, prop: int, value: float) -> bool:
        try:
            return bool(self._cap.set(prop, value))
        except cv2.error:  # some backends throw instead of returning False
            return False

    def _configure(self) -> None:
        s = self.settings
        cap = self._cap
        # Order matters: each of FOURCC / size / fps restarts the V4L2 stream (cap_v4l.cpp: v4l2_reset).
        if s.fourcc is not None:
            ok = self._set(cv2.CAP_PROP_FOURCC, fourcc_code(s.fourcc))
            got = fourcc_text(cap.get(cv2.CAP_PROP_FOURCC))
            if not ok or got != s.fourcc:
                raise self._fail("fourcc", repr(s.fourcc.strip()), repr(got.strip()) if got else "unknown")
        if s.width is not None:
            self._set(cv2.CAP_PROP_FRAME_WIDTH, s.width)
        if s.height is not None:
            self._set(cv2.CAP_PROP_FRAME_HEIGHT, s.height)
        self._check_size()
        if s.fps is not None:
            self._set(cv2.CAP_PROP_FPS, s.fps)
            self._check_fps()
        self._mono = s.fourcc in MONO_FORMATS
        convert = False if (s.convert_rgb is None and self._mono) else s.convert_rgb
        if convert is not None:
            # With CONVERT_RGB on, OpenCV squashes Y16/Y10 to 8 bit and makes mono frames 3-channel BGR.
            ok = self._set(cv2.CAP_PROP_CONVERT_RGB, int(convert))
            got = cap.get(cv2.CAP_PROP_CONVERT_RGB)
            if not ok or bool(got) != convert:
                raise self._fail("convert_rgb", "on" if convert else "off (full bit depth)", got)
            self._applied["convert_rgb"] = convert
        if s.buffer_size is not None:
            ok = self._set(cv2.CAP_PROP_BUFFERSIZE, s.buffer_size)
            got = cap.get(cv2.CAP_PROP_BUFFERSIZE)
            if not ok or int(got) != s.buffer_size:
                raise self._fail("buffer_size", s.buffer_size, got)
        if s.exposure_ms is not None:
            self._manual_exposure(s.exposure_ms)
        # The buffer-size change restarted the stream again: verify the format survived.
        if s.fourcc is not None and fourcc_text(cap.get(cv2.CAP_PROP_FOURCC)) != s.fourcc:
            raise self._fail("fourcc", repr(s.fourcc.strip()), repr(fourcc_text(cap.get(cv2.CAP_PROP_FOURCC))))
        self._check_size()
        if s.fps is not None:
            self._check_fps()
        self.width = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH))
        self.height = int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
        if self.width <= 0 or self.height <= 0:
            raise DeviceError(f"camera {self.name}: the {self.backend} backend reports no frame size")
        fourcc = fourcc_text(cap.get(cv2.CAP_PROP_FOURCC))
        self._applied.update(fourcc=fourcc.strip() or None, fps=_positive_or_none(cap.get(cv2.CAP_PROP_FPS)))

    def _check_size(self) -> None:
        s = self.settings
        got_w = int(self._cap.get(cv2.CAP_PROP_FRAME_WIDTH))
        got_h = int(self._cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
        if (s.width is not None and got_w != s.width) or (s.height is not None and got_h != s.height):
            wanted = f"{s.width or got_w}x{s.height or got_h}"
            raise self._fail("width/height", wanted, f"{got_w}x{got_h}")

    def _check_fps(self) -> None:
        wanted = float(self.settings.fps)  # type: ignore[arg-type]
        got = self._cap.get(cv2.CAP_PROP_FPS)
        if not abs(got - wanted) <= 0.01 * wanted:
            hint = ""
            if self.backend == "V4L2" and wanted != round(wanted):
                hint = "OpenCV's V4L2 backend requests whole frames per second only"
            raise self._fail("fps", f"{wanted:g}", f"{got:g}", hint)

    def _manual_exposure(self, exposure_ms: float) -> None:
        cap = self._cap
        if self.backend == "V4L2":
            # Raw control values (not OpenCV's optional [0, 1) normalisation): cap_v4l.cpp, CAP_PROP_MODE.
            self._set(cv2.CAP_PROP_MODE, 0)
        ok = self._set(cv2.CAP_PROP_AUTO_EXPOSURE, _AUTO_EXPOSURE_MANUAL)
        got = cap.get(cv2.CAP_PROP_AUTO_EXPOSURE)
        if got == -1 and not ok:
            self._applied["auto_exposure"] = "absent"
        elif int(got) != _AUTO_EXPOSURE_MANUAL:
            raise self._fail("auto_exposure", f"{_AUTO_EXPOSURE_MANUAL} (manual)", got)
        else:
            self._applied["auto_exposure"] = "manual"
        units = round(exposure_ms / _EXPOSURE_UNIT_MS)
        ok = self._set(cv2.CAP_PROP_EXPOSURE, units)
        got = cap.get(cv2.CAP_PROP_EXPOSURE)
        if not ok or abs(got - units) > 1:
            raise self._fail(
                "exposure",
                f"{exposure_ms:g} ms ({units} × 100 µs)",
                f"{got * _EXPOSURE_UNIT_MS:g} ms" if got >= 0 else "unavailable",
                "" if self.backend != "V4L2" else "outside the camera's range or step; v4l2-ctl -d DEV --list-ctrls shows it",
            )
        self._applied["exposure_ms"] = got * _EXPOSURE_UNIT_MS
        # Auto white balance and autofocus off; a camera without the control has nothing to switch off.
        for key, prop in (("auto_wb", cv2.CAP_PROP_AUTO_WB), ("autofocus", cv2.CAP_PROP_AUTOFOCUS)):
            ok = self._set(prop, 0)
            got = cap.get(prop)
            if got == -1 and not ok:
                self._applied[key] = "absent"
            elif got != 0:
                raise self._fail(key, "0 (off)", got)
            else:
                self._applied[key] = "off"
        # OpenCV has no property for V4L2_CID_AUTOGAIN; UVC cameras have no auto gain apart from auto exposure.
        self._applied["auto_gain"] = "not controllable through OpenCV (docs/camera.md)"

    def _discard(self, count: int) -> None:
        deadline = self._clock() + self.settings.timeout_ms / 1000.0 * max(1, count)
        got = 0
        while got < count:
            if self._clock() >= deadline:
                raise DeviceTimeout(
                    f"camera {self.name}: only {got} of the {count} frames to discard after opening arrived within "
                    f"{(self.settings.timeout_ms * max(1, count)):.0f} ms (is the camera streaming?)"
                )
            ok, img = self._cap.read()
            if ok and img is not None:
                self._clock_map.stamp(self._cap.get(cv2.CAP_PROP_POS_MSEC), self._clock())
                got += 1
            else:
                time.sleep(0.005)
        self._applied["discarded"] = count

    # ----- Camera protocol ---------------------------------------------------------------------------------------

    def grab(self, *, after_s: float, timeout_s: float) -> Frame:
        """The first frame whose time is later than `after_s` (host monotonic s); DeviceTimeout after `timeout_s`.

        Frames exposed before `after_s` show the previous pattern; rather than read them the camera waits until
        `after_s`, then drops whatever stale frames are still queued. The deadline is checked between reads; one
        blocking V4L2 read may overrun it by up to OPENCV_VIDEOIO_V4L_SELECT_TIMEOUT seconds.
        """
        self._check_open()
        start = self._clock()
        deadline = start + timeout_s
        self._wait_until(min(after_s, deadline))
        stale = failed = 0
        while True:
            if self._clock() >= deadline:
                raise DeviceTimeout(self._timeout_message(after_s, timeout_s, stale, failed))
            ok, raw = self._cap.read()
            host_s = self._clock()
            if not ok or raw is None:
                failed += 1
                time.sleep(0.005)
                continue
            device_ms = self._cap.get(cv2.CAP_PROP_POS_MSEC)
            t = self._clock_map.stamp(device_ms, host_s)
            if t is None or t <= after_s:
                stale += 1
                continue
            image = self._image(raw)
            self._sequence += 1
            meta = {"device_time_ms": device_ms, "stale_dropped": stale, "clock": self._clock_map.mode}
            return Frame(image=image, timestamp_s=t, sequence=self._sequence, meta=meta)

    def _wait_until(self, t: float) -> None:
        while True:
            remaining = t - self._clock()
            if remaining <= 0:
                return
            time.sleep(min(remaining, 0.01))

    def _timeout_message(self, after_s: float, timeout_s: float, stale: int, failed: int) -> str:
        msg = f"camera {self.name}: no frame newer than the pattern switch + settle within {timeout_s * 1000:.0f} ms"
        if stale:
            msg += (
                f"; {stale} frame(s) arrived but were older than that (frame clock: {self._clock_map.mode}); is the "
                "trigger reaching the camera, and is camera.timeout_ms longer than settle_ms plus one frame period?"
            )
        elif failed:
            msg += f"; {failed} read(s) failed: the camera stopped streaming (unplugged? USB bandwidth? trigger mode?)"
        else:
            msg += "; the wait for the settle time used it all up (raise camera.timeout_ms)"
        return msg

    def _image(self, raw: np.ndarray) -> np.ndarray:
        if self._mono:
            image = decode_raw(raw, fourcc=self.settings.fourcc or "GREY", width=self.width, height=self.height)
        else:
            image = raw
        if image.shape[:2] != (self.height, self.width):
            raise DeviceError(
                f"camera {self.name}: delivered a {image.shape[1]}x{image.shape[0]} frame, expected "
                f"{self.width}x{self.height} (the format changed under the driver?)"
            )
        return image

    def describe(self) -> dict:
        """Device settings as applied (read back), for the capture manifest."""
        s = self.settings
        return {
            "kind": "v4l2",
            "name": self.name,
            "backend": self.backend,
            "width": self.width,
            "height": self.height,
            "mono_full_depth": bool(self._mono),
            "bit_depth": MONO_FORMATS[s.fourcc][1] if self._mono and s.fourcc else None,
            "buffer_size": s.buffer_size,
            "settle_ms": s.settle_ms,
            "timeout_ms": s.timeout_ms,
            "frame_clock": getattr(getattr(self, "_clock_map", None), "mode", None),
            "select_timeout_s": os.environ.get(SELECT_TIMEOUT_ENV) if self.backend == "V4L2" else None,
            "requested": {
                "width": s.width, "height": s.height, "fps": s.fps, "fourcc": s.fourcc, "exposure_ms": s.exposure_ms,
            },
            **self._applied,
        }

    def _check_open(self) -> None:
        if self._closed:
            raise DeviceError(f"camera {self.name} is closed")

    def close(self) -> None:
        """Release the capture (idempotent)."""
        if self._closed:
            return
        self._closed = True
        self._cap.release()

    def __enter__(self) -> "V4L2Camera":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _backend_name(capture: cv2.VideoCapture) -> str:
    try:
        return capture.getBackendName()
    except cv2.error:
        return "unknown"


def _positive_or_none(v: float) -> float | None:
    return float(v) if v > 0 else None
