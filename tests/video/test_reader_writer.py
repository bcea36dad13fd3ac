"""Tests for ``fastdet.video.reader``: streaming reader with clear errors, atomic writer."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from fastdet.errors import InputError
from fastdet.video.reader import VideoReader
from fastdet.video.writer import VideoWriter

SIZE = (64, 48)


def numbered_frame(i):
    """A frame whose mean grey level (20 * i + 10) survives lossy compression."""
    return np.full((SIZE[1], SIZE[0], 3), 20 * i + 10, np.uint8)


def frame_number(frame):
    return int(round((float(frame.mean()) - 10) / 20))


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    """A 10-frame mp4 whose frame i has grey level 20 * i + 10."""
    path = tmp_path_factory.mktemp("video") / "clip.mp4"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 12.0, SIZE)
    for i in range(10):
        writer.write(numbered_frame(i))
    writer.release()
    return path


def leftovers(folder):
    return sorted(p.name for p in folder.iterdir() if ".part" in p.name)


# -- reader ---------------------------------------------------------------------
def test_reader_streams_every_frame_with_metadata(clip):
    with VideoReader(clip) as video:
        assert video.size == SIZE
        assert video.fps == pytest.approx(12.0)
        assert video.frame_count == 10 and video.expected_frames == 10
        numbers = [frame_number(frame) for frame in video]
    assert numbers == list(range(10))


@pytest.mark.parametrize("start, end", [(0, None), (3, None), (3, 7), (9, None), (0, 1),
                                        (8, 50)])
def test_reader_start_and_end(clip, start, end):
    with VideoReader(clip, start=start, end=end) as video:
        numbers = [frame_number(frame) for frame in video]
        assert video.expected_frames == len(numbers)
    assert numbers == list(range(start, min(end or 10, 10)))


def test_reader_on_the_real_video(data_dir):
    with VideoReader(data_dir / "test_video.mp4") as video:
        assert video.size == (1280, 720)
        assert sum(1 for _ in video) == 38


def test_missing_file(tmp_path):
    with pytest.raises(InputError, match="video not found: .*nope.mp4"):
        VideoReader(tmp_path / "nope.mp4")


def test_file_that_is_not_a_video(tmp_path, capfd):
    path = tmp_path / "notes.mp4"
    path.write_text("these are not moving pictures\n")
    with pytest.raises(InputError, match="cannot read .*notes.mp4 as a video"):
        VideoReader(path)
    # FFmpeg's own complaints are kept off the terminal: one line, ours.
    assert capfd.readouterr().err == ""


def test_image_is_not_a_video(tmp_path):
    path = tmp_path / "still.png"
    cv2.imwrite(str(path), numbered_frame(1))
    with pytest.raises(InputError, match="is an image, not a video"):
        VideoReader(path)


def test_directory_is_not_a_video(tmp_path):
    with pytest.raises(InputError, match="not a video file"):
        VideoReader(tmp_path)


def test_video_with_zero_frames(tmp_path):
    path = tmp_path / "empty.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 25.0, SIZE)
    writer.release()
    with pytest.raises(InputError, match="empty.avi holds no frames"):
        VideoReader(path)


def test_start_past_the_end(clip):
    message = r"--start 10 is past the end of .*clip.mp4 \(10 frames\)"
    with pytest.raises(InputError, match=message):
        VideoReader(clip, start=10)


@pytest.mark.parametrize("start, end, message", [(-1, None, "--start must be >= 0"),
                                                 (5, 5, "--end .5. must be greater")])
def test_bad_ranges(clip, start, end, message):
    with pytest.raises(InputError, match=message):
        VideoReader(clip, start=start, end=end)


# -- writer ---------------------------------------------------------------------
def read_numbers(path):
    capture = cv2.VideoCapture(str(path))
    numbers = []
    while True:
        ok, frame = capture.read()
        if not ok:
            return numbers, (int(capture.get(cv2.CAP_PROP_FRAME_WIDTH)),
                             int(capture.get(cv2.CAP_PROP_FRAME_HEIGHT)))
        numbers.append(frame_number(frame))


@pytest.mark.parametrize("background", [False, True])
def test_writer_writes_a_readable_video_atomically(tmp_path, background):
    path = tmp_path / "out.mp4"
    with VideoWriter(path, 25.0, SIZE, background=background) as writer:
        for i in range(5):
            writer.write(numbered_frame(i))
        assert not path.exists()          # only the temporary file so far
        assert len(leftovers(tmp_path)) == 1
    assert read_numbers(path) == (list(range(5)), SIZE)
    assert leftovers(tmp_path) == []
    assert path.stat().st_mode & 0o044  # not left owner-only like a temp file


@pytest.mark.parametrize("background", [False, True])
def test_writer_discards_on_error_and_keeps_the_old_file(tmp_path, background):
    path = tmp_path / "out.mp4"
    path.write_bytes(b"previous")
    with pytest.raises(RuntimeError):
        with VideoWriter(path, 25.0, SIZE, background=background) as writer:
            writer.write(numbered_frame(0))
            raise RuntimeError("boom")
    assert path.read_bytes() == b"previous"
    assert leftovers(tmp_path) == []


@pytest.mark.parametrize("background", [False, True])
def test_writer_keeps_frames_done_before_ctrl_c(tmp_path, background):
    path = tmp_path / "out.mp4"
    with pytest.raises(KeyboardInterrupt):
        with VideoWriter(path, 25.0, SIZE, background=background) as writer:
            for i in range(3):
                writer.write(numbered_frame(i))
            raise KeyboardInterrupt
    assert read_numbers(path) == ([0, 1, 2], SIZE)
    assert leftovers(tmp_path) == []


def test_background_encoder_keeps_order_and_reports_failures(tmp_path):
    path = tmp_path / "out.mp4"
    with VideoWriter(path, 25.0, SIZE, background=True) as writer:
        for i in range(12):                      # more than the queue holds
            writer.write(numbered_frame(i))
    assert read_numbers(path) == (list(range(12)), SIZE)

    class Broken:
        def write(self, frame):
            raise RuntimeError("disk full")

        def release(self):
            pass

    writer = VideoWriter(tmp_path / "broken.mp4", 25.0, SIZE, background=True)
    writer._writer.release()
    writer._writer = Broken()
    writer.write(numbered_frame(0))
    with pytest.raises(InputError, match="cannot write a video to .*broken.mp4: disk full"):
        writer.close()
    assert not (tmp_path / "broken.mp4").exists() and leftovers(tmp_path) == []


def test_writer_without_frames_leaves_nothing(tmp_path):
    path = tmp_path / "out.mp4"
    with VideoWriter(path, 25.0, SIZE):
        pass
    assert not path.exists() and leftovers(tmp_path) == []


def test_writer_rejects_frames_of_another_size(tmp_path):
    with VideoWriter(tmp_path / "out.mp4", 25.0, SIZE) as writer:
        with pytest.raises(InputError, match="does not fit a 64x48 video"):
            writer.write(np.zeros((10, 10, 3), np.uint8))
        writer.write(numbered_frame(0))


@pytest.mark.parametrize("name, message", [("missing/out.mp4", "cannot write .*out.mp4"),
                                           ("", "it is a directory")])
def test_writer_unwritable_destination(tmp_path, name, message):
    with pytest.raises(InputError, match=message):
        VideoWriter(tmp_path / name, 25.0, SIZE)
    assert leftovers(tmp_path) == []


def test_frames_can_skip_conversion(clip):
    with VideoReader(clip) as video:
        got = [None if f is None else frame_number(f)
               for f in video.frames(skip=iter([True, False] * 5).__next__)]
    # The first frame is read at opening to validate the file; skip() is
    # asked from the second frame on.
    assert got == [0, None, 2, None, 4, None, 6, None, 8, None]
