"""The OpenCV peer, timed frame by frame in turn with fastdet.

The peer script (``benchmarks/opencv_peer/peer.py``) runs for real, in a
subprocess, against a stand-in ``cv2`` put first on its path: OpenCV 4 (the
last with ``HOGDescriptor``) lives in an environment of its own that the test
machine need not have, and what is tested here is the protocol, the order of
the timings and what happens when the peer fails, not OpenCV.
"""

from __future__ import annotations

import signal
import stat
import sys
from pathlib import Path

import numpy as np
import pytest

from fastdet.bench.latency import run_benchmark
from fastdet.bench.peers import (OPENCV_DISPATCH_LEVELS, OpenCVPeer, benchmarks_dir,
                                 opencv_levels_above_build, opencv_peer_environment)
from fastdet.kernels import _llvm
from fastdet.bench.timing import time_fastdet_in_turn
from fastdet.detector.config import DetectorConfig
from fastdet.detector.detector import Detector
from fastdet.detector.features import FeatureLayout, FeatureOptions
from fastdet.detector.model import Model
from fastdet.detector.plan import plan_scales
from fastdet.errors import InputError

#: A stand-in for OpenCV 4's ``cv2``: grey and resized images carry their
#: frame's first pixel (the frame's number in these tests), each grey
#: conversion is logged, and ``detect`` fails or stalls on request.
FAKE_CV2 = '''
import os, time
import numpy as np

__version__ = "4.99.0-stand-in"
COLOR_BGR2GRAY = 6
IMREAD_GRAYSCALE = 0
INTER_AREA, INTER_LINEAR = 3, 1
HOGDESCRIPTOR_L2HYS = 0
threads = []


def setNumThreads(count):
    threads.append(count)


def getCPUFeaturesLine():
    return "left out: " + os.environ.get("OPENCV_CPU_DISABLE", "")


def imread(path, flags=None):
    return np.full((64, 64), 255 if "non-vehicles" not in str(path) else 0, np.uint8)


def cvtColor(frame, code):
    with open(os.environ["FAKE_CV2_LOG"], "a") as log:
        log.write(f"opencv {int(frame[0, 0, 0])} {threads[-1]}\\n")
    return np.ascontiguousarray(frame[..., 0])


def resize(image, size, fx=None, fy=None, interpolation=None):
    if size is None:
        size = (int(image.shape[1] * fx), int(image.shape[0] * fy))
    return np.full((size[1], size[0]), image.flat[0], np.uint8)


class HOGDescriptor:
    def __init__(self, *args):
        pass

    def getDescriptorSize(self):
        return 1764

    def compute(self, grey):
        return np.full(1764, grey.mean() / 255, np.float32)

    def setSVMDetector(self, detector):
        self.detector = detector

    def detect(self, image, hitThreshold, winStride, padding):
        value = int(image.flat[0])
        if value == int(os.environ.get("FAKE_CV2_FAIL_ON", -1)):
            raise RuntimeError(f"stand-in OpenCV fails on frame {value}")
        if value == int(os.environ.get("FAKE_CV2_STALL_ON", -1)):
            time.sleep(60)
        rows = (image.shape[0] - 64) // winStride[1] + 1
        cols = (image.shape[1] - 64) // winStride[0] + 1
        found = [(0, 0)] * (rows * cols) if hitThreshold < -1e20 else []
        return found, []

    def detectMultiScale(self, image, hitThreshold, winStride, padding, scale,
                         groupThreshold=2):
        found, _ = self.detect(image, hitThreshold, winStride, padding)
        return found, []
'''


@pytest.fixture()
def model():
    options = FeatureOptions()
    rng = np.random.default_rng(5)
    weights = rng.normal(scale=0.01, size=FeatureLayout(options).length).astype(np.float32)
    return Model(weights=weights, bias=0.0, options=options)


@pytest.fixture()
def peer_log(tmp_path, monkeypatch):
    """A peer environment whose ``cv2`` is the stand-in; returns the log it writes."""
    site = tmp_path / "stand-in"
    site.mkdir()
    (site / "cv2.py").write_text(FAKE_CV2)
    venv = tmp_path / "peer-venv"
    (venv / "bin").mkdir(parents=True)
    python = venv / "bin" / "python"
    python.write_text(f'#!/bin/sh\nPYTHONPATH="{site}" exec "{sys.executable}" "$@"\n')
    python.chmod(python.stat().st_mode | stat.S_IXUSR)
    data = tmp_path / "data"
    for folder in ("vehicles/a", "non-vehicles/a"):
        (data / folder).mkdir(parents=True)
        for k in range(2):
            (data / folder / f"{k}.png").write_bytes(b"")  # the stand-in's imread reads nothing
    log = tmp_path / "calls.log"
    monkeypatch.setenv("FASTDET_OPENCV_PEER", str(venv))
    monkeypatch.setenv("FASTDET_DATA", str(data))
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    monkeypatch.setenv("FAKE_CV2_LOG", str(log))
    return log


def numbered_frames(count):
    return [np.full((180, 320, 3), k, np.uint8) for k in range(count)]


def log_fastdet_calls(monkeypatch, log):
    original = Detector.__call__

    def detect(self, frame):
        with open(log, "a") as out:
            out.write(f"fastdet {int(frame[0, 0, 0])} {self.threads}\n")
        return original(self, frame)

    monkeypatch.setattr(Detector, "__call__", detect)


def test_the_checkout_has_the_peer_script():
    assert (benchmarks_dir() / "opencv_peer" / "peer.py").is_file()


@pytest.mark.parametrize("turn_frames", [1, 2, 8])
def test_opencv_is_timed_in_turns_with_fastdet_on_every_frame(model, peer_log, monkeypatch,
                                                               turn_frames):
    log_fastdet_calls(monkeypatch, peer_log)
    frames = numbered_frames(3)
    run = run_benchmark(frames, threads=(1, 2), repeat=2, reference_frames=0, opencv=True,
                        model=model, log=lambda line: None, turn_frames=turn_frames)
    assert run.notes == []
    assert [r.name for r in run.results] == [
        "fastdet 1 thread", "fastdet 2 threads",
        "opencv same windows, 1 thread", "opencv native multiscale, 1 thread",
        "opencv same windows, 2 threads", "opencv native multiscale, 2 threads"]
    # Only the timed calls count, not the warm-up of each turn.
    assert all(len(r.seconds) == 3 and r.frame_indices == [0, 1, 2] for r in run.results)
    same = run.opencv_same_windows
    assert same.windows_per_frame == run.results[0].windows_per_frame  # the same windows
    assert run.opencv["opencv_version"] == "4.99.0-stand-in"

    calls = peer_log.read_text().splitlines()
    timed = calls[calls.index("fastdet 0 1"):]  # from fastdet's untimed first call on
    # Untimed first calls, then per turn: fastdet with 1 thread, once untimed on the turn's
    # first frame and twice on each of its frames, the same with 2 threads, then OpenCV:
    # once per mode (same windows, native) on the turn's first frame with 1 and 2 threads,
    # then per frame with 1 and 2 threads, each thread count twice per mode.
    expected = ["fastdet 0 1", "fastdet 0 2"]
    for first in range(0, 3, turn_frames):
        turn = range(first, min(first + turn_frames, 3))
        for threads in (1, 2):
            expected += [f"fastdet {first} {threads}"]
            for k in turn:
                expected += [f"fastdet {k} {threads}"] * 2
        expected += [f"opencv {first} 1"] * 2 + [f"opencv {first} 2"] * 2
        for k in turn:
            expected += [f"opencv {k} 1"] * 4 + [f"opencv {k} 2"] * 4
    assert timed == expected


def test_turn_frames_below_one_is_refused(model):
    with pytest.raises(ValueError, match="turn_frames must be at least 1"):
        time_fastdet_in_turn([("fastdet", Detector(model=model, threads=1))],
                             numbered_frames(2), turn_frames=0)


def test_a_peer_that_fails_mid_run_leaves_a_note_and_fastdet_timed(model, peer_log,
                                                                     monkeypatch):
    monkeypatch.setenv("FAKE_CV2_FAIL_ON", "2")
    run = run_benchmark(numbered_frames(4), threads=(1,), repeat=1, reference_frames=0,
                        opencv=True, model=model, log=lambda line: None)
    assert [r.name for r in run.results] == ["fastdet 1 thread"]
    assert len(run.results[0].seconds) == 4
    assert len(run.notes) == 1 and run.notes[0].startswith("OpenCV peer skipped: OpenCV peer "
                                                           "failed (exit 1)")
    assert "stand-in OpenCV fails on frame 2" in run.notes[0]


def test_a_peer_that_does_not_answer_is_stopped(model, peer_log, monkeypatch):
    monkeypatch.setenv("FAKE_CV2_STALL_ON", "1")
    frames = numbered_frames(2)
    plans = plan_scales(DetectorConfig(), model.options, (320, 180))
    peer = OpenCVPeer(frames, plans, threads=(1,), repeat=1, frame_timeout=1.0)
    with peer:
        peer.time_frame(0)
        process = peer._process
        with pytest.raises(InputError, match="did not answer within 1 s"):
            peer.time_frame(1)
        assert process.wait(timeout=5) == -signal.SIGKILL  # not left sleeping
    assert [len(r.seconds) for r in peer.results()] == [1, 1]


@pytest.mark.parametrize("avx2, avx512, left_out", [
    (True, True, ()),
    (True, False, ("AVX512-SKX",)),
    (False, False, OPENCV_DISPATCH_LEVELS),
])
def test_opencv_leaves_out_the_levels_above_the_kernels_build(monkeypatch, avx2, avx512,
                                                              left_out):
    monkeypatch.setattr(_llvm, "HAVE_AVX2", avx2)
    monkeypatch.setattr(_llvm, "HAVE_AVX512F", avx512)
    assert opencv_levels_above_build() == left_out


def test_the_peer_environment_keeps_what_the_user_left_out(monkeypatch):
    monkeypatch.setattr(_llvm, "HAVE_AVX2", True)
    monkeypatch.setattr(_llvm, "HAVE_AVX512F", False)
    environ = opencv_peer_environment({"OPENCV_CPU_DISABLE": "FP16,AVX512-SKX", "HOME": "/h"})
    assert environ == {"OPENCV_CPU_DISABLE": "FP16,AVX512-SKX", "HOME": "/h"}
    assert opencv_peer_environment({})["OPENCV_CPU_DISABLE"] == "AVX512-SKX"
    monkeypatch.setattr(_llvm, "HAVE_AVX512F", True)
    assert "OPENCV_CPU_DISABLE" not in opencv_peer_environment({"HOME": "/h"})


def test_an_avx2_build_is_timed_against_opencv_without_its_avx512_code(model, peer_log,
                                                                         monkeypatch):
    monkeypatch.delenv("OPENCV_CPU_DISABLE", raising=False)
    monkeypatch.setattr(_llvm, "HAVE_AVX2", True)
    monkeypatch.setattr(_llvm, "HAVE_AVX512F", False)
    plans = plan_scales(DetectorConfig(), model.options, (320, 180))
    with OpenCVPeer(numbered_frames(1), plans, threads=(1,), repeat=1) as peer:
        assert peer.report["cpu_features"] == "left out: AVX512-SKX"
    monkeypatch.setattr(_llvm, "HAVE_AVX512F", True)
    with OpenCVPeer(numbered_frames(1), plans, threads=(1,), repeat=1) as peer:
        assert peer.report["cpu_features"] == "left out: "


def test_a_missing_peer_environment_is_an_input_error(model, tmp_path, monkeypatch):
    monkeypatch.setenv("FASTDET_OPENCV_PEER", str(tmp_path / "no-such-venv"))
    plans = plan_scales(DetectorConfig(), model.options, (320, 180))
    with pytest.raises(InputError, match="setup.sh"):
        OpenCVPeer(numbered_frames(1), plans).start()


def test_the_peer_files_are_removed_when_it_closes(model, peer_log):
    frames = numbered_frames(1)
    plans = plan_scales(DetectorConfig(), model.options, (320, 180))
    with OpenCVPeer(frames, plans, threads=(1,), repeat=1) as peer:
        folder = Path(peer._folder.name)
        assert (folder / "frames.npy").is_file()
        peer.time_frame(0)
    assert not folder.exists()
    assert peer._process is None


@pytest.mark.parametrize("turn_frames, turns", [(1, [[0], [1], [2], [3], [4]]),
                                                (2, [[0, 1], [2, 3], [4]]),
                                                (5, [[0, 1, 2, 3, 4]]),
                                                (9, [[0, 1, 2, 3, 4]])])
def test_time_fastdet_in_turn_calls_also_after_each_turn(model, turn_frames, turns):
    seen = []
    detector = Detector(model=model, threads=1)
    result, = time_fastdet_in_turn([("fastdet", detector)], numbered_frames(5), repeat=1,
                                   also=seen.append, turn_frames=turn_frames)
    assert seen == turns
    assert result.frame_indices == [0, 1, 2, 3, 4] and len(result.seconds) == 5



def test_a_peer_that_fails_to_start_is_an_input_error_and_leaves_nothing(model, peer_log,
                                                                         monkeypatch):
    monkeypatch.setenv("FAKE_CV2_FAIL_ON", "0")  # its warm-up on the first frame fails
    plans = plan_scales(DetectorConfig(), model.options, (320, 180))
    peer = OpenCVPeer(numbered_frames(2), plans, threads=(1,), repeat=1)
    with pytest.raises(InputError, match="stand-in OpenCV fails on frame 0"):
        peer.start()
    assert peer._process is None and peer._folder is None
    assert peer.results() == []


def test_missing_training_data_skips_the_peer_with_a_note(model, peer_log, tmp_path,
                                                          monkeypatch):
    # A bench of the user's own video needs no shared data; only OpenCV's SVM does.
    monkeypatch.setenv("FASTDET_DATA", str(tmp_path / "no-data"))
    run = run_benchmark(numbered_frames(2), threads=(1,), repeat=1, reference_frames=0,
                        opencv=True, model=model, log=lambda line: None)
    assert [r.name for r in run.results] == ["fastdet 1 thread"]
    assert len(run.notes) == 1 and "shared data not found" in run.notes[0]
