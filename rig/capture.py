"""Raw capture directories (`rig scan --record DIR`): frames on disk before anything else touches them.

Layout (docs/recording.md):

    DIR/manifest.json     header (software, command line, configuration, devices, patterns); rewritten at the end
                          with "complete": true and the frame list
    DIR/frames.jsonl      one line per frame, appended and flushed as each frame is written (survives a crash)
    DIR/frames/NNNNNN.png the raw frames, full bit depth (8- or 16-bit PNG)
    DIR/patterns/NNN.png  the projector images, by pattern id
    DIR/serial.jsonl      the serial transcript (when the projector is a serial board)
    DIR/calibration.json  the calibration the scan used

`camera = "replay:DIR"` plays such a directory back.
"""

from __future__ import annotations

import json
import os
import platform
import sys
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from calibration.errors import DeviceError
from calibration.file import atomic_write, write_text_atomic

FORMAT = "rig-capture"
FORMAT_VERSION = 1


def write_png_atomic(path: Path, image: np.ndarray) -> None:
    """PNG at full bit depth (uint8 or uint16), written to a temporary name, fsynced and renamed."""
    ok, buf = cv2.imencode(".png", image)
    if not ok:
        raise DeviceError(f"cannot encode a {image.dtype} {image.shape} frame as PNG")
    atomic_write(path, lambda f: f.write(buf.tobytes()))


def software_versions() -> dict[str, str]:
    import rerun

    from rig import __version__

    return {
        "rig": __version__,
        "python": platform.python_version(),
        "opencv": cv2.__version__,
        "numpy": np.__version__,
        "rerun": rerun.__version__,
    }


class CaptureWriter:
    """Writes one capture directory; frames go to disk (fsynced) the moment they are handed over."""

    def __init__(self, directory: str | os.PathLike, *, header: dict[str, Any]):
        self.dir = Path(directory)
        if (self.dir / "manifest.json").exists():
            raise DeviceError(f"{self.dir} already holds a capture; choose a new --record directory")
        (self.dir / "frames").mkdir(parents=True, exist_ok=True)
        (self.dir / "patterns").mkdir(exist_ok=True)
        self.header = {
            "format": FORMAT,
            "format_version": FORMAT_VERSION,
            "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
            "software": software_versions(),
            "command": sys.argv,
            **header,
            "complete": False,
        }
        self._write_manifest(frames=None)
        self._frames = open(self.dir / "frames.jsonl", "a", encoding="utf-8")
        self.count = 0
        self._closed = False

    @property
    def transcript_path(self) -> Path:
        return self.dir / "serial.jsonl"

    def write_pattern(self, pattern_id: int, image: np.ndarray) -> str:
        rel = f"patterns/{pattern_id:03d}.png"
        write_png_atomic(self.dir / rel, image)
        return rel

    def write_frame(self, image: np.ndarray, *, pattern: int, timestamp_s: float, **meta: Any) -> str:
        """Write the raw frame and its manifest line; returns the frame's relative path."""
        rel = f"frames/{self.count:06d}.png"
        write_png_atomic(self.dir / rel, image)
        entry = {"file": rel, "pattern": pattern, "timestamp_s": timestamp_s, **meta}
        self._frames.write(json.dumps(entry) + "\n")
        self._frames.flush()
        os.fsync(self._frames.fileno())
        self.count += 1
        return rel

    def _write_manifest(self, *, frames: Path | None, complete: bool = False) -> None:
        # The frame list is streamed from frames.jsonl into the manifest: constant memory for any length.
        tmp = self.dir / ".manifest.json.tmp"
        head = dict(self.header, complete=complete)
        with open(tmp, "w", encoding="utf-8") as out:
            text = json.dumps(head, indent=2, default=str)
            out.write(text[:-2] + ',\n  "frames": [')
            first = True
            if frames is not None and frames.exists():
                with open(frames, encoding="utf-8") as f:
                    for line in f:
                        if line.strip():
                            out.write(("\n    " if first else ",\n    ") + line.strip())
                            first = False
            out.write("\n  ]\n}\n")
            out.flush()
            os.fsync(out.fileno())
        os.replace(tmp, self.dir / "manifest.json")

    def close(self, *, complete: bool = True, summary: dict | None = None) -> None:
        """Finish the manifest (idempotent). `complete` is False when the scan stopped on an error."""
        if self._closed:
            return
        self._closed = True
        self._frames.close()
        if summary:
            self.header["summary"] = summary
        self._write_manifest(frames=self.dir / "frames.jsonl", complete=complete)

    def __enter__(self) -> "CaptureWriter":
        return self

    def __exit__(self, exc_type, *exc) -> None:
        self.close(complete=exc_type is None)


def save_calibration_copy(directory: Path, text: str) -> None:
    write_text_atomic(directory / "calibration.json", text)
