"""Video end to end: decode the shared test video and run the video pipeline.

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
from fastdet.detector.detector import Detector

from ._common import bench_model, video_path

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
    """Frames of the video, decoded lazily (fastdet's reader if there is one).

    ``skip`` (called before each frame) lets fastdet's reader leave out the
    BGR conversion of frames the pipeline will not look at.
    """
    try:
        from fastdet.video.reader import VideoReader
    except ImportError:
        VideoReader = None
    if VideoReader is not None:
        with VideoReader(path) as reader:
            if skip is not None and hasattr(reader, "frames"):
                yield from reader.frames(skip=skip)
            else:
                yield from reader
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
