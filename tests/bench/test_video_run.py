"""Tests for ``fastdet.bench.video_run``: the input it makes, its runs and its report."""

from __future__ import annotations

import numpy as np
import pytest

from fastdet.bench.video_run import (MODES, ModeResult, VideoBenchmark, fastdet_run,
                                     format_video_benchmark, looped_video, opencv_decode_rate,
                                     pingpong)
from fastdet.video.source import VideoSource


def test_pingpong_loops_forward_and_back():
    assert [pingpong(i, 4) for i in range(10)] == [0, 1, 2, 3, 2, 1, 0, 1, 2, 3]


def test_looped_video_is_the_clip_forward_and_back(data_dir, tmp_path):
    path = looped_video(data_dir / "test_video.mp4", frames=40, folder=tmp_path)
    assert looped_video(data_dir / "test_video.mp4", frames=40, folder=tmp_path) == path
    with VideoSource(path) as looped, VideoSource(data_dir / "test_video.mp4") as clip:
        assert looped.frame_count == 40 and looped.fps == clip.fps
        frames, originals = list(looped), list(clip)
    # Frames 37, 38, 39 are the clip's 37, 36, 35: the loop turns back.
    for index, source in ((0, 0), (37, 37), (38, 36), (39, 35)):
        assert np.abs(frames[index].astype(int) - originals[source]).mean() < 3


def test_runs_report_fps_stages_and_memory(data_dir, tmp_path):
    rate, cpu_ms, frames = opencv_decode_rate(data_dir / "test_video.mp4")
    assert frames == 38 and rate > 0 and cpu_ms > 0
    run, done, stages, bound = fastdet_run(data_dir / "test_video.mp4", MODES[0][1],
                                           folder=tmp_path)
    assert done == 38 and run.wall > 0 and run.cpu > 0 and run.peak_rss_mib > 50
    assert {"decode", "detect", "encode", "write"} <= set(stages)
    assert bound in stages
    assert (tmp_path / "out.mp4").exists() and (tmp_path / "dets.jsonl").exists()


def test_report_compares_each_mode_with_its_target():
    modes = [ModeResult("fast", 0.5, fps=[150.0], ratios=[0.6], stages=[{"decode": 3.0}],
                        bounds=["decode"], cpu_per_frame_ms=[9.0], peak_rss_mib=[300.0]),
             ModeResult("slow", 1.2, fps=[100.0], ratios=[0.4], stages=[{"decode": 3.0}],
                        bounds=["detect"], cpu_per_frame_ms=[12.0], peak_rss_mib=[300.0])]
    report = format_video_benchmark(
        VideoBenchmark("in.mp4", 1000, [250.0], [4.0], modes, (3.0, 0, 0), (3.5, 0, 0),
                       rss_short_mib=300.0, rss_long_mib=306.0), cores=2)
    lines = report.splitlines()
    assert "| fast | 150.0 | 0.60 | 0.50 | yes | 9.0 | 0.89 | decode |" in lines
    assert "| slow | 100.0 | 0.40 | 1.20 | no | 12.0 | 0.67 | detect |" in lines
    assert "R = OpenCV single-thread decode-only rate, median 250.0 fps" in report
    assert "(+2.0%)" in report


@pytest.mark.parametrize("label", [label for label, _, _ in MODES])
def test_every_mode_has_a_target(label):
    target = dict((name, goal) for name, _, goal in MODES)[label]
    assert 0 < target < 2
