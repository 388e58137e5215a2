"""The host side of the trigger board protocol (docs/protocol.md): `SerialProjector`.

Host rules it keeps: one request in flight; a deadline on every wait; a request that times out, comes back
garbled or is answered BUSY is resent with the *same* sequence number (the board answers a repeat from its
reply cache, so a lost acknowledgement never fires the camera twice); after the retries it reconnects
(`reopen`), handshakes, reads STATUS and reconciles (restoring the pattern order and timing after a reboot)
before a last round of resends; `stop()` on every exit path (`close()`, the context manager).
"""

from __future__ import annotations

import io
import select
import threading
import time
from collections import deque
from dataclasses import asdict, dataclass
from typing import Any, Callable, Iterator, Sequence

import numpy as np

from calibration.errors import ConfigError, DeviceError, DeviceTimeout, ProtocolError
from drivers.base import Shown
from drivers.serial import protocol as P
from drivers.serial.transport import TranscriptWriter

MAX_RECONNECTS = 3  # per request
_HOST_MAX_LINE = 4096  # the host keeps longer garbage lines whole (for the transcript); frames are ≤ 128


@dataclass
class LinkStats:
    """Counters of one driver's link (the fault matrix reads them).

    sent: requests issued; retries: resends of a request with its sequence number; recovered: requests
    that succeeded after at least one resend; failed: requests that raised (given up, or refused);
    refused: those of them refused with an ERR reply (not BUSY); reconnects; reboots: device reboots
    noticed (a banner, the clock going backwards, or STATUS having forgotten the patterns); garbage: received
    lines that were not valid frames; stale: valid replies to an earlier request (late duplicates).
    """

    sent: int = 0
    retries: int = 0
    recovered: int = 0
    failed: int = 0
    refused: int = 0
    reconnects: int = 0
    reboots: int = 0
    garbage: int = 0
    stale: int = 0

    def as_dict(self) -> dict[str, int]:
        return asdict(self)


@dataclass(frozen=True)
class SeqEvent:
    """One trigger of a running sequence: position k in the order, pattern index, device time of the
    trigger (µs since boot) and host monotonic time at which the event was received."""

    k: int
    index: int
    device_time_us: int
    host_time_s: float


@dataclass(frozen=True)
class SeqDone:
    """The end of a sequence: triggers fired, slots missed by the device (it was late), events fired but
    never received by the host (lost on the line), device time at the end (None if reconstructed from
    STATUS because the DONE message was lost)."""

    fired: int
    missed: int
    lost_events: int
    device_time_us: int | None


def _prefixed(what: str, e: BaseException) -> str:
    """`what: e`, without doubling a prefix pyserial already wrote ("write failed: write failed: …")."""
    text = str(e)
    return text if text.startswith(what) else f"{what}: {text}"


class _LinkDown(DeviceError):
    """The transport raised (port vanished, I/O error). Handled inside the driver by reconnecting; should it
    escape (while following a sequence, say), it is a DeviceError like any other."""


class SerialProjector:
    """A projector whose pattern switching and camera trigger are driven by a serial board.

    transport: an OPEN byte stream (`open_transport(...)`, a test transport); the driver never builds one.
    timeout_s: deadline of one request before it is resent; retries: resends before reconnecting.
    reopen: returns a freshly opened transport after a disconnect (None: re-handshake on the same one).
    transcript: records every frame sent and received (the caller owns and closes it).
    clock: host monotonic seconds (injectable for tests).

    The pattern images stay on the host (they reach the projector over its video input); the board holds
    the number of patterns and their order. The handshake happens on first use (or `hello()`).
    """

    def __init__(
        self,
        transport: Any,
        *,
        timeout_s: float = 0.5,
        retries: int = 3,
        reopen: Callable[[], Any] | None = None,
        transcript: TranscriptWriter | None = None,
        clock: Callable[[], float] = time.monotonic,
    ):
        if timeout_s <= 0:
            raise ConfigError(f"serial timeout must be > 0 s, got {timeout_s}")
        if retries < 0:
            raise ConfigError(f"serial retries must be ≥ 0, got {retries}")
        self._t = transport
        self.timeout_s = float(timeout_s)
        self.retries = int(retries)
        self._reopen = reopen
        self._transcript = transcript
        self.clock = clock
        self.stats = LinkStats()
        self._lock = threading.RLock()
        self._splitter = P.LineSplitter(max_line=_HOST_MAX_LINE)
        self._lines: deque[tuple[bytes, float]] = deque()
        self._messages: deque[tuple[P.Message, float]] = deque()
        self._seq = 0
        self._info: dict | None = None
        self._patterns: list[np.ndarray] | None = None
        self._n = 0
        self._order: list[int] = []
        self._params: dict[str, int] = {}
        self._params_set: dict[str, int] = {}
        self._showing: int | None = None
        self._device_us = -1  # last device time seen, to notice a reboot (time going backwards)
        self._rebooted = False
        self._run: dict | None = None
        self._done: SeqDone | None = None
        self._closed = False
        self.close_error: DeviceError | None = None  # why close() could not stop the board, if it could not
        self.clock_offset_s: float | None = None  # host time ≈ device time + offset (from ping())
        self.port = str(getattr(transport, "port", None) or getattr(transport, "name", None) or type(transport).__name__)

    # ------------------------------------------------------------------ lifecycle

    def __enter__(self) -> "SerialProjector":
        return self

    def __exit__(self, exc_type: object, exc: object, tb: object) -> None:
        self.close()

    def close(self) -> None:
        """Stop (safe state) and close the transport. Idempotent, and never raises: it runs on exit paths,
        where an error here would hide the one that got us there. If STOP could not be delivered, the
        problem is kept in `close_error` (the board's watchdog darkens it anyway)."""
        with self._lock:
            if self._closed:
                return
            try:
                # Full recovery only if the board ever answered; a board that never did gets the resends only.
                self._stop(recover=self._info is not None)
            except DeviceError as e:
                self.close_error = DeviceError(f"trigger board on {self.port}: could not stop it before closing: {e}")
            finally:
                self._closed = True
                self._showing = None
                try:
                    self._t.close()
                except OSError:
                    pass

    # ------------------------------------------------------------------ public verbs

    def hello(self) -> dict:
        """Handshake: device, firmware, protocol version, capabilities. Refuses a different major version."""
        with self._lock:
            self._check_open()
            self._flush_input()
            try:
                reply = self._request("HELLO", P.PROTOCOL_VERSION, lead=True, recover=False)
            except DeviceTimeout as e:
                if self._reopen is None:
                    raise DeviceTimeout(
                        f"{e} (is it a rig trigger board with its firmware flashed, at the configured baud rate?)"
                    ) from e
                self._reconnect(str(e))  # handshakes itself; raises DeviceError naming the problem
                self._rebooted = False
                assert self._info is not None
                return dict(self._info)
            self._rebooted = False  # a boot banner before the first handshake is not a reboot to reconcile
            return self._take_hello(reply)

    def _take_hello(self, reply: P.Reply) -> dict:
        f = reply.fields
        missing = [k for k in ("device", "fw", "proto") if k not in f]
        if missing:
            raise ProtocolError(f"trigger board on {self.port}: HELLO reply lacks {', '.join(missing)}: {reply.body!r}")
        major = f["proto"].split(".")[0]
        if major != P.PROTOCOL_VERSION.split(".")[0]:
            raise ProtocolError(
                f"trigger board on {self.port} speaks protocol {f['proto']}, this rig speaks "
                f"{P.PROTOCOL_VERSION}: flash firmware for protocol {P.PROTOCOL_VERSION.split('.')[0]}.x "
                f"or update rig"
            )
        self._info = {
            "device": f["device"],
            "firmware": f["fw"],
            "protocol": f["proto"],
            "capabilities": [c for c in f.get("caps", "").split(",") if c],
            "max_order": int(f.get("max_order", "64")),
            "max_line": int(f.get("max_line", str(P.MAX_LINE))),
        }
        return dict(self._info)

    def ping(self) -> tuple[float, int]:
        """Round trip in host seconds and the device time in µs; updates `clock_offset_s`."""
        with self._lock:
            self._ready()
            t0 = self.clock()
            reply = self._request("PING")
            t1 = self.clock()
            t_us = self._int(reply, "t_us")
            self._note_device_time(t_us)
            self.clock_offset_s = (t0 + t1) / 2 - t_us * 1e-6
            return t1 - t0, t_us

    def get(self, name: str) -> int:
        """A timing parameter (µs): pulse_us, delay_us, period_us, exposure_us, watchdog_us."""
        self._check_param(name)
        with self._lock:
            self._ready()
            value = self._int(self._request("GET", name), name)
            self._params[name] = value
            return value

    def set(self, name: str, value: int) -> int:
        """Set a timing parameter (µs); returns the value the board actually applied (it may round)."""
        self._check_param(name)
        lo, hi, _ = P.PARAMS[name]
        value = int(value)
        if not lo <= value <= hi:
            raise ConfigError(f"{name}={value} is outside the protocol's range {lo}..{hi}")
        with self._lock:
            self._ready()
            applied = self._int(self._request("SET", name, value), name)
            self._params[name] = self._params_set[name] = applied
            return applied

    def load(self, patterns: Sequence[np.ndarray]) -> None:
        """Keep the pattern images (each (H, W) or (H, W, 3), all one shape) on the host and load the
        order 0…N−1 on the board."""
        images = [np.asarray(p) for p in patterns]
        if not images:
            raise ConfigError("load() needs at least one pattern image")
        if any(im.ndim not in (2, 3) or im.shape != images[0].shape for im in images):
            raise ConfigError(f"pattern images must share one (H, W) or (H, W, 3) shape; got {[im.shape for im in images]}")
        with self._lock:
            self._ready()
            self._load_order(list(range(len(images))), n=len(images))
            frozen = []
            for im in images:
                im = im.copy()
                im.setflags(write=False)
                frozen.append(im)
            self._patterns = frozen
            self._showing = None

    def show(self, index: int) -> Shown:
        """Switch to pattern `index` and fire the camera trigger; returns once the board acknowledged (the
        acknowledgement comes after the trigger pulse). host_time_s: when the acknowledgement arrived."""
        with self._lock:
            self._ready()
            if self._patterns is None:
                raise ConfigError("show() before load(): load the pattern images first")
            if not 0 <= index < len(self._patterns):
                raise ConfigError(f"pattern index {index} outside 0..{len(self._patterns) - 1}")
            extra_s = (self._params.get("delay_us", 0) + self._params.get("pulse_us", 0)) * 1e-6
            reply = self._request("SHOW", int(index), extra_s=extra_s)
            if self._int(reply, "i") != index:
                raise ProtocolError(f"trigger board on {self.port}: asked for pattern {index}, it showed {reply.fields['i']}")
            self._showing = index
            return Shown(index=index, host_time_s=self._rx_time, device_time_us=self._int(reply, "t_us"))

    @property
    def showing(self) -> np.ndarray | None:
        """The image the host believes is projected (None: dark, after stop/reset/watchdog)."""
        self._drain_messages()
        if self._patterns is None or self._showing is None:
            return None
        return self._patterns[self._showing]

    @property
    def showing_index(self) -> int | None:
        self._drain_messages()
        return self._showing

    def status(self) -> dict:
        """The board's STATUS as a dict (numbers as int): state, i, n, len, k, triggers, missed, last, t_us."""
        with self._lock:
            self._ready()
            return self._status()

    def _status(self, *, recover: bool = True) -> dict:
        reply = self._request("STATUS", recover=recover)
        out: dict[str, Any] = {}
        for k, v in reply.fields.items():
            out[k] = int(v) if v.lstrip("-").isdigit() else v
        if isinstance(out.get("t_us"), int):
            self._note_device_time(out["t_us"])
        return out

    def stop(self) -> None:
        """Put the projector in its safe state (dark, no sequence running). Idempotent."""
        with self._lock:
            if self._closed:
                return
            self._stop(recover=True)

    def _stop(self, *, recover: bool) -> None:
        self._request("STOP", recover=recover)
        self._showing = None
        self._run = None

    def reset(self) -> dict:
        """Reboot the board; returns its boot banner (device, fw, proto, reason). The pattern order and the
        timing parameters set through this driver are restored afterwards; nothing is shown."""
        with self._lock:
            self._ready()
            self._request("RESET")
            deadline = self.clock() + self.timeout_s + 2.0
            while True:
                item = self._receive(deadline)
                if item is None:
                    raise DeviceTimeout(f"trigger board on {self.port}: no boot banner within {self.timeout_s + 2.0:.1f} s after RESET")
                if isinstance(item, P.Message) and item.kind == "BOOT":
                    banner = dict(item.fields)
                    break
            self._rebooted = False
            self._restore()
            return banner

    def describe(self) -> dict:
        """Device, firmware, protocol version, port and capabilities, for the scan manifest."""
        with self._lock:
            self._ready()
            assert self._info is not None
            return {"kind": "serial-trigger", "port": self.port, **self._info}

    def keepalive(self) -> None:
        """Feed the board's watchdog (a PING) when the host has nothing else to say for a while."""
        self.ping()

    # ------------------------------------------------------------------ sequence mode

    def arm(self, order: Sequence[int] | None = None) -> int:
        """Load `order` (pattern indices; None: keep the loaded one) and arm the sequence; returns its length."""
        with self._lock:
            self._ready()
            if order is not None:
                order = [int(i) for i in order]
                if not order:
                    raise ConfigError("an empty sequence order")
                n = len(self._patterns) if self._patterns is not None else self._n
                if n == 0:
                    raise ConfigError("arm() before load(): load the pattern images first")
                bad = [i for i in order if not 0 <= i < n]
                if bad:
                    raise ConfigError(f"sequence order has indices outside 0..{n - 1}: {bad[:5]}")
                self._load_order(order, n=n)
            reply = self._request("ARM")
            self._params["period_us"] = self._int(reply, "period_us")
            return self._int(reply, "len")

    def start(self) -> int:
        """Start the armed sequence; returns the device time (µs) of the start."""
        with self._lock:
            self._ready()
            reply = self._request("START")
            length = self._int(reply, "len")
            self._run = {"len": length, "seen": set(), "t0": self.clock()}
            self._done = None
            return self._int(reply, "t_us")

    def events(self, *, timeout_s: float | None = None) -> Iterator[SeqEvent]:
        """The running sequence's triggers as they arrive, until DONE (then `done` is set).

        timeout_s: how long to wait in total (default: the sequence's length × period + 2 × timeout_s). If
        DONE is lost, STATUS reconstructs the end; if the board is still running at the deadline,
        DeviceTimeout."""
        if self._run is None:
            raise ConfigError("events() without a started sequence: arm() and start() first")
        run = self._run
        period_s = self._params.get("period_us", P.PARAMS["period_us"][2]) * 1e-6
        if timeout_s is None:
            timeout_s = run["len"] * period_s + 2 * self.timeout_s + 0.5
        deadline = run["t0"] + timeout_s
        while True:
            ev: SeqEvent | None = None
            with self._lock:
                item: Any
                if self._messages:
                    item, t = self._messages.popleft()
                else:
                    try:
                        item = self._receive(deadline, keep_messages=False)
                    except _LinkDown as e:
                        self._run = None
                        raise DeviceError(
                            f"trigger board on {self.port}: link lost during the sequence after "
                            f"{len(run['seen'])} events: {e}"
                        ) from e
                    t = self._rx_time
                if item is None:
                    self._done = self._done_from_status(run)
                    self._run = None
                    return
                if not isinstance(item, P.Message):
                    continue
                if item.kind == "BOOT":
                    self._run = None
                    raise DeviceError(
                        f"trigger board on {self.port} rebooted during the sequence after {len(run['seen'])} events"
                    )
                if item.kind == "EVT":
                    ev = SeqEvent(
                        k=self._msg_int(item, "k"),
                        index=self._msg_int(item, "i"),
                        device_time_us=self._msg_int(item, "t_us"),
                        host_time_s=t,
                    )
                    run["seen"].add(ev.k)
                    self._showing = ev.index
                elif item.kind == "DONE":
                    fired = self._msg_int(item, "fired")
                    self._done = SeqDone(
                        fired=fired,
                        missed=self._msg_int(item, "missed"),
                        lost_events=max(fired - len(run["seen"]), 0),
                        device_time_us=self._msg_int(item, "t_us"),
                    )
                    self._run = None
                    return
            if ev is not None:
                yield ev  # outside the lock: the consumer may call other methods from another thread

    def _done_from_status(self, run: dict) -> SeqDone:
        st = self._status()
        if st.get("state") == "running":
            raise DeviceTimeout(
                f"trigger board on {self.port}: sequence of {run['len']} still running at the deadline "
                f"({len(run['seen'])} events received)"
            )
        missed = int(st.get("missed", 0))
        fired = run["len"] - missed
        return SeqDone(fired=fired, missed=missed, lost_events=max(fired - len(run["seen"]), 0), device_time_us=None)

    @property
    def done(self) -> SeqDone | None:
        """How the last sequence ended (None while running or before any)."""
        return self._done

    def run_sequence(self, order: Sequence[int], *, on_event: Callable[[SeqEvent], None] | None = None) -> SeqDone:
        """Load `order`, arm, start and follow the events to the end; returns the end summary."""
        self.arm(order)
        self.start()
        for ev in self.events():
            if on_event is not None:
                on_event(ev)
        assert self._done is not None
        return self._done

    # ------------------------------------------------------------------ internals: state

    def _check_open(self) -> None:
        if self._closed:
            raise DeviceError(f"trigger board on {self.port}: used after close()")

    def _ready(self) -> None:
        self._check_open()
        if self._info is None:
            self.hello()

    @staticmethod
    def _check_param(name: str) -> None:
        if name not in P.PARAMS:
            raise ConfigError(f"no timing parameter {name!r} (one of {', '.join(P.PARAMS)})")

    def _int(self, reply: P.Reply, key: str) -> int:
        v = reply.fields.get(key)
        if v is None or not v.lstrip("-").isdigit():
            raise ProtocolError(f"trigger board on {self.port}: reply {reply.body!r} lacks an integer {key}")
        return int(v)

    def _msg_int(self, msg: P.Message, key: str) -> int:
        v = msg.fields.get(key)
        if v is None or not v.lstrip("-").isdigit():
            raise ProtocolError(f"trigger board on {self.port}: message {msg.body!r} lacks an integer {key}")
        return int(v)

    def _note_device_time(self, t_us: int) -> None:
        """Device time from a fresh answer (PING, STATUS: queries are never cached; a cached action reply
        carries an old time): if it went backwards, the board rebooted."""
        if t_us < self._device_us - 1000:
            self._rebooted = True  # the device clock went backwards: it rebooted
        self._device_us = t_us

    def _load_order(self, order: list[int], *, n: int) -> None:
        """LOAD in chunks that fit the line limit (the first chunk at 0 replaces the order)."""
        max_line = (self._info or {}).get("max_line", P.MAX_LINE)
        at = 0
        while at < len(order) or at == 0:
            head = f"{P.SEQ_MODULO - 1} LOAD {n} {at} "
            room = max_line - len(head) - 5
            chunk: list[str] = []
            used = 0
            for i in order[at:]:
                s = str(i)
                if used + len(s) + (1 if chunk else 0) > room:
                    break
                used += len(s) + (1 if chunk else 0)
                chunk.append(s)
            reply = self._request("LOAD", n, at, ",".join(chunk))
            at += len(chunk)
            if self._int(reply, "len") != at:
                raise ProtocolError(f"trigger board on {self.port}: LOAD left an order of {reply.fields['len']} entries, expected {at}")
            if at >= len(order):
                break
        self._n, self._order = n, list(order)

    def _restore(self) -> None:
        """After a reboot: the order and the timing parameters set through this driver, again."""
        self._showing = None
        self._rebooted = False
        self._run = None
        for name, value in self._params_set.items():
            self._params[name] = self._int(self._request("SET", name, value, recover=False), name)
        if self._n:
            self._load_order(self._order, n=self._n)

    # ------------------------------------------------------------------ internals: the link

    def _next_seq(self) -> int:
        self._seq = self._seq % (P.SEQ_MODULO - 1) + 1  # 1 … 65535
        return self._seq

    def _write(self, data: bytes) -> None:
        if self._transcript is not None:
            self._transcript.tx(data)
        try:
            self._t.write(data)
        except (OSError, ValueError) as e:  # SerialException is an OSError; ValueError: closed fd
            raise _LinkDown(_prefixed("write failed", e)) from e

    def _flush_input(self) -> None:
        try:
            self._t.reset_input_buffer()
        except (OSError, NotImplementedError, AttributeError):
            pass
        self._splitter.clear()
        self._lines.clear()

    def _wait(self, remaining_s: float) -> None:
        wait = getattr(self._t, "wait_readable", None)
        if wait is not None:
            wait(min(remaining_s, 0.05))
            return
        try:
            fd = self._t.fileno()
        except (AttributeError, OSError, ValueError, io.UnsupportedOperation):
            fd = None
        if fd is not None:
            select.select([fd], [], [], min(remaining_s, 0.05))
        else:
            time.sleep(min(remaining_s, 0.002))

    def _receive(self, deadline: float, *, keep_messages: bool = True) -> P.Reply | P.Message | str | None:
        """The next received item before `deadline`: a Reply, a Message (queued for events() unless
        keep_messages is False), the string "garbage" for a line that is not a valid frame, or None."""
        while True:
            while not self._lines:
                try:
                    n = self._t.in_waiting
                    data = self._t.read(n) if n else b""
                except (OSError, ValueError, TypeError) as e:
                    raise _LinkDown(_prefixed("read failed", e)) from e
                if data:
                    now = self.clock()
                    for line, _overflow in self._splitter.feed(data):
                        self._lines.append((line, now))
                    continue
                remaining = deadline - self.clock()
                if remaining <= 0:
                    return None
                try:
                    self._wait(remaining)
                except (OSError, ValueError) as e:
                    raise _LinkDown(f"wait failed: {e}") from e
            line, t = self._lines.popleft()
            self._rx_time = t
            if self._transcript is not None:
                self._transcript.rx(line + b"\n")
            if not line:
                continue  # an empty line is a resynchronisation, not a frame
            body = P.check_frame(line)
            item = P.parse_incoming(body) if body is not None else None
            if item is None:
                self.stats.garbage += 1
                return "garbage"
            if isinstance(item, P.Message):
                self._on_message(item)
                if keep_messages and item.kind in ("EVT", "DONE"):
                    self._messages.append((item, t))
            return item

    def _on_message(self, msg: P.Message) -> None:
        if msg.kind == "SAFE":
            self._showing = None
        elif msg.kind == "BOOT":
            self._rebooted = True
            self._showing = None
            self._device_us = -1
            self.stats.reboots += 1

    def _drain_messages(self) -> None:
        """Take in whatever already arrived (a SAFE message makes `showing` None) without waiting."""
        if self._closed or not self._lock.acquire(blocking=False):
            return
        try:
            if self._run is None:
                try:
                    while self._receive(self.clock(), keep_messages=False) is not None:
                        pass
                except _LinkDown:
                    pass
        finally:
            self._lock.release()

    def _request(
        self,
        verb: str,
        *args: object,
        extra_s: float = 0.0,
        recover: bool = True,
        lead: bool = False,
        reissued: bool = False,
    ) -> P.Reply:
        """Send one request and return its OK reply, resending the same frame on silence, garbage or BUSY;
        after `retries` resends (or at once when the link is down) reconnect and reconcile, then one more
        round. ERR replies other than BUSY raise ProtocolError (INTERNAL: DeviceError)."""
        self._check_open()
        if recover and self._rebooted and self._info is not None:
            self._restore()  # a BOOT banner arrived between requests: the board forgot its order
        seq = self._next_seq()
        frame = P.encode(P.request_body(seq, verb, *args))
        self.stats.sent += 1
        resends = 0  # in all
        budget = self.retries  # resends left before the next reconnect
        reconnects = 0
        problem = ""
        prefix = b"\n" if lead else b""
        while True:
            try:
                self._write(prefix + frame)
                outcome, reply, problem = self._await(seq, verb, self.clock() + self.timeout_s + extra_s)
            except _LinkDown as e:
                outcome, reply, problem = "down", None, str(e)
            if outcome == "ok":
                assert reply is not None
                if resends:
                    self.stats.recovered += 1
                return reply
            if outcome == "err":
                assert reply is not None
                if reply.code == "STATE" and recover and not reissued and self._n and self._unseen_reboot():
                    # The board forgot its order: it rebooted and its banner was lost. It did not execute
                    # this request (and cached the refusal), so after restoring we ask again, as a new one.
                    return self._request(verb, *args, extra_s=extra_s, recover=recover, reissued=True)
                self.stats.refused += 1
                self.stats.failed += 1
                cls = DeviceError if reply.code == "INTERNAL" else ProtocolError
                raise cls(f"trigger board on {self.port} refused {verb}: ERR {reply.code} {reply.text}".rstrip())
            prefix = b"\n"  # end whatever partial line the board may hold before resending
            if outcome == "reboot" and recover:
                self._restore_quietly(verb, seq)
            elif outcome == "busy":
                time.sleep(min(self.timeout_s / 10, 0.02))
            if outcome != "down" and budget > 0:
                budget -= 1
                resends += 1
                self.stats.retries += 1
                continue
            if not recover or reconnects >= MAX_RECONNECTS:
                if recover:
                    self.stats.failed += 1
                raise DeviceTimeout(
                    f"trigger board on {self.port}: {verb} failed after {resends} resends"
                    f"{f' and {reconnects} reconnects' if reconnects else ''}: {problem}"
                )
            reconnects += 1
            try:
                self._reconnect(problem, pending_seq=seq)
            except DeviceError:
                self.stats.failed += 1
                raise
            budget = self.retries
            resends += 1
            self.stats.retries += 1

    def _unseen_reboot(self) -> bool:
        """After ERR STATE: does STATUS show the board lost the patterns we loaded? Then restore them."""
        status = self._status(recover=False)
        if status.get("n", 0) == self._n:
            return False
        self.stats.reboots += 1
        self._restore()
        return True

    def _restore_quietly(self, verb: str, seq: int) -> None:
        """A boot banner came while a request was pending: restore the board's state before the resend,
        unless STATUS shows the board still holds the reply to this very request (a late banner)."""
        try:
            status = self._status(recover=False)
            if status.get("last") == seq and status.get("n", 0) == self._n:
                self._rebooted = False
                return
            self._restore()
        except DeviceTimeout:
            pass  # the link failed too: the resend finds out and reconnects, which reconciles again

    def _await(self, seq: int, verb: str, deadline: float) -> tuple[str, P.Reply | None, str]:
        """Wait for the reply to `seq`: ("ok"|"err", reply, "") or ("timeout"|"garbled"|"busy"|"reboot", None, why)."""
        while True:
            item = self._receive(deadline)
            if item is None:
                self._splitter.clear()  # a partial line at the deadline is stale
                return "timeout", None, f"no reply to {verb} within {self.timeout_s:g} s"
            if item == "garbage":
                return "garbled", None, f"garbled line while waiting for the reply to {verb}"
            if isinstance(item, P.Message):
                if item.kind == "BOOT":
                    return "reboot", None, f"the board rebooted (reason={item.fields.get('reason', '?')}) during {verb}"
                continue
            assert isinstance(item, P.Reply)
            if item.seq is None:
                if item.ok:
                    self.stats.garbage += 1
                    continue
                return "garbled", None, f"the board received a damaged frame (ERR {item.code}) for {verb}"
            if item.seq != seq:
                self.stats.stale += 1
                continue
            if item.ok:
                return "ok", item, ""
            if item.code == "BUSY":
                return "busy", None, f"the board was busy ({item.text})"
            return "err", item, ""

    def _reconnect(self, problem: str, *, pending_seq: int | None = None) -> None:
        """Reopen (if we can), handshake, read STATUS, reconcile; several attempts within a deadline
        (a second fault may strike the handshake itself). Raises DeviceError naming `problem`."""
        self.stats.reconnects += 1
        deadline = self.clock() + max(3.0, 6 * self.timeout_s)
        last: BaseException | None = None
        while True:
            try:
                if self._reopen is not None:
                    try:
                        self._t.close()
                    except OSError:
                        pass
                    self._t = self._reopen()
                self._flush_input()
                reply = self._request("HELLO", P.PROTOCOL_VERSION, lead=True, recover=False)
                self._take_hello(reply)
                status = self._status(recover=False)
                if pending_seq is not None and status.get("last") == pending_seq and status.get("n", 0) == self._n:
                    # The board holds the reply to the pending request: it has not rebooted since executing
                    # it, and a restore now would overwrite that cached reply (and trigger twice).
                    self._rebooted = False
                elif self._rebooted or status.get("n", 0) != self._n:
                    self._restore()
                return
            except (DeviceTimeout, _LinkDown, OSError) as e:
                last = e
            except DeviceError as e:  # the reopen failed (port not back yet)
                last = e
            if self.clock() >= deadline:
                prefix = f"trigger board on {self.port}: "
                prob, detail = str(problem).removeprefix(prefix), str(last).removeprefix(prefix)
                tail = "" if detail == prob else f": {detail}"
                raise DeviceError(f"{prefix}{prob}; reconnecting failed too{tail}") from last
            time.sleep(0.05)
