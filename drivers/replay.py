"""Replay a recorded capture directory as a camera, through OpenCV's own image-sequence backend (CAP_IMAGES).

A capture directory is what `rig scan --record DIR` writes (docs/recording.md): `manifest.json` with a `frames`
list (`{"file": "frames/000000.png", "pattern": 0, "timestamp_s": …}`), `frames.jsonl` with the same entries
appended as frames are written (the only list left when a scan was killed), and the frames as 8- or 16-bit
PNG. The frame list is taken from the manifest, else from frames.jsonl, else the image files in DIR (or DIR/frames)
in name order.

CAP_IMAGES reads each file with `imread(…, IMREAD_UNCHANGED)` (cap_images.cpp), so 16-bit frames stay 16-bit and
grey frames stay (H, W); tests/drivers/test_camera_replay.py checks it. A run of consecutively numbered files is
one VideoCapture opened on its first file (OpenCV derives the printf pattern and the start number from the name);
gaps in the numbering start a new run.

Timing: a replayed frame is "exposed" when it is asked for. `grab(after_s=…)` waits until `after_s` has passed (as
a real camera would deliver no fresh frame earlier) and stamps the frame with the host time; the recorded time and
pattern id travel in `Frame.meta`.
"""

from __future__ import annotations

import json
import re
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from calibration.errors import DeviceError, DeviceTimeout
from drivers.base import Frame

IMAGE_SUFFIXES = {".png", ".tif", ".tiff", ".pgm", ".ppm", ".pnm", ".bmp", ".jpg", ".jpeg"}
_FIRST_NUMBER = re.compile(r"^(\D*)(\d+)(.*)$")  # OpenCV's icvExtractPattern: the first digit run of the name


@dataclass(frozen=True)
class ReplayEntry:
    """One recorded frame: its file (absolute), and whatever the recording said about it."""

    path: Path
    pattern: int | None = None
    timestamp_s: float | None = None
    meta: dict | None = None


def load_entries(directory: Path) -> tuple[list[ReplayEntry], str, dict]:
    """The frames of a capture directory in playing order, where the list came from, and the manifest header.

    Source: "manifest" (manifest.json's frames), "frames.jsonl" (a recording that was not closed), or "files".
    DeviceError for a missing directory, an unreadable manifest, a listed file that is missing, or no frames.
    """
    directory = Path(directory)
    if not directory.exists():
        raise DeviceError(f"replay {directory}: no such directory (record one with `rig scan --record {directory}`)")
    if not directory.is_dir():
        raise DeviceError(f"replay {directory}: not a directory (camera = \"replay:DIR\" names a capture directory)")
    header: dict = {}
    records: list[dict] = []
    source = "files"
    manifest = directory / "manifest.json"
    if manifest.exists():
        try:
            header = json.loads(manifest.read_text(encoding="utf-8"))
        except (OSError, ValueError) as e:
            raise DeviceError(f"replay {directory}: cannot read manifest.json ({e}); is the recording intact?") from e
        if not isinstance(header, dict):
            raise DeviceError(f"replay {directory}: manifest.json is not a JSON object")
        records = list(header.get("frames") or [])
        source = "manifest"
    if not records and (directory / "frames.jsonl").exists():
        records = _read_jsonl(directory / "frames.jsonl")
        source = "frames.jsonl"
    if records:
        entries = []
        for i, r in enumerate(records):
            if not isinstance(r, dict) or not isinstance(r.get("file"), str):
                raise DeviceError(f"replay {directory}: frame entry {i} in {source} has no \"file\"")
            path = directory / r["file"]
            if not path.is_file():
                raise DeviceError(f"replay {directory}: {source} lists {r['file']} but the file is missing")
            extra = {k: v for k, v in r.items() if k not in ("file", "pattern", "timestamp_s")}
            entries.append(ReplayEntry(path, r.get("pattern"), r.get("timestamp_s"), extra))
        return entries, source, header
    for folder in (directory, directory / "frames"):
        files = sorted(p for p in folder.glob("*") if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)
        if files:
            return [ReplayEntry(p) for p in files], "files", header
    raise DeviceError(
        f"replay {directory}: no frames (expected manifest.json from `rig scan --record`, or image files such as "
        "000000.png in the directory or in its frames/ folder)"
    )


def _read_jsonl(path: Path) -> list[dict]:
    out = []
    with open(path, encoding="utf-8") as f:
        for line in f:
            line = line.strip()
            if not line:
                continue
            try:
                out.append(json.loads(line))
            except ValueError:
                break  # a line cut short by a crash ends the list; the frames before it are good
    return out


def contiguous_runs(paths: list[Path]) -> list[tuple[int, int]]:
    """Split `paths` into (start, count) runs that one CAP_IMAGES capture plays in order.

    A run is a sequence of files in one folder whose names differ only in their first number, which increases by
    one (frames/000007.png, frames/000008.png, …). Names without a number are runs of one.
    """
    runs: list[tuple[int, int]] = []
    i = 0
    while i < len(paths):
        start = i
        m = _FIRST_NUMBER.match(paths[i].name)
        while m and i + 1 < len(paths):
            prefix, digits, suffix = m.groups()
            nxt = paths[i].with_name(f"{prefix}{int(digits) + 1:0{len(digits)}d}{suffix}")
            if paths[i + 1] != nxt:
                break
            i += 1
            m = _FIRST_NUMBER.match(paths[i].name)
        runs.append((start, i - start + 1))
        i += 1
    return runs


class ReplayCamera:
    """`drivers.base.Camera` playing a capture directory back, frame by frame, in recorded order.

    directory: the capture directory. loop: start again at the first frame after the last one (else the grab after
    the last frame raises DeviceError "replay DIR has no more frames (N played)").
    """

    def __init__(self, directory: Path, *, loop: bool = False):
        self.directory = Path(directory)
        self.loop = loop
        self.entries, self.source, self._header = load_entries(self.directory)
        self._runs = contiguous_runs([e.path for e in self.entries])
        self._cap: cv2.VideoCapture | None = None
        self._run = -1
        self._left_in_run = 0
        self._next = 0  # index into entries of the next frame
        self.played = 0
        self._closed = False
        try:
            first = self._read_next()
        except BaseException:
            self.close()
            raise
        self._pending: np.ndarray | None = first
        self._shape = first.shape
        self.height, self.width = first.shape[:2]
        self.dtype = first.dtype
        self.channels = 1 if first.ndim == 2 else first.shape[2]

    @property
    def frame_count(self) -> int:
        return len(self.entries)

    def _open_run(self, run: int) -> None:
        if self._cap is not None:
            self._cap.release()
            self._cap = None
        start, count = self._runs[run]
        path = self.entries[start].path
        try:
            cap = cv2.VideoCapture(str(path), cv2.CAP_IMAGES)
        except cv2.error as e:
            raise DeviceError(f"replay {self.directory}: OpenCV cannot open {path.name} as an image sequence ({e})") from e
        if not cap.isOpened():
            cap.release()
            raise DeviceError(f"replay {self.directory}: OpenCV cannot read {path.name} (not an image, or unreadable)")
        self._cap = cap
        self._run = run
        self._left_in_run = count

    def _read_next(self) -> np.ndarray:
        """The image of entry `self._next` (advances the position); the caller checks the end."""
        if self._left_in_run == 0:
            self._open_run(self._run + 1)
        assert self._cap is not None
        ok, image = self._cap.read()
        if not ok or image is None:
            raise DeviceError(f"replay {self.directory}: cannot read {self.entries[self._next].path.name}")
        self._left_in_run -= 1
        self._next += 1
        return image

    def _restart(self) -> None:
        self._run = -1
        self._left_in_run = 0
        self._next = 0

    def grab(self, *, after_s: float, timeout_s: float) -> Frame:
        """The next recorded frame, delivered once `after_s` has passed; DeviceTimeout if that is after the deadline."""
        if self._closed:
            raise DeviceError(f"replay {self.directory} is closed")
        now = time.monotonic()
        deadline = now + timeout_s
        if after_s >= deadline:
            time.sleep(max(0.0, deadline - now))
            raise DeviceTimeout(
                f"replay {self.directory}: no frame newer than {after_s - now:.3f} s from now can arrive within the "
                f"{timeout_s * 1000:.0f} ms deadline"
            )
        if self._pending is not None:
            image, self._pending = self._pending, None
            index = 0
        else:
            if self._next >= len(self.entries):
                if not self.loop:
                    raise DeviceError(f"replay {self.directory} has no more frames ({self.played} played)")
                self._restart()
            index = self._next
            image = self._read_next()
        if image.shape != self._shape or image.dtype != self.dtype:
            raise DeviceError(
                f"replay {self.directory}: {self.entries[index].path.name} is "
                f"{image.dtype} {image.shape}, but the recording's first frame is {self.dtype} {self._shape}"
            )
        while (t := time.monotonic()) <= after_s:
            time.sleep(min(after_s - t, 0.01) + 1e-6)
        entry = self.entries[index]
        self.played += 1
        meta: dict[str, Any] = {"file": str(entry.path.relative_to(self.directory)), "replayed": True}
        if entry.pattern is not None:
            meta["pattern"] = entry.pattern
        if entry.timestamp_s is not None:
            meta["recorded_timestamp_s"] = entry.timestamp_s
        if entry.meta:
            meta.update(entry.meta)
        return Frame(image=image, timestamp_s=t, sequence=self.played, meta=meta)

    def describe(self) -> dict:
        recorded = (self._header.get("devices") or {}).get("camera") if isinstance(self._header, dict) else None
        return {
            "kind": "replay",
            "directory": str(self.directory),
            "frames": len(self.entries),
            "frame_list": self.source,
            "loop": self.loop,
            "width": self.width,
            "height": self.height,
            "dtype": str(self.dtype),
            "recorded_camera": recorded,
            "complete": self._header.get("complete") if isinstance(self._header, dict) else None,
        }

    def close(self) -> None:
        """Release the image-sequence capture (idempotent)."""
        if self._closed:
            return
        self._closed = True
        if self._cap is not None:
            self._cap.release()
            self._cap = None

    def __enter__(self) -> "ReplayCamera":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
