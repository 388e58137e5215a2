"""The trigger board's wire protocol (docs/protocol.md): framing, CRC, parsing. Pure functions, no I/O.

A frame is one line of printable ASCII: ``BODY*CCCC\\n`` where CCCC is CRC-16/CCITT-FALSE (poly 0x1021,
init 0xFFFF, no reflection, no final xor; ``binascii.crc_hqx(body, 0xFFFF)``) of BODY in four upper-case hex
digits. BODY is ``SEQ VERB args…`` (requests), ``SEQ OK key=value…`` / ``SEQ ERR CODE text`` (replies, SEQ
echoed; ``-`` when the request's sequence number could not be trusted) or ``! KIND key=value…`` (messages the
device sends on its own: EVT, DONE, SAFE, BOOT). Both ends resynchronise at the next newline after garbage.
"""

from __future__ import annotations

import binascii
import re
from dataclasses import dataclass, field

PROTOCOL_VERSION = "1.0"
MAX_LINE = 128  # bytes of BODY*CCCC, without the newline; longer lines are an OVERFLOW
SEQ_MODULO = 65536
CRC_INIT = 0xFFFF

#: every error code a device may send (docs/protocol.md § Errors); RETRYABLE ones make the host resend.
ERROR_CODES = ("CRC", "SYNTAX", "RANGE", "STATE", "BUSY", "OVERFLOW", "INTERNAL")
RETRYABLE = frozenset({"CRC", "BUSY", "OVERFLOW"})

REQUEST_VERBS = ("HELLO", "PING", "GET", "SET", "SHOW", "LOAD", "ARM", "START", "STOP", "STATUS", "RESET")
#: read-only requests: always executed, never answered from (nor stored in) the reply cache
QUERY_VERBS = frozenset({"HELLO", "PING", "GET", "STATUS"})
MESSAGE_KINDS = ("EVT", "DONE", "SAFE", "BOOT")

#: settable timing parameters, their limits (inclusive) and the emulator's defaults, all in µs
PARAMS: dict[str, tuple[int, int, int]] = {
    "pulse_us": (1, 1_000_000, 100),
    "delay_us": (0, 1_000_000, 0),
    "period_us": (1_000, 10_000_000, 33_333),
    "exposure_us": (10, 10_000_000, 16_667),
    "watchdog_us": (0, 60_000_000, 5_000_000),
}

_BODY_CHARS = re.compile(rb"[\x20-\x29\x2b-\x7e]+")  # printable ASCII except '*'
_TOKEN = re.compile(r"[!-~]+")  # one printable, non-space token
_KEY = re.compile(r"[a-z][a-z0-9_]*")
_SEQ = re.compile(r"0|[1-9][0-9]{0,4}")


def crc16(body: bytes) -> int:
    """CRC-16/CCITT-FALSE of `body` (check value: crc16(b"123456789") == 0x29B1)."""
    return binascii.crc_hqx(body, CRC_INIT)


def encode(body: str) -> bytes:
    """One frame, newline included: ``BODY*CCCC\\n``. Raises ValueError on a body the grammar forbids."""
    raw = body.encode("ascii")
    if not _BODY_CHARS.fullmatch(raw) or "  " in body or body != body.strip():
        raise ValueError(f"not a valid frame body: {body!r}")
    frame = raw + b"*%04X" % crc16(raw)
    if len(frame) > MAX_LINE:
        raise ValueError(f"frame of {len(frame)} bytes exceeds the {MAX_LINE}-byte line limit: {body[:40]!r}…")
    return frame + b"\n"


def check_frame(line: bytes) -> str | None:
    """The BODY of one received line (newline and an optional CR already stripped) if its CRC is right,
    else None. Never raises."""
    if len(line) < 6 or len(line) > MAX_LINE or line[-5:-4] != b"*":
        return None
    body, crc_hex = line[:-5], line[-4:]
    if not _BODY_CHARS.fullmatch(body):
        return None
    if not re.fullmatch(rb"[0-9A-F]{4}", crc_hex):
        return None
    if int(crc_hex, 16) != crc16(body):
        return None
    return body.decode("ascii")


def parse_pairs(tokens: list[str]) -> dict[str, str] | None:
    """``key=value`` tokens as a dict; None if any token is malformed or a key repeats."""
    out: dict[str, str] = {}
    for tok in tokens:
        key, sep, value = tok.partition("=")
        if not sep or not _KEY.fullmatch(key) or not value or key in out:
            return None
        out[key] = value
    return out


@dataclass(frozen=True)
class Request:
    """A parsed request: `seq` 0…65535, `verb` one of REQUEST_VERBS, positional `args`."""

    seq: int
    verb: str
    args: tuple[str, ...]
    body: str


@dataclass(frozen=True)
class Reply:
    """A parsed reply. `seq` None for ``-`` (the device could not read the request's number).
    ok: True for OK (values in `fields`), False for ERR (`code`, `text`)."""

    seq: int | None
    ok: bool
    fields: dict[str, str] = field(default_factory=dict)
    code: str = ""
    text: str = ""
    body: str = ""


@dataclass(frozen=True)
class Message:
    """An unsolicited device message (``! KIND key=value…``): EVT, DONE, SAFE or BOOT."""

    kind: str
    fields: dict[str, str]
    body: str = ""


def parse_request(body: str) -> Request | str:
    """A request from a CRC-checked body, or the text of a SYNTAX error explaining what is wrong."""
    tokens = body.split(" ")
    if len(tokens) < 2 or any(not t for t in tokens):
        return "expected 'SEQ VERB [args]'"
    if not _SEQ.fullmatch(tokens[0]) or int(tokens[0]) >= SEQ_MODULO:
        return f"bad sequence number {tokens[0][:8]!r}"
    if tokens[1] not in REQUEST_VERBS:
        return f"unknown verb {tokens[1][:12]!r}"
    if not all(_TOKEN.fullmatch(t) for t in tokens[2:]):
        return "bad argument"
    return Request(seq=int(tokens[0]), verb=tokens[1], args=tuple(tokens[2:]), body=body)


def parse_incoming(body: str) -> Reply | Message | None:
    """A reply or a message from a CRC-checked body (what the host receives); None if the body does not
    follow the grammar (the host treats it as garbage). Never raises."""
    tokens = body.split(" ")
    if len(tokens) < 2 or any(not t for t in tokens):
        return None
    head, kind = tokens[0], tokens[1]
    if head == "!":
        if kind not in MESSAGE_KINDS:
            return None
        fields = parse_pairs(tokens[2:])
        return None if fields is None else Message(kind=kind, fields=fields, body=body)
    if head == "-":
        seq = None
    elif _SEQ.fullmatch(head) and int(head) < SEQ_MODULO:
        seq = int(head)
    else:
        return None
    if kind == "OK":
        fields = parse_pairs(tokens[2:])
        return None if fields is None else Reply(seq=seq, ok=True, fields=fields, body=body)
    if kind == "ERR":
        if len(tokens) < 3 or tokens[2] not in ERROR_CODES:
            return None
        return Reply(seq=seq, ok=False, code=tokens[2], text=" ".join(tokens[3:]), body=body)
    return None


def request_body(seq: int, verb: str, *args: object) -> str:
    """``SEQ VERB args…`` for a request."""
    return " ".join([str(seq), verb, *(str(a) for a in args)])


def ok_body(seq: int | None, **fields: object) -> str:
    return " ".join(["-" if seq is None else str(seq), "OK", *(f"{k}={v}" for k, v in fields.items())])


def err_body(seq: int | None, code: str, text: str) -> str:
    assert code in ERROR_CODES, code
    clean = "".join(c if 0x20 <= ord(c) < 0x7F and c != "*" else "?" for c in text)
    clean = " ".join(clean.split())[:80]
    return " ".join(["-" if seq is None else str(seq), "ERR", code, *([clean] if clean else [])])


def message_body(kind: str, **fields: object) -> str:
    assert kind in MESSAGE_KINDS, kind
    return " ".join(["!", kind, *(f"{k}={v}" for k, v in fields.items())])


class LineSplitter:
    """Cuts a byte stream into lines at b"\\n" (dropping one trailing b"\\r").

    Lines longer than `max_line` are reported once as `overflow` and their remainder discarded up to the
    next newline (resynchronisation). `feed(data)` returns the complete lines, each as (bytes, overflowed).
    """

    def __init__(self, *, max_line: int = MAX_LINE):
        self.max_line = max_line
        self._buf = bytearray()
        self._skipping = False

    def feed(self, data: bytes) -> list[tuple[bytes, bool]]:
        out: list[tuple[bytes, bool]] = []
        start = 0
        while True:
            nl = data.find(b"\n", start)
            piece = data[start:] if nl < 0 else data[start:nl]
            if not self._skipping:
                self._buf += piece
                if len(self._buf) > self.max_line + 1:  # +1: a trailing CR is not counted
                    self._buf.clear()
                    self._skipping = True
            if nl < 0:
                return out
            line = bytes(self._buf)
            if line.endswith(b"\r"):
                line = line[:-1]
            if self._skipping or len(line) > self.max_line:
                out.append((b"", True))
            else:
                out.append((line, False))
            self._buf.clear()
            self._skipping = False
            start = nl + 1

    @property
    def pending(self) -> int:
        """Bytes of an incomplete line held."""
        return len(self._buf)

    def clear(self) -> None:
        self._buf.clear()
        self._skipping = False
