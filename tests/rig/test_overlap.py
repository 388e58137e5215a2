"""rig/overlap.py: the two reconstruction stages on two threads, in order, bounded, errors on the caller's thread."""

from __future__ import annotations

import threading

import pytest

from calibration.errors import ReconstructionError
from rig.overlap import StagePipeline


def test_results_come_back_in_order_and_equal_the_stages_applied_in_turn():
    with StagePipeline(lambda x: x * 3, lambda y: (y, y + 1)) as p:
        got = []
        for k in range(50):
            got += p.submit(k)
        got += p.drain()
    assert got == [(3 * k, 3 * k + 1) for k in range(50)]
    with StagePipeline(lambda x: x * 3, lambda y: y - 1, lambda z: ("scan", z), depth=1) as p:
        got = [r for k in range(30) for r in p.submit(k)] + p.drain()
    assert got == [("scan", 3 * k - 1) for k in range(30)]


def test_the_two_stages_run_at_the_same_time():
    """Stage 2 of item 0 waits for stage 1 of item 1 to start: only possible if they overlap (no timing)."""
    item1_started = threading.Event()
    seen = []

    def first(k):
        if k == 1:
            item1_started.set()
        return k

    def second(k):
        if k == 0:
            seen.append(item1_started.wait(timeout=10))
        return k

    with StagePipeline(first, second) as p:
        out = p.submit(0) + p.submit(1) + p.drain()
    assert out == [0, 1] and seen == [True]


def test_submit_waits_when_both_queues_are_full_and_memory_stays_bounded():
    release = threading.Event()
    entered = threading.Event()
    started = []

    def first(k):
        started.append(k)
        entered.set()
        release.wait(timeout=10)
        return k

    p = StagePipeline(first, lambda k: k, depth=2)
    try:
        p.submit(0)  # stage 1 takes it and blocks
        assert entered.wait(timeout=10)
        p.submit(1)
        p.submit(2)  # the queue before stage 1 is full now (depth 2)
        returned: list = []
        extra = threading.Thread(target=lambda: returned.extend(p.submit(3)))
        extra.start()
        extra.join(timeout=0.3)
        assert extra.is_alive(), "a fourth scan must wait while stage 1 is busy and two scans are queued"
        assert started == [0]
        release.set()
        extra.join(timeout=10)
        assert not extra.is_alive()
        assert returned + p.drain() == [0, 1, 2, 3]
        assert p.waits == 1 and p.wait_s > 0
    finally:
        release.set()
        p.close()


@pytest.mark.parametrize("stage", [1, 2])
def test_an_error_in_a_stage_is_raised_on_the_calling_thread_and_later_items_are_dropped(stage):
    boom = ReconstructionError("the image is 10x10 but the calibration's camera is 20x20")
    calls = []

    def fail_on_2(k):
        if k == 2:
            raise boom
        calls.append(k)
        return k

    first, second = (fail_on_2, lambda k: k) if stage == 1 else (lambda k: k, fail_on_2)
    p = StagePipeline(first, second)
    got = []
    with pytest.raises(ReconstructionError) as err:
        for k in range(100):
            got += p.submit(k)
        got += p.drain()
    assert err.value is boom
    assert got == [0, 1][: len(got)], "results before the failing item keep their order; none after it"
    p.close()
    p.close()  # idempotent
    assert all(c < 2 for c in calls), "nothing after the failing item went through the failing stage"
    with pytest.raises(RuntimeError, match="closed"):
        p.submit(0)


def test_depth_must_be_positive():
    with pytest.raises(ValueError, match="depth"):
        StagePipeline(lambda x: x, lambda x: x, depth=0)


def test_items_in_flight_stay_bounded_over_a_long_run():
    """Memory stays constant over any number of scans: a slow last stage holds the capture back instead of
    letting scans pile up (the payloads alive at any time are counted, not timed)."""
    import time
    import weakref

    alive = 0
    peak = 0
    lock = threading.Lock()

    class Payload:
        def __init__(self):
            nonlocal alive, peak
            with lock:
                alive += 1
                peak = max(peak, alive)
            weakref.finalize(self, _dec)

    def _dec():
        nonlocal alive
        with lock:
            alive -= 1

    def slow(p):
        time.sleep(0.002)
        return 1

    depth, n_stages = 2, 3
    with StagePipeline(lambda p: p, lambda p: p, slow, depth=depth) as pipe:
        done = 0
        for _ in range(400):
            done += len(pipe.submit(Payload()))
        done += len(pipe.drain())
    assert done == 400
    assert peak <= n_stages * (depth + 1) + 1, peak
    assert pipe.waits > 300, "the capture waited for the slow stage rather than queueing without bound"
