"""Video end to end: the main job's throughput, and the video pipeline over the test clip.

``FastdetRun`` times whole ``fastdet run`` processes per mode on a 1000-frame
H.264 input (the test clip looped forward and back, made once) against
OpenCV's single-thread decode-only rate R of the same file, measured in the
same rounds (``fastdet.bench.video_run``; ``fastdet bench --video`` prints the
same figures as a table): frames per second, the ratio to R, and the peak RSS
on the 1000-frame input relative to the 38-frame clip.

``PipelineThreads`` times the pipeline over the decoded clip with one thread,
with all threads sharing each frame, and with all threads scoring as many
frames at once.


Frames per second of ``fastdet.VideoPipeline`` (``fastdet.video.pipeline``) over all 38
frames of ``test_video.mp4``, decoding included (writing excluded), with
detection on every frame, every 5th frame (the boxes reused between), and
every 5th frame plus patch tracking in between.  As in ``fastdet run``, frames
the pipeline does not look at are decoded but not converted to BGR.  Skipped
(asv's ``NotImplementedError``) when this fastdet has no video pipeline.
"""

from __future__ import annotations

import time

import numba

import fastdet
from fastdet.bench.video_run import MODES, video_benchmark
from fastdet.detector.detector import Detector

from ._common import bench_model, skip_if_missing, skip_reason, video_frames, video_path

#: Track settings by asv label (keyword arguments of ``TrackConfig``).
TRACK_SETTINGS = {"detect every frame": {}, "detect every 5th": {"every": 5},
                  "detect every 5th + tracking": {"every": 5, "tracking": True}}


def video_pipeline_api():
    """``(VideoPipeline, TrackConfig)``, or NotImplementedError if fastdet has none."""
    pipeline = getattr(fastdet, "VideoPipeline", None)
    try:
        from fastdet.video.config import TrackConfig
        from fastdet.video.pipeline import VideoPipeline as TrackPipeline
    except ImportError:
        TrackConfig = TrackPipeline = None
    pipeline = pipeline or TrackPipeline
    if pipeline is None or TrackConfig is None:
        raise NotImplementedError("this fastdet has no VideoPipeline (fastdet.video.pipeline)")
    return pipeline, TrackConfig


def decoded_frames(path, skip=None):
    """Frames of the video, decoded lazily (fastdet's VideoSource if there is one).

    ``skip`` (called before each frame) lets the source leave out the BGR
    conversion of frames the pipeline will not look at.
    """
    try:
        from fastdet.video.source import VideoSource
    except ImportError:
        VideoSource = None
    if VideoSource is not None:
        with VideoSource(path) as source:
            yield from source.frames(skip=skip)
        return
    import cv2

    capture = cv2.VideoCapture(str(path))
    try:
        while True:
            ok, frame = capture.read()
            if not ok:
                return
            yield frame
    finally:
        capture.release()


class VideoEndToEnd:
    """Seconds to decode and process the whole video; frames per second."""

    params = (list(TRACK_SETTINGS), ["1", "all"])
    param_names = ("track", "threads")
    number = 1
    repeat = (1, 5, 30.0)
    warmup_time = 0
    timeout = 600

    def setup(self, track, threads):
        pipeline_class, track_config = video_pipeline_api()
        count = 1 if threads == "1" else numba.config.NUMBA_NUM_THREADS
        detector = Detector(bench_model(), threads=count)
        self.pipeline = pipeline_class(detector, track_config(**TRACK_SETTINGS[track]))
        self.path = video_path()
        self._run()  # compile or load kernels, warm the decoder

    def _run(self):
        self.pipeline.reset()
        frames = 0
        pipeline = self.pipeline
        skip = (lambda: not pipeline.wants_frame) if hasattr(pipeline, "wants_frame") else None
        for _ in pipeline(decoded_frames(self.path, skip)):
            frames += 1
        return frames

    def time_video(self, track, threads):
        self._run()

    def track_frames_per_second(self, track, threads):
        start = time.perf_counter()
        frames = self._run()
        return frames / (time.perf_counter() - start)

    track_frames_per_second.unit = "frames/s"


class FastdetRun:
    """Whole ``fastdet run`` processes per mode against OpenCV's decoding rate (one round)."""

    params = [[label for label, _, _ in MODES]]
    param_names = ["mode"]
    timeout = 1800
    number = 1
    repeat = 1

    def setup_cache(self):
        reason = skip_reason(bench_model)
        if reason:
            return {"skip": reason}
        benchmark = video_benchmark(video_path(), rounds=1)
        return {"opencv_fps": benchmark.opencv_fps[0],
                "fps": {m.label: m.fps[0] for m in benchmark.modes},
                "ratio": {m.label: m.ratios[0] for m in benchmark.modes},
                "rss_growth": benchmark.rss_long_mib / benchmark.rss_short_mib - 1}

    def setup(self, cache, mode):
        skip_if_missing(cache)

    def track_fps(self, cache, mode):
        return cache["fps"][mode]

    track_fps.unit = "frames/s"

    def track_ratio_to_opencv_decoding(self, cache, mode):
        return cache["ratio"][mode]

    track_ratio_to_opencv_decoding.unit = "x R"

    def track_opencv_decoding_fps(self, cache, mode):
        return cache["opencv_fps"]

    track_opencv_decoding_fps.unit = "frames/s"

    def track_peak_rss_growth_1000_vs_38_frames(self, cache, mode):
        return cache["rss_growth"]

    track_peak_rss_growth_1000_vs_38_frames.unit = "fraction"


#: How the detector's threads share the work, by asv label: (threads, frames at once).
PIPELINE_THREADS = {"1 thread": ("1", 1), "all threads share each frame": ("all", 1),
                    "all threads, frames at once": ("all", None)}


class PipelineThreads:
    """The video pipeline over the 38 decoded frames (default ``[track]``), seconds per pass.

    One thread; all threads sharing each frame; or as many single-thread
    detectors scoring that many frames at once (``fastdet.video.ahead``), as
    in the last table of ``fastdet bench``.  Decoding is left out (frames
    decoded once), so the figures are the pipeline's own.
    """

    params = (list(PIPELINE_THREADS),)
    param_names = ("threads",)
    number = 1
    repeat = (3, 15, 30.0)
    warmup_time = 0
    timeout = 600

    def setup(self, threads):
        pipeline_class, track_config = video_pipeline_api()
        try:
            from fastdet.video.ahead import process_ahead  # noqa: F401
            from fastdet.video.memory import reuse_freed_frames
        except ImportError:
            raise NotImplementedError("this fastdet cannot score frames at once") from None
        reuse_freed_frames()
        label, at_once = PIPELINE_THREADS[threads]
        count = 1 if label == "1" else numba.config.NUMBA_NUM_THREADS
        self.workers = count if at_once is None else at_once
        detector = Detector(bench_model(), threads=1 if self.workers > 1 else count)
        self.pipeline = pipeline_class(detector, track_config())
        self.frames = video_frames()
        self._run()  # compile or load kernels, allocate buffers

    def _run(self):
        self.pipeline.reset()
        for _ in self.pipeline(self.frames, workers=self.workers):
            pass

    def time_pipeline(self, threads):
        self._run()


class VideoHorizon:
    """``[search] horizon = "auto"`` before a video's first frame: reading the
    frames it is estimated from (every 10th of the first 250) and the estimate.

    ``estimate`` times the estimate alone, on the 38 decoded frames' first four
    of every ten (what the test video gives it); ``read and estimate`` opens
    the file again and decodes them too, as a run does.
    """

    params = (["estimate", "read and estimate"],)
    param_names = ("part",)
    number = 1
    repeat = (3, 10, 30.0)
    warmup_time = 0

    def setup(self, part):
        try:
            from fastdet.detector.horizon import FRAME_STEP, estimate_horizon
            from fastdet.video.horizon import horizon_frames
            from fastdet.video.source import VideoSource
        except ImportError:
            raise NotImplementedError("this fastdet has no horizon estimate") from None
        self.estimate, self.read = estimate_horizon, horizon_frames
        self.source_class = VideoSource
        self.frames = video_frames()[::FRAME_STEP]
        self.estimate(self.frames)

    def time_horizon(self, part):
        if part == "estimate":
            self.estimate(self.frames)
        else:
            with self.source_class(video_path()) as video:
                self.estimate(self.read(video))
