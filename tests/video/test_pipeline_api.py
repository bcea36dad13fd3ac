"""VideoPipeline's Python API refuses misuse in one line, at the call, never deep inside."""

from __future__ import annotations

import copy
import pickle
import threading

import numpy as np
import pytest
from video_stubs import BlockDetector, moving_block

from fastdet.detector.scoring import Hits
from fastdet.errors import ConfigError, InputError
from fastdet.video.config import TrackConfig
from fastdet.video.pipeline import VideoPipeline


def never_read():
    raise AssertionError("a frame was read")
    yield  # pragma: no cover


@pytest.mark.parametrize("keyword, value, fragment", [
    ("first_index", 2.5, "first_index must be a whole number, got 2.5"),
    ("first_index", "3", "first_index must be a whole number"),
    ("first_index", True, "first_index must be a whole number"),
    ("workers", 2.5, "workers must be a whole number, got 2.5"),
    ("workers", "2", "workers must be a whole number"),
    ("workers", 0, "workers must be 1-256, got 0"),
    ("workers", -1, "workers must be 1-256, got -1"),
    ("workers", 10**6, "workers must be 1-256, got 1000000"),
])
def test_first_index_and_workers_are_checked_at_the_call(keyword, value, fragment):
    # 2.5 gave indices 2.5, 3.5, ...; workers=10**6 built a detector and a
    # thread per worker; 0 and -1 passed as 1.
    pipeline = VideoPipeline(BlockDetector())
    with pytest.raises(InputError, match=fragment):
        pipeline(never_read(), **{keyword: value})


def test_indices_are_python_ints_counted_from_any_whole_first_index():
    frames, _ = moving_block(3)
    pipeline = VideoPipeline(BlockDetector())
    indices = [index for index, *_ in pipeline(frames, first_index=np.int64(-2))]
    assert indices == [-2, -1, 0] and all(type(index) is int for index in indices)


@pytest.mark.parametrize("shape", [(120, 200, 3), (120, 200), (120, 200, 1), (120, 200, 4)])
def test_one_frame_given_as_the_frames_is_a_type_error(shape):
    # Iterated, its rows were taken for grey frames of 200 x 3 pixels.
    with pytest.raises(TypeError, match=r"got one frame of shape .*give \[frame\]"):
        VideoPipeline(BlockDetector())(np.zeros(shape, np.uint8))


def test_a_stack_of_frames_is_frames():
    frames, _ = moving_block(4)
    listed = [(b.tolist(), t.tolist()) for _, _, b, t in VideoPipeline(BlockDetector())(frames)]
    stacked = VideoPipeline(BlockDetector())(np.stack(frames))
    assert [(b.tolist(), t.tolist()) for _, _, b, t in stacked] == listed


class OnlyHits:
    def hits(self, frame):
        return BlockDetector().hits(frame)


@pytest.mark.parametrize("detector, fragment", [
    (object(), "object lacks hits, heat_region, boxes_from_heat"),
    (None, "NoneType lacks hits"),
    (OnlyHits(), "OnlyHits lacks heat_region, boxes_from_heat"),
    (BlockDetector, "must be an instance, got the class BlockDetector"),
])
def test_a_detector_without_the_methods_is_a_type_error(detector, fragment):
    with pytest.raises(TypeError, match=fragment):
        VideoPipeline(detector)


@pytest.mark.parametrize("config", [{"every": 2}, {}, "track.toml"])
def test_config_must_be_a_track_config(config):
    # {"every": 2} failed at the first frame; {} silently became the defaults.
    with pytest.raises(TypeError, match="config must be a TrackConfig"):
        VideoPipeline(BlockDetector(), config)


class EmptyAware(BlockDetector):
    """The stub, giving no hits for a frame without pixels (as the Detector does)."""

    def hits(self, frame):
        if frame.size == 0:
            return Hits(np.zeros((0, 4), np.int32), np.zeros(0, np.float32),
                        np.zeros(0, np.int64), 100)
        return super().hits(frame)


@pytest.mark.parametrize("tracking", [False, True])
def test_a_frame_without_pixels_has_no_boxes_with_a_detector_without_config(tracking):
    # The search radius was scaled by size / size: ZeroDivisionError.
    frames, _ = moving_block(3)
    pipeline = VideoPipeline(EmptyAware(), TrackConfig(tracking=tracking))
    out = [(b.tolist(), t.tolist()) for _, _, b, t in
           pipeline([np.zeros((0, 0, 3), np.uint8)] + frames)]
    assert out[0] == ([], []) and out[1][0] and out[3][1] == out[1][1]


class Blocking(BlockDetector):
    def __init__(self):
        super().__init__()
        self.inside, self.release = threading.Event(), threading.Event()

    def hits(self, frame):
        self.inside.set()
        self.release.wait(10)
        return super().hits(frame)


def test_process_from_a_second_thread_at_once_raises_and_leaves_the_state():
    frames, _ = moving_block(2)
    detector = Blocking()
    pipeline = VideoPipeline(detector)
    first = threading.Thread(target=pipeline.process, args=(frames[0],))
    first.start()
    try:
        assert detector.inside.wait(10)
        with pytest.raises(RuntimeError, match="from two threads at once"):
            pipeline.process(frames[1])
    finally:
        detector.release.set()
        first.join()
    assert pipeline.frames == 1
    assert pipeline.process(frames[1]).track_id.tolist() == [1]   # usable again after


def test_a_pipeline_still_pickles_and_copies_mid_stream():
    frames, _ = moving_block(3)
    pipeline = VideoPipeline(BlockDetector(), TrackConfig(tracking=True))
    pipeline.process(frames[0])
    for other in (pickle.loads(pickle.dumps(pipeline)), copy.deepcopy(pipeline)):
        assert (other.process(frames[1]).xyxy.tolist()
                == copy.deepcopy(pipeline).process(frames[1]).xyxy.tolist())


def test_from_dict_names_a_key_that_is_not_a_string():
    with pytest.raises(ConfigError, match=r"unknown key\(s\) in \[track\]: 1, every2"):
        TrackConfig.from_dict({1: 2, "every2": 3})
