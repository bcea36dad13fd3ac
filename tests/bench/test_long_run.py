"""Tests for ``fastdet.bench.long_run``: sampling a live ``fastdet run`` and its report."""

from __future__ import annotations

import os
import subprocess
import sys
import time

from fastdet.bench.long_run import (ResourceSample, format_long_run, long_run_profile,
                                    process_resources)
from fastdet.bench.video_run import looped_video


def test_process_resources_sees_files_a_process_opens(tmp_path):
    child = subprocess.Popen(
        [sys.executable, "-c",
         "import sys; handles = [open(sys.argv[1], 'w') for _ in range(7)]; sys.stdin.read()",
         str(tmp_path / "f")], stdin=subprocess.PIPE)
    try:
        rss, peak, threads, before = process_resources(os.getpid())
        assert 0 < rss <= peak and threads >= 1 and before >= 3
        for _ in range(200):
            if len(os.listdir(f"/proc/{child.pid}/fd")) >= 10:
                break
            time.sleep(0.02)
        assert process_resources(child.pid)[3] == 3 + 7   # stdin, stdout, stderr and 7
    finally:
        child.communicate(b"")


def test_profile_of_a_real_run_has_a_row_per_step(data_dir, tmp_path):
    video = looped_video(data_dir / "test_video.mp4", 60, tmp_path, preset="ultrafast")
    samples = long_run_profile(video, every=20, options=("--every", "5"), interval=0.01)
    steps = [sample.frames for sample in samples if not sample.closing]
    # One row as each multiple of 20 is passed (sampling may see a frame or two later).
    assert len(steps) >= 2 and all(20 * (k + 1) <= n < 20 * (k + 1) + 20
                                   for k, n in enumerate(steps))
    assert all(s.rss_mib > 50 and s.open_files >= 3 and s.threads >= 1 for s in samples)


def test_report_shows_growth_while_frames_flowed():
    samples = [ResourceSample(1000, 10.0, 300.0, 301.0, 6, 10),
               ResourceSample(2000, 20.0, 302.5, 303.0, 6, 10),
               ResourceSample(2010, 20.2, 280.0, 303.0, 3, 6, closing=True)]
    report = format_long_run(samples)
    assert "2010 (end)" in report
    assert ("From 1000 to 2000 frames: RSS +2.5 MiB, peak RSS +2.0 MiB, open files +0, "
            "threads +0.") in report
