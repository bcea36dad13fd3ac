"""A Detector crosses processes: pickled, it is built again from its model and settings."""

import concurrent.futures
import multiprocessing
import pickle

import cv2
import numpy as np
import pytest

from fastdet import Detector
from fastdet.detector.config import DetectorConfig, with_search_horizon
from fastdet.detector.horizon import HorizonEstimate


@pytest.fixture(scope="module")
def frame(data_dir):
    return cv2.imread(str(data_dir / "test_images" / "test1.jpg"))


def same(a, b):
    return np.array_equal(a.xyxy, b.xyxy) and np.array_equal(a.score, b.score)


def test_a_copy_detects_what_the_original_does(frame):
    config = with_search_horizon(DetectorConfig(), 0.57)
    detector = Detector(config=config, threads=1, preload=False)
    copy = pickle.loads(pickle.dumps(detector))
    assert copy is not detector and copy.config == detector.config == config
    assert copy.threads == 1 and copy.scorer is not detector.scorer
    found = detector(frame)
    assert len(found) > 0 and same(copy(frame), found)


def test_a_horizon_taken_stays_taken_and_auto_stays_auto(frame):
    detector = Detector(config=with_search_horizon(DetectorConfig(), "auto"), threads=1,
                        preload=False)
    detector.take_horizon(HorizonEstimate(0.6, 5, 5, (0.59, 0.61)))
    copy = pickle.loads(pickle.dumps(detector))
    assert copy.config == detector.config and copy.config.search.horizon == pytest.approx(0.6)
    assert copy.auto_horizon
    # Another camera's estimate is still taken from the configuration as given.
    copy.take_horizon(HorizonEstimate(0.62, 5, 5, (0.61, 0.63)))
    assert copy.config.search.horizon == pytest.approx(0.62)


def test_threads_left_to_numba_stay_left_to_the_receiving_process():
    detector = Detector(preload=False)
    assert pickle.loads(pickle.dumps(detector))._arguments == (None, False)


def _detect_in_child(detector, frame):
    found = detector(frame)
    return found.xyxy, found.score


def test_a_detector_sent_to_a_spawned_worker_process(frame):
    detector = Detector(threads=1, preload=False)
    context = multiprocessing.get_context("spawn")
    with concurrent.futures.ProcessPoolExecutor(1, mp_context=context) as pool:
        xyxy, score = pool.submit(_detect_in_child, detector, frame).result(timeout=300)
    found = detector(frame)
    assert np.array_equal(xyxy, found.xyxy) and np.array_equal(score, found.score)
