"""``fastdet bench``'s video-pipeline table: steady-state passes, one row per way of threading."""

from __future__ import annotations

from fastdet.bench.frame_level import (MIN_PASS_FRAMES, PipelinePoint, format_frame_level,
                                       frame_level_study, looped, paired_speedup)


def test_looped_plays_the_frames_forward_and_back_to_the_length():
    frames = ["a", "b", "c"]
    assert looped(frames, 7) == ["a", "b", "c", "c", "b", "a", "a", "b", "c"]
    assert looped(frames, 2) == frames
    assert looped([], 5) == []
    assert len(looped(list(range(38)))) == 304 >= MIN_PASS_FRAMES


def test_frame_level_study_times_each_way_over_looped_passes(small_frames):
    points = frame_level_study(small_frames, threads=(1, 2), rounds=1, log=lambda *a: None,
                               min_frames=6)
    assert [(p.threads, p.frames_at_once) for p in points] == [(1, 1), (2, 1), (2, 2)]
    assert all(p.ms_per_frame > 0 and p.cpu_ms_per_frame > 0 for p in points)
    table = format_frame_level(points).splitlines()
    assert table[0].endswith("| threads put to sleep per frame |")
    assert table[2].startswith("| 1 thread |") and "| 1.00x | 1.00x |" in table[2]
    assert table[3].startswith("| 2 threads sharing each frame |")
    assert table[4].startswith("| 2 threads, 2 frames at once |")
    assert points[0].paired_speedup == 1.0
    assert all(p.paired_speedup > 0 for p in points)
    # One thread never waits for another; a thread sharing each frame sleeps
    # between frames waiting for the next one's tasks.
    one, shared, _ = (p.switches_per_frame for p in points)
    assert 0 <= one < 1 <= shared
    assert all(row.endswith(f"| {p.switches_per_frame:.1f} |") for row, p in zip(table[2:], points))


def test_frame_level_table_says_so_where_sleeps_are_not_counted():
    table = format_frame_level([PipelinePoint(1, 1, 2.0, 2.0, 1.0, None)]).splitlines()
    assert table[2] == "| 1 thread | 2.00 | 2.00 | 1.00x | 1.00x | - |"


def test_paired_speedup_is_the_median_of_each_rounds_ratio():
    # Rounds 2 and 3 hit a slow spell: the ratio of medians (10 / 5) would say
    # 2x, each round's own passes say 1x, 2x and 1x.
    assert paired_speedup([1.0, 10.0, 10.0], [1.0, 5.0, 10.0]) == 1.0
    assert paired_speedup([4.0, 6.0, 3.0], [2.0, 2.0, 2.0]) == 2.0
