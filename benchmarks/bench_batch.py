"""``fastdet batch`` on local Dask clusters: scaling over videos, segments, per-video overhead.

Inputs are the shared test video played forwards and backwards to 1000 frames
(H.264, made once by ``setup_cache``) and copies of it.  Every figure is a
ratio or a difference measured in one process, the two sides run back to
back, so load from elsewhere on the machine hits both alike.  Detections
only: with annotated videos every task also encodes on a second thread, which
a one-worker run overlaps with its detection on an otherwise idle core.

* ``track_videos_default_layout_vs_one_worker``: 8 copies on one single-threaded
  worker, then on the machine's default layout (one worker per core); the
  ratio of their throughputs.
* ``track_one_video_whole_vs_two_segments``: one copy whole, then split in two
  segments (``--segment 500``) on the default layout; the ratio of their times.
* ``track_overhead_ms_per_video``: what a batch adds to each video's job
  (hashing, scheduling, results, the manifest): the time of 16 one-frame
  videos on one worker, per video, less the time the job itself takes on
  such a video in this process.
* ``track_worker_setup_seconds``: a worker's one-off set-up (model, kernels
  loaded from the cache, the pipeline run once).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
import time
from pathlib import Path

from ._common import video_path

#: Frames of the long clip and copies of it in the scaling benchmark.
FRAMES, COPIES = 1000, 8


def _looped_clip(target, count, take=None):
    """``count`` frames of the test video, forwards and backwards (H.264 via PyAV)."""
    import av

    from fastdet.video.source import VideoSource

    with VideoSource(video_path()) as reader:
        frames, fps = list(reader)[:take], reader.fps
    period = 2 * (len(frames) - 1) or 1
    with av.open(str(target), "w") as container:
        stream = container.add_stream("libx264", rate=round(fps))
        stream.height, stream.width = frames[0].shape[:2]
        stream.pix_fmt = "yuv420p"
        stream.options = {"preset": "veryfast", "crf": "23"}
        for i in range(count):
            k = i % period
            frame = frames[k if k < len(frames) else period - k]
            for packet in stream.encode(av.VideoFrame.from_ndarray(frame, format="bgr24")):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)


@contextlib.contextmanager
def _cluster(workers, threads=1):
    """A local cluster of ``workers`` single-task processes, as ``fastdet batch`` starts it."""
    from distributed import Client, LocalCluster

    env = {"NUMBA_NUM_THREADS": str(threads), "OMP_NUM_THREADS": "1"}
    with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                      host="127.0.0.1", dashboard_address="127.0.0.1:0", env=env) as cluster, \
            Client(cluster) as client:
        yield client


def _timed(client, inputs, threads=1, **options):
    """Seconds of one batch on a cluster whose workers are already set up (outputs discarded)."""
    import fastdet

    out = tempfile.mkdtemp(prefix="fastdet-bench-batch-")
    try:
        start = time.perf_counter()
        records = fastdet.batch(inputs, out, client, video=False, threads=threads, **options)
        seconds = time.perf_counter() - start
    finally:
        shutil.rmtree(out, ignore_errors=True)
    assert all(r["status"] == "done" for r in records), records
    return seconds


def _warm(client, clip, threads=1):
    """Set the workers up (model, kernels) so that the timed batches do not include it."""
    _timed(client, [clip], threads=threads)


class BatchScaling:
    """Throughput ratios of local layouts (see the module notes)."""

    number = 1
    repeat = 1
    rounds = 1
    warmup_time = 0
    timeout = 3600

    def setup_cache(self):
        # asv runs this in a folder of its own, which it removes after the benchmarks.
        folder = Path("batch-clips").resolve()
        folder.mkdir()
        _looped_clip(folder / "long.mp4", FRAMES)
        copies = folder / "copies"
        copies.mkdir()
        for k in range(COPIES):
            os.link(folder / "long.mp4", copies / f"copy{k}.mp4")
        short = folder / "short"
        short.mkdir()
        _looped_clip(folder / "one-frame.mp4", 1)
        for k in range(16):
            os.link(folder / "one-frame.mp4", short / f"f{k:02d}.mp4")
        return str(folder)

    def track_videos_default_layout_vs_one_worker(self, folder):
        from fastdet.batch.cluster import plan_layout

        folder = Path(folder)
        with _cluster(1) as client:
            _warm(client, folder / "long.mp4")
            one = _timed(client, [folder / "copies"])
        with _cluster(plan_layout()) as client:
            _warm(client, folder / "long.mp4")
            default = _timed(client, [folder / "copies"])
        return one / default

    track_videos_default_layout_vs_one_worker.unit = "x"

    def track_one_video_whole_vs_two_segments(self, folder):
        from fastdet.batch.cluster import plan_layout

        clip = Path(folder) / "long.mp4"
        with _cluster(plan_layout()) as client:
            _warm(client, clip)
            whole = _timed(client, [clip])
            split = _timed(client, [clip], segment=str(FRAMES // 2))
        return whole / split

    track_one_video_whole_vs_two_segments.unit = "x"

    def track_overhead_ms_per_video(self, folder):
        return 1e3 * overhead_per_video(Path(folder))["overhead"]

    track_overhead_ms_per_video.unit = "ms"

    def track_worker_setup_seconds(self, folder):
        return worker_setup_seconds()

    track_worker_setup_seconds.unit = "s"


def worker_setup_seconds():
    """Seconds to register the batch's plugin on a fresh worker (its one-off set-up)."""
    from fastdet.batch.settings import make_settings
    from fastdet.batch.worker import BatchSetup

    settings = make_settings()
    with _cluster(1) as client:
        start = time.perf_counter()
        client.register_plugin(BatchSetup(settings), name=settings.name)
        return time.perf_counter() - start


def job_seconds(clip, repeats=5):
    """Median seconds of the per-video job on ``clip`` in this process (detector warm)."""
    import statistics

    from fastdet.batch.job import process_one
    from fastdet.batch.outputs import OutputPaths
    from fastdet.batch.settings import make_settings
    from fastdet.detector.detector import Detector

    settings, detector = make_settings(video=False), Detector(threads=1)
    times = []
    with tempfile.TemporaryDirectory() as out:
        for _ in range(repeats + 1):
            start = time.perf_counter()
            process_one(clip, OutputPaths(None, Path(out) / "d.jsonl", None), settings,
                        detector=detector)
            times.append(time.perf_counter() - start)
    return statistics.median(times[1:])


def overhead_per_video(folder):
    """Seconds a batch adds to each video's job, on one worker (see the module notes)."""
    short = sorted((folder / "short").glob("f*.mp4"))
    with _cluster(1) as client:
        _warm(client, folder / "long.mp4")
        batch = _timed(client, short) / len(short)
    job = job_seconds(folder / "one-frame.mp4")
    return {"overhead": batch - job, "per_video": batch, "job": job}
