"""Tests for ``fastdet.video.stages``: the thread plan and the conveyor of stage threads."""

from __future__ import annotations

import itertools
import queue
import time

import pytest

from fastdet.video.stages import _put_newest
from fastdet.video.stages import (END, QUEUE_FRAMES, WARM_UP_FRAMES, Conveyor, FrameQueue,
                                  plan_threads, warm_up_queue_frames)


# -- the thread plan -------------------------------------------------------------------
@pytest.mark.parametrize("cores, video, fraction, expected", [
    (2, True, 1.0, (1, 1, 1)),       # three parts, two cores: one each (the minimum)
    (2, False, 1.0, (1, 1, 0)),      # each a core: no spare core for the heavier detector
    (2, False, 0.2, (2, 1, 0)),      # --every 5: decoding is most of the work
    (1, True, 1.0, (1, 1, 1)),
    (4, False, 1.0, (2, 2, 0)),
    (4, True, 1.0, (1, 2, 1)),       # the heaviest takes the one spare core
    (8, True, 1.0, (2, 3, 3)),
])
def test_plan_shares_the_cores_by_load(cores, video, fraction, expected):
    plan = plan_threads(cores, video, fraction)
    assert (plan.decoder, plan.detector, plan.encoder) == expected
    # The heaviest part may get a thread more than its share, never more.
    assert plan.decoder + plan.detector + plan.encoder <= max(cores + 1, 2 + video)
    assert f"{cores} cores" in plan.describe()


# -- the conveyor ------------------------------------------------------------------------
def chain(conveyor, items, work=None):
    """source -> middle (applies ``work``) -> sink; returns the list the sink fills."""
    first, second, received = conveyor.queue(2), conveyor.queue(2), []

    def source(clock):
        for item in items:
            if conveyor.stopping.is_set():
                break
            conveyor.put(first, item, clock)
        conveyor.put(first, END, clock)

    def middle(clock):
        while (item := conveyor.get(first, clock)) is not END:
            conveyor.put(second, work(item) if work else item, clock)
        conveyor.put(second, END, clock)

    def sink(clock):
        while (item := conveyor.get(second, clock)) is not END:
            received.append(item)

    conveyor.add("sink", sink, inbox=second)
    conveyor.add("source", source)
    conveyor.add("middle", middle, inbox=first)
    return received


def test_items_arrive_in_order_through_bounded_queues():
    conveyor = Conveyor()
    received = chain(conveyor, range(500))
    conveyor.run()
    assert received == list(range(500))
    assert set(conveyor.times.stages) == {"source", "middle", "sink"}
    assert conveyor.times.bound() in conveyor.times.stages


def test_an_error_in_any_stage_stops_every_stage():
    def work(item):
        if item == 50:
            raise ValueError("stage broke")
        return item

    conveyor = Conveyor()
    received = chain(conveyor, itertools.count(), work)   # an endless source
    started = time.monotonic()
    with pytest.raises(ValueError, match="stage broke"):
        conveyor.run()
    assert time.monotonic() - started < 10
    assert received == list(range(len(received))) and len(received) <= 50


def test_stop_lets_what_was_read_reach_the_end():
    conveyor = Conveyor()
    produced = []

    def counted():
        for item in itertools.count():
            produced.append(item)
            yield item

    received = chain(conveyor, counted())
    conveyor.run(on_tick=lambda: len(received) > 20 and conveyor.stop())
    assert len(received) > 20
    assert received == produced[:len(received)]
    assert len(produced) - len(received) <= 1   # at most the item in the source's hands


def test_abort_stops_at_once():
    conveyor = Conveyor()
    received = chain(conveyor, itertools.count(), work=lambda item: time.sleep(0.001) or item)
    started = time.monotonic()
    conveyor.run(on_tick=lambda: len(received) > 5 and conveyor.abort())
    assert conveyor.aborted and time.monotonic() - started < 10


def test_a_stage_that_stops_reading_does_not_block_the_one_before():
    conveyor = Conveyor()
    inbox = conveyor.queue(1)

    def source(clock):
        for item in range(100):
            conveyor.put(inbox, item, clock)

    def quitter(clock):
        conveyor.get(inbox, clock)

    conveyor.add("quitter", quitter, inbox=inbox)
    conveyor.add("source", source)
    started = time.monotonic()
    conveyor.run()
    assert time.monotonic() - started < 10


def test_realtime_keeps_the_newest_frames():
    box = queue.Queue(maxsize=2)
    dropped = sum(_put_newest(box, item) for item in range(5))
    assert dropped == 3
    assert [box.get_nowait(), box.get_nowait()] == [3, 4]


# -- the queue of decoded frames ----------------------------------------------------------
def test_a_frame_queue_counts_only_the_frames_with_pixels():
    box = FrameQueue(frames=2, placeholders=3)
    box.put((0, "pixels", None))
    box.put((1, None, None))
    box.put((2, "pixels", None))
    with pytest.raises(queue.Full):
        box.put_nowait((3, "pixels", None))        # two frames with pixels wait already
    for index in (3, 4):
        box.put_nowait((index, None, None))         # placeholders still fit, up to three
    with pytest.raises(queue.Full):
        box.put_nowait((5, None, None))
    with pytest.raises(queue.Full):
        box.put((5, None, None), timeout=0.05)
    assert box.get_nowait() == (0, "pixels", None)
    box.put_nowait((5, "pixels", None))            # room for one more frame
    assert [box.get_nowait()[0] for _ in range(5)] == [1, 2, 3, 4, 5]
    with pytest.raises(queue.Empty):
        box.get_nowait()


def test_a_frame_queue_bound_can_shrink_while_in_use():
    box = FrameQueue(frames=3)
    for index in range(3):
        box.put_nowait((index, "pixels", None))
    box.frames = 1
    box.get_nowait()
    with pytest.raises(queue.Full):                 # two still wait: over the new bound
        box.put_nowait((3, "pixels", None))
    box.get_nowait()
    box.get_nowait()
    box.put_nowait((3, "pixels", None))
    box.put_nowait(END)                             # the end marker carries no pixels


def test_a_waiting_put_goes_through_once_a_frame_is_taken():
    conveyor = Conveyor()
    box = conveyor.frame_queue(frames=1)
    box.put((0, "pixels", None))
    got = []

    def consumer(clock):
        time.sleep(0.2)
        got.append(conveyor.get(box, clock))
        got.append(conveyor.get(box, clock))

    def producer(clock):
        conveyor.put(box, (1, "pixels", None), clock)

    conveyor.add("consumer", consumer, inbox=box)
    conveyor.add("producer", producer)
    conveyor.run()
    assert [item[0] for item in got] == [0, 1]
    assert conveyor.times.stages["producer"].blocked > 0.1


def test_the_warm_up_queue_holds_the_same_memory_at_every_size():
    assert warm_up_queue_frames((1280, 720)) == WARM_UP_FRAMES
    assert warm_up_queue_frames((640, 360)) == WARM_UP_FRAMES
    assert warm_up_queue_frames((1920, 1080)) == WARM_UP_FRAMES * 1280 * 720 // (1920 * 1080)
    assert warm_up_queue_frames((7680, 4320)) == QUEUE_FRAMES


# -- a stage started before the run -------------------------------------------------------
def test_a_stage_started_early_runs_before_the_others_and_once():
    conveyor = Conveyor()
    received = chain(conveyor, range(100))
    conveyor.start("source")
    time.sleep(0.2)
    assert not received                              # the others wait for run()
    conveyor.run()
    assert received == list(range(100))


def test_cancel_stops_a_stage_started_early():
    conveyor = Conveyor()
    inbox = conveyor.queue(2)

    def endless(clock):
        for item in itertools.count():
            conveyor.put(inbox, item, clock)

    conveyor.add("source", endless)
    conveyor.start("source")
    time.sleep(0.1)
    started = time.monotonic()
    conveyor.cancel()
    assert conveyor.aborted and time.monotonic() - started < 5
    assert inbox.qsize() == 2


# -- pacing a file read as if live ---------------------------------------------------------
class _PacedSource:
    """A stand-in file source: frames 40 ms apart, read "live" (``realtime``)."""

    live = False
    start = 0
    time_base = 1 / 1000
    ended = None
    frames_left_undecoded = 0
    frames_read = 3

    class damage:  # noqa: N801 - the attribute a real source carries
        @staticmethod
        def describe(frames_read):
            return None

    def decoded_frames(self, needed):
        return _Frames(type("Frame", (), {"pts": pts})() for pts in (0, 40, 80))


class _Frames(list):
    """Decoded frames as ``decode`` reads them: iterable and closable."""

    def close(self):
        pass


class _SteppingClock:
    """``perf_counter`` that moves 15 ms on every read, against frames 40 ms apart.

    The second frame's deadline falls between the third and the fourth read: a
    wait that reads the clock twice (the test, then the sleep) gets a negative sleep.
    """

    def __init__(self):
        self.now = 1000.0

    def __call__(self):
        self.now += 0.015
        return self.now


def test_pacing_survives_the_clock_passing_the_deadline_between_reads(monkeypatch):
    from fastdet.video import stages

    monkeypatch.setattr(stages.time, "perf_counter", _SteppingClock())
    conveyor = Conveyor()
    outbox = conveyor.queue(8)
    stats = type("Stats", (), {"dropped": 0})()
    stages.decode(stages.StageClock(), conveyor, _PacedSource(), outbox, True, stats)
    items = [outbox.get_nowait() for _ in range(4)]
    assert [item[0] for item in items[:3]] == [0, 1, 2] and items[3] is END
