"""Byte transports for the trigger board: opening a port by path or URL, recording and replaying a session.

The driver never builds its transport (docs/decisions/0020-serial-protocol-design.md): `open_transport` does,
and the result is handed to `SerialProjector`. Anything with pyserial's `read`, `write`, `in_waiting`,
`reset_input_buffer` and `close` works; a transport may also offer `fileno()` (the driver then waits on it
with select) or `wait_readable(timeout_s) -> bool` (test and replay transports).
"""

from __future__ import annotations

import errno
import json
import os
import time
from pathlib import Path
from typing import Any, Callable

from calibration.errors import ConfigError, DeviceError, ProtocolError

REPLAY_PREFIX = "replay:"


def open_transport(url: str, *, baudrate: int = 115200, exclusive: bool = True) -> Any:
    """Open the trigger board's port: a device path (/dev/ttyACM0, /dev/serial/by-id/…), a pyserial URL
    (socket://host:port, loop://, spy://…, rfc2217://…) or ``replay:FILE.jsonl`` (a recorded transcript,
    see `ReplayTransport`). Non-blocking reads (timeout=0): the driver keeps its own deadlines.

    exclusive: lock the port (flock) so a second program cannot open it while we use it. Raises
    DeviceError naming the port and the fix (missing port, permission, busy).
    """
    import serial

    if url.startswith(REPLAY_PREFIX):
        return ReplayTransport(url[len(REPLAY_PREFIX) :])
    is_path = "://" not in url
    if is_path and not os.path.exists(url):
        raise DeviceError(f"serial port {url} does not exist (is the board plugged in? `rig devices` lists the ports)")
    try:
        port = serial.serial_for_url(url, baudrate=baudrate, timeout=0, write_timeout=1.0, exclusive=exclusive)
    except ValueError as e:
        raise ConfigError(f"serial port {url!r}: {e} (use a device path or a pyserial URL such as socket://host:port)") from e
    except serial.SerialException as e:
        code = e.errno if isinstance(e.errno, int) else None
        text = str(e)
        if code in (errno.EACCES, errno.EPERM) or "Permission denied" in text:
            raise DeviceError(
                f"serial port {url}: permission denied (add yourself to the port's group, usually "
                f"`sudo usermod -aG dialout $USER`, then log in again)"
            ) from e
        if code in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EBUSY) or "exclusively lock" in text:
            raise DeviceError(f"serial port {url} is busy: another program has it open (close it, e.g. a serial monitor)") from e
        if code == errno.ENOENT or "No such file" in text:
            raise DeviceError(f"serial port {url} does not exist (`rig devices` lists the ports)") from e
        raise DeviceError(f"serial port {url}: cannot open: {text}") from e
    try:
        port.reset_input_buffer()  # bytes from before we opened belong to nobody
    except (NotImplementedError, AttributeError, OSError):  # some URL handlers lack it; harmless
        pass
    return port


def _text(data: bytes) -> str:
    """Bytes as a JSON-safe string, one code point per byte (latin-1), so any garbage round-trips."""
    return data.decode("latin-1")


class TranscriptWriter:
    """Writes a serial session as JSON Lines: one header, then one record per write and per received line.

    ``{"dir": "meta", "format": "rig-serial-transcript", "version": 1, …}`` then
    ``{"t": 12.345678, "dir": "tx", "data": "12 SHOW 3*1A2B\\n"}`` (host → device, each write) and
    ``{"t": …, "dir": "rx", "data": "12 OK i=3 …\\n"}`` (device → host, each complete line as received,
    garbage included). t: host monotonic seconds; data: the bytes as latin-1 text. Lines are flushed as
    written, so a crash keeps everything up to it. A context manager; close() is idempotent.
    """

    def __init__(self, path: str | os.PathLike, *, meta: dict | None = None, clock: Callable[[], float] = time.monotonic):
        self.path = Path(path)
        self.clock = clock
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._f = open(self.path, "w", encoding="utf-8")
        self._record({"dir": "meta", "format": "rig-serial-transcript", "version": 1, **(meta or {})})

    def _record(self, rec: dict) -> None:
        if self._f is None:
            return
        self._f.write(json.dumps(rec, separators=(",", ":")) + "\n")
        self._f.flush()

    def tx(self, data: bytes) -> None:
        self._record({"t": round(self.clock(), 6), "dir": "tx", "data": _text(data)})

    def rx(self, data: bytes) -> None:
        self._record({"t": round(self.clock(), 6), "dir": "rx", "data": _text(data)})

    def close(self) -> None:
        if self._f is not None:
            self._f.close()
            self._f = None

    def __enter__(self) -> "TranscriptWriter":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def read_transcript(path: str | os.PathLike) -> tuple[dict, list[tuple[str, bytes, float]]]:
    """A transcript's header and its records as (dir, bytes, t). Raises ConfigError if malformed."""
    path = Path(path)
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except OSError as e:
        raise ConfigError(f"{path}: cannot read the serial transcript: {e.strerror}") from e
    records: list[tuple[str, bytes, float]] = []
    meta: dict = {}
    for n, line in enumerate(lines, 1):
        try:
            rec = json.loads(line)
            if rec["dir"] == "meta":
                meta = rec
                continue
            if rec["dir"] not in ("tx", "rx"):
                raise KeyError("dir")
            records.append((rec["dir"], rec["data"].encode("latin-1"), float(rec["t"])))
        except (ValueError, KeyError, TypeError, UnicodeEncodeError) as e:
            raise ConfigError(f"{path}:{n}: not a serial transcript record ({e!r})") from e
    if meta.get("format") != "rig-serial-transcript":
        raise ConfigError(f"{path}: not a rig serial transcript (no header line with format=rig-serial-transcript)")
    return meta, records


class ReplayTransport:
    """Plays a recorded transcript back as a transport: a strict device stand-in.

    Every write must continue the recorded host output exactly (else ProtocolError naming the first
    difference); after each recorded write, the device lines recorded after it become readable. Timing is
    not reproduced: replies are available at once (the driver's deadlines only matter where the recording
    has a retry after silence; the driver then waits its timeout, as it did when recording).
    `remaining` counts records not yet replayed.
    """

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        self.port = f"{REPLAY_PREFIX}{self.path}"
        self.meta, self._records = read_transcript(self.path)
        self._i = 0
        self._rx = bytearray()
        self._tx = bytearray()
        self.is_open = True
        self.timeout = 0
        self._release()

    def _release(self) -> None:
        while self._i < len(self._records) and self._records[self._i][0] == "rx":
            self._rx += self._records[self._i][1]
            self._i += 1

    @property
    def remaining(self) -> int:
        return len(self._records) - self._i + (1 if self._tx else 0)

    @property
    def in_waiting(self) -> int:
        return len(self._rx)

    def read(self, size: int = 1) -> bytes:
        out = bytes(self._rx[:size])
        del self._rx[:size]
        return out

    def wait_readable(self, timeout_s: float) -> bool:
        if not self._rx:
            time.sleep(min(timeout_s, 0.005))
        return bool(self._rx)

    def write(self, data: bytes) -> int:
        if not self.is_open:
            raise DeviceError(f"{self.port}: write after close")
        self._tx += data
        while self._tx:
            if self._i >= len(self._records):
                raise ProtocolError(f"{self.port}: the host sent {bytes(self._tx)!r} after the end of the recording")
            expected = self._records[self._i][1]
            if self._tx.startswith(expected):
                del self._tx[: len(expected)]
                self._i += 1
                self._release()
            elif expected.startswith(self._tx):
                break  # a partial write: wait for the rest
            else:
                raise ProtocolError(
                    f"{self.port}: replay diverged at record {self._i + 1}: recorded {expected!r}, "
                    f"the host sent {bytes(self._tx)!r}"
                )
        return len(data)

    def flush(self) -> None:
        return None

    def reset_input_buffer(self) -> None:
        # Recorded rx lines are exactly those the host read, so none of them may be discarded here.
        return None

    def close(self) -> None:
        self.is_open = False

    def __enter__(self) -> "ReplayTransport":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def connect(
    url: str,
    *,
    baudrate: int = 115200,
    timeout_s: float = 0.5,
    retries: int = 3,
    transcript: "TranscriptWriter | None" = None,
):
    """Open `url` (see `open_transport`) and hand it to a SerialProjector that can reopen it after a
    disconnect (replay transcripts are not reopened). The caller closes the projector (a context manager)."""
    from drivers.serial.projector import SerialProjector

    def reopen() -> Any:
        return open_transport(url, baudrate=baudrate)

    transport = open_transport(url, baudrate=baudrate)
    return SerialProjector(
        transport,
        timeout_s=timeout_s,
        retries=retries,
        reopen=None if url.startswith(REPLAY_PREFIX) else reopen,
        transcript=transcript,
    )
