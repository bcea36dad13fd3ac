"""Tests for ``fastdet.video.run.process_video``: the pipelined run against a plain loop.

The detections of the pipelined run must be exactly those of a plain loop
over ``VideoPipeline``; Ctrl-C and SIGTERM (sent to a real ``fastdet run``
process) must leave complete outputs, a second signal none.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import av
import numpy as np
import pytest
from video_files import record_sources
from video_stubs import BlockDetector, bundled_model_path, moving_block

from fastdet.detector.detector import Detector
from fastdet.errors import InputError
from fastdet.video.config import TrackConfig
from fastdet.video.detection_files import DetectionWriter
from fastdet.video.pipeline import VideoPipeline
from fastdet.video.run import process_video
from fastdet.video.sink import VideoSink
from fastdet.video.source import VideoSource

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def detector():
    detector = Detector(bundled_model_path(), threads=1)
    return detector


def leftovers(folder):
    return sorted(p.name for p in folder.iterdir() if ".part" in p.name)


def plain_loop(path, detector, track_config, out, start=0, end=None, first_output=0):
    """The reference: frames one by one through VideoPipeline into a DetectionWriter."""
    pipeline = VideoPipeline(detector, track_config)
    with VideoSource(path, start, end) as video, DetectionWriter(out) as writer:
        for index, frame in enumerate(video, start):
            detections = pipeline.process(frame)
            if index >= first_output:
                writer.write(index, detections)
    return out.read_text()


@pytest.mark.parametrize("track", [{}, {"every": 5}, {"every": 5, "tracking": True}],
                         ids=["every frame", "every 5", "every 5 + tracking"])
def test_detections_equal_a_plain_loop(data_dir, detector, tmp_path, track):
    video = data_dir / "test_video.mp4"
    expected = plain_loop(video, detector, TrackConfig(**track), tmp_path / "plain.jsonl")
    stats = process_video(video, tmp_path / "out.mp4",
                          VideoPipeline(detector, TrackConfig(**track)),
                          detections=tmp_path / "piped.jsonl")
    assert (tmp_path / "piped.jsonl").read_text() == expected
    assert stats.frames == 38 and stats.boxes > 0 and stats.interrupted is None
    assert sum(1 for line in expected.splitlines() if '"box"' in line) > 30


def test_a_range_with_warm_up_frames_equals_the_loop_from_their_start(data_dir, detector,
                                                                      tmp_path):
    video = data_dir / "test_video.mp4"
    track = TrackConfig(every=3)
    expected = plain_loop(video, detector, track, tmp_path / "plain.jsonl", start=6, end=20,
                          first_output=10)
    stats = process_video(video, None, VideoPipeline(detector, track),
                          detections=tmp_path / "piped.jsonl", start=10, end=20, warmup=4)
    assert (tmp_path / "piped.jsonl").read_text() == expected
    assert [json.loads(line)["frame"] for line in expected.splitlines()] == list(range(10, 20))
    assert stats.frames == 10


@pytest.fixture(scope="module")
def b_frame_video(data_dir, tmp_path_factory):
    """The test video again with B-frames (x264 medium), which it has none of."""
    path = tmp_path_factory.mktemp("bframes") / "test_video_b.mp4"
    with VideoSource(data_dir / "test_video.mp4") as video, \
            av.open(str(path), "w") as container:
        stream = container.add_stream("libx264", rate=video.rate,
                                      options={"preset": "medium", "bf": "3", "crf": "18"})
        stream.width, stream.height, stream.pix_fmt = *video.size, "yuv420p"
        for frame in video.decoded_frames():
            # A fresh frame: a decoded one carries its picture type, which x264 keeps.
            fresh = av.VideoFrame.from_ndarray(frame.to_ndarray(), format="yuv420p")
            container.mux(stream.encode(fresh))
        container.mux(stream.encode(None))
    return path


@pytest.mark.parametrize("every", [2, 5])
def test_frames_left_undecoded_change_no_detection(b_frame_video, detector, tmp_path, every):
    track = TrackConfig(every=every)
    expected = plain_loop(b_frame_video, detector, track, tmp_path / "plain.jsonl")
    stats = process_video(b_frame_video, None, VideoPipeline(detector, track),
                          detections=tmp_path / "piped.jsonl")
    assert (tmp_path / "piped.jsonl").read_text() == expected
    assert stats.frames == 38 and stats.undecoded > 0
    assert f"{stats.undecoded} not looked at left undecoded" in stats.summary([])
    # With a video to write, every frame is decoded.
    stats = process_video(b_frame_video, tmp_path / "out.mp4", VideoPipeline(detector, track),
                          detections=tmp_path / "piped.jsonl")
    assert stats.undecoded == 0 and (tmp_path / "piped.jsonl").read_text() == expected


@pytest.mark.parametrize("track", [{"every": 5}, {"every": 3, "tracking": True}],
                         ids=["every 5", "every 3 + tracking"])
def test_annotated_frames_tracked_as_in_a_plain_loop(b_frame_video, detector, tmp_path,
                                                     monkeypatch, track):
    from fastdet.video import evaluate

    sources = record_sources(monkeypatch, evaluate)
    expected = plain_loop(b_frame_video, detector, TrackConfig(**track), tmp_path / "plain.jsonl")
    names = ["frame3", "frame10", "frame26", "frame37"]
    got = evaluate.track_annotated_frames(VideoPipeline(detector, TrackConfig(**track)),
                                          b_frame_video, names)
    lines = {line["frame"]: line for line in map(json.loads, expected.splitlines())}
    for name, detections in got.items():
        boxes = [box["box"] for box in lines[int(name[5:])]["boxes"]]
        assert detections.xyxy.tolist() == boxes, name
    assert sum(len(d) for d in got.values()) >= 4
    # Without tracking the frames between searches are left undecoded.
    assert (sources[0].frames_left_undecoded > 0) == ("tracking" not in track)


def test_annotated_output_keeps_size_rate_and_timestamps(data_dir, detector, tmp_path):
    out = tmp_path / "out.mp4"
    process_video(data_dir / "test_video.mp4", out, VideoPipeline(detector), end=6)
    with av.open(str(out)) as written, VideoSource(data_dir / "test_video.mp4", end=6) as video:
        stream = written.streams.video[0]
        assert (stream.codec_context.name, stream.codec_context.pix_fmt) == ("h264", "yuv420p")
        assert stream.average_rate == 25 and stream.codec_context.colorspace == 1   # BT.709 kept
        frames = [f.to_ndarray(format="bgr24") for f in written.decode(stream)]
        originals = list(video)
    assert len(frames) == 6
    # The boxes are drawn: some pixels changed a lot, most not at all.
    difference = np.abs(frames[0].astype(int) - originals[0]).max(axis=2)
    assert (difference > 100).sum() > 500 and np.median(difference) < 4


def test_callback_sees_every_frame_in_order(tmp_path):
    frames, _ = moving_block(9)
    path = tmp_path / "blocks.mp4"
    with VideoSink(path, 10.0, (frames[0].shape[1], frames[0].shape[0])) as sink:
        for frame in frames:
            sink.write(frame)
    seen = []
    stats = process_video(path, None, VideoPipeline(BlockDetector()),
                          callback=lambda index, detections: seen.append((index, len(detections))))
    assert [index for index, _ in seen] == list(range(9)) and stats.frames == 9
    assert all(count == 1 for _, count in seen)
    with pytest.raises(InputError, match="callback must be callable, got int"):
        process_video(path, None, VideoPipeline(BlockDetector()), callback=5)


@pytest.mark.parametrize("outputs, problem", [
    (lambda clip, folder: {"target": clip}, "it is the input"),
    (lambda clip, folder: {"target": folder / "link.mp4"}, "it is the input"),
    (lambda clip, folder: {"detections": clip}, "it is the input"),
    (lambda clip, folder: {"target": folder / "o.mp4", "detections": folder / "o.mp4"},
     "same file"),
    (lambda clip, folder: {"detections": folder / "run.toml", "config": folder / "run.toml"},
     "it is the input"),
])
def test_outputs_never_replace_the_input(tmp_path, outputs, problem):
    """The API refuses what ``fastdet run`` refuses: an output that would replace the
    video read (once, through the API, the input became its annotated copy), the
    config file or the other output; nothing is opened or written."""
    frames, _ = moving_block(4)
    clip = tmp_path / "clip.mp4"
    with VideoSink(clip, 10.0, (frames[0].shape[1], frames[0].shape[0])) as sink:
        for frame in frames:
            sink.write(frame)
    (tmp_path / "link.mp4").symlink_to(clip)
    (tmp_path / "run.toml").write_text("[track]\nevery = 1\n")
    before = {path.name: path.read_bytes() for path in tmp_path.iterdir()}
    arguments = outputs(clip, tmp_path)
    with pytest.raises(InputError, match=problem):
        process_video(clip, arguments.pop("target", None), VideoPipeline(BlockDetector()),
                      **arguments)
    assert {path.name: path.read_bytes() for path in tmp_path.iterdir()} == before


class SlowWarmUpDetector(BlockDetector):
    """A detector whose warm-up (the kernels' loading) takes a while, or fails."""

    def __init__(self, source_list, fail=False):
        super().__init__()
        self.source_list, self.fail = source_list, fail
        self.read_during_warm_up = None

    def warm_up(self, frame):
        # Until the decoder stops (queue full or video read), at most 5 s.
        source, deadline, still = self.source_list[0], time.monotonic() + 5, 0
        while time.monotonic() < deadline and still < 6:
            read = source.frames_read
            time.sleep(0.05)
            still = still + 1 if source.frames_read == read else 0
        self.read_during_warm_up = source.frames_read
        if self.fail:
            raise InputError("the kernels did not load")
        return 0.0


def block_video(path, n_frames):
    frames, _ = moving_block(n_frames)
    with VideoSink(path, 10.0, (frames[0].shape[1], frames[0].shape[0])) as sink:
        for frame in frames:
            sink.write(frame)
    return path


@pytest.mark.parametrize("every, least, most", [(5, 12, 30), (1, 2, 6)],
                         ids=["frames left out: a larger queue", "every frame: the usual 4"])
def test_decoding_starts_while_the_kernels_load(tmp_path, monkeypatch, every, least, most):
    import fastdet.video.run as run_module

    sources = record_sources(monkeypatch, run_module)
    path = block_video(tmp_path / "blocks.mp4", 30)
    detector = SlowWarmUpDetector(sources)
    seen = []
    stats = process_video(path, None, VideoPipeline(detector, TrackConfig(every=every)),
                          callback=lambda index, detections: seen.append(index))
    # Read at opening (1), queued (4, or 24 with pixels when most frames
    # travel without), and one in the decoder's hands.
    assert least <= detector.read_during_warm_up <= most
    assert seen == list(range(30)) and stats.frames == 30


def test_a_failed_warm_up_stops_the_decoder_and_leaves_no_output(tmp_path, monkeypatch):
    import threading

    import fastdet.video.run as run_module

    sources = record_sources(monkeypatch, run_module)
    path = block_video(tmp_path / "blocks.mp4", 60)
    with pytest.raises(InputError, match="did not load"):
        process_video(path, None, VideoPipeline(SlowWarmUpDetector(sources, fail=True)),
                      detections=tmp_path / "dets.jsonl")
    assert not [t for t in threading.enumerate() if t.name.startswith("fastdet-")]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["blocks.mp4"]


def test_an_error_in_a_stage_leaves_no_output(data_dir, detector, tmp_path):
    def fail(index, detections):
        if index == 4:
            raise InputError("the callback refuses frame 4")

    with pytest.raises(InputError, match="refuses frame 4"):
        process_video(data_dir / "test_video.mp4", tmp_path / "out.mp4",
                      VideoPipeline(detector), callback=fail,
                      detections=tmp_path / "dets.jsonl")
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_a_cut_input_is_processed_as_far_as_it_decodes(data_dir, detector, tmp_path):
    cut = tmp_path / "cut.mp4"
    cut.write_bytes((data_dir / "test_video.mp4").read_bytes()[:300_000])
    dets = tmp_path / "dets.jsonl"
    stats = process_video(cut, tmp_path / "out.mp4", VideoPipeline(detector), detections=dets)
    # The first 300 kB hold 4 whole frames, then part of a fifth that does not decode.
    assert stats.frames == 4 and [json.loads(line)["frame"] for line in
                                  dets.read_text().splitlines()] == [0, 1, 2, 3]
    assert stats.damage.startswith("input damaged: read 4 of 38 frames, decoding failed after "
                                   "frame 3 (Invalid data found when processing input")
    assert stats.damage in stats.summary([])
    with VideoSource(tmp_path / "out.mp4") as video:
        assert sum(1 for _ in video.decoded_frames()) == 4
    assert leftovers(tmp_path) == []


def test_a_cut_input_is_an_error_when_strict(data_dir, detector, tmp_path):
    cut = tmp_path / "cut.mp4"
    cut.write_bytes((data_dir / "test_video.mp4").read_bytes()[:300_000])
    with pytest.raises(InputError, match=r"cut.mp4: .*after frame 3"):
        process_video(cut, tmp_path / "out.mp4", VideoPipeline(detector),
                      detections=tmp_path / "dets.jsonl", strict=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cut.mp4"]


def test_realtime_drops_frames_when_processing_falls_behind(data_dir, tmp_path):
    slow = lambda index, detections: time.sleep(0.2)  # noqa: E731 - 5 fps against 25
    stats = process_video(data_dir / "test_video.mp4", None, VideoPipeline(BlockDetector()),
                          detections=tmp_path / "d.jsonl", callback=slow, realtime=True)
    assert stats.dropped > 0 and stats.frames + stats.dropped == 38
    frames = [json.loads(line)["frame"] for line in (tmp_path / "d.jsonl").read_text().splitlines()]
    assert frames == sorted(frames) and len(frames) == stats.frames and frames[0] == 0


# -- signals, on a real process -----------------------------------------------------------
#: ``fastdet run`` with each frame's processing slowed to 0.1 s, so that a run is still going,
#: and still draining its queues after a first signal, when the test sends its signals.
SLOW_RUN = """
import sys, time
from fastdet.video.pipeline import VideoPipeline
process = VideoPipeline.process
VideoPipeline.process = lambda self, frame: time.sleep(0.1) or process(self, frame)
from fastdet.cli import console_main
console_main(sys.argv[1:])
"""


def run_and_signal(args, folder, signals, gap=0.3):
    """Start a slowed ``fastdet run``, wait for its first detection line, send ``signals``."""
    command = [sys.executable, "-c", SLOW_RUN, "run", *args, "--quiet"]
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                               text=True, env=env, cwd=ROOT)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and process.poll() is None:
        # The detections file is written line by line: wait for its first frame.
        if any(p.stat().st_size > 0 for p in folder.iterdir() if p.suffix == ".jsonl"):
            break
        time.sleep(0.02)
    time.sleep(0.3)
    for signum in signals:
        process.send_signal(signum)
        time.sleep(gap)
    out, err = process.communicate(timeout=120)
    return process.returncode, out, err


@pytest.mark.parametrize("signum, code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_a_signal_completes_both_outputs(data_dir, tmp_path, signum, code):
    out, dets = tmp_path / "out.mp4", tmp_path / "dets.jsonl"
    returncode, stdout, stderr = run_and_signal(
        [str(data_dir / "test_video.mp4"), "--out", str(out), "--detections", str(dets)],
        tmp_path, [signum])
    assert returncode == code, stderr
    assert stdout.startswith("interrupted after ")
    lines = dets.read_text().splitlines()
    assert 0 < len(lines) < 38
    with VideoSource(out) as video:
        assert sum(1 for _ in video.decoded_frames()) == len(lines)
    assert leftovers(tmp_path) == []


def test_a_second_signal_aborts_and_leaves_nothing(data_dir, tmp_path):
    returncode, stdout, stderr = run_and_signal(
        [str(data_dir / "test_video.mp4"), "--out", str(tmp_path / "out.mp4"), "--detections",
         str(tmp_path / "dets.jsonl")], tmp_path, [signal.SIGINT, signal.SIGINT])
    assert returncode == 130, stderr
    assert stdout == "" and stderr == "fastdet: interrupted\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == []


@pytest.mark.parametrize("size", [(853, 480), (1281, 721)])
def test_odd_sized_input_is_padded_through_the_pipeline(tmp_path, size):
    from video_files import frame_number, write_clip

    clip = write_clip(tmp_path / "odd.mp4", 5, fps=25.0, size=size)
    process_video(clip, tmp_path / "out.mp4", VideoPipeline(BlockDetector()),
                  detections=tmp_path / "d.jsonl")
    with VideoSource(tmp_path / "out.mp4") as video:
        assert video.size == (size[0] + size[0] % 2, size[1] + size[1] % 2)
        assert [frame_number(f[:size[1], :size[0]]) for f in video] == list(range(5))


@pytest.mark.parametrize("track, cores", [({}, 4), ({"every": 3}, 8),
                                         ({"every": 3, "tracking": True}, 8)],
                         ids=["every frame", "every 3", "every 3 + tracking"])
def test_frames_scored_at_once_equal_a_plain_loop(data_dir, detector, tmp_path, track, cores):
    # Detections only on 4 cores (8 with --every 3, where decoding weighs
    # more): 2 detector threads (tests/video/test_stages.py), which score two
    # frames at once unless tracking needs them one at a time.
    video = data_dir / "test_video.mp4"
    expected = plain_loop(video, detector, TrackConfig(**track), tmp_path / "plain.jsonl")
    notes = []
    stats = process_video(video, None, VideoPipeline(detector, TrackConfig(**track)),
                          detections=tmp_path / "piped.jsonl", threads=cores, log=notes.append)
    assert (tmp_path / "piped.jsonl").read_text() == expected
    at_once = 1 if track.get("tracking") else 2
    assert stats.plan.detector == 2 and stats.plan.frames_at_once == at_once
    assert ("2 frames at once" in notes[0]) == (at_once == 2), notes


class OnlyHits:
    """A detector with ``hits`` but not the pipeline's other two methods."""

    def hits(self, frame):
        return None


@pytest.mark.parametrize("arguments, message", [
    ({"start": 1.5}, "start must be a whole number of frames, got 1.5"),
    ({"start": 2, "warmup": 0.5}, "warmup must be a whole number of frames, got 0.5"),
    ({"threads": 0}, "--threads must be 1-256, got 0"),
    ({"threads": 2.5}, "--threads must be a whole number of cores, got 2.5"),
    ({"threads": -4}, "--threads must be 1-256, got -4"),
    ({"detector": "model.npz"}, "detector must be a Detector or a VideoPipeline, not str"),
    # VideoPipeline's rule, as an InputError: one lacking some methods was its TypeError.
    ({"detector": OnlyHits()}, r"not OnlyHits \(OnlyHits lacks heat_region, boxes_from_heat"),
    ({"detector": BlockDetector}, r"not type \(detector must be an instance, got the class"),
    ({"progress": 5}, "progress must be callable, got int"),
    ({"log": "print"}, "log must be callable, got str"),
])
def test_process_video_refuses_arguments_it_would_truncate_or_trip_on(tmp_path, arguments,
                                                                      message):
    """start=1.5 began at frame 1 (int() before the source's check), threads=0 meant all
    cores and 2.5 two, a model path failed with an AttributeError mid-pipeline, and a
    progress that was no function with a TypeError on the first tick."""
    clip = block_video(tmp_path / "clip.mp4", 4)
    arguments.setdefault("detector", VideoPipeline(BlockDetector()))
    with pytest.raises(InputError, match=message):
        process_video(clip, tmp_path / "out.mp4", detections=tmp_path / "d.jsonl", **arguments)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["clip.mp4"]


def test_threads_have_an_upper_bound(tmp_path):
    """``threads=100000`` gave FFmpeg tens of thousands of decoder threads: "can't start new
    thread", or no frame decoded and a process that never ended.  The bound itself runs."""
    from fastdet.video.stages import MAX_THREADS

    clip = block_video(tmp_path / "clip.mp4", 4)
    with pytest.raises(InputError, match=f"--threads must be 1-{MAX_THREADS}, got 100000"):
        process_video(clip, tmp_path / "out.mp4", VideoPipeline(BlockDetector()),
                      threads=100000)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["clip.mp4"]
    stats = process_video(clip, tmp_path / "out.mp4", VideoPipeline(BlockDetector()),
                          threads=MAX_THREADS)
    assert stats.frames == 4 and stats.plan.cores == MAX_THREADS


def test_a_source_closed_or_partly_read_is_refused(tmp_path):
    """Its frames were counted from its start and its first frame (gone) warmed up the
    kernels: "a frame must be a numpy array, got NoneType"."""
    clip = block_video(tmp_path / "clip.mp4", 4)
    closed = VideoSource(clip)
    closed.close()
    with pytest.raises(InputError, match="clip.mp4 is closed"):
        process_video(closed, None, VideoPipeline(BlockDetector()), detections=tmp_path / "d")
    with VideoSource(clip) as started:
        next(iter(started))
        with pytest.raises(InputError, match="1 frames were read already"):
            process_video(started, None, VideoPipeline(BlockDetector()),
                          detections=tmp_path / "d")
    assert not (tmp_path / "d").exists()


@pytest.mark.parametrize("track", [{}, {"every": 3, "tracking": True}],
                         ids=["every frame", "every 3 + tracking"])
def test_a_pipeline_used_again_starts_afresh(tmp_path, track):
    """A second video through the same VideoPipeline began with the first one's smoothed
    heat, tracks and ids: its detections were not those of a fresh run."""
    clip = block_video(tmp_path / "clip.mp4", 9)
    pipeline = VideoPipeline(BlockDetector(), TrackConfig(**track))
    outputs = []
    for name in ("first.jsonl", "second.jsonl"):
        process_video(clip, None, pipeline, detections=tmp_path / name)
        outputs.append((tmp_path / name).read_text())
    assert outputs[0] == outputs[1]
    assert '"track": 1' in outputs[1]
