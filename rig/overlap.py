"""Reconstruction beside the capture: one worker thread per stage, fed in scan order.

The scan loop (rig/acquire.py) captures a scan, writes and logs its raw frames, and hands the frames to
`StagePipeline.submit`; it goes on with the next capture at once. Each stage runs on its own thread (for the
grid: extraction; labelling and triangulation; logging the results and writing the products), so consecutive
scans are in different stages at the same time, on both cores, and the loop waits only when the first stage is
busy and `depth` scans are queued before it (decision 0088). The reconstruction kernels release the GIL; the
Python between them does not, which is what keeps the overlap below the number of cores.

Memory stays bounded: at most `depth` scans wait before each stage, plus one in each stage. Results come back
in submission order through `poll` (non-blocking) and `drain` (waits for everything submitted). The first error
raised in a stage is re-raised, as the same exception object, by the next `submit`, `poll` or `drain` on the
calling thread; scans queued behind it are dropped (their raw frames are already on disk). `close` stops the
threads (idempotent); use the pipeline as a context manager.
"""

from __future__ import annotations

import queue
import threading
import time
from typing import Any, Callable

_STOP = object()


class StagePipeline:
    """stages[0](item) on one thread, stages[1] of its result on the next, …; the last stage's results in order.

    depth: how many items may wait before each stage (>= 1). Counters (read on the calling thread):
    `waits` (submits that had to wait for room) and `wait_s` (their total time).
    """

    def __init__(self, *stages: Callable[[Any], Any], depth: int = 2, name: str = "scan"):
        if depth < 1:
            raise ValueError(f"depth must be at least 1, got {depth}")
        if not stages:
            raise ValueError("a pipeline needs at least one stage")
        queues = [queue.Queue(maxsize=depth) for _ in stages]
        self._q1 = queues[0]
        self._queues = queues
        self._done: queue.Queue = queue.Queue()  # finished results, drained by the caller
        self._error: BaseException | None = None
        self._lock = threading.Lock()
        self._submitted = 0
        self._returned = 0
        self._closed = False
        self.waits = 0
        self.wait_s = 0.0
        outs = [*queues[1:], self._done]
        self._threads = [
            threading.Thread(target=self._run, args=(src, work, dst), name=f"{name}-stage{k + 1}", daemon=True)
            for k, (src, work, dst) in enumerate(zip(queues, stages, outs))
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
            if self._error is not None and all(q.empty() for q in self._queues):
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
        """Stop the threads after the items already queued (idempotent)."""
        if self._closed:
            return
        self._closed = True
        self._q1.put(_STOP)  # each stage passes it on to the next once it is through its queue
        for t in self._threads:
            t.join(timeout=timeout_s)

    def __enter__(self) -> "StagePipeline":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
