"""A firmware emulator of the trigger board: the state machine of docs/protocol.md, bytes in, bytes out.

It has no I/O of its own: `receive(data)` takes what the host wrote, `transmit()` returns what the device
sends now (by its injectable `clock`), `next_due_s()` says when something will happen next. `serve_on_pty`
(drivers/serial/pty.py) pumps it through a real pseudo-terminal; tests may drive it directly with a fake clock.

Fault knobs (`EmulatorFaults`) act like a noisy cable and a flaky board: per frame and per direction a byte
dropped, corrupted or duplicated, a device frame delayed; per request a stall, a spontaneous reboot or a
disconnect of the link. Faults draw from a seeded RNG, so a run is reproducible for a given seed and timing.
"""

from __future__ import annotations

import random
import time
from dataclasses import dataclass, fields
from typing import Callable

from calibration.errors import ConfigError
from drivers.serial import protocol as P

STATES = ("idle", "showing", "armed", "running")


@dataclass(frozen=True)
class EmulatorFaults:
    """Fault rates in 0…1 and their durations.

    drop / corrupt / duplicate: probability that a frame (each direction) loses one byte / has one byte
    replaced / has one byte sent twice. delay: probability that a device frame is held back `delay_s`.
    stall: probability per request that the device freezes `stall_s` before handling it (input queues).
    reset: probability per request that the device reboots instead of executing it (state lost, BOOT
    banner). disconnect: probability per request that the link drops for `disconnect_s` (the request is
    lost; the device keeps its state, like a native-USB board whose cable was pulled).
    """

    drop: float = 0.0
    corrupt: float = 0.0
    duplicate: float = 0.0
    delay: float = 0.0
    stall: float = 0.0
    reset: float = 0.0
    disconnect: float = 0.0
    delay_s: float = 0.6
    stall_s: float = 1.2
    disconnect_s: float = 0.3

    KINDS = ("drop", "corrupt", "duplicate", "delay", "stall", "reset", "disconnect")

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name in self.KINDS and not 0.0 <= v <= 1.0:
                raise ConfigError(f"fault rate {f.name}={v} is outside 0…1")
            if f.name.endswith("_s") and v < 0:
                raise ConfigError(f"fault duration {f.name}={v} must be ≥ 0 seconds")

    @classmethod
    def parse(cls, spec: str) -> "EmulatorFaults":
        """From ``"drop=0.05,corrupt=0.05,delay_s=0.3"`` (empty string: no faults)."""
        known = {f.name for f in fields(cls)}
        values: dict[str, float] = {}
        for item in filter(None, (s.strip() for s in spec.split(","))):
            key, sep, value = item.partition("=")
            key = key.strip()
            if not sep or key not in known:
                raise ConfigError(
                    f"bad fault {item!r}: expected name=value with name one of {', '.join(sorted(known))}"
                )
            try:
                values[key] = float(value)
            except ValueError as e:
                raise ConfigError(f"bad fault {item!r}: {value!r} is not a number") from e
        return cls(**values)

    @property
    def any(self) -> bool:
        return any(getattr(self, k) > 0 for k in self.KINDS)


class Emulator:
    """The trigger board's firmware as a state machine (docs/protocol.md).

    clock: host seconds (monotonic); the device time t_us counts µs since the last boot. Counters for tests
    and benchmarks: `triggers` (camera pulses fired since boot), `executed` (bodies of requests executed,
    not answered from the cache, refusals included), `fired` ((boot, SEQ) of each SHOW that triggered),
    `cache_hits`, `fault_counts` (faults injected, by kind), `boots`.
    """

    def __init__(
        self,
        *,
        clock: Callable[[], float] = time.monotonic,
        faults: EmulatorFaults = EmulatorFaults(),
        seed: int = 0,
        device: str = "rig-trigger-emulator",
        firmware: str = "1.0.0",
        protocol: str = P.PROTOCOL_VERSION,
        max_order: int = 256,
        max_patterns: int = 1024,
        boot_s: float = 0.02,
    ):
        self.clock = clock
        self.faults = faults
        self.device, self.firmware, self.protocol = device, firmware, protocol
        self.max_order, self.max_patterns, self.boot_s = max_order, max_patterns, boot_s
        self._rng = random.Random(seed)
        self.fault_counts = {k: 0 for k in EmulatorFaults.KINDS}
        self.executed: list[str] = []
        self.executed_boot: list[int] = []  # the boot number (`boots`) each entry of `executed` ran in
        self.fired: list[tuple[int, int]] = []  # (boot number, request SEQ) of every SHOW that fired the trigger
        self.cache_hits = 0
        self.boots = 0
        self._out: list[tuple[float, bytes]] = []  # FIFO of (due host time, bytes)
        self._raw_in = bytearray()  # host bytes before the line faults
        self._inbox = bytearray()  # host bytes after the line faults
        self._stalled_until = 0.0
        self._stall_from = 0.0
        self._deferred: bytes | None = None  # the line a stall interrupted (handled without new faults)
        self._reboot_at: float | None = None
        self._reboot_reason = "reset"
        self._disconnect: float | None = None
        self._boot("power")

    # ---------------------------------------------------------------- state

    def _boot(self, reason: str) -> None:
        self.boots += 1
        self._t0 = self.clock()
        self.state = "idle"
        self.shown = -1
        self.n_patterns = 0
        self.order: list[int] = []
        self.params = {k: d for k, (_, _, d) in P.PARAMS.items()}
        self.triggers = 0
        self.missed = 0
        self._cache: tuple[int, str, bytes] | None = None  # (seq, request body, reply frame)
        self._busy_until = 0.0
        self._fed = self.clock()
        self._seq_k = 0
        self._seq_fired = 0
        self._seq_start = 0.0
        self._splitter = P.LineSplitter()
        self._lines: list[tuple[bytes, bool]] = []
        self._inbox.clear()
        self._deferred = None
        self._reboot_at = None
        self._emit(P.message_body("BOOT", device=self.device, fw=self.firmware, proto=self.protocol, reason=reason))

    def t_us(self, at: float | None = None) -> int:
        """Device time in µs since boot (of host time `at`, default now)."""
        return int(round(((self.clock() if at is None else at) - self._t0) * 1e6))

    # ---------------------------------------------------------------- byte interface

    def receive(self, data: bytes) -> None:
        """Bytes the host wrote (the line faults act on each complete line)."""
        self._raw_in += data
        while (nl := self._raw_in.find(b"\n")) >= 0:
            line = bytes(self._raw_in[: nl + 1])
            del self._raw_in[: nl + 1]
            self._inbox += self._mangle(line)

    def transmit(self) -> bytes:
        """Everything the device sends by now (runs the state machine up to the clock first)."""
        self.poll()
        now = self.clock()
        out = bytearray()
        while self._out and self._out[0][0] <= now:
            out += self._out.pop(0)[1]
        return bytes(out)

    def next_due_s(self) -> float | None:
        """Host time at which the device will next have something to do or send (None: only input)."""
        cands = []
        if self._out:
            cands.append(self._out[0][0])
        if self._stalled_until > self.clock():
            cands.append(self._stalled_until)
        if self._reboot_at is not None:
            cands.append(self._reboot_at)
        if self.state == "running":
            cands.append(self._slot_trigger_s(self._seq_k) + self.params["pulse_us"] * 1e-6)
        wd = self.params["watchdog_us"]
        if wd and self.state in ("showing", "armed"):
            cands.append(self._fed + wd * 1e-6)
        return min(cands) if cands else None

    def take_disconnect(self) -> float | None:
        """If a disconnect fault fired: its duration in seconds (once), else None. For the link owner."""
        d, self._disconnect = self._disconnect, None
        return d

    def link_reset(self) -> None:
        """The link came back: bytes in flight on the old link are gone."""
        self._raw_in.clear()
        self._inbox.clear()
        self._lines.clear()
        self._out.clear()
        self._splitter.clear()

    # ---------------------------------------------------------------- time

    def poll(self) -> None:
        """Run the state machine up to the clock: stalls, reboots, input, the sequence, the watchdog."""
        now = self.clock()
        if now < self._stalled_until or self._disconnect is not None:
            return
        if self._reboot_at is not None:
            if now < self._reboot_at:
                self._inbox.clear()  # a rebooting board hears nothing
                return
            self._boot(self._reboot_reason)
        if self._inbox:
            self._lines += self._splitter.feed(bytes(self._inbox))
            self._inbox.clear()
        if self._deferred is not None:
            line, self._deferred = self._deferred, None
            self._handle(line, faults=False)
        while self._lines and self._free():
            line, overflow = self._lines.pop(0)
            if overflow:
                self._emit(P.err_body(None, "OVERFLOW", f"line longer than {P.MAX_LINE} bytes"))
            else:
                self._handle(line, faults=True)
        if not self._free():
            return
        self._run_sequence(now)
        wd = self.params["watchdog_us"]
        if wd and self.state in ("showing", "armed") and now - self._fed > wd * 1e-6:
            self.state, self.shown = "idle", -1
            self._emit(P.message_body("SAFE", reason="watchdog", t_us=self.t_us()))

    def _free(self) -> bool:
        """Not stalled, rebooting or disconnected."""
        return self.clock() >= self._stalled_until and self._reboot_at is None and self._disconnect is None

    def _slot_trigger_s(self, k: int) -> float:
        return self._seq_start + (k * self.params["period_us"] + self.params["delay_us"]) * 1e-6

    def _run_sequence(self, now: float) -> None:
        pulse_s = self.params["pulse_us"] * 1e-6
        while self.state == "running" and now >= self._slot_trigger_s(self._seq_k) + pulse_s:
            k = self._seq_k
            t_trig = self._slot_trigger_s(k)
            if self._stall_from <= t_trig < self._stalled_until:  # the board was frozen: the slot is lost
                self.missed += 1
            else:
                self.shown = self.order[k]
                self.triggers += 1
                self._seq_fired += 1
                self._emit(P.message_body("EVT", k=k, i=self.order[k], t_us=self.t_us(t_trig)), at=t_trig + pulse_s)
            self._seq_k += 1
            if self._seq_k >= len(self.order):
                self.state = "showing" if self.shown >= 0 else "idle"
                self._fed = now  # the watchdog restarts when the sequence ends
                self._emit(P.message_body("DONE", fired=self._seq_fired, missed=self.missed, t_us=self.t_us()))

    # ---------------------------------------------------------------- faults

    def _roll(self, kind: str) -> bool:
        rate = getattr(self.faults, kind)
        if rate > 0 and self._rng.random() < rate:
            self.fault_counts[kind] += 1
            return True
        return False

    def _mangle(self, frame: bytes) -> bytes:
        """The byte faults on one frame (newline included, so a lost newline merges two lines)."""
        b = bytearray(frame)
        if self._roll("drop"):
            del b[self._rng.randrange(len(b))]
        if b and self._roll("corrupt"):
            j = self._rng.randrange(len(b))
            b[j] = (b[j] + self._rng.randrange(1, 256)) % 256
        if b and self._roll("duplicate"):
            j = self._rng.randrange(len(b))
            b[j:j] = b[j : j + 1]
        return bytes(b)

    def _emit(self, body: str, *, at: float | None = None) -> bytes:
        frame = P.encode(body)
        self._send(frame, at=at)
        return frame

    def _send(self, frame: bytes, *, at: float | None = None) -> None:
        """Queue a frame (FIFO, like a UART): due at `at` (default now), later if delayed by a fault."""
        due = max(self.clock() if at is None else at, self._out[-1][0] if self._out else 0.0)
        if self._roll("delay"):
            due += self.faults.delay_s
        self._out.append((due, self._mangle(frame)))

    # ---------------------------------------------------------------- requests

    def _handle(self, line: bytes, *, faults: bool) -> None:
        if not line:
            return  # empty lines resynchronise; they are not requests
        body = P.check_frame(line)
        if body is None:
            self._emit(P.err_body(None, "CRC", "bad frame check"))
            return
        req = P.parse_request(body)
        if isinstance(req, str):
            head = body.split(" ", 1)[0]
            seq = int(head) if head.isdigit() and len(head) <= 5 and int(head) < P.SEQ_MODULO else None
            self._emit(P.err_body(seq, "SYNTAX", req))
            return
        if faults:
            if self._roll("disconnect"):
                self._disconnect = self.faults.disconnect_s
                return
            if self._roll("reset"):
                self._reboot_at, self._reboot_reason = self.clock() + self.boot_s, "fault"
                return
            if self._roll("stall"):
                self._stall_from = self.clock()
                self._stalled_until = self._stall_from + self.faults.stall_s
                self._deferred = line
                return
        self._fed = self.clock()
        cacheable = req.verb not in P.QUERY_VERBS
        if cacheable and self._cache is not None and self._cache[:2] == (req.seq, req.body):
            self.cache_hits += 1
            self._send(self._cache[2])
            return
        self.executed.append(req.body)
        self.executed_boot.append(self.boots)
        reply, at = self._execute(req)
        frame = self._emit(reply, at=at)
        if cacheable and " ERR BUSY" not in reply:
            self._cache = (req.seq, req.body, frame)

    def _execute(self, req: P.Request) -> tuple[str, float | None]:
        seq, a = req.seq, req.args
        now = self.clock()

        def ok(**kv: object) -> tuple[str, None]:
            return P.ok_body(seq, **kv), None

        def err(code: str, text: str) -> tuple[str, None]:
            return P.err_body(seq, code, text), None

        def nargs(lo: int, hi: int) -> bool:
            return lo <= len(a) <= hi

        def as_int(s: str) -> int | None:
            return int(s) if s.isdigit() and len(s) <= 10 else None

        v = req.verb
        if v in ("SHOW", "SET", "LOAD", "ARM", "START") and now < self._busy_until:
            return err("BUSY", "trigger in progress")
        if v == "HELLO":
            if not nargs(0, 1):
                return err("SYNTAX", "HELLO [major.minor]")
            return ok(
                device=self.device,
                fw=self.firmware,
                proto=self.protocol,
                caps="show,seq,evt,wdt",
                max_order=self.max_order,
                max_line=P.MAX_LINE,
            )
        if v == "PING":
            return ok(t_us=self.t_us()) if nargs(0, 0) else err("SYNTAX", "PING takes no argument")
        if v == "STATUS":
            if not nargs(0, 0):
                return err("SYNTAX", "STATUS takes no argument")
            return ok(
                state=self.state,
                i=self.shown,
                n=self.n_patterns,
                len=len(self.order),
                k=self._seq_k if self.state == "running" else 0,
                triggers=self.triggers,
                missed=self.missed,
                last=self._cache[0] if self._cache else -1,
                t_us=self.t_us(),
            )
        if v == "GET":
            if not nargs(1, 1):
                return err("SYNTAX", "GET name")
            if a[0] not in self.params:
                return err("RANGE", f"no parameter {a[0][:16]}")
            return ok(**{a[0]: self.params[a[0]]})
        if v == "SET":
            if not nargs(2, 2) or as_int(a[1]) is None:
                return err("SYNTAX", "SET name value (value: unsigned integer)")
            name, value = a[0], as_int(a[1])
            if name not in P.PARAMS:
                return err("RANGE", f"no parameter {name[:16]}")
            lo, hi, _ = P.PARAMS[name]
            if not lo <= value <= hi:
                return err("RANGE", f"{name} {value} outside {lo}..{hi}")
            if self.state in ("armed", "running"):
                return err("STATE", f"{self.state}: STOP first")
            step = {"exposure_us": 100, "watchdog_us": 1000}.get(name, 4)  # the board's timer resolution
            applied = 0 if value == 0 else min(max(int(round(value / step)) * step, lo, step if lo == 0 else 1), hi)
            self.params[name] = applied
            return ok(**{name: applied})
        if v == "SHOW":
            if not nargs(1, 1) or as_int(a[0]) is None:
                return err("SYNTAX", "SHOW index")
            i = as_int(a[0])
            if self.state in ("armed", "running"):
                return err("STATE", f"{self.state}: STOP first")
            if self.n_patterns == 0:
                return err("STATE", "no patterns loaded: LOAD first")
            if i >= self.n_patterns:
                return err("RANGE", f"pattern {i} outside 0..{self.n_patterns - 1}")
            t_trig = now + self.params["delay_us"] * 1e-6
            self._busy_until = t_trig + self.params["pulse_us"] * 1e-6
            self.shown, self.state = i, "showing"
            self.triggers += 1
            self.fired.append((self.boots, seq))
            return P.ok_body(seq, i=i, t_us=self.t_us(t_trig), n=self.triggers), self._busy_until
        if v == "LOAD":
            if not nargs(3, 3) or as_int(a[0]) is None or as_int(a[1]) is None:
                return err("SYNTAX", "LOAD n at i,i,...")
            n, at = as_int(a[0]), as_int(a[1])
            entries = [as_int(s) for s in a[2].split(",")]
            if any(e is None for e in entries):
                return err("SYNTAX", "LOAD n at i,i,... (indices: unsigned integers)")
            if self.state in ("armed", "running"):
                return err("STATE", f"{self.state}: STOP first")
            if not 1 <= n <= self.max_patterns:
                return err("RANGE", f"n {n} outside 1..{self.max_patterns}")
            if at > 0 and (n != self.n_patterns or at > len(self.order)):
                return err("RANGE", f"at {at}: continue an order of the same n at most at its length {len(self.order)}")
            if any(e >= n for e in entries):
                return err("RANGE", f"index outside 0..{n - 1}")
            if at + len(entries) > self.max_order:
                return err("OVERFLOW", f"order longer than {self.max_order}")
            if n != self.n_patterns:
                self.shown, self.state = -1, "idle"
            self.n_patterns = n
            self.order = self.order[:at] + entries
            return ok(n=n, len=len(self.order))
        if v == "ARM":
            if not nargs(0, 0):
                return err("SYNTAX", "ARM takes no argument")
            if self.state == "running" or not self.order:
                return err("STATE", "running" if self.order else "no order loaded: LOAD first")
            p = self.params
            if p["period_us"] < p["delay_us"] + p["pulse_us"]:
                return err("RANGE", "period_us shorter than delay_us + pulse_us")
            self.state = "armed"
            return ok(len=len(self.order), period_us=p["period_us"])
        if v == "START":
            if not nargs(0, 0):
                return err("SYNTAX", "START takes no argument")
            if self.state != "armed":
                return err("STATE", f"{self.state}: ARM first")
            self.state = "running"
            self._seq_start = now
            self._seq_k = self._seq_fired = 0
            self.missed = 0
            return ok(t_us=self.t_us(now), len=len(self.order))
        if v == "STOP":
            if not nargs(0, 0):
                return err("SYNTAX", "STOP takes no argument")
            self.state, self.shown = "idle", -1
            return ok(state="idle")
        if v == "RESET":
            if not nargs(0, 0):
                return err("SYNTAX", "RESET takes no argument")
            self._reboot_at, self._reboot_reason = now + self.boot_s, "reset"
            return ok()
        return err("INTERNAL", f"verb {v} not implemented")
