"""Tests for ``fastdet.video.ahead``: frames scored at once give a plain loop's results."""

from __future__ import annotations

import dataclasses
import threading

import cv2
import numpy as np
import pytest
from video_stubs import BlockDetector, moving_block

from fastdet.detector.detector import Detector
from fastdet.errors import InputError
from fastdet.video.ahead import can_look_ahead, process_ahead
from fastdet.video.config import TrackConfig
from fastdet.video.pipeline import VideoPipeline


@pytest.fixture(scope="module")
def frames(data_dir):
    capture = cv2.VideoCapture(str(data_dir / "test_video.mp4"))
    frames = []
    while True:
        ok, frame = capture.read()
        if not ok:
            return frames
        frames.append(frame)


def results(pipeline, frames, workers):
    return [(index, boxes.tolist(), ids.tolist())
            for index, _, boxes, ids in pipeline(frames, workers=workers)]


def helpers_alive():
    return [t.name for t in threading.enumerate() if t.name.startswith("fastdet-frame")]


@pytest.mark.parametrize("workers", [2, 3])
@pytest.mark.parametrize("track", [{}, {"every": 3}, {"every": 4, "heat_smoothing": "fir"},
                                   {"every": 2, "tracking": True}],
                         ids=["every frame", "every 3", "every 4 fir", "every 2 tracking"])
def test_same_results_as_one_frame_at_a_time(frames, track, workers):
    expected = results(VideoPipeline(Detector(threads=1), TrackConfig(**track)), frames, 1)
    assert sum(len(boxes) for _, boxes, _ in expected) > 30
    got = results(VideoPipeline(Detector(threads=1), TrackConfig(**track)), frames, workers)
    assert got == expected
    assert helpers_alive() == []


def test_searched_frames_are_scored_ahead_and_the_rest_not_looked_at(frames):
    pipeline = VideoPipeline(Detector(threads=1), TrackConfig(every=3))
    assert pipeline.searches_ahead(7) == [True, False, False, True, False, False, True]
    wanted = []

    def to_frame(index, want):
        wanted.append(want)
        return frames[index] if want else None

    out = [item for item, frame, _ in process_ahead(pipeline, range(12), 2, to_frame)]
    assert out == list(range(12))
    assert wanted == [index % 3 == 0 for index in range(12)]
    assert pipeline.full_searches == 4


def test_a_helper_finds_frames_to_score_while_the_calling_thread_scores_one(frames,
                                                                           monkeypatch):
    # The calling thread queues frames only between those it scores, and runs
    # every frame's temporal steps besides: a helper must find frames to score
    # meanwhile (QUEUED_PER_THREAD), not wait for the queue to be topped up.
    by_helpers = threading.Semaphore(0)
    helper_frames_meanwhile = []
    original = Detector.hits

    def hits(self, frame):
        result = original(self, frame)
        if threading.current_thread().name.startswith("fastdet-frame"):
            by_helpers.release()
        elif not helper_frames_meanwhile:
            # The calling thread's first frame lasts until the helper scored
            # three (or gave up waiting for work).
            count = 0
            while count < 3 and by_helpers.acquire(timeout=10):
                count += 1
            helper_frames_meanwhile.append(count)
        return result

    monkeypatch.setattr(Detector, "hits", hits)
    pipeline = VideoPipeline(Detector(threads=1), TrackConfig())
    out = [item for item, _, _ in process_ahead(pipeline, range(8), 2,
                                                lambda index, wanted: frames[index])]
    assert out == list(range(8))
    assert helper_frames_meanwhile == [3]
    assert helpers_alive() == []


def test_tracking_and_other_detectors_go_one_frame_at_a_time():
    block, _ = moving_block(3)
    assert not can_look_ahead(VideoPipeline(Detector(threads=1), TrackConfig(tracking=True)))
    stub = VideoPipeline(BlockDetector(), TrackConfig())
    assert not can_look_ahead(stub)
    assert len(list(process_ahead(stub, block, 2))) == 3


def test_an_error_scoring_a_frame_ahead_is_raised_in_order(frames):
    pipeline = VideoPipeline(Detector(threads=1), TrackConfig())
    bad = list(frames[:6])
    bad[4] = np.zeros((10, 10, 2), np.uint8)     # two channels: no frame
    done = []
    with pytest.raises(InputError):
        for item, _, _ in process_ahead(pipeline, bad, 2):
            done.append(item is bad[len(done)])
    assert done == [True] * 4                     # every frame before it came out
    assert helpers_alive() == []


def test_closing_early_stops_the_helpers(frames):
    generator = process_ahead(VideoPipeline(Detector(threads=1), TrackConfig()), frames, 3)
    next(generator)
    assert len(helpers_alive()) == 2
    generator.close()
    assert helpers_alive() == []


def test_helper_detectors_are_kept_for_the_next_run_of_the_same_settings(frames, monkeypatch):
    made = []
    original = Detector.__init__

    def counted(self, *args, **kwargs):
        made.append(self)
        original(self, *args, **kwargs)

    pipeline = VideoPipeline(Detector(threads=1))
    monkeypatch.setattr(Detector, "__init__", counted)
    first = results(pipeline, frames[:6], 3)
    assert len(made) == 2                       # the calling thread scores with the pipeline's
    pipeline.reset()
    assert results(pipeline, frames[:6], 3) == first and len(made) == 2   # kept, reused
    # Two runs at once on pipelines of one detector never share a helper.
    other = VideoPipeline(pipeline.detector)
    running = process_ahead(pipeline, frames[:6], 3)
    next(running)
    results(other, frames[:6], 3)
    running.close()
    assert len(made) == 4
    # Another config: new helpers, with it.
    config = pipeline.detector.config
    pipeline.detector.config = dataclasses.replace(
        config, heat=dataclasses.replace(config.heat, threshold=config.heat.threshold + 1))
    pipeline.reset()
    results(pipeline, frames[:6], 3)
    assert len(made) == 6 and all(h.config == pipeline.detector.config for h in made[4:])


def test_the_pipeline_reads_only_the_rows_it_says(frames):
    # fastdet run and batch convert only rows_read of each decoded frame: noise
    # elsewhere must change nothing (the boxes' sides snap to image edges, read
    # inside the search band only).
    pipeline = VideoPipeline(Detector(threads=1), TrackConfig())
    first, stop = pipeline.rows_read((frames[0].shape[1], frames[0].shape[0]))
    assert 0 < first < stop < frames[0].shape[0]
    rng = np.random.default_rng(3)
    noisy = []
    for frame in frames:
        frame = frame.copy()
        frame[:first] = rng.integers(0, 256, frame[:first].shape, dtype=np.uint8)
        frame[stop:] = rng.integers(0, 256, frame[stop:].shape, dtype=np.uint8)
        noisy.append(frame)
    expected = results(pipeline, frames, 1)
    assert sum(len(boxes) for _, boxes, _ in expected) > 30
    pipeline.reset()
    assert results(pipeline, noisy, 1) == expected
