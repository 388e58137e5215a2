"""Serve an Emulator on a real pseudo-terminal, so a host talks to it exactly as to a board's /dev/ttyACM0."""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
import select
import threading
import time
import tty
from pathlib import Path
from typing import Iterator

from calibration.errors import DeviceError
from drivers.serial.emulator import Emulator


class _PtyServer:
    """A thread pumping bytes between the pty's master side and the emulator.

    The server keeps its own descriptor on the slave side (in raw mode, never read) so that the terminal
    survives the host closing and reopening it. A disconnect fault closes the whole pty and makes a new one
    after the fault's duration; with `link` set, that symlink is re-pointed at the new device (as udev's
    /dev/serial/by-id links follow a re-plugged board), so a host reopening `link` finds it again.
    """

    def __init__(self, emulator: Emulator, *, link: Path | None, lock: threading.Lock):
        self.emulator = emulator
        self.link = link
        self.lock = lock
        self.stopping = threading.Event()
        self.ready = threading.Event()  # set once what the board sent before any host (its banner) is out
        self.disconnects = 0
        self.error: BaseException | None = None
        self._open()

    def _open(self) -> None:
        self.master, self.keeper = os.openpty()
        tty.setraw(self.keeper)  # no echo, no line discipline: bytes pass untouched
        fl = fcntl.fcntl(self.master, fcntl.F_GETFL)
        fcntl.fcntl(self.master, fcntl.F_SETFL, fl | os.O_NONBLOCK)
        self.slave_path = os.ttyname(self.keeper)
        if self.link is not None:
            tmp = self.link.with_name(self.link.name + ".new")
            with contextlib.suppress(FileNotFoundError):
                tmp.unlink()
            tmp.symlink_to(self.slave_path)
            tmp.replace(self.link)

    def _close(self) -> None:
        for fd in (self.master, self.keeper):
            with contextlib.suppress(OSError):
                os.close(fd)

    @property
    def path(self) -> str:
        return str(self.link) if self.link is not None else self.slave_path

    def run(self) -> None:
        try:
            self._loop()
        except BaseException as e:  # reported by serve_on_pty on exit
            self.error = e
        finally:
            self._close()

    def _loop(self) -> None:
        em = self.emulator
        while not self.stopping.is_set():
            with self.lock:
                due = em.next_due_s()
            wait = 0.05 if due is None else min(max(due - em.clock(), 0.0), 0.05)
            try:
                ready, _, _ = select.select([self.master], [], [], wait)
            except (OSError, ValueError):
                ready = []
            data = b""
            if ready:
                try:
                    data = os.read(self.master, 4096)
                except BlockingIOError:
                    pass
                except OSError as e:
                    if e.errno != errno.EIO:  # EIO: no host has the terminal open
                        raise
                    time.sleep(0.005)
            with self.lock:
                if data:
                    em.receive(data)
                out = em.transmit()
                gone = em.take_disconnect()
            if out:
                try:
                    os.write(self.master, out)
                except (BlockingIOError, OSError):
                    pass  # nobody reading and the buffer is full: a UART would lose these bytes too
            self.ready.set()
            if gone is not None:
                self.disconnects += 1
                self._close()
                if self.link is not None:
                    with contextlib.suppress(FileNotFoundError):
                        self.link.unlink()
                if self.stopping.wait(gone):
                    return
                with self.lock:
                    em.link_reset()
                self._open()


@contextlib.contextmanager
def serve_on_pty(emulator: Emulator, *, link: str | os.PathLike | None = None) -> Iterator[str]:
    """Run `emulator` behind a fresh pseudo-terminal; yields the device path a host opens.

    link: optional symlink path made to point at the terminal (and re-pointed after a disconnect fault,
    whose new terminal has a new /dev/pts number); without it the yielded path is the /dev/pts/N device
    itself. The pumping thread stops and the terminal closes when the context exits; an error inside the
    thread is raised there as DeviceError.
    """
    lock = threading.Lock()
    server = _PtyServer(emulator, link=Path(link) if link is not None else None, lock=lock)
    thread = threading.Thread(target=server.run, name="rig-emulator-pty", daemon=True)
    thread.start()
    # Let the power-up banner reach the terminal's buffer before a host opens it (opening discards it),
    # as a board that booted before the host connected.
    server.ready.wait(timeout=2.0)
    time.sleep(0.01)
    try:
        yield server.path
    finally:
        server.stopping.set()
        thread.join(timeout=5.0)
        if server.link is not None:
            with contextlib.suppress(FileNotFoundError):
                server.link.unlink()
        if server.error is not None:
            raise DeviceError(f"emulator pump thread failed: {server.error!r}") from server.error
