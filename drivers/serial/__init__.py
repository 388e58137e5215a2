"""The serial pattern trigger: the wire protocol (docs/protocol.md), the host driver, the firmware
emulator and the transports (device path or pyserial URL, recorded transcripts)."""

from drivers.serial.emulator import Emulator, EmulatorFaults
from drivers.serial.projector import LinkStats, SeqDone, SeqEvent, SerialProjector
from drivers.serial.ptylink import serve_on_pty
from drivers.serial.transport import ReplayTransport, TranscriptWriter, connect, open_transport, read_transcript

__all__ = [
    "Emulator",
    "EmulatorFaults",
    "LinkStats",
    "ReplayTransport",
    "SeqDone",
    "SeqEvent",
    "SerialProjector",
    "TranscriptWriter",
    "connect",
    "open_transport",
    "read_transcript",
    "serve_on_pty",
]
