"""Tests for ``fastdet.video.source``: files, HTTP, UDP and cameras, with one-line errors.

Network tests talk only to 127.0.0.1 and are bounded in time: an HTTP server
thread serves the shared test video, a sender thread streams MPEG-TS over UDP.
"""

from __future__ import annotations

import functools
import http.server
import socket
import threading
import time

import cv2
import numpy as np
import pytest

from fastdet.errors import InputError
from fastdet.video.frame_arrays import FrameConverter
from fastdet.video.source import VideoSource
from video_files import (SIZE, UdpSender, frame_number, free_port, mpegts_bytes,
                         numbered_frame, write_clip)


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    """A 10-frame mp4 whose frame i has grey level 20 * i + 10."""
    return write_clip(tmp_path_factory.mktemp("video") / "clip.mp4", 10, fps=12.0)


# -- files -----------------------------------------------------------------------
def test_source_streams_every_frame_with_metadata(clip):
    with VideoSource(clip) as video:
        assert video.size == SIZE
        assert video.fps == pytest.approx(12.0)
        assert video.frame_count == 10 and video.expected_frames == 10
        assert not video.live
        numbers = [frame_number(frame) for frame in video]
    assert numbers == list(range(10))


@pytest.mark.parametrize("start, end", [(0, None), (3, None), (3, 7), (9, None), (0, 1),
                                        (8, 50)])
def test_source_start_and_end(clip, start, end):
    with VideoSource(clip, start=start, end=end) as video:
        numbers = [frame_number(frame) for frame in video]
        assert video.expected_frames == len(numbers)
    assert numbers == list(range(start, min(end or 10, 10)))


def test_source_gives_opencv_pixels_on_the_real_video(data_dir):
    capture = cv2.VideoCapture(str(data_dir / "test_video.mp4"))
    with VideoSource(data_dir / "test_video.mp4") as video:
        assert video.size == (1280, 720) and video.frame_count == 38
        count = 0
        for frame in video:
            ok, expected = capture.read()
            assert ok and np.array_equal(frame, expected)
            count += 1
    capture.release()
    assert count == 38


def test_band_conversion_is_the_full_conversion_on_its_rows(data_dir):
    converter = FrameConverter()
    with VideoSource(data_dir / "test_video.mp4", end=6) as video:
        for frame in video.decoded_frames():
            full = converter.to_bgr(frame)
            for rows in ((360, 618), (361, 617), (0, 3), (715, 720)):
                band = converter.to_bgr(frame, rows)
                assert np.array_equal(band[rows[0]:rows[1]], full[rows[0]:rows[1]])


def test_missing_file(tmp_path):
    with pytest.raises(InputError, match="video not found: .*nope.mp4"):
        VideoSource(tmp_path / "nope.mp4")


def test_file_that_is_not_a_video(tmp_path, capfd):
    path = tmp_path / "notes.mp4"
    path.write_text("these are not moving pictures\n")
    with pytest.raises(InputError, match="cannot read .*notes.mp4 as a video"):
        VideoSource(path)
    # FFmpeg's own complaints are kept off the terminal: one line, ours.
    assert capfd.readouterr().err == ""


def test_image_is_not_a_video(tmp_path):
    path = tmp_path / "still.png"
    cv2.imwrite(str(path), numbered_frame(1))
    with pytest.raises(InputError, match="is an image, not a video"):
        VideoSource(path)


def test_directory_is_not_a_video(tmp_path):
    with pytest.raises(InputError, match="not a video file"):
        VideoSource(tmp_path)


def test_video_with_zero_frames(tmp_path):
    path = tmp_path / "empty.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 25.0, SIZE)
    writer.release()
    with pytest.raises(InputError, match="empty.avi"):
        VideoSource(path)


def test_truncated_file_fails_after_its_good_frames(data_dir, tmp_path):
    path = tmp_path / "cut.mp4"
    path.write_bytes((data_dir / "test_video.mp4").read_bytes()[:300_000])
    with VideoSource(path) as video:
        frames = []
        with pytest.raises(InputError, match=r"cut.mp4: .* after frame \d+"):
            for frame in video:
                frames.append(frame)
    assert 0 < len(frames) < 38


def test_start_past_the_end(clip):
    message = r"--start 10 is past the end of .*clip.mp4 \(10 frames\)"
    with pytest.raises(InputError, match=message):
        VideoSource(clip, start=10)


@pytest.mark.parametrize("start, end, message", [(-1, None, "--start must be >= 0"),
                                                 (5, 5, "--end .5. must be greater")])
def test_bad_ranges(clip, start, end, message):
    with pytest.raises(InputError, match=message):
        VideoSource(clip, start=start, end=end)


def test_frames_can_skip_conversion(clip):
    with VideoSource(clip) as video:
        got = [None if f is None else frame_number(f)
               for f in video.frames(skip=iter([True, False] * 5).__next__)]
    # The first frame is read at opening to validate the file; skip() is
    # asked from the second frame on.
    assert got == [0, None, 2, None, 4, None, 6, None, 8, None]


def test_closed_source_says_so(clip):
    video = VideoSource(clip)
    video.close()
    with pytest.raises(InputError, match="is closed"):
        list(video)


def test_timestamps_of_a_2997_fps_video(tmp_path):
    path = write_clip(tmp_path / "ntsc.mp4", 6, fps=30000 / 1001)
    with VideoSource(path) as video:
        assert video.rate == pytest.approx(30000 / 1001)
        times = [float(frame.pts * video.time_base) for frame in video.decoded_frames()]
    assert times == pytest.approx([i * 1001 / 30000 for i in range(6)], abs=1e-4)


# -- cameras -------------------------------------------------------------------------
@pytest.mark.parametrize("camera", ["/dev/video97", "97", 97])
def test_missing_camera(camera):
    with pytest.raises(InputError, match="no camera at /dev/video97"):
        VideoSource(camera)


# -- HTTP ----------------------------------------------------------------------------
class _QuietHandler(http.server.SimpleHTTPRequestHandler):
    def log_message(self, *args):
        pass


@pytest.fixture
def http_root(data_dir):
    """``http://127.0.0.1:PORT/`` serving the shared data folder, stopped after the test."""
    handler = functools.partial(_QuietHandler, directory=str(data_dir))
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}"
    finally:
        server.shutdown()
        server.server_close()
        thread.join(5)


def test_http_source_reads_every_frame(http_root):
    with VideoSource(f"{http_root}/test_video.mp4", timeout=5) as video:
        assert video.size == (1280, 720) and not video.live and video.frame_count == 38
        assert sum(1 for _ in video.decoded_frames()) == 38


def test_http_not_found_is_one_line(http_root):
    with pytest.raises(InputError, match=r"cannot open http://.*/missing.mp4: .*404"):
        VideoSource(f"{http_root}/missing.mp4", timeout=5)


def test_refused_connection_is_one_line():
    port = free_port(socket.SOCK_STREAM)
    with pytest.raises(InputError, match=r"cannot open http://127.0.0.1:\d+/v.mp4: .*refused"):
        VideoSource(f"http://127.0.0.1:{port}/v.mp4", timeout=2)


# -- UDP -----------------------------------------------------------------------------
@pytest.fixture(scope="module")
def transport_stream(data_dir):
    return mpegts_bytes(data_dir / "test_video.mp4")


def test_udp_stream_is_live_and_ends_when_the_sender_stops(transport_stream):
    port = free_port(socket.SOCK_DGRAM)
    with UdpSender(transport_stream, port, seconds=3.0) as sender:
        started = time.monotonic()
        with VideoSource(f"udp://127.0.0.1:{port}", timeout=1.5) as video:
            assert video.live and video.frame_count is None and video.expected_frames is None
            assert video.size == (1280, 720) and video.fps == pytest.approx(25.0)
            frames = 0
            for frame in video:
                assert frame.shape == (720, 1280, 3)
                frames += 1
                if frames == 20:
                    sender.stop.set()
            assert "stream ended" in video.ended
    assert frames >= 20
    assert time.monotonic() - started < 30


def test_silent_udp_source_times_out_in_one_line():
    port = free_port(socket.SOCK_DGRAM)
    started = time.monotonic()
    with pytest.raises(InputError, match=r"cannot open udp://127.0.0.1:\d+: no data within"):
        VideoSource(f"udp://127.0.0.1:{port}", timeout=1.0)
    assert time.monotonic() - started < 10


# -- exact seeking -------------------------------------------------------------------
@pytest.fixture(scope="module")
def gop_clip(tmp_path_factory):
    """120 numbered frames with a keyframe every 12 and B-frames (decode order != display)."""
    path = tmp_path_factory.mktemp("gop") / "gop.mp4"
    return write_clip(path, 120, fps=25.0, options={"preset": "medium", "g": "12",
                                                    "bf": "3", "keyint_min": "12"})


@pytest.mark.parametrize("start", [65, 72, 73, 83, 119])
def test_a_late_start_seeks_to_the_keyframe_before_it_exactly(gop_clip, start, monkeypatch):
    from fastdet.video import source as source_module

    decoded_from = []
    seek = source_module.VideoSource._seek_to_start

    def recorded(self):
        frame = seek(self)
        decoded_from.append(frame is not None)
        return frame

    monkeypatch.setattr(source_module.VideoSource, "_seek_to_start", recorded)
    with VideoSource(gop_clip) as full, VideoSource(gop_clip, start=start, end=start + 5) as part:
        expected = list(full)[start:start + 5]
        got = list(part)
    assert decoded_from == [True]                        # it did seek ...
    assert len(got) == len(expected)                     # ... and landed exactly
    assert all(np.array_equal(a, b) for a, b in zip(got, expected))
    assert [frame_number(f) for f in got] == list(range(start, min(start + 5, 120)))


def test_a_seek_that_cannot_be_checked_decodes_from_the_start(gop_clip, monkeypatch):
    from fastdet.video import source as source_module

    monkeypatch.setattr(source_module, "seek_point", lambda *args: None)
    with VideoSource(gop_clip, start=100) as video:
        assert [frame_number(f) for f in video] == list(range(100, 120))


@pytest.mark.parametrize("timeout", [0, -1, float("nan"), float("inf"), "5"])
def test_a_timeout_that_is_no_positive_number_is_refused(data_dir, timeout):
    """NaN reached FFmpeg's options (an internal error on a stream) and passed
    unnoticed on a file."""
    with pytest.raises(InputError, match="--timeout must be a positive number of seconds"):
        VideoSource(data_dir / "test_video.mp4", timeout=timeout)


@pytest.mark.parametrize("start, end", [(1.5, None), (0, 3.0), (True, None), ("1", None)])
def test_frame_numbers_must_be_whole(clip, start, end):
    """VideoSource(start=1.5) began at frame 1."""
    with pytest.raises(InputError, match="must be a whole number of frames"):
        VideoSource(clip, start, end)


@pytest.mark.parametrize("source, kind", [(None, "NoneType"), (1.5, "float"), (True, "bool"),
                                          (b"clip.mp4", "bytes")])
def test_a_source_of_a_type_that_names_no_video_is_a_type_error(source, kind):
    """None and 1.5 said "expected str, bytes or os.PathLike object", bytes "startswith first
    arg must be bytes", True opened camera 1."""
    with pytest.raises(TypeError, match=f"^a video source is a path, a URL or a camera index, "
                                         f"not {kind}"):
        VideoSource(source)


@pytest.mark.parametrize("source, message", [
    ("", r"the video source is an empty name \(''\): give a file, a URL or a camera"),
    (-1, "a camera index is a whole number >= 0, got -1"),
    ("\u0663", "video not found: \u0663")])      # an Arabic 3 is no camera index
def test_an_empty_name_or_a_negative_camera_is_named_as_such(source, message):
    """"" said "not a video file: .", -1 "no camera at /dev/video-1"."""
    with pytest.raises(InputError, match=f"^{message}$"):
        VideoSource(source)


@pytest.mark.parametrize("threads", ["x", -1, 0, 1.5, True, 257])
def test_decoder_threads_must_be_a_count(clip, threads):
    """"x" raised a bare ValueError from int(); -1, 0, 1.5 and True were accepted."""
    with pytest.raises(InputError, match=f"decoder threads must be a whole number 1-256 "
                                         f"\\(None: FFmpeg's choice\\), got {threads!r}"):
        VideoSource(clip, threads=threads)
    with VideoSource(clip, threads=np.int64(2)) as video:
        assert len(list(video)) == 10


def test_closing_a_source_while_reading_it_says_so(clip):
    """It blamed the file: "the input ends after frame 0 of 10 frames (truncated or damaged)"."""
    video = VideoSource(clip, start=np.int64(0))
    frames = iter(video)
    next(frames)
    video.close()
    with pytest.raises(InputError, match=r"clip\.mp4 is closed"):
        next(frames)


@pytest.mark.parametrize("end", [None, 6])
def test_a_source_is_read_once_and_a_second_pass_says_so(clip, end):
    """A second ``for frame in video`` yielded nothing, silently."""
    with VideoSource(clip, start=2, end=end) as video:
        first = iter(video)
        assert [frame_number(next(first)) for _ in range(2)] == [2, 3]
        first.close()
        # An iteration stopped early is continued by the next one ...
        rest = [frame_number(frame) for frame in video]
        assert rest == list(range(4, end or 10))
        # ... and one after the last frame is refused, naming the frames read.
        with pytest.raises(InputError, match=rf"clip\.mp4: all {len(rest) + 2} frames were read; "
                                             "open it again"):
            next(iter(video))


def rotated_clip(path, degrees, size):
    """A clip of ``numbered_frame`` whose display matrix turns it by ``degrees`` clockwise,
    as a phone stores a portrait video (the track header's matrix, patched in place)."""
    import struct

    write_clip(path, 3, size=size)
    one = 0x10000
    a, b, c, d = {90: (0, one, -one, 0), 180: (-one, 0, 0, -one), 270: (0, -one, one, 0)}[degrees]
    identity = struct.pack(">9i", one, 0, 0, 0, one, 0, 0, 0, 0x40000000)
    data = path.read_bytes()
    at = data.index(identity, data.index(b"tkhd"))
    path.write_bytes(data[:at] + struct.pack(">9i", a, b, 0, c, d, 0, 0, 0, 0x40000000)
                     + data[at + len(identity):])
    return path


@pytest.mark.parametrize("degrees", [90, 180, 270])
@pytest.mark.parametrize("size", [(64, 48), (63, 47)], ids=["even", "odd"])
def test_a_rotated_video_is_read_upright_as_opencv_reads_it(tmp_path, degrees, size):
    """The frames were the stored, sideways pictures: the detector searched them sideways
    and the annotated copy played sideways; cv2.VideoCapture (the promised pixels) and
    players turn them by the display matrix."""
    path = rotated_clip(tmp_path / "phone.mp4", degrees, size)
    capture = cv2.VideoCapture(str(path))
    expected = []
    while (read := capture.read())[0]:
        expected.append(read[1])
    with VideoSource(path) as video:
        frames = list(video)
        turned = size[::-1] if degrees % 180 else size
        assert video.size == turned
    assert len(frames) == len(expected) == 3
    for frame, reference in zip(frames, expected):
        assert frame.shape == reference.shape == (turned[1], turned[0], 3)
        assert np.abs(frame.astype(int) - reference).max() <= 2
