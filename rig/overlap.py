"""Reconstruction beside the capture: two worker threads, one per reconstruction stage, fed in scan order.

The scan loop (rig/acquire.py) captures a scan, writes and logs its raw frames, and hands the frames to
`StagePipeline.submit`; it goes on with the next capture at once. Thread 1 runs the first stage (`prepare`: for
the grid, extraction), thread 2 the second (`finish`: labelling, triangulation, logging, products), so on two
cores both stages of consecutive scans run at the same time and the loop waits only when both threads are
busy and `depth` scans are queued (decision 0088). The reconstruction kernels release the GIL; the Python
between them does not, which is what keeps the overlap below two.

Memory stays bounded: at most `depth` scans wait before each stage, plus one in each stage. Results come back
in submission order through `poll` (non-blocking) and `drain` (waits for everything submitted). The first error
raised in a stage is re-raised, as the same exception object, by the next `submit`, `poll` or `drain` on the
calling thread; scans queued behind it are dropped (their raw frames are already on disk). `close` stops both
threads (idempotent); use the pipeline as a context manager.
"""

from __future__ import annotations

import queue
import threading
import time
from typing import Any, Callable

_STOP = object()


class StagePipeline:
    """prepare(item) -> state on one thread, finish(state) -> result on another, results in order.

    depth: how many items may wait before each stage (>= 1). Counters (read on the calling thread):
    `waits` (submits that had to wait for room) and `wait_s` (their total time).
    """

    def __init__(self, prepare: Callable[[Any], Any], finish: Callable[[Any], Any], *, depth: int = 2, name: str = "scan"):
        if depth < 1:
            raise ValueError(f"depth must be at least 1, got {depth}")
        self._prepare, self._finish = prepare, finish
        self._q1: queue.Queue = queue.Queue(maxsize=depth)
        self._q2: queue.Queue = queue.Queue(maxsize=depth)
        self._done: queue.Queue = queue.Queue()  # finished results: at most 2·depth + 2 outstanding
        self._error: BaseException | None = None
        self._lock = threading.Lock()
        self._submitted = 0
        self._returned = 0
        self._closed = False
        self.waits = 0
        self.wait_s = 0.0
        self._threads = [
            threading.Thread(target=self._run, args=(self._q1, self._prepare, self._q2), name=f"{name}-stage1", daemon=True),
            threading.Thread(target=self._run, args=(self._q2, self._finish, self._done), name=f"{name}-stage2", daemon=True),
        ]
        for t in self._threads:
            t.start()

    # --- worker side -------------------------------------------------------------------------------------------
    def _run(self, src: queue.Queue, work: Callable, dst: queue.Queue) -> None:
        while True:
            item = src.get()
            if item is _STOP:
                dst.put(_STOP)
                return
            if self._error is not None:
                continue  # after a failure: drop what is queued (its raw frames are on disk), keep draining
            try:
                out = work(item)
            except BaseException as e:  # noqa: BLE001 - handed to the calling thread, re-raised there
                with self._lock:
                    if self._error is None:
                        self._error = e
                continue
            dst.put(out)

    # --- calling side ------------------------------------------------------------------------------------------
    def _raise_if_failed(self) -> None:
        if self._error is not None:
            raise self._error

    def submit(self, item: Any) -> list:
        """Queue `item` for stage 1; waits while the queue is full. Returns the results finished so far
        (as `poll`)."""
        if self._closed:
            raise RuntimeError("the pipeline is closed")
        self._raise_if_failed()
        try:
            self._q1.put_nowait(item)
        except queue.Full:
            t0 = time.perf_counter()
            while True:
                self._raise_if_failed()
                try:
                    self._q1.put(item, timeout=0.05)
                    break
                except queue.Full:
                    continue
            self.waits += 1
            self.wait_s += time.perf_counter() - t0
        self._submitted += 1
        return self.poll()

    def poll(self) -> list:
        """The results finished since the last call, in submission order (non-blocking)."""
        out = []
        while True:
            try:
                r = self._done.get_nowait()
            except queue.Empty:
                break
            if r is _STOP:
                self._done.put(_STOP)  # keep the marker for drain
                break
            out.append(r)
        self._returned += len(out)
        self._raise_if_failed()
        return out

    def drain(self) -> list:
        """Wait until every submitted item has gone through both stages; their results, in order."""
        out = []
        while self._returned + len(out) < self._submitted:
            if self._error is not None and self._q1.empty() and self._q2.empty():
                break
            try:
                r = self._done.get(timeout=0.05)
            except queue.Empty:
                continue
            if r is _STOP:
                self._done.put(_STOP)
                break
            out.append(r)
        self._returned += len(out)
        self._raise_if_failed()
        return out

    def close(self, *, timeout_s: float = 30.0) -> None:
        """Stop both threads after the items already queued (idempotent)."""
        if self._closed:
            return
        self._closed = True
        self._q1.put(_STOP)  # stage 1 passes it on to stage 2 once it is through its queue
        for t in self._threads:
            t.join(timeout=timeout_s)

    def __enter__(self) -> "StagePipeline":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
