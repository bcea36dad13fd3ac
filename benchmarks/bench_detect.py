"""Per-frame detection latency on the shared test video, and its peers.

* ``DetectLatency``: ``fastdet.Detector`` with one thread and with all
  threads; each timed call detects the next frame of the video, so the
  samples cover its frames and asv's median is the median per-frame latency.
* ``ReferenceLatency``: the seed-faithful reference (``benchmarks/reference.py``,
  seconds per frame) on a few frames spread over the video.
* ``ReferenceRatio`` / ``OpenCVPeer``: ratios measured in one run, on the
  same frames: fastdet with one thread against the reference, and against
  OpenCV's ``HOGDescriptor`` (in its own environment, see
  ``benchmarks/opencv_peer/``) on exactly fastdet's windows and in its
  native multi-scale search, fastdet and OpenCV in turns of a few frames
  (``fastdet.bench.timing.TURN_FRAMES``).

The model is ``$FASTDET_BENCH_MODEL`` or the bundled default.
"""

from __future__ import annotations

import itertools
from pathlib import Path

import numba

# The module, not its functions: asv would take time_* names here for benchmarks.
from fastdet.bench import peers, timing
from fastdet.detector.detector import Detector

from ._common import bench_model, skip_if_missing, skip_reason, spread, video_frames

#: The OpenCV peer script, beside this module.
PEER_SCRIPT = Path(__file__).resolve().parent / "opencv_peer" / "peer.py"
#: Frames the slow reference is timed on (about 5 s each).
REFERENCE_FRAMES = 3


def all_threads():
    return numba.config.NUMBA_NUM_THREADS


class DetectLatency:
    """fastdet's latency per frame (all 38 frames of the video, cycled)."""

    params = (["1", "all"],)
    param_names = ("threads",)

    def setup(self, threads):
        count = 1 if threads == "1" else all_threads()
        self.detector = Detector(bench_model(), threads=count)
        frames = video_frames()
        self.detector(frames[0])  # compile or load kernels, allocate buffers
        self.frames = itertools.cycle(frames)

    def time_detect_frame(self, threads):
        self.detector(next(self.frames))

    def track_windows_per_frame(self, threads):
        self.detector(video_frames()[0])
        return self.detector.last_windows_scored

    track_windows_per_frame.unit = "windows"


class ReferenceLatency:
    """The reference pipeline's latency per frame (slow: a few frames, one call each)."""

    number = 1
    repeat = (REFERENCE_FRAMES, REFERENCE_FRAMES, 120.0)
    rounds = 1
    warmup_time = 0
    timeout = 900

    def setup(self):
        from .reference import ReferenceDetector  # needs scikit-image (bench extra)

        Detector(bench_model(), threads=1)  # one thread for OpenCV, as for fastdet
        self.reference = ReferenceDetector(bench_model())
        self.frames = itertools.cycle(spread(video_frames(), REFERENCE_FRAMES))

    def time_reference_frame(self):
        self.reference(next(self.frames))


class ReferenceRatio:
    """fastdet (1 thread) vs the reference on the same frames, in one run."""

    timeout = 900

    def setup_cache(self):
        from .reference import ReferenceDetector

        if skip_reason(bench_model):
            return {"skip": skip_reason(bench_model)}
        frames = spread(video_frames(), REFERENCE_FRAMES)
        indices = list(range(len(frames)))
        detector = Detector(bench_model(), threads=1)
        fastdet = timing.time_fastdet(detector, frames, repeat=3)
        reference = timing.time_callable("reference", ReferenceDetector(bench_model()),
                                                frames, indices, fastdet.windows_per_frame)
        return {"fastdet": fastdet.median_ms / 1e3, "reference": reference.median_ms / 1e3}

    def setup(self, cache):
        skip_if_missing(cache)

    def track_reference_per_frame(self, cache):
        return cache["reference"]

    track_reference_per_frame.unit = "seconds"

    def track_fastdet_per_frame(self, cache):
        return cache["fastdet"]

    track_fastdet_per_frame.unit = "seconds"

    def track_speedup_vs_reference(self, cache):
        return cache["reference"] / cache["fastdet"]

    track_speedup_vs_reference.unit = "x faster than reference"


class OpenCVPeer:
    """fastdet vs OpenCV's HOGDescriptor on all frames, in one run.

    Skipped when the peer's environment is missing: run
    ``bash benchmarks/opencv_peer/setup.sh`` first.
    """

    timeout = 1800

    def setup_cache(self):
        if peers.opencv_peer_python() is None:
            return {"skip": "OpenCV peer environment missing: run "
                            "`bash benchmarks/opencv_peer/setup.sh`"}
        if skip_reason(bench_model):
            return {"skip": skip_reason(bench_model)}
        frames = list(video_frames())
        detector = Detector(bench_model(), threads=1)
        plans = detector.plans((frames[0].shape[1], frames[0].shape[0]))
        with peers.OpenCVPeer(frames, plans, threads=(1,), repeat=3,
                              peer_script=PEER_SCRIPT) as peer:
            fastdet, = timing.time_fastdet_in_turn([("fastdet", detector)], frames, repeat=3,
                                                   also=peer.time_turn,
                                                   turn_frames=timing.TURN_FRAMES)
            results = peer.results()
        by_mode = {("same" if "same windows" in r.name else "native"): r for r in results}
        return {"fastdet": fastdet.median_ms / 1e3, "same": by_mode["same"].median_ms / 1e3,
                "native": by_mode["native"].median_ms / 1e3,
                "native_windows": by_mode["native"].windows_per_frame}

    def setup(self, cache):
        skip_if_missing(cache)

    def track_opencv_same_windows_per_frame(self, cache):
        return cache["same"]

    track_opencv_same_windows_per_frame.unit = "seconds"

    def track_opencv_native_per_frame(self, cache):
        return cache["native"]

    track_opencv_native_per_frame.unit = "seconds"

    def track_opencv_native_windows_per_frame(self, cache):
        return cache["native_windows"]

    track_opencv_native_windows_per_frame.unit = "windows"

    def track_fastdet_per_frame(self, cache):
        return cache["fastdet"]

    track_fastdet_per_frame.unit = "seconds"

    def track_speedup_vs_opencv_same_windows(self, cache):
        return cache["same"] / cache["fastdet"]

    track_speedup_vs_opencv_same_windows.unit = "x faster than OpenCV"

    def track_speedup_vs_opencv_native(self, cache):
        return cache["native"] / cache["fastdet"]

    track_speedup_vs_opencv_native.unit = "x faster than OpenCV"
