"""Segment boundaries: the flush argument, the state digests, the verdicts and the id maps.

The pipelines here run the block-finding stub detector (``video_stubs``) on
synthetic frames, so whole-video and segment runs are cheap to compare.
"""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from batch_stubs import STUB_HEAT, STUB_THRESHOLD, two_blocks
from video_stubs import BlockDetector

from fastdet.batch.boundary import IdMap, compare, flush_level
from fastdet.batch.state import (
    FLUSH_LEVELS,
    flushed_digests,
    frame_digest,
    pipeline_state,
    reorder_tracks,
)
from fastdet.video.config import TrackConfig
from fastdet.video.pipeline import VideoPipeline
from fastdet.video.smoothing import ExponentialHeat



# -- the flush argument -----------------------------------------------------------------
def test_flush_level_is_half_the_float32_spacing_of_the_smallest_step():
    # alpha * floor = 0.25 * 2**-10 = 2**-12: float32 spacing 2**-35, half of it 2**-36.
    assert flush_level(3.0, 0.25, 2.0 ** -10) == 36
    assert flush_level(3.0, 0.25, float("inf")) == 0          # only the threshold limits it
    assert flush_level(0.3, 0.25, float("inf")) == 2          # 2**-2 <= 0.3
    assert flush_level(-1.0, 0.25, 1.0) is None               # no level below a threshold <= 0
    assert flush_level(3.0, 0.25, 1e-44) is None              # a subnormal step leaves no margin


@settings(max_examples=200, deadline=None)
@given(alpha=st.sampled_from([0.25, 0.1, 0.5, 0.3, 1 / 3]),
       threshold=st.floats(0.5, 8.0), floor_exponent=st.integers(-30, 2),
       seed=st.integers(0, 2**32 - 1))
def test_maps_equal_above_the_flush_level_stay_equal_for_ever(alpha, threshold, floor_exponent,
                                                              seed):
    """Two exponential heat maps that differ only where both lie below the flush level E
    agree, or both lie below E, after any later heat of at least the floor: the proof in
    fastdet.batch.boundary, run."""
    rng = np.random.default_rng(seed)
    floor = 2.0 ** floor_exponent
    level = flush_level(threshold, alpha, floor)
    flush = np.float32(2.0 ** -level)
    shared = rng.exponential(threshold, (6, 7)).astype(np.float32)
    below = rng.random((6, 7)) < 0.5
    tiny = lambda: (flush * rng.random((6, 7)) ** 8).astype(np.float32)  # noqa: E731
    one, two = ExponentialHeat(alpha), ExponentialHeat(alpha)
    one._state = np.where(below, tiny(), shared).astype(np.float32)
    two._state = np.where(below, tiny(), shared).astype(np.float32)
    two._state[0, 0] = np.float32(1e-45) if below[0, 0] else two._state[0, 0]   # a subnormal
    for _ in range(25):
        heat = rng.exponential(threshold, (6, 7)).astype(np.float32) + np.float32(floor)
        heat[rng.random((6, 7)) < 0.6] = 0
        a, b = one.update(heat), two.update(heat)
        assert np.all((a == b) | ((a < flush) & (b < flush)))
        assert np.array_equal(a > threshold, b > threshold)


def test_without_the_floor_a_remnant_survives():
    """The check that can fail: compared at the threshold alone, a remnant of 1e-3 is not
    absorbed by later heat and leaves the two maps different above the threshold."""
    one, two = ExponentialHeat(0.25), ExponentialHeat(0.25)
    one._state = np.array([[1e-3]], np.float32)
    two._state = np.array([[0.0]], np.float32)
    coarse = 2.0 ** -flush_level(STUB_THRESHOLD, 0.25, float("inf"))
    assert one._state[0, 0] < coarse
    for _ in range(5):
        a, b = one.update(np.full((1, 1), 8, np.float32)), two.update(np.full((1, 1), 8, np.float32))
    assert a[0, 0] != b[0, 0] and min(a[0, 0], b[0, 0]) > STUB_THRESHOLD
    fine = 2.0 ** -flush_level(STUB_THRESHOLD, 0.25, 1.0)
    assert one._state[0, 0] >= fine       # the right level would not have certified it


@settings(max_examples=300, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), level=st.sampled_from(FLUSH_LEVELS),
       changes=st.integers(0, 3))
def test_flushed_digests_agree_exactly_when_the_maps_do_above_the_level(seed, level, changes):
    rng = np.random.default_rng(seed)
    exponents = rng.integers(-152, 4, (7, 9))
    one = (rng.random((7, 9)) * 2.0 ** exponents).astype(np.float32)
    one[rng.random((7, 9)) < 0.3] = 0
    two = one.copy()
    for _ in range(changes):
        where = tuple(rng.integers(0, [7, 9]))
        two[where] = np.float32(rng.random() * 2.0 ** rng.integers(-152, 4))
    flush = np.float32(2.0 ** -level)
    agree = bool(np.all((one == two) | ((one < flush) & (two < flush))))
    assert (flushed_digests(one)[level] == flushed_digests(two)[level]) == agree


# -- states of real pipelines -----------------------------------------------------------
def run(frames, first=0, warmup=0, order=None, config=None):
    """Detections of frames[first:] after warming up on the `warmup` frames before."""
    pipeline = VideoPipeline(BlockDetector(), config or TrackConfig())
    for frame in frames[first - warmup:first]:
        pipeline.process(frame)
    if order is not None:
        reorder_tracks(pipeline, order)
    last = (first - 1, frame_digest(frames[first - 1])) if first else None
    start = pipeline_state(pipeline, last)
    out = [pipeline.process(frame) for frame in frames[first:]]
    return start, out, pipeline


def end_state(frames, end, config=None):
    pipeline = VideoPipeline(BlockDetector(), config or TrackConfig())
    for frame in frames[:end]:
        pipeline.process(frame)
    return pipeline_state(pipeline, (end - 1, frame_digest(frames[end - 1]))), pipeline


def same_outputs(whole, segment, ids):
    """Each frame's boxes, scores and ids equal once the segment's ids are mapped (and its
    boxes listed by id, as the merge lists them)."""
    for w, s in zip(whole, segment):
        mapped = [ids(t) for t in s.track_id]
        order = np.argsort(mapped, kind="stable")
        if not (np.array_equal(w.xyxy, s.xyxy[order]) and np.array_equal(w.score, s.score[order])
                and [int(t) for t in w.track_id] == sorted(mapped)):
            return False
    return len(whole) == len(segment)


def test_pipeline_state_reads_the_pipelines_internals():
    """Pins the private attributes state.py reads: a change in the video layer fails here."""
    frames = two_blocks(12)
    _, _, pipeline = run(frames)
    state = pipeline_state(pipeline, (11, frame_digest(frames[11])))
    assert set(state) == {"scalars", "heat", "tracks", "ids", "next_id", "frame"}
    assert state["heat"]["kind"] == "exponential"
    assert set(state["heat"]["levels"]) == set(FLUSH_LEVELS)
    assert state["ids"] == [1, 2] and state["next_id"] == 3 and len(set(state["tracks"])) == 2
    fresh = pipeline_state(VideoPipeline(BlockDetector(), TrackConfig()))
    assert fresh["heat"]["levels"] is None and fresh["tracks"] == []


@pytest.mark.parametrize("config", [TrackConfig(), TrackConfig(heat_smoothing="fir"),
                                    TrackConfig(heat_smoothing="none", box_frames=3)],
                         ids=["exponential", "fir", "none"])
def test_a_certified_boundary_reproduces_the_whole_run(config):
    frames = two_blocks()
    _, whole, _ = run(frames, config=config)
    verdicts = {}
    for start in (20, 40, 62):
        previous, _ = end_state(frames, start, config)
        for warmup in (3, 12, 20):
            if config.heat_smoothing == "fir":
                warmup = warmup // config.heat_frames * config.heat_frames or config.heat_frames
            state, segment, _ = run(frames, start, warmup, config=config)
            verdict = compare(previous, state, STUB_THRESHOLD, STUB_HEAT)
            verdicts[start, warmup] = verdict
            if verdict.exact:
                ids = IdMap.across(previous["ids"], previous["next_id"], state)
                assert same_outputs(whole[start:], segment, ids), (start, warmup)
    assert any(v.exact for v in verdicts.values())
    assert not all(v.exact for v in verdicts.values())


def test_tracks_found_in_another_order_are_put_in_order():
    # Two parked vehicles, heat unsmoothed (with smoothing, A's heat would creep up to
    # 2 - 2**-23 in the whole run and stay there, while the warm-up takes 2 as it is).
    frames, config = two_blocks(110, speed=0), TrackConfig(heat_alpha=1.0)
    _, whole, _ = run(frames, config=config)
    previous, _ = end_state(frames, 100, config)
    state, _, _ = run(frames, 100, warmup=20, config=config)
    verdict = compare(previous, state, STUB_THRESHOLD, STUB_HEAT)
    # The whole run met B (bottom) first; the warm-up meets A (top) first, in raster order.
    assert not verdict.exact and verdict.order == [1, 0]
    state, segment, _ = run(frames, 100, warmup=20, order=verdict.order, config=config)
    assert compare(previous, state, STUB_THRESHOLD, STUB_HEAT).exact
    ids = IdMap.across(previous["ids"], previous["next_id"], state)
    assert same_outputs(whole[100:], segment, ids)
    assert ids.continued == {2: 1, 1: 2}


def test_other_frames_before_the_boundary_are_caught():
    frames = two_blocks()
    previous, _ = end_state(frames, 30)
    state, _, _ = run(frames[:29] + [frames[30]] + frames[30:], 30, warmup=20)
    assert compare(previous, state, STUB_THRESHOLD, STUB_HEAT).reason == \
        "the frames before the boundary differ"


def test_id_maps():
    ids = IdMap({4: 10, 5: 12}, first_new=7, shift=6)
    assert [ids(4), ids(5), ids(7), ids(9)] == [10, 12, 13, 15]
    with pytest.raises(ValueError, match="neither carried over nor new"):
        ids(6)
    assert IdMap.from_dict(ids.to_dict()) == ids
    assert ids.end_ids({"ids": [5, 8], "next_id": 11}) == ([12, 14], 17)
    assert IdMap.identity()(3) == 3
