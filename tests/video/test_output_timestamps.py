"""The annotated video keeps the spacing of the input's timestamps and starts at 0 (README, "Video")."""

from __future__ import annotations

from fractions import Fraction

import av
import pytest
from video_files import SIZE, frame_number, numbered_frame, write_clip
from video_stubs import BlockDetector

from fastdet.video.pipeline import VideoPipeline
from fastdet.video.run import process_video
from fastdet.video.sink import VideoSink


def frame_times(path):
    """``(frame numbers, seconds)`` of a written video, as a player reads them."""
    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        frames = list(container.decode(stream))
        return ([frame_number(f.to_ndarray(format="bgr24")[:SIZE[1], :SIZE[0]]) for f in frames],
                [float(f.pts * stream.time_base) for f in frames])


@pytest.mark.parametrize("suffix", [".mp4", ".mkv"])
def test_a_start_offset_is_removed_and_the_spacing_kept(tmp_path, suffix):
    """As FFmpeg's output without -copyts: the irregular spacing stays, the offset goes."""
    times = [10.0, 10.1, 10.15, 10.4]
    clip = write_clip(tmp_path / "offset.mp4", len(times), times=times)
    out = tmp_path / f"out{suffix}"
    process_video(clip, out, VideoPipeline(BlockDetector()))
    numbers, written = frame_times(out)
    assert numbers == [0, 1, 2, 3]
    assert written == pytest.approx([t - times[0] for t in times], abs=1e-3)


def test_a_range_starts_at_zero(tmp_path):
    clip = write_clip(tmp_path / "clip.mp4", 6)
    out = tmp_path / "out.mp4"
    process_video(clip, out, VideoPipeline(BlockDetector()), start=2, end=5)
    numbers, written = frame_times(out)
    assert numbers == [2, 3, 4] and written == pytest.approx([0, 1 / 12, 2 / 12], abs=1e-3)


def test_negative_timestamps_move_later_and_lose_no_frame(tmp_path):
    path = tmp_path / "out.mp4"
    with VideoSink(path, 25, SIZE, time_base=Fraction(1, 25)) as sink:
        for i, pts in enumerate([-2, -1, 0, 1]):
            sink.write(numbered_frame(i), pts)
    numbers, written = frame_times(path)
    assert numbers == [0, 1, 2, 3] and written == pytest.approx([0, 0.04, 0.08, 0.12])
