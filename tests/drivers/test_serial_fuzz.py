"""Property tests: random bytes and truncated, corrupted or interleaved frames never crash the parser, and
are never taken for a valid reply (hypothesis, derandomized so CI is deterministic)."""

from __future__ import annotations

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drivers.serial import Emulator, SerialProjector
from drivers.serial import protocol as P
from tests.drivers.strict_transport import FakeClock

FAST = settings(max_examples=150, deadline=None, derandomize=True, database=None, suppress_health_check=[HealthCheck.too_slow])

GENUINE = [
    P.encode("5 OK i=2 t_us=18392 n=7"),
    P.encode("! EVT k=0 i=3 t_us=90000"),
    P.encode("4 OK device=rig-trigger-emulator fw=1.0.0 proto=1.0 caps=show"),
    P.encode("- ERR CRC bad frame check"),
    P.encode("6 ERR RANGE pattern 9 outside 0..3"),
]


def parse_stream(data: bytes, *, chunk: int) -> list[str]:
    """Every body the host's parser accepts from `data`, fed in chunks of `chunk` bytes."""
    splitter = P.LineSplitter(max_line=4096)
    bodies = []
    for i in range(0, len(data), chunk):
        for line, _overflow in splitter.feed(data[i : i + chunk]):
            body = P.check_frame(line)
            if body is not None and P.parse_incoming(body) is not None:
                bodies.append(body)
    return bodies


@st.composite
def damaged(draw, frame: bytes) -> bytes:
    """One frame truncated, with a byte changed, inserted or removed (never the identity)."""
    kind = draw(st.sampled_from(["truncate", "corrupt", "insert", "delete"]))
    core = frame[:-1]  # without the newline
    j = draw(st.integers(0, len(core) - 1))
    if kind == "truncate":
        return core[:j]
    if kind == "corrupt":
        delta = draw(st.integers(1, 255))
        return core[:j] + bytes([(core[j] + delta) % 256]) + core[j + 1 :]
    if kind == "insert":
        return core[:j] + bytes([draw(st.integers(0, 255).filter(lambda b: b != 10))]) + core[j:]
    return core[:j] + core[j + 1 :]


@FAST
@given(st.binary(max_size=600), st.integers(1, 64))
def test_random_bytes_never_crash_the_parser_nor_parse_as_frames(data, chunk):
    for body in parse_stream(data, chunk=chunk):
        assert P.encode(body).rstrip(b"\n") in data  # only a genuine, intact frame can come out


@FAST
@given(st.data())
def test_damaged_and_interleaved_frames_are_never_accepted(data):
    frames = data.draw(st.lists(st.sampled_from(GENUINE), min_size=1, max_size=6))
    stream = b""
    intact = []
    for frame in frames:
        action = data.draw(st.sampled_from(["keep", "damage", "garbage-before", "splice"]))
        if action == "keep":
            stream += frame
            intact.append(frame.rstrip(b"\n").decode())
        elif action == "damage":
            stream += data.draw(damaged(frame)) + b"\n"
        elif action == "garbage-before":
            stream += data.draw(st.binary(min_size=1, max_size=20).filter(lambda b: b"\n" not in b)) + frame
            # the garbage joins the frame's line: the line is no longer valid
        else:  # the first part of this frame, then another whole frame on the same line
            other = data.draw(st.sampled_from(GENUINE))
            stream += frame[: data.draw(st.integers(1, len(frame) - 1))] + other
    accepted = parse_stream(stream, chunk=data.draw(st.integers(1, 50)))
    assert accepted == [f.rsplit("*", 1)[0] for f in intact]


class _NoisyBoard:
    """A transport: the first write is answered with `noise`, every later one with the genuine reply."""

    def __init__(self, noise: bytes, genuine: bytes, clock: FakeClock):
        self.noise, self.genuine, self.clock = noise, genuine, clock
        self.writes = 0
        self._rx = bytearray()
        self.port = "noisy://"

    def write(self, data: bytes) -> int:
        self._rx += self.noise if self.writes == 0 else self.genuine
        self.writes += 1
        return len(data)

    @property
    def in_waiting(self) -> int:
        return len(self._rx)

    def read(self, n: int) -> bytes:
        out = bytes(self._rx[:n])
        del self._rx[:n]
        return out

    def wait_readable(self, timeout_s: float) -> bool:
        if not self._rx:
            self.clock.advance(timeout_s)
        return bool(self._rx)

    def reset_input_buffer(self) -> None:
        self._rx.clear()

    def close(self) -> None:
        return None


@FAST
@given(st.data())
def test_the_driver_takes_only_the_genuine_reply(data):
    """Damaged copies of the reply, valid replies to other sequence numbers and random bytes come first;
    the driver must resend until the genuine reply arrives and return exactly its values."""
    genuine = P.encode("1 OK device=real fw=2.0.0 proto=1.0 caps=show")
    pieces = []
    for _ in range(data.draw(st.integers(1, 5))):
        kind = data.draw(st.sampled_from(["damaged", "other-seq", "random"]))
        if kind == "damaged":
            pieces.append(data.draw(damaged(genuine)) + b"\n")
        elif kind == "other-seq":
            seq = data.draw(st.integers(2, 65535))
            pieces.append(P.encode(f"{seq} OK device=fake fw=6.6.6 proto=1.0 caps=show"))
        else:
            pieces.append(data.draw(st.binary(max_size=40)))
    clock = FakeClock()
    board = _NoisyBoard(b"".join(pieces), genuine, clock)
    proj = SerialProjector(board, clock=clock, retries=20)
    info = proj.hello()
    assert (info["device"], info["firmware"]) == ("real", "2.0.0")


@FAST
@given(st.binary(max_size=300), st.integers(1, 40))
def test_the_emulator_survives_random_input_and_answers_only_with_valid_frames(data, chunk):
    clock = FakeClock(0.0)
    em = Emulator(clock=clock)
    em.transmit()
    for i in range(0, len(data), chunk):
        em.receive(data[i : i + chunk])
        clock.advance(0.001)
    em.receive(b"\n" + P.encode("65535 PING"))
    clock.advance(0.01)
    out = em.transmit()
    lines = [ln for ln in out.split(b"\n") if ln]
    assert all(P.check_frame(ln) is not None for ln in lines)
    assert any(ln.startswith(b"65535 OK t_us=") for ln in lines)  # still understands the next request
