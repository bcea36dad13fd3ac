"""Tests for ``fastdet.video.sink``: H.264 that browsers play, odd sizes, timestamps, atomicity."""

from __future__ import annotations

from fractions import Fraction

import av
import numpy as np
import pytest

from fastdet.errors import InputError
from fastdet.video.sink import VideoSink, available_codecs, pad_to_even
from fastdet.video.source import VideoSource
from video_files import SIZE, frame_number, numbered_frame, top_level_boxes, write_clip


def leftovers(folder):
    return sorted(p.name for p in folder.iterdir() if ".part" in p.name)


def read_back(path):
    """``(codec, pixel format, size, frame numbers, times in s)`` of a written video."""
    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        frames = list(container.decode(stream))
        context = stream.codec_context
        return (context.name, context.pix_fmt, (context.width, context.height),
                [frame_number(f.to_ndarray(format="bgr24")[:SIZE[1], :SIZE[0]]) for f in frames],
                [float(f.pts * stream.time_base) for f in frames])


def test_default_output_is_h264_yuv420p_with_the_index_first(tmp_path):
    path = tmp_path / "out.mp4"
    with VideoSink(path, 25.0, SIZE) as sink:
        for i in range(5):
            sink.write(numbered_frame(i))
        assert not path.exists()          # only the temporary file so far
        assert len(leftovers(tmp_path)) == 1
    codec, pix_fmt, size, numbers, times = read_back(path)
    assert (codec, pix_fmt, size) == ("h264", "yuv420p", SIZE)
    assert numbers == list(range(5)) and times == pytest.approx([0, 0.04, 0.08, 0.12, 0.16])
    boxes = top_level_boxes(path)
    assert boxes[0] == "ftyp" and boxes.index("moov") < boxes.index("mdat")   # +faststart
    assert leftovers(tmp_path) == []
    assert path.stat().st_mode & 0o044  # not left owner-only like a temp file


@pytest.mark.parametrize("width, height", [(853, 480), (1281, 721), (64, 47)])
def test_odd_sizes_are_padded_never_rescaled(tmp_path, width, height):
    rng = np.random.default_rng(width)
    # Smooth content so compression keeps it: a gradient plus a bright last column and row.
    frame = np.zeros((height, width, 3), np.uint8)
    frame[:] = np.linspace(30, 220, width, dtype=np.uint8)[None, :, None]
    frame[:, -1] = (250, 40, 40)
    frame[-1] = (40, 250, 40)
    frame[: height // 2, : width // 2, 2] = rng.integers(90, 110)
    path = tmp_path / "odd.mp4"
    with VideoSink(path, 25.0, (width, height)) as sink:
        for _ in range(3):
            sink.write(frame)
    with VideoSource(path) as video:
        assert video.size == (width + width % 2, height + height % 2)
        decoded = next(iter(video)).astype(int)
    # The picture sits unscaled in the top-left corner ...
    assert np.abs(decoded[:height, :width] - frame).mean() < 3
    # ... and the padding repeats the last column and row.
    if width % 2:
        assert np.abs(decoded[:height, -1] - decoded[:height, -2]).mean() < 6
    if height % 2:
        assert np.abs(decoded[-1, :width] - decoded[-2, :width]).mean() < 6


def test_pad_to_even_repeats_the_edges():
    image = np.arange(15, dtype=np.uint8).reshape(3, 5)
    padded = pad_to_even(image)
    assert padded.shape == (4, 6)
    assert np.array_equal(padded[:3, :5], image)
    assert np.array_equal(padded[:3, 5], image[:, 4]) and np.array_equal(padded[3], padded[2])
    even = np.zeros((4, 6, 3), np.uint8)
    assert pad_to_even(even) is even


def test_decoded_frames_pass_through_with_their_timestamps_2997(tmp_path):
    source_path = write_clip(tmp_path / "ntsc.mp4", 8, fps=30000 / 1001)
    out = tmp_path / "out.mp4"
    with VideoSource(source_path) as video:
        with VideoSink(out, video.rate, video.size, time_base=video.time_base,
                       colour=video.colour) as sink:
            for frame in video.decoded_frames():
                sink.write(frame, frame.pts)
    with av.open(str(out)) as container:
        assert container.streams.video[0].average_rate == Fraction(30000, 1001)
    _, _, _, numbers, times = read_back(out)
    assert numbers == list(range(8))
    assert times == pytest.approx([i * 1001 / 30000 for i in range(8)], abs=1e-4)


def test_variable_frame_rate_is_kept(tmp_path):
    times = [0.0, 0.04, 0.08, 0.1, 0.2, 0.233, 0.266, 0.4, 0.41, 0.5]
    source_path = write_clip(tmp_path / "vfr.mp4", len(times), times=times)
    out = tmp_path / "out.mp4"
    with VideoSource(source_path) as video:
        with VideoSink(out, video.rate, video.size, time_base=video.time_base) as sink:
            for frame in video.decoded_frames():
                sink.write(frame, frame.pts)
    _, _, _, numbers, written = read_back(out)
    assert numbers == list(range(len(times)))
    assert written == pytest.approx(times, abs=1e-3)


def test_timestamps_always_increase(tmp_path):
    path = tmp_path / "out.mp4"
    with VideoSink(path, 10.0, SIZE) as sink:
        for i, pts in enumerate([0, 1, 1, 0, 5, None]):
            sink.write(numbered_frame(i), pts)
    _, _, _, numbers, times = read_back(path)
    assert numbers == list(range(6))
    assert np.all(np.diff(times) > 0)
    assert times == pytest.approx([0.0, 0.1, 0.2, 0.3, 0.5, 0.6])


@pytest.mark.parametrize("codec", available_codecs())
def test_every_codec_the_wheel_has_writes_a_readable_video(tmp_path, codec):
    path = tmp_path / "out.mkv"
    size = (128, 96)   # large enough for every encoder's minimum
    with VideoSink(path, 25.0, size, codec=codec) as sink:
        for i in range(6):
            sink.write(numbered_frame(i, size))
    with VideoSource(path) as video:
        assert video.size == size
        assert [frame_number(f) for f in video] == list(range(6))


def test_h264_is_available():
    assert {"h264", "mp4v"} <= set(available_codecs())


@pytest.mark.parametrize("options, message", [
    ({"codec": "theora"}, "unknown codec 'theora'"),
    ({"codec": "mp4v", "preset": "fast"}, "--preset does not apply to mp4v"),
    ({"codec": "mp4v", "crf": 40}, "must be 2-31"),
    ({"preset": "warp-speed"}, "h264 has no preset 'warp-speed' \\(choose from ultrafast,"),
    ({"codec": "vp9", "preset": "99"}, "the vp9 encoder refuses --preset 99 --crf 35"),
    ({"crf": 60}, "h264 quality \\(--crf\\) must be 0-51, got 60"),
    ({"codec": "vp9", "crf": -1}, "must be 0-63"),
])
def test_bad_encoder_settings_are_one_line_errors(tmp_path, options, message):
    with pytest.raises(InputError, match=message):
        VideoSink(tmp_path / "out.mp4", 25.0, SIZE, **options)
    assert leftovers(tmp_path) == [] and not (tmp_path / "out.mp4").exists()


@pytest.mark.parametrize("fps, size, message", [
    (0, SIZE, "frame rate must be a positive number, got 0"),
    (-25, SIZE, "frame rate must be a positive number, got -25"),
    (float("nan"), SIZE, "frame rate must be a positive number, got nan"),
    (float("inf"), SIZE, "frame rate must be a positive number, got inf"),
    (1e-9, SIZE, "frame rate must be a positive number"),
    ("abc", SIZE, "frame rate must be a positive number, got 'abc'"),
    (25.0, (-320, -240), "size must be \\(width, height\\) in whole pixels, got \\(-320, -240\\)"),
    (25.0, 320, "size must be .* got 320"),
    (25.0, (320.5, 240), "size must be .* got \\(320.5, 240\\)"),
    (25.0, ("a", "b"), "size must be .* got \\('a', 'b'\\)"),
])
def test_bad_rates_and_sizes_are_one_line_errors(tmp_path, fps, size, message):
    """They were Python's own errors (ZeroDivisionError, OverflowError, TypeError), or the
    encoder's refusal of its preset, with a temporary file left behind."""
    with pytest.raises(InputError, match=message):
        VideoSink(tmp_path / "out.mp4", fps, size)
    assert leftovers(tmp_path) == [] and not (tmp_path / "out.mp4").exists()


@pytest.mark.parametrize("crf", ["a", True, [23]])
def test_a_quality_that_is_no_number_is_a_one_line_error(tmp_path, crf):
    with pytest.raises(InputError, match="must be a number 0-51"):
        VideoSink(tmp_path / "out.mp4", 25.0, SIZE, crf=crf)
    assert leftovers(tmp_path) == []


@pytest.mark.parametrize("threads", [-3, 0, 1.5, True, "2"])
def test_encoder_threads_that_are_no_count_are_a_one_line_error(tmp_path, threads):
    """-3 was handed to FFmpeg as it was."""
    with pytest.raises(InputError, match="encoder threads must be a whole number >= 1, got"):
        VideoSink(tmp_path / "out.mp4", 25.0, SIZE, threads=threads)
    assert leftovers(tmp_path) == []


@pytest.mark.parametrize("frame", [None, [[0, 0, 0]], "frame"])
def test_a_frame_that_is_no_array_is_refused(tmp_path, frame):
    with pytest.raises(InputError, match="a frame is a numpy array or an av.VideoFrame"):
        with VideoSink(tmp_path / "out.mp4", 25.0, SIZE) as sink:
            sink.write(frame)
    assert leftovers(tmp_path) == [] and not (tmp_path / "out.mp4").exists()


@pytest.mark.parametrize("size", [(1280, 16), (24, 1280), (2, 2)])
def test_av1_refuses_sides_its_encoder_hangs_or_fails_on(tmp_path, size):
    """SVT-AV1 waited forever inside its encoder on 1280x16 (SIGTERM and all) and
    printed its own errors on 2x2."""
    with pytest.raises(InputError, match="the av1 encoder needs at least 32 pixels on each side"):
        VideoSink(tmp_path / "out.mp4", 25.0, size, codec="av1")
    assert leftovers(tmp_path) == []


def test_discards_on_error_and_keeps_the_old_file(tmp_path):
    path = tmp_path / "out.mp4"
    path.write_bytes(b"previous")
    with pytest.raises(RuntimeError):
        with VideoSink(path, 25.0, SIZE) as sink:
            sink.write(numbered_frame(0))
            raise RuntimeError("boom")
    assert path.read_bytes() == b"previous"
    assert leftovers(tmp_path) == []


def test_keeps_frames_done_before_ctrl_c(tmp_path):
    path = tmp_path / "out.mp4"
    with pytest.raises(KeyboardInterrupt):
        with VideoSink(path, 25.0, SIZE) as sink:
            for i in range(3):
                sink.write(numbered_frame(i))
            raise KeyboardInterrupt
    assert read_back(path)[3] == [0, 1, 2]
    assert leftovers(tmp_path) == []


def test_encoder_failure_is_reported_and_leaves_nothing(tmp_path, monkeypatch):
    path = tmp_path / "broken.mp4"
    sink = VideoSink(path, 25.0, SIZE)

    def full_disk(*args):
        raise av.error.OSError(28, "No space left on device")

    monkeypatch.setattr(sink, "_container", type("Broken", (), {"mux": staticmethod(full_disk),
                                                                "close": lambda self: None})())
    with pytest.raises(InputError, match="cannot write a video to .*broken.mp4: No space left"):
        with sink:
            sink.write(numbered_frame(0))
    assert not path.exists() and leftovers(tmp_path) == []


def test_sink_without_frames_leaves_nothing(tmp_path):
    path = tmp_path / "out.mp4"
    with VideoSink(path, 25.0, SIZE):
        pass
    assert not path.exists() and leftovers(tmp_path) == []


def test_rejects_frames_of_another_size(tmp_path):
    with VideoSink(tmp_path / "out.mp4", 25.0, SIZE) as sink:
        with pytest.raises(InputError, match="does not fit a 64x48 video"):
            sink.write(np.zeros((10, 10, 3), np.uint8))
        sink.write(numbered_frame(0))


@pytest.mark.parametrize("name, message", [
    ("missing/out.mp4", "cannot write .*out.mp4"),
    ("", "it is a directory"),
    ("out.xyz", "unsupported suffix"),
    ("out", "the name has no suffix; use one of .mp4"),
    # A file named just ".mp4" said "unsupported suffix".
    (".mp4", "\\.mp4 is a hidden file's name with no suffix \\(its dot starts the name\\); "
             "name the video, e.g. video\\.mp4$"),
    (".MKV", "e.g. video\\.MKV$")])
def test_unwritable_destination(tmp_path, name, message):
    with pytest.raises(InputError, match=message):
        VideoSink(tmp_path / name, 25.0, SIZE)
    assert leftovers(tmp_path) == []


def test_a_frame_of_another_dtype_or_after_closing_is_named_as_such(tmp_path):
    """A float32 frame of the right shape "did not fit", a write after close said "End of file"."""
    path = tmp_path / "out.mp4"
    sink = VideoSink(path, 12, SIZE)
    with pytest.raises(InputError, match="a frame is BGR uint8, got float32"):
        sink.write(numbered_frame(0).astype(np.float32))
    sink.write(numbered_frame(0))
    sink.close()
    with pytest.raises(InputError, match=f"the video {path} is closed"):
        sink.write(numbered_frame(1))
    with VideoSource(path) as video:
        assert [frame_number(frame[:SIZE[1], :SIZE[0]]) for frame in video] == [0]


@pytest.mark.parametrize("name, codec, message", [
    ("out.mov", "vp9", "the QuickTime \\(.mov\\) format cannot hold vp9 \\(use --codec h264, "
                       "hevc or mp4v, or write .mp4 or .mkv\\)"),
    ("out.mov", "av1", "the QuickTime \\(.mov\\) format cannot hold av1"),
    ("out.avi", "hevc", "the AVI format cannot hold hevc \\(use --codec h264, mp4v, av1 or vp9, "
                        "or write .mp4 or .mkv\\)"),
    ("out.webm", "mp4v", "the WebM format cannot hold mp4v \\(use --codec vp9 or av1, or write "
                         ".mp4 or .mkv\\)"),
    ("out.webm", "h264", "the WebM format cannot hold h264 \\(use --codec vp9 or av1"),
    ("out.ts", "vp9", "the MPEG-TS \\(.ts\\) format cannot hold vp9 \\(use --codec h264, hevc "
                      "or mp4v"),
    ("out.ts", "av1", "the MPEG-TS \\(.ts\\) format cannot hold av1")])
def test_a_container_that_cannot_hold_the_codec_is_refused_at_opening(tmp_path, name, codec,
                                                                      message):
    """AV1 or VP9 in .mov: refused at the first packet only, as "Invalid argument" (after a
    whole run's work, from ``fastdet run``); HEVC in .avi and mp4v or H.264 in .webm said
    "'avi' format does not support 'libx265' codec" without a way out; AV1 and VP9 in .ts
    were written as a data stream that no player shows.  Now when the sink opens, saying what
    to use."""
    with pytest.raises(InputError, match=f"^cannot write {tmp_path / name}: {message}"):
        VideoSink(tmp_path / name, 12, (64, 64), codec=codec)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("name", ["out.webm", "OUT.WEBM"])
def test_a_webm_without_a_codec_is_vp9_written_atomically(tmp_path, name):
    """WebM holds only VP9 and AV1: without a codec the sink chose H.264 and failed at once
    ("'webm' format does not support 'libx264' codec")."""
    path = tmp_path / name
    size = (128, 96)
    with VideoSink(path, 25.0, size) as sink:
        assert sink.codec == "vp9"
        for i in range(6):
            sink.write(numbered_frame(i, size))
        assert not path.exists() and len(leftovers(tmp_path)) == 1
    assert leftovers(tmp_path) == []
    with av.open(str(path)) as container:
        assert container.format.name.split(",")[0] in ("matroska", "webm")
        stream = container.streams.video[0]
        assert stream.codec_context.name == "vp9"
        frames = [f.to_ndarray(format="bgr24") for f in container.decode(stream)]
    assert [frame_number(f[:size[1], :size[0]]) for f in frames] == list(range(6))


def test_every_other_container_keeps_h264_by_default(tmp_path):
    for name in ("out.mp4", "out.m4v", "out.mov", "out.mkv", "out.avi", "out.ts"):
        with VideoSink(tmp_path / name, 25.0, SIZE) as sink:
            assert sink.codec == "h264"
            sink.write(numbered_frame(0))
        assert read_back(tmp_path / name)[:3] == ("h264", "yuv420p", SIZE)


def test_a_webm_without_vp9_suggests_a_codec(tmp_path, monkeypatch):
    import fastdet.video.sink as sink_module

    monkeypatch.setattr(sink_module.av, "codecs_available",
                        set(av.codecs_available) - {"libvpx-vp9"})
    with pytest.raises(InputError, match="^cannot write .*out.webm: a WebM video is vp9 unless "
                                         "--codec says otherwise, and this FFmpeg cannot encode "
                                         "vp9 \\(libvpx-vp9 is missing\\): give --codec av1, or "
                                         "write .mp4 or .mkv$"):
        VideoSink(tmp_path / "out.webm", 25.0, SIZE)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("colour", [5, "x", (1,), (1, 1, 1), (1, True), (-1, 1), (1.5, 1)])
def test_colour_tags_that_are_no_pair_of_numbers_are_refused(tmp_path, colour):
    """colour=5 raised a bare TypeError ('int' object is not subscriptable); "x" and (1,)
    were taken."""
    with pytest.raises(InputError, match="^colour is the \\(matrix, range\\) pair of FFmpeg's "
                                         "colour tags, as VideoSource.colour gives it, got "):
        VideoSink(tmp_path / "out.mp4", 25.0, SIZE, colour=colour)
    assert list(tmp_path.iterdir()) == []
    with VideoSink(tmp_path / "out.mp4", 25.0, SIZE, colour=(np.int64(1), 1)) as sink:
        assert sink.bt709
        sink.write(numbered_frame(0))


@pytest.mark.parametrize("time_base", [0, -1, "x", True])
def test_a_time_base_that_is_no_positive_number_is_refused(tmp_path, time_base):
    """A time base of 0 opened a sink whose first write divided by zero."""
    with pytest.raises(InputError, match="time base must be a positive number"):
        VideoSink(tmp_path / "out.mp4", 12, SIZE, time_base=time_base)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("pts", [1.5, float("nan"), "3"])
def test_a_pts_that_is_no_whole_number_is_refused(tmp_path, pts):
    """int() truncated 1.5 and raised a bare ValueError for NaN."""
    with VideoSink(tmp_path / "out.mp4", 12, SIZE) as sink:
        sink.write(numbered_frame(0), pts=np.int64(0))
        with pytest.raises(InputError, match="pts is a whole number"):
            sink.write(numbered_frame(1), pts=pts)
    with VideoSource(tmp_path / "out.mp4") as video:
        assert [frame_number(frame) for frame in video] == [0]
