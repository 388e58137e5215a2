"""A strict scripted transport for byte-for-byte protocol tests (PyMeasure's `expected_protocol` style).

The script is a list of (bytes the host must write, bytes the device answers). It fails (AssertionError)
on any write that differs from the script, on a write while a scripted reply is still unread, on input
discarded unread, and — in `verify()` — on script entries never reached. A reply of b"" is silence: the
host's wait then passes on a fake clock, without sleeping.
"""

from __future__ import annotations

import contextlib
from typing import Iterator, Sequence


class FakeClock:
    """A host clock that only moves when told (or when a strict transport waits)."""

    def __init__(self, start: float = 1000.0):
        self.t = float(start)

    def __call__(self) -> float:
        return self.t

    def advance(self, dt: float) -> None:
        self.t += dt


class StrictTransport:
    """Scripted device: see the module docstring. `writes` lists what the host wrote, in order."""

    def __init__(self, script: Sequence[tuple[bytes, bytes]], *, clock: FakeClock | None = None, port: str = "strict://test"):
        self.script = [(bytes(w), bytes(r)) for w, r in script]
        self.clock = clock or FakeClock()
        self.port = port
        self.writes: list[bytes] = []
        self.is_open = True
        self._i = 0
        self._tx = bytearray()
        self._rx = bytearray()

    def write(self, data: bytes) -> int:
        assert self.is_open, f"write after close: {data!r}"
        assert not self._rx, f"host wrote {data!r} while the reply {bytes(self._rx)!r} was unread"
        self.writes.append(bytes(data))
        self._tx += data
        while self._tx:
            assert self._i < len(self.script), f"unexpected write {bytes(self._tx)!r}: the script has ended"
            expected, reply = self.script[self._i]
            if self._tx.startswith(expected):
                del self._tx[: len(expected)]
                self._i += 1
                self._rx += reply
            elif expected.startswith(self._tx):
                break
            else:
                raise AssertionError(f"unexpected write {bytes(self._tx)!r}; script step {self._i + 1} expects {expected!r}")
        return len(data)

    @property
    def in_waiting(self) -> int:
        return len(self._rx)

    def read(self, size: int = 1) -> bytes:
        out = bytes(self._rx[:size])
        del self._rx[:size]
        return out

    def wait_readable(self, timeout_s: float) -> bool:
        if not self._rx:
            self.clock.advance(timeout_s)
        return bool(self._rx)

    def reset_input_buffer(self) -> None:
        assert not self._rx, f"the host discarded the unread reply {bytes(self._rx)!r}"

    def flush(self) -> None:
        return None

    def close(self) -> None:
        self.is_open = False

    def verify(self) -> None:
        """Every scripted write happened and every reply was read."""
        assert not self._tx, f"partial write {bytes(self._tx)!r} never completed"
        assert self._i == len(self.script), (
            f"script stopped at step {self._i + 1} of {len(self.script)}: the host never wrote {self.script[self._i][0]!r}"
        )
        assert not self._rx, f"reply {bytes(self._rx)!r} was never read"


@contextlib.contextmanager
def expected_protocol(script: Sequence[tuple[bytes, bytes]], **driver_options) -> Iterator:
    """A SerialProjector on a StrictTransport running `script`; verifies the whole script on exit.

    The driver is closed by the test (or not at all) — its STOP, if any, must be in the script."""
    from drivers.serial import SerialProjector

    clock = FakeClock()
    transport = StrictTransport(script, clock=clock)
    driver = SerialProjector(transport, clock=clock, **driver_options)
    yield driver, transport
    transport.verify()
