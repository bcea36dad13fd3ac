"""``fastdet run ... --detections - | head``: a run whose stdout reader goes away stops quietly.

Exit status 141 (128 + SIGPIPE, what a Unix tool ended by ``head`` returns)
and no message, as for every verb (``fastdet.cli.app``); ``run`` also stops
reading at once and completes its other output with the frames read, as
after Ctrl-C.  A FIFO's reader going away stays an error.  ``--realtime``
reads the 38-frame test video at its own 25 fps, so the run is still writing
when the reader leaves.
"""

from __future__ import annotations

import os
import subprocess
import sys
import threading

import av

FASTDET = [sys.executable, "-m", "fastdet.cli"]
EXIT_READER_GONE = 141
TEST_VIDEO_FRAMES = 38


def start_run(data_dir, *options, stdout=subprocess.PIPE):
    return subprocess.Popen([*FASTDET, "run", str(data_dir / "test_video.mp4"), "--realtime",
                             *options], stdout=stdout, stderr=subprocess.PIPE)


def test_detections_on_stdout_stop_quietly_and_the_video_is_kept(data_dir, tmp_path):
    video = tmp_path / "out.mp4"
    run = start_run(data_dir, "--detections", "-", "--format", "csv", "--out", str(video))
    assert run.stdout.readline().startswith(b"frame,track")
    run.stdout.close()                               # what head -1 does
    err = run.stderr.read()
    assert run.wait(60) == EXIT_READER_GONE and err == b""
    with av.open(str(video)) as container:
        assert 0 < len(list(container.decode(video=0))) < TEST_VIDEO_FRAMES


def test_a_video_on_stdout_stops_quietly_and_the_detections_are_kept(data_dir, tmp_path):
    detections = tmp_path / "d.jsonl"
    run = start_run(data_dir, "--out", "-", "--detections", str(detections))
    assert len(run.stdout.read(100)) == 100
    run.stdout.close()
    err = run.stderr.read()
    assert run.wait(60) == EXIT_READER_GONE and err == b""
    # Fragmented MP4 leaves a keyframe's group at a time: here all of it at the end.
    assert 0 < len(detections.read_text().splitlines()) <= TEST_VIDEO_FRAMES


def test_a_pipe_closed_before_the_run_starts(data_dir):
    read, write = os.pipe()
    os.close(read)
    try:
        run = start_run(data_dir, "--detections", "-", "--end", "2", stdout=write)
    finally:
        os.close(write)
    err = run.stderr.read()
    assert run.wait(60) == EXIT_READER_GONE and err == b""


def test_a_fifo_whose_reader_leaves_is_still_an_error(data_dir, tmp_path):
    fifo = tmp_path / "dets"
    os.mkfifo(fifo)

    def read_one_line():
        with open(fifo, "rb") as reader:
            reader.readline()

    threading.Thread(target=read_one_line, daemon=True).start()
    run = start_run(data_dir, "--detections", str(fifo), "--format", "csv")
    err = run.stderr.read().decode()
    assert run.wait(60) == 2
    assert err.startswith(f"fastdet: error: cannot write {fifo}: Broken pipe")
    assert err.count("\n") == 1
