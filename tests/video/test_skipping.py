"""Frames nothing looks at stay undecoded (``fastdet.video.skipping``); the others are exact."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from fastdet.video.skipping import LOOKAHEAD, FrameSkipper
from fastdet.video.source import VideoSource
from video_files import frame_number, write_clip

FRAMES = 120


@pytest.fixture(scope="module")
def b_frame_clip(tmp_path_factory):
    """120 numbered frames, a keyframe every 12, up to 3 B-frames in a row (x264 medium)."""
    return write_clip(tmp_path_factory.mktemp("skip") / "b.mp4", FRAMES, fps=25.0,
                      options={"preset": "medium", "g": "12", "bf": "3", "keyint_min": "12"})


@pytest.fixture(scope="module")
def variable_rate_clip(tmp_path_factory):
    """The same with irregular timestamps (gaps of 1 to 3 frame times)."""
    steps = np.random.default_rng(3).integers(1, 4, FRAMES)
    times = np.concatenate([[0.0], np.cumsum(steps[:-1]) / 25.0])
    return write_clip(tmp_path_factory.mktemp("skip") / "vfr.mp4", FRAMES, fps=25.0,
                      times=list(times), options={"preset": "medium", "bf": "3"})


def _planes(frame):
    return frame.to_ndarray(format="yuv420p")


def _decode(path, needed=None, start=0, threads=None):
    with VideoSource(path, start=start, threads=threads) as video:
        frames = [None if f is None else _planes(f) for f in video.decoded_frames(needed)]
        return frames, video.frames_left_undecoded


@pytest.mark.parametrize("clip", ["b_frame_clip", "variable_rate_clip"])
@pytest.mark.parametrize("period,offset", [(5, 0), (3, 1), (2, 0), (7, 4)])
@pytest.mark.parametrize("threads", [1, 2])
def test_only_unneeded_frames_are_left_out_and_the_others_are_exact(request, clip, period,
                                                                   offset, threads):
    path = request.getfixturevalue(clip)
    needed = lambda index: (index - offset) % period == 0  # noqa: E731
    everything, _ = _decode(path, threads=threads)
    some, left_out = _decode(path, needed, threads=threads)
    assert len(some) == len(everything) == FRAMES
    missing = [index for index, frame in enumerate(some) if frame is None]
    assert left_out == len(missing) > 0          # it did leave frames out ...
    assert not any(needed(index) for index in missing)   # ... only unneeded ones
    for index, frame in enumerate(some):
        if frame is not None:
            assert np.array_equal(frame, everything[index]), index


def _encode(path, codec, options, container_format=None, frames=60):
    import av

    from video_files import SIZE, numbered_frame

    with av.open(str(path), "w", format=container_format) as container:
        stream = container.add_stream(codec, rate=25, options=options)
        stream.width, stream.height, stream.pix_fmt = *SIZE, "yuv420p"
        for i in range(frames):
            picture = av.VideoFrame.from_ndarray(numbered_frame(i), format="bgr24")
            container.mux(stream.encode(picture.reformat(format="yuv420p")))
        container.mux(stream.encode(None))
    return path


@pytest.mark.parametrize("name,codec,options,container_format", [pytest.param(*case, id=case[0])
                                                                  for case in [
    ("bf16.mp4", "libx264", {"preset": "veryfast", "bf": "16", "b_strategy": "0"}, None),
    ("open_gop.mp4", "libx264", {"x264-params": "open-gop=1:keyint=12:bframes=3"}, None),
    ("h264.mkv", "libx264", {"preset": "medium"}, None),
    ("h264.ts", "libx264", {"preset": "medium"}, "mpegts"),
    ("hevc.mp4", "libx265", {"preset": "ultrafast",
                             "x265-params": "bframes=4:log-level=error"}, None),
    ("mpeg4.avi", "mpeg4", {"bf": "2"}, None),
]])
def test_codecs_and_containers(tmp_path, name, codec, options, container_format):
    path = _encode(tmp_path / name, codec, options, container_format)
    needed = lambda index: index % 4 == 1  # noqa: E731
    everything, _ = _decode(path)
    some, left_out = _decode(path, needed, threads=2)
    assert len(some) == len(everything) == 60 and left_out > 0
    for index, frame in enumerate(some):
        assert (frame is None and not needed(index)) or np.array_equal(frame, everything[index])


def test_a_late_start_keeps_the_indices(b_frame_clip):
    start = 73   # past the seek threshold: decoding starts at the keyframe before it
    with VideoSource(b_frame_clip, start=start) as video:
        frames = list(video.decoded_frames(lambda index: index % 4 == 0))
        left_out = video.frames_left_undecoded
    assert len(frames) == FRAMES - start and left_out > 0
    for index, frame in enumerate(frames, start):
        if frame is None:
            assert index % 4
        else:
            bgr = frame.to_ndarray(format="bgr24")
            assert frame_number(bgr) == index


@pytest.mark.parametrize("start,seek", [(30, True), (83, True), (100, False)],
                         ids=["before the seek threshold", "after a seek", "seek refused"])
def test_frames_before_the_start_are_left_out_on_the_way(b_frame_clip, start, seek,
                                                          monkeypatch):
    from fastdet.video import source as source_module

    if not seek:   # the seek cannot be checked: decoded from the beginning
        monkeypatch.setattr(source_module, "seek_point", lambda *args: None)
    with VideoSource(b_frame_clip) as video:
        everything = [_planes(frame) for frame in video.decoded_frames()]
    with VideoSource(b_frame_clip, start=start) as video:
        frames = [_planes(frame) for frame in video.decoded_frames()]
        left_out = video._skipper.left_out
    assert left_out > 0 and video.frames_left_undecoded == 0
    assert len(frames) == FRAMES - start
    assert all(np.array_equal(a, b) for a, b in zip(frames, everything[start:]))


def test_bgr_frames_of_the_needed_indices(b_frame_clip):
    needed = lambda index: index % 6 == 2  # noqa: E731
    with VideoSource(b_frame_clip) as video:
        frames = list(video.frames(needed=needed))
        left_out = video.frames_left_undecoded
    assert len(frames) == FRAMES and left_out > 0
    for index, frame in enumerate(frames):
        if index == 0 or needed(index):
            assert frame_number(frame) == index
        else:
            assert frame is None


def test_a_stream_without_b_frames_decodes_everything(data_dir):
    # The test video has no pictures that nothing references.
    frames, left_out = _decode(data_dir / "test_video.mp4", lambda index: index % 5 == 0)
    assert left_out == 0 and all(frame is not None for frame in frames)


# -- the bookkeeping, with stand-in packets and frames -----------------------------------
def _packet(pts, size=100):
    return SimpleNamespace(pts=pts, size=size)


class _Decoder:
    """A codec context stand-in that records the skip setting each packet got."""

    def __init__(self):
        self.skip_frame = "DEFAULT"


def test_packets_wait_for_the_lookahead_then_go_in_order():
    skipper = FrameSkipper(_Decoder())
    skipper.start(lambda index: True, lambda: 0)
    released = [p.pts for pts in range(LOOKAHEAD + 3) for p in skipper.demuxed(_packet(pts))]
    assert released == [0, 1, 2]
    assert [p.pts for p in skipper.finished()] == list(range(3, LOOKAHEAD + 3))


def test_a_frame_index_counts_the_earlier_frames_still_to_come():
    # Decoding order I0 P4 B2 b1 b3 ...: b1 is frame 1 although it comes fourth.
    decoder = _Decoder()
    skipper = FrameSkipper(decoder)
    order = [0, 4, 2, 1, 3, 8, 6, 5, 7]
    settings = {}
    skipper.start(lambda index: index % 2 == 0, lambda: 0)
    for pts in order:
        for packet in skipper.demuxed(_packet(pts)):
            settings[packet.pts] = decoder.skip_frame
    for packet in skipper.finished():
        settings[packet.pts] = decoder.skip_frame
    assert settings == {pts: "DEFAULT" if pts % 2 == 0 else "NONREF" for pts in order}


@pytest.mark.parametrize("trouble", ["no timestamp", "same timestamp"])
def test_timestamps_it_cannot_count_on_stop_the_skipping(trouble):
    decoder = _Decoder()
    skipper = FrameSkipper(decoder)
    skipper.start(lambda index: False, lambda: 0)
    list(skipper.demuxed(_packet(0)))
    list(skipper.demuxed(_packet(None if trouble == "no timestamp" else 0)))
    assert not skipper.active
    later = [p for pts in range(1, 5) for p in skipper.demuxed(_packet(pts))]
    assert len(later) == 4 and decoder.skip_frame == "DEFAULT"


def test_placeholders_come_before_the_next_frame_shown():
    skipper = FrameSkipper(_Decoder())
    skipper.start(lambda index: index in (0, 3), lambda: 0)
    for pts in (0, 3, 1, 2):
        list(skipper.demuxed(_packet(pts)))
    list(skipper.finished())
    assert skipper.decoded(SimpleNamespace(pts=0)) == []
    assert [p.pts for p in skipper.decoded(SimpleNamespace(pts=3))] == [1, 2]   # left out
    assert skipper.remaining() == [] and skipper.left_out == 2


def test_a_frame_the_decoder_drops_by_itself_stops_the_skipping():
    skipper = FrameSkipper(_Decoder())
    skipper.start(lambda index: index % 2 == 0, lambda: 0)
    for pts in (0, 1, 2):
        list(skipper.demuxed(_packet(pts)))
    list(skipper.finished())
    # Frame 1 was left out and its placeholder comes before frame 2; then frame 3,
    # sent to be decoded, never comes out: the indices after it cannot be trusted.
    assert skipper.decoded(SimpleNamespace(pts=0)) == []
    assert len(skipper.decoded(SimpleNamespace(pts=2))) == 1 and skipper.active
    list(skipper.demuxed(_packet(4)))
    list(skipper.demuxed(_packet(3)))
    list(skipper.finished())
    assert skipper.decoded(SimpleNamespace(pts=4)) == []   # 3 was to be decoded: dropped
    assert not skipper.active


def test_a_live_source_keeps_no_timestamps_however_long_it_runs():
    skipper = FrameSkipper(_Decoder(), enabled=False)
    skipper.start(lambda index: False, lambda: 0)
    assert not skipper.active
    for pts in range(10_000):
        assert [p.pts for p in skipper.demuxed(_packet(pts))] == [pts]   # none held back
        assert skipper.decoded(SimpleNamespace(pts=None if pts % 7 else pts)) == []
    assert skipper._pending == [] and skipper.left_out == 0
