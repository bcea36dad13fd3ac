"""Segment lengths, warm-ups and boundaries."""

import math

import pytest

from fastdet.batch.segments import (
    MEMORY_BITS,
    parse_segment,
    plan_segments,
    segment_frames,
    warmup_frames,
)
from fastdet.errors import InputError
from fastdet.video.config import TrackConfig


@pytest.mark.parametrize("spec, parsed", [("500", (500, None)), (" 30s", (None, 30.0)),
                                          ("2.5s", (None, 2.5)), ("1 seconds", (None, 1.0))])
def test_segment_specs(spec, parsed):
    assert parse_segment(spec) == parsed


@pytest.mark.parametrize("spec", ["0", "-3", "2.5", "ten", "30m", ""])
def test_bad_segment_specs(spec):
    with pytest.raises(InputError, match="--segment"):
        parse_segment(spec)


def test_seconds_become_frames_at_the_video_rate():
    assert segment_frames((None, 30.0), 25.0) == 750
    assert segment_frames((120, None), 25.0) == 120


def test_the_default_warmup_forgets_the_heat_by_2_to_the_memory_bits():
    warmup, align = warmup_frames(TrackConfig())
    assert (warmup, align) == (174, 1)
    assert 0.75 ** warmup < 2.0 ** -MEMORY_BITS < 0.75 ** (warmup - 1)


def test_warmups_of_other_settings():
    # Each full search is `every` frames apart, and the warm-up starts on that schedule.
    assert warmup_frames(TrackConfig(every=5)) == (870, 5)
    # FIR holds `heat_frames` maps, whose ring must be in phase as well.
    assert warmup_frames(TrackConfig(heat_smoothing="fir", heat_frames=6, every=2)) == (12, 12)
    # Without smoothing only the tracks remember: max_missed + box_frames + 1 searches.
    assert warmup_frames(TrackConfig(heat_smoothing="none", box_frames=4)) == (7, 1)
    assert warmup_frames(TrackConfig(heat_alpha=1.0)) == (4, 1)


def test_a_short_video_is_one_segment():
    assert plan_segments(500, 500, 174) == [(0, None, 0)]
    assert plan_segments(None, 500, 174) == [(0, None, 0)]


@pytest.mark.parametrize("frames, length, warmup, align", [
    (1000, 500, 174, 1), (1000, 250, 174, 1), (10_000, 750, 174, 5), (38, 12, 174, 1),
    (1001, 1000, 20, 3)])
def test_segments_cover_the_video_once_with_even_work(frames, length, warmup, align):
    segments = plan_segments(frames, length, warmup, align)
    assert len(segments) == math.ceil(frames / length) or frames < warmup
    assert segments[0][0] == 0 and segments[-1][1] is None
    for (start, end, warm), (next_start, _, _) in zip(segments, segments[1:]):
        assert end == next_start and start < end
    for start, _, warm in segments:
        assert warm % align == 0 and start - warmup - align < warm <= start
    if frames > 4 * warmup:
        ends = [end or frames for _, end, _ in segments]
        work = [end - warm for (_, _, warm), end in zip(segments, ends)]
        assert max(work) - min(work) <= 2 + align
