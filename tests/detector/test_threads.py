"""One Detector called from several threads at once gives the detections serial calls give."""

from __future__ import annotations

import threading

import cv2
import numpy as np
import pytest

from fastdet.detector import scoring
from fastdet.detector.detector import Detector

#: Threads calling the one detector at once, and passes each makes over the frames.
CALLERS = 4
PASSES = 3


@pytest.fixture(scope="module")
def frames(data_dir):
    """Test images at two sizes: threads detect on the same size (same plans,
    same work arrays before they were kept per thread) and on different ones."""
    paths = sorted((data_dir / "test_images").glob("*.jpg"))[:3]
    assert len(paths) == 3, f"expected test images in {data_dir / 'test_images'}"
    images = [cv2.imread(str(path)) for path in paths]
    return images + [cv2.resize(image, (960, 540)) for image in images[:2]]


def detect_concurrently(detector, frames):
    """Every caller detects on every frame, each in its own order, all at once."""
    barrier = threading.Barrier(CALLERS)
    results = [[] for _ in range(CALLERS)]
    errors = []

    def caller(k):
        order = np.random.default_rng(k).permutation(len(frames) * PASSES) % len(frames)
        try:
            barrier.wait()
            for index in order:
                results[k].append((index, detector(frames[index]), detector.hits(frames[index])))
        except BaseException as exc:  # noqa: BLE001 - reported by the test
            errors.append(exc)

    threads = [threading.Thread(target=caller, args=(k,)) for k in range(CALLERS)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert not errors, errors
    return [item for per_caller in results for item in per_caller]


@pytest.mark.parametrize("pool_threads", [1, 2])
def test_concurrent_calls_match_serial_calls(frames, pool_threads):
    serial = Detector(threads=1)
    expected = [(serial(frame), serial.hits(frame)) for frame in frames]
    assert sum(len(detections) for detections, _ in expected) > 0
    try:
        shared = Detector(threads=pool_threads)
        results = detect_concurrently(shared, frames)
    finally:
        Detector(threads=1)  # restore the thread count for later tests
    assert len(results) == CALLERS * PASSES * len(frames)
    for index, detections, hits in results:
        want_detections, want_hits = expected[index]
        np.testing.assert_array_equal(detections.xyxy, want_detections.xyxy)
        np.testing.assert_array_equal(detections.score, want_detections.score)
        np.testing.assert_array_equal(hits.boxes, want_hits.boxes)
        np.testing.assert_array_equal(hits.scores, want_hits.scores)
    # Each call publishes its own complete timings.
    assert shared.timings["cells"] > 0



@pytest.mark.parametrize("cut_scales", [False, True])
def test_threads_sharing_a_new_frame_size_match_one_thread(cut_scales, monkeypatch):
    """The first frame of a size, whose work arrays the threads sharing it make as they
    start on its scales: two threads once each made their own array of a scale, and its
    windows were scored from the one that held only its own rows (found when the
    arrays started as zeros; stale memory of an earlier detector had hidden it).
    ``cut_scales``: the largest scales in row tasks, as with more threads."""
    if cut_scales:
        monkeypatch.setattr(scoring, "BALANCE_TOLERANCE", -1.0)
    rng = np.random.default_rng(1)
    try:
        for _ in range(24):
            height, width = int(rng.integers(64, 400)), int(rng.integers(64, 720))
            frame = rng.integers(0, 256, (height, width, 3), dtype=np.uint8)
            frame[: height // 2] = rng.integers(0, 256)
            serial = Detector(threads=1).hits(frame)
            shared = Detector(threads=2).hits(frame)
            np.testing.assert_array_equal(shared.boxes, serial.boxes)
            np.testing.assert_array_equal(shared.scores, serial.scores)
    finally:
        Detector(threads=1)  # restore the thread count for later tests


def test_row_tasks_of_a_model_without_colour_histograms():
    """Two threads cut a scale into row tasks at whole cells and spatial boxes; a
    model without histogram features has no colour tiles for them to respect
    (the cut at row 24 of a 32-px tile stopped such a detection with an error)."""
    from fastdet.detector.config import BoxConfig, DetectorConfig, HeatConfig, ScaleConfig
    from fastdet.detector.config import SearchConfig
    from fastdet.detector.features import FeatureLayout, FeatureOptions
    from fastdet.detector.model import Model

    options = FeatureOptions(use_hog=False, spatial_size=16, hist_bins=0, color_space="RGB")
    model = Model(np.full(FeatureLayout(options).length, 1.0 / 768, np.float32), bias=-100.0,
                  options=options)
    config = DetectorConfig(
        search=SearchConfig(scales=(ScaleConfig(64, 0.5, (0, 256), (16, 144)),),
                            reference_size=(256, 128), decision_threshold=0.0),
        heat=HeatConfig(threshold=0.5), boxes=BoxConfig(min_size=8, horizon_y=0))
    image = np.zeros((128, 256, 3), np.uint8)
    image[32:96, 64:128] = 250
    two = Detector(model, config, threads=2)
    assert any(task.kind == "rows" for task in two.bands((256, 128)))
    one = Detector(model, config, threads=1).hits(image)
    hits = two.hits(image)
    np.testing.assert_array_equal(hits.boxes, one.boxes)
    np.testing.assert_array_equal(hits.scores, one.scores)
