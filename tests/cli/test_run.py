"""Tests for ``fastdet run`` (``fastdet.cli.run``) through ``fastdet.cli.app.main``."""

from __future__ import annotations

import argparse
import io
import json
import re
import shutil
import socket

import av
import cv2
import numpy as np
import pytest
from video_files import UdpSender, free_port, mpegts_bytes
from video_stubs import BlockDetector, bundled_model_path, moving_block

from fastdet.cli import app as cli
from fastdet.cli import run as commands_run
from fastdet.cli.run import ProgressBar, add_run_parser, default_output
from fastdet.video.config import TrackConfig
from fastdet.video.pipeline import VideoPipeline
from fastdet.video.sink import VideoSink


@pytest.fixture
def fastdet(monkeypatch):
    """``fastdet.cli.app.main`` with the ``run`` command registered (until cli.py wires it)."""
    parser = cli.build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    if "run" not in sub.choices:
        add_run_parser(sub)
        monkeypatch.setattr(cli, "build_parser", lambda: parser)
    return cli.main


@pytest.fixture
def model_args():
    path = bundled_model_path()
    return [] if path is None else ["--model", path]


@pytest.fixture
def stub_pipeline(monkeypatch):
    """Make ``run`` use the block-finding stub detector instead of a model."""
    def build(args):
        config = TrackConfig(every=args.every, tracking=args.track)
        return VideoPipeline(BlockDetector(), config)
    monkeypatch.setattr(commands_run, "_pipeline", build)


@pytest.fixture(scope="module")
def block_video(tmp_path_factory):
    """A 12-frame mp4 of one textured block moving right (the stub detector finds it)."""
    path = tmp_path_factory.mktemp("blocks") / "blocks.mp4"
    frames, _ = moving_block(12)
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 10.0, (200, 120))
    for frame in frames:
        writer.write(frame)
    writer.release()
    return path


def video_frames(path):
    capture = cv2.VideoCapture(str(path))
    assert capture.isOpened()
    count = 0
    while capture.read()[0]:
        count += 1
    size = (int(capture.get(cv2.CAP_PROP_FRAME_WIDTH)),
            int(capture.get(cv2.CAP_PROP_FRAME_HEIGHT)))
    return count, size, capture.get(cv2.CAP_PROP_FPS)


def leftovers(folder):
    return sorted(p.name for p in folder.iterdir() if ".part" in p.name)


# -- the real video ------------------------------------------------------------------
def test_run_writes_annotated_video_and_detections(fastdet, model_args, data_dir, tmp_path,
                                                   capsys):
    out, dets = tmp_path / "out.mp4", tmp_path / "dets.jsonl"
    code = fastdet(["run", str(data_dir / "test_video.mp4"), "--out", str(out),
                    "--detections", str(dets), "--threads", "1", *model_args])
    assert code == 0
    assert video_frames(out) == (38, (1280, 720), pytest.approx(25.0))
    lines = [json.loads(line) for line in dets.read_text().splitlines()]
    assert [line["frame"] for line in lines] == list(range(38))
    # The two cars: the black one stays near x = 880, the white one drifts
    # right from x = 1100 to 1185.  Each is boxed in every frame, by one id.
    ids = {"black": set(), "white": set()}
    for line in lines:
        i = line["frame"]
        for car, point in (("black", (880, 455)), ("white", (1100 + 85 * i / 37, 455))):
            covering = [b["track"] for b in line["boxes"]
                        if b["box"][0] <= point[0] < b["box"][2]
                        and b["box"][1] <= point[1] < b["box"][3]]
            assert covering, f"{car} car not boxed in frame {i}"
            ids[car].update(covering)
    assert len(ids["black"]) == 1 and len(ids["white"]) == 1 and ids["black"] != ids["white"]
    summary = capsys.readouterr().out.strip().splitlines()
    assert len(summary) == 1
    assert summary[0].startswith("38 frames, ") and "ms/frame: decode" in summary[0]


def test_run_output_is_h264_yuv420p_with_the_index_first(fastdet, model_args, data_dir,
                                                         tmp_path):
    out = tmp_path / "out.mp4"
    assert fastdet(["run", str(data_dir / "test_video.mp4"), "--out", str(out), "--quiet",
                    *model_args]) == 0
    with av.open(str(out)) as container:
        stream = container.streams.video[0]
        assert stream.codec_context.name == "h264"
        assert stream.codec_context.pix_fmt == "yuv420p"
        assert sum(1 for _ in container.decode(stream)) == 38
    data = out.read_bytes()
    # Top-level boxes: the index (moov) precedes the media data (mdat), so browsers stream it.
    boxes, offset = [], 0
    while offset + 8 <= len(data):
        size = int.from_bytes(data[offset:offset + 4], "big")
        boxes.append(data[offset + 4:offset + 8].decode("latin-1"))
        offset += size
    assert boxes[0] == "ftyp" and boxes.index("moov") < boxes.index("mdat")


def test_run_reads_a_udp_stream_and_prints_the_plan(fastdet, stub_pipeline, tmp_path, capsys):
    h264 = tmp_path / "blocks.mp4"    # H.264 repeats its headers: a receiver may join late
    frames, _ = moving_block(12)
    with VideoSink(h264, 10.0, (frames[0].shape[1], frames[0].shape[0])) as sink:
        for frame in frames:
            sink.write(frame)
    port = free_port(socket.SOCK_DGRAM)
    dets = tmp_path / "d.jsonl"
    with UdpSender(mpegts_bytes(h264), port, seconds=3.0):
        code = fastdet(["--verbose", "run", f"udp://127.0.0.1:{port}", "--detections", str(dets),
                        "--timeout", "1.5"])
    assert code == 0
    captured = capsys.readouterr()
    assert "threads: " in captured.err and "decoder" in captured.err
    assert "stream ended" in captured.out
    assert len(dets.read_text().splitlines()) >= 12


@pytest.mark.parametrize("options", [["--every", "5"], ["--track"]])
def test_run_modes_on_the_real_video(fastdet, model_args, data_dir, tmp_path, options):
    dets = tmp_path / "dets.csv"
    code = fastdet(["run", str(data_dir / "test_video.mp4"), "--detections", str(dets),
                    "--end", "12", "--quiet", *options, *model_args])
    assert code == 0
    rows = dets.read_text().splitlines()
    assert rows[0] == "frame,track,x1,y1,x2,y2,score"
    assert {int(row.split(",")[0]) for row in rows[1:]} == set(range(12))


# -- outputs and options (stub detector) ---------------------------------------------------
def test_default_output_beside_the_input(fastdet, stub_pipeline, block_video, tmp_path, capsys):
    video = tmp_path / "clip.mp4"
    shutil.copy(block_video, video)
    assert fastdet(["run", str(video)]) == 0
    expected = tmp_path / "clip_fastdet.mp4"
    assert default_output(video) == expected
    assert video_frames(expected)[:2] == (12, (200, 120))
    captured = capsys.readouterr()
    assert f"writing {expected}" in captured.err
    assert captured.out.startswith("12 frames, 12 detections, 1 tracks")


@pytest.mark.parametrize("fmt, first_row", [
    ("jsonl", r'\{"frame": 3, "boxes": \[\{"box": \[3\d, 4\d, 7\d, 7\d\], "score": 2.0, '
              r'"track": 1\}\]\}'),
    ("csv", r"frame,track,x1,y1,x2,y2,score"),
    ("mot", r"4,1,3\d,4\d,4\d,3\d,2.0000,-1,-1,-1"),  # frames from 1; width, height
])
def test_formats_and_start_end(fastdet, stub_pipeline, block_video, tmp_path, fmt, first_row):
    dets = tmp_path / "dets.out"
    code = fastdet(["run", str(block_video), "--detections", str(dets), "--format", fmt,
                    "--start", "3", "--end", "6", "--quiet"])
    assert code == 0
    rows = dets.read_text().splitlines()
    assert re.fullmatch(first_row, rows[0])
    assert len(rows) == 3 + (fmt == "csv")
    assert not (tmp_path / "dets_fastdet.mp4").exists()


def test_every_and_track_reach_the_pipeline(fastdet, stub_pipeline, block_video, tmp_path,
                                            capsys):
    for options, searches in ((["--every", "4"], 3), (["--track"], 1)):
        assert fastdet(["run", str(block_video), "--detections", str(tmp_path / "d.jsonl"),
                        "-q", *options]) == 0
        assert f"{searches} full searches" in capsys.readouterr().out


def test_quiet_and_non_terminal_runs_print_no_progress(fastdet, stub_pipeline, block_video,
                                                      tmp_path, capsys):
    assert fastdet(["run", str(block_video), "--out", str(tmp_path / "o.mp4")]) == 0
    assert capsys.readouterr().err == ""     # stderr is not a terminal here


def test_progress_bar_shows_frames_fps_and_time_left(monkeypatch):
    clock = iter(float(t) for t in range(100))
    monkeypatch.setattr("tqdm.std.time", lambda: next(clock))   # one second per call
    stream = io.StringIO()
    bar = ProgressBar(enabled=True, stream=stream)
    bar.update(4, 10)
    bar.update(8, 10)
    shown = stream.getvalue().split("\r")[-1]
    assert "8/10" in shown and "frames/s" in shown and "<00:" in shown   # time left
    bar.close()
    live = io.StringIO()
    bar = ProgressBar(enabled=True, stream=live)
    bar.update(4, None)
    bar.update(9, None)
    shown = live.getvalue().split("\r")[-1]
    assert "9 frames" in shown and "frames/s" in shown and "<" not in shown   # no end, no ETA
    bar.close()
    silent = io.StringIO()
    ProgressBar(enabled=False, stream=silent).update(4, 10)
    assert silent.getvalue() == ""


# -- bad input: one line, non-zero exit, no output ------------------------------------------
def expect_error(fastdet, argv, capsys, message, folder):
    before = sorted(p.name for p in folder.iterdir())
    code = fastdet(argv)
    err = capsys.readouterr().err
    assert code == cli.EXIT_ERROR
    assert err.count("\n") == 1 and err.startswith("fastdet: error: ")
    assert message in err
    assert sorted(p.name for p in folder.iterdir()) == before


def test_error_missing_file(fastdet, stub_pipeline, tmp_path, capsys):
    expect_error(fastdet, ["run", str(tmp_path / "nope.mp4")], capsys, "video not found",
                 tmp_path)


def test_error_not_a_video(fastdet, stub_pipeline, tmp_path, capsys):
    path = tmp_path / "text.mp4"
    path.write_text("hello")
    expect_error(fastdet, ["run", str(path)], capsys, "as a video", tmp_path)


def test_error_zero_frames(fastdet, stub_pipeline, tmp_path, capsys):
    path = tmp_path / "empty.avi"
    cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 25.0, (64, 48)).release()
    expect_error(fastdet, ["run", str(path)], capsys, "holds no frames", tmp_path)


def test_error_unwritable_output(fastdet, stub_pipeline, block_video, tmp_path, capsys):
    expect_error(fastdet, ["run", str(block_video), "--out", str(tmp_path / "no" / "o.mp4")],
                 capsys, "cannot write", tmp_path)
    expect_error(fastdet, ["run", str(block_video), "--detections", str(tmp_path)],
                 capsys, "is a directory", tmp_path)


def test_a_webm_out_without_a_codec_is_vp9_and_plays(fastdet, stub_pipeline, block_video,
                                                     tmp_path, capsys):
    """``--out a.webm`` failed at once: "'webm' format does not support 'libx264' codec"."""
    out = tmp_path / "a.webm"
    assert fastdet(["run", str(block_video), "--out", str(out), "--quiet"]) == 0
    assert leftovers(tmp_path) == []
    with av.open(str(out)) as container:
        stream = container.streams.video[0]
        assert stream.codec_context.name == "vp9"
        sizes = [(f.width, f.height) for f in container.decode(stream)]
    assert sizes == [(200, 120)] * 12
    # A codec WebM cannot hold, given explicitly: refused before any output, saying what would do.
    expect_error(fastdet, ["run", str(block_video), "--out", str(tmp_path / "b.webm"),
                           "--codec", "mp4v"], capsys,
                 "the WebM format cannot hold mp4v (use --codec vp9 or av1, or write .mp4 or "
                 ".mkv)", tmp_path)
    expect_error(fastdet, ["run", str(block_video), "--out", str(tmp_path / "b.avi"),
                           "--codec", "hevc"], capsys,
                 "the AVI format cannot hold hevc (use --codec h264, mp4v, av1 or vp9", tmp_path)


def test_an_out_named_only_by_its_suffix_is_named_as_such(fastdet, stub_pipeline, block_video,
                                                          tmp_path, capsys):
    """``--out .mp4`` said "unsupported suffix"."""
    expect_error(fastdet, ["run", str(block_video), "--out", str(tmp_path / ".mp4")], capsys,
                 ".mp4 is a hidden file's name with no suffix (its dot starts the name); name "
                 "the video, e.g. video.mp4", tmp_path)


def test_error_start_past_the_end(fastdet, stub_pipeline, block_video, tmp_path, capsys):
    expect_error(fastdet, ["run", str(block_video), "--start", "12", "--out",
                           str(tmp_path / "o.mp4")], capsys, "--start 12 is past the end",
                 tmp_path)


def test_error_output_would_overwrite_input(fastdet, stub_pipeline, block_video, tmp_path,
                                           capsys):
    expect_error(fastdet, ["run", str(block_video), "--out", str(block_video)], capsys,
                 "it is the input", tmp_path)


def test_error_bad_every(fastdet, block_video, tmp_path, capsys):
    expect_error(fastdet, ["run", str(block_video), "--every", "0", "--out",
                           str(tmp_path / "o.mp4")], capsys, "--every must be at least 1",
                 tmp_path)


# -- Ctrl-C ----------------------------------------------------------------------------------
def test_ctrl_c_completes_both_outputs(fastdet, monkeypatch, block_video, tmp_path, capsys):
    class Interrupted(VideoPipeline):
        def process(self, frame):
            if self.frames == 5:
                raise KeyboardInterrupt
            return super().process(frame)

    monkeypatch.setattr(commands_run, "_pipeline",
                        lambda args: Interrupted(BlockDetector(), TrackConfig()))
    out, dets = tmp_path / "o.mp4", tmp_path / "d.jsonl"
    code = fastdet(["run", str(block_video), "--out", str(out), "--detections", str(dets)])
    assert code == cli.EXIT_INTERRUPTED
    assert video_frames(out)[0] == 5
    assert [json.loads(line)["frame"] for line in dets.read_text().splitlines()] == list(range(5))
    assert leftovers(tmp_path) == []
    captured = capsys.readouterr()
    assert captured.out.startswith("interrupted after 5 frames")
    assert "interrupted" in captured.err


def test_ctrl_c_before_any_frame_leaves_no_output(fastdet, monkeypatch, block_video, tmp_path):
    class Interrupted(VideoPipeline):
        def process(self, frame):
            raise KeyboardInterrupt

    monkeypatch.setattr(commands_run, "_pipeline",
                        lambda args: Interrupted(BlockDetector(), TrackConfig()))
    out, dets = tmp_path / "o.mp4", tmp_path / "d.jsonl"
    assert fastdet(["run", str(block_video), "--out", str(out), "--detections", str(dets)]) == 130
    # A video without frames is not a video; the detections file goes with it, so the two
    # outputs always hold the same frames.
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_pipeline_frames_are_numbered_from_the_video_start(stub_pipeline, block_video):
    frames, _ = moving_block(3)
    indices = [i for i, *_ in VideoPipeline(BlockDetector())(frames, first_index=7)]
    assert indices == [7, 8, 9]
    assert np.all(np.asarray(indices) >= 7)


def test_debug_view_draws_heat_inset_and_timings(fastdet, model_args, data_dir, tmp_path):
    plain, debug = tmp_path / "plain.mp4", tmp_path / "debug.mp4"
    for out, extra in ((plain, []), (debug, ["--debug-view"])):
        code = fastdet(["run", str(data_dir / "test_video.mp4"), "--out", str(out), "--end", "3",
                        "--quiet", *extra, *model_args])
        assert code == 0
    assert video_frames(debug)[:2] == (3, (1280, 720))
    a = cv2.VideoCapture(str(plain)).read()[1].astype(int)
    b = cv2.VideoCapture(str(debug)).read()[1].astype(int)
    # The inset sits in the top-right corner and the timings in the top-left one.
    assert np.abs(a[:100, -300:] - b[:100, -300:]).mean() > 10
    assert np.abs(a[:60, :150] - b[:60, :150]).mean() > 10


def test_more_threads_than_a_run_can_use_is_a_one_line_error(fastdet, stub_pipeline,
                                                             block_video, tmp_path, capsys):
    """``--threads 100000`` planned tens of thousands of decoder threads: "holds no frames"
    and a process that never ended, or "internal error: can't start new thread"."""
    out = tmp_path / "out.mp4"
    assert fastdet(["run", str(block_video), "--out", str(out), "--threads", "100000"]) == 2
    assert capsys.readouterr().err == "fastdet: error: --threads must be 1-256, got 100000\n"
    assert list(tmp_path.iterdir()) == []
