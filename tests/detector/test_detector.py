"""Detector: input handling, planning, heat and boxes (independent of the bundled model)."""

import numpy as np
import pytest

from fastdet.detector import scoring
from fastdet.detector.config import (
    PREVIOUS_SCALES,
    PUBLISHED_SCALES,
    BoxConfig,
    DetectorConfig,
    HeatConfig,
    ScaleConfig,
    SearchConfig,
)
from fastdet.detector.detector import PLANNED_SIZES, Detector
from fastdet.detector.features import FeatureLayout, FeatureOptions
from fastdet.detector.frames import as_bgr_frame
from fastdet.detector.model import Model
from fastdet.detector.plan import plan_scales
from fastdet.detector.scoring import Hits
from fastdet.errors import InputError


@pytest.fixture(scope="module")
def random_model():
    options = FeatureOptions()
    rng = np.random.default_rng(3)
    weights = rng.normal(scale=0.01, size=FeatureLayout(options).length).astype(np.float32)
    return Model(weights=weights, bias=-0.2, options=options)


def test_frame_conversions():
    grey = np.full((20, 30), 7, np.uint8)
    assert as_bgr_frame(grey).shape == (20, 30, 3)
    assert as_bgr_frame(grey[:, :, None]).shape == (20, 30, 3)
    bgra = np.zeros((20, 30, 4), np.uint8)
    bgra[..., 0] = 9
    out = as_bgr_frame(bgra)
    assert out.shape == (20, 30, 3) and out[0, 0, 0] == 9
    strided = np.zeros((20, 60, 3), np.uint8)[:, ::2]
    assert as_bgr_frame(strided).flags.c_contiguous


@pytest.mark.parametrize("frame, words", [
    (np.zeros((10, 10, 3), np.float32), "uint8"),
    (np.zeros((10, 10, 2), np.uint8), "shape"),
    (np.zeros((2, 10, 10, 3), np.uint8), "shape"),
    ([[0, 1]], "numpy array"),
])
def test_bad_frames_raise_input_error(random_model, frame, words):
    detector = Detector(random_model, threads=1)
    with pytest.raises(InputError, match=words):
        detector(frame)


@pytest.mark.parametrize("shape", [(10, 10, 3), (63, 500, 3), (40, 40), (1, 1, 3)])
def test_frames_smaller_than_any_window_give_no_boxes(random_model, shape):
    detector = Detector(random_model, threads=1)
    detections = detector(np.zeros(shape, np.uint8))
    assert len(detections) == 0
    assert detector.heatmap(np.zeros(shape, np.uint8)).shape == shape[:2]


@pytest.mark.parametrize("scales, grids", [
    (PUBLISHED_SCALES, [(2, 20), (6, 52), (6, 12), (6, 42), (5, 37)]),
    (PREVIOUS_SCALES, [(2, 20), (6, 52), (3, 77), (6, 42), (5, 37)]),
])
def test_plans_follow_the_configured_grid(random_model, scales, grids):
    config = DetectorConfig(search=SearchConfig(scales=scales))
    plans = plan_scales(config, random_model.options, (1280, 720))
    assert [p.grid for p in plans] == grids
    first = plans[0]
    assert first.roi == (320, 396, 960, 460)
    assert first.boxes[0].tolist() == [320, 396, 352, 428]
    # Every window lies inside its region of interest.
    for plan in plans:
        x0, y0, x1, y1 = plan.roi
        assert plan.boxes[:, 0].min() >= x0 and plan.boxes[:, 2].max() <= x1
        assert plan.boxes[:, 1].min() >= y0 and plan.boxes[:, 3].max() <= y1


@pytest.mark.parametrize("config", [DetectorConfig(),
                                    DetectorConfig(search=SearchConfig(scales=PREVIOUS_SCALES))])
def test_plans_scale_with_the_frame(random_model, config):
    full = plan_scales(config, random_model.options, (1280, 720))
    for size in ((640, 360), (960, 540), (1920, 1080)):
        other = plan_scales(config, random_model.options, size)
        assert [p.grid for p in other] == [p.grid for p in full]
        factor = size[0] / 1280
        for a, b in zip(other, full):
            # Each window is rounded to whole pixels at both sizes.
            np.testing.assert_allclose(a.boxes, b.boxes * factor, atol=2 * max(factor, 1))


def test_default_windows_lie_in_their_band_and_reach(random_model):
    search = SearchConfig()
    for width, height in ((1280, 720), (960, 540), (1000, 750)):
        plans = plan_scales(DetectorConfig(search=search), random_model.options, (width, height))
        assert len(plans) == len(search.windows)
        for plan, window in zip(plans, search.windows):
            side = window.size * height
            boxes = plan.boxes.astype(float)
            # Square windows of the configured side (to the pixel).
            assert np.abs(boxes[:, 2] - boxes[:, 0] - side).max() <= 1
            assert np.abs(boxes[:, 3] - boxes[:, 1] - side).max() <= 1
            tops = (boxes[:, 1] - search.horizon * height) / side
            slack = (search.margin * height + 1) / side
            assert tops.min() >= search.band[0] - slack
            assert tops.max() <= search.band[1] + slack
            centres = (boxes[:, 0] + boxes[:, 2]) / 2 - width / 2
            assert np.abs(centres).max() <= search.reach * side + 2
            # The step follows the overlap (rounded to whole 8-pixel cells of the 64-px window).
            step = np.diff(np.unique(boxes[:, 0]))
            assert np.abs(step - (1 - window.overlap) * side).max() <= side / 8 + 1


def test_a_lower_horizon_moves_every_band_down(random_model):
    high = plan_scales(DetectorConfig(), random_model.options, (1280, 720))
    low = plan_scales(DetectorConfig(search=SearchConfig(horizon=0.65)), random_model.options,
                      (1280, 720))
    for a, b in zip(high, low):
        assert b.roi[1] - a.roi[1] == pytest.approx(0.07 * 720, abs=1)


def test_heatmap_and_boxes_from_known_hits(random_model):
    config = DetectorConfig(heat=HeatConfig(threshold=1, weighting="count", peak_fraction=0),
                            boxes=BoxConfig(min_size=1, horizon_y=0, width_scale=1,
                                            height_scale=1, center_dy=0, refine=()))
    detector = Detector(random_model, config, threads=1)
    boxes = np.array([[10, 10, 50, 50], [20, 20, 60, 60], [200, 200, 240, 240]], np.int32)
    hits = Hits(boxes, np.ones(3, np.float32), np.zeros(3, np.int64), 3)
    heat, origin = detector.heat_region(hits, (300, 300))
    assert origin == (10, 10)
    assert heat.max() == 2
    detections = detector.boxes_from_heat(heat, origin, (300, 300))
    assert detections.xyxy.tolist() == [[20, 20, 50, 50]]
    assert detections.score.tolist() == [2.0]


def test_box_filter_applies_size_aspect_and_horizon(random_model):
    config = DetectorConfig(boxes=BoxConfig(min_size=20, min_aspect=0.5, max_aspect=3.0,
                                            horizon_y=100))
    detector = Detector(random_model, config, threads=1)
    boxes = np.array([
        [0, 200, 40, 240],    # kept
        [0, 200, 10, 240],    # too narrow, aspect 0.25
        [0, 200, 130, 230],   # aspect 4.3
        [0, 40, 40, 90],      # above the horizon
        [0, 80, 40, 120],     # crosses the horizon: kept
    ], np.int32)
    assert detector.box_finder.box_filter(boxes, (1280, 720)).tolist() == [True, False, False, False, True]


@pytest.mark.parametrize("cut_scales", [False, True])
def test_threaded_and_serial_detectors_agree_exactly(data_dir, cut_scales, monkeypatch):
    import cv2
    import numba
    if numba.config.NUMBA_NUM_THREADS < 2:
        pytest.skip("NUMBA_NUM_THREADS caps the detector at one thread")
    if cut_scales:  # the two largest scales in row tasks, as with more threads
        monkeypatch.setattr(scoring, "BALANCE_TOLERANCE", -1.0)
    frame = cv2.imread(str(data_dir / "test_images" / "test1.jpg"))
    serial = Detector(threads=1)
    try:
        threaded = Detector(threads=2)
        assert threaded.threads == 2
        kinds = {task.kind for task in threaded.bands((1280, 720))}
        assert kinds == ({"whole", "rows", "windows"} if cut_scales else {"whole"})
        for _ in range(2):  # the second call reuses the scales' buffers
            a, b = serial.hits(frame), threaded.hits(frame)
            assert a.windows_scored == b.windows_scored > 0
            np.testing.assert_array_equal(a.boxes, b.boxes)
            np.testing.assert_array_equal(a.scores, b.scores)
            np.testing.assert_array_equal(a.scale_index, b.scale_index)
        assert threaded._pool is not None  # the scales did run on the pool
        assert len(a.scores) > 0
        boxes_a, boxes_b = serial(frame), threaded(frame)
        np.testing.assert_array_equal(boxes_a.xyxy, boxes_b.xyxy)
        np.testing.assert_array_equal(boxes_a.score, boxes_b.score)
        # The scales' stage times of every pool thread are all counted.
        assert threaded.timings["cells"] > 0 and threaded.timings["blocks_score"] > 0
    finally:
        Detector(threads=1)  # restore the thread count for later tests


@pytest.mark.parametrize("size", [(1280, 720), (960, 540), (1920, 1080)])
def test_default_scales_take_one_kernel_call_and_score_what_three_calls_do(data_dir, size,
                                                                           monkeypatch):
    """Every scale of the default search, at the three frame sizes, is scored in one
    kernel call (fastdet.kernels.band), and the hits are those of the three calls."""
    import cv2

    from fastdet.kernels.band import BandScorer
    frames = [cv2.resize(cv2.imread(str(path)), size)
              for path in sorted((data_dir / "test_images").glob("*.jpg"))[:3]]
    one_call = Detector(threads=1)
    expected = [one_call.hits(frame) for frame in frames]
    plans = one_call.plans(size)
    assert all(one_call.scorer._work(plan).band is not None for plan in plans)
    monkeypatch.setattr(BandScorer, "fits", staticmethod(lambda *bound: False))
    three_calls = Detector(threads=1)
    assert all(three_calls.scorer._work(plan).band is None for plan in three_calls.plans(size))
    for frame, hits in zip(frames, expected):
        again = three_calls.hits(frame)
        np.testing.assert_array_equal(again.boxes, hits.boxes)
        np.testing.assert_array_equal(again.scores, hits.scores)
    assert sum(len(hits.scores) for hits in expected) > 0
    assert one_call.timings["cells"] > 0 and one_call.timings["colour_maps"] > 0
    assert one_call.timings["blocks_score"] > 0


def test_buffers_follow_the_plan_objects(random_model):
    import cv2
    detector = Detector(random_model, threads=1)
    frame = np.random.default_rng(0).integers(0, 256, (720, 1280, 3), dtype=np.uint8)
    small = cv2.resize(frame, (640, 360))
    expected = {size: [detector.score_scale(detector.prepare(image), plan)
                       for plan in detector.plans(size)]
                for size, image in (((1280, 720), frame), ((640, 360), small))}
    # Plans made fresh for every call (ids of dead plans get reused) still
    # get buffers of their own size and the same scores.
    for _ in range(3):
        for size, image in (((1280, 720), frame), ((640, 360), small)):
            prepared = detector.prepare(image)
            for plan, scores in zip(plan_scales(detector.config, detector.model.options, size),
                                    expected[size]):
                np.testing.assert_array_equal(detector.score_scale(prepared, plan), scores)


def test_full_width_regions_at_scale_one_are_scored_in_place(random_model):
    detector = Detector(random_model, threads=1)
    frame = np.random.default_rng(1).integers(0, 256, (720, 1280, 3), dtype=np.uint8)
    prepared = detector.prepare(frame)
    plan = detector.plans((1280, 720))[2]
    assert plan.scaled_size[0] == 1280                      # the default 64-px scale
    x0, y0, x1, y1 = plan.roi
    ox, oy = prepared.origin
    region = prepared.converted[y0 - oy:y1 - oy, x0 - ox:x1 - ox]
    assert np.shares_memory(detector.scorer.scaled_region(region, plan, 3), prepared.converted)
    in_place = detector.score_scale(prepared, plan)
    copied = Detector(random_model, threads=1)
    copied.scorer.scaled_region = lambda region, plan, channels, *band: np.array(region)
    np.testing.assert_array_equal(copied.score_scale(prepared, plan), in_place)


def test_one_scale_config_scores_only_that_scale(random_model):
    config = DetectorConfig(search=SearchConfig(scales=(ScaleConfig(64, 0.5, (0, 256), (0, 128)),),
                                                reference_size=(256, 128)))
    detector = Detector(random_model, config, threads=1)
    hits = detector.hits(np.random.default_rng(0).integers(0, 255, (128, 256, 3), np.uint8))
    assert hits.windows_scored == 3 * 7


def _boxes_from_hits(model, windows, split, min_size=48):
    config = DetectorConfig(heat=HeatConfig(threshold=0.5, weighting="count", peak_fraction=0,
                                            split=split, split_min_size=min_size),
                            boxes=BoxConfig(min_size=10, horizon_y=0, max_aspect=5, width_scale=1,
                                            height_scale=1, center_dy=0, refine=()))
    detector = Detector(model, config, threads=1)
    boxes = np.array(windows, np.int32)
    hits = Hits(boxes, np.ones(len(boxes), np.float32), np.zeros(len(boxes), np.int64), len(boxes))
    heat, origin = detector.heat_region(hits, (1280, 720))
    return detector.boxes_from_heat(heat, origin, (1280, 720)).xyxy.tolist()


def test_two_cars_side_by_side_are_split(random_model):
    # Two clusters of hits whose heat islands touch with a valley between their peaks.
    left = [[400 + dx, 400 + dy, 470 + dx, 470 + dy] for dx in (0, 5, 10) for dy in (0, 5)]
    right = [[490 + dx, 400 + dy, 560 + dx, 470 + dy] for dx in (-10, -5, 0) for dy in (0, 5)]
    assert _boxes_from_hits(random_model, left + right, split=False) == [[400, 400, 560, 475]]
    assert _boxes_from_hits(random_model, left + right, split=True) == [
        [400, 400, 480, 475], [480, 400, 560, 475]]


def test_one_wide_car_stays_one_box(random_model):
    # Evenly overlapping hits along a wide car: one plateau, no valley.
    wide = [[400 + dx, 400, 480 + dx, 480] for dx in range(0, 100, 8)]
    assert _boxes_from_hits(random_model, wide, split=True) == [[400, 400, 576, 480]]


def test_small_parts_are_not_split_off(random_model):
    # A valley, but one side is narrower than split_min_size: not a second car.
    big = [[400 + dx, 400 + dy, 470 + dx, 470 + dy] for dx in (0, 5, 10) for dy in (0, 5)]
    small = [[478 + dx, 420 + dy, 518 + dx, 460 + dy] for dx in (-4, 0, 4) for dy in (0, 5)]
    assert _boxes_from_hits(random_model, big + small, split=True) == [[400, 400, 522, 475]]
    # The same blob splits when parts of 20 pixels count as cars.
    assert len(_boxes_from_hits(random_model, big + small, split=True, min_size=20)) == 2


def test_shape_correction_scales_about_the_centre(random_model):
    config = DetectorConfig(boxes=BoxConfig(width_scale=1.5, height_scale=0.5, center_dy=0.25,
                                            refine=()))
    detector = Detector(random_model, config, threads=1)
    boxes = np.array([[100, 100, 200, 200], [0, 0, 40, 40]], np.int32)
    out = detector.box_finder.reshape_boxes(boxes, (1280, 720))
    assert out[0].tolist() == [75, 150, 225, 200]   # centre y moved by 25, half height 25
    assert out[1].tolist() == [0, 20, 50, 40]       # clipped to the frame


def test_tasks_are_whole_scales_unless_the_threads_would_be_unbalanced(random_model):
    detector = Detector(random_model, threads=1, preload=False)
    plans = detector.plans((1280, 720))
    # One thread, and two on the default search (whose whole scales split evenly).
    for threads in (1, 2):
        tasks = detector.scorer.bands(plans, threads)
        assert sorted(task.index for task in tasks) == list(range(len(plans)))
        assert {task.kind for task in tasks} == {"whole"}
    # Three threads: whole scales (the two largest 27 % of the pixels each) would leave
    # one thread 37 % of the frame against an even third, so the scales are cut.
    used = [((plan.grid[0] - 1) * plan.step_cells * 8 + 64) * plan.scaled_size[0]
            for plan in plans]
    assert scoring._longest_share(used, 2) / (sum(used) / 2) < 1 + scoring.BALANCE_TOLERANCE
    assert scoring._longest_share(used, 3) / (sum(used) / 3) > 1 + scoring.BALANCE_TOLERANCE
    tasks = detector.scorer.bands(plans, 3)
    largest = max(range(len(plans)),
                  key=lambda i: plans[i].scaled_size[0] * plans[i].scaled_size[1])
    rows = sorted((task.first, task.stop) for task in tasks
                  if task.index == largest and task.kind == "rows")
    assert len(rows) == 2
    plan = plans[largest]
    assert rows[0][0] == 0 and rows[0][1] == rows[1][0]
    assert rows[1][1] == used[largest] // plan.scaled_size[0]  # every row the windows cover
    assert rows[0][1] % detector.scorer._row_alignment(plan) == 0
    # A cut scale's windows are scored after all of its rows.
    for position, task in enumerate(tasks):
        if task.kind == "windows":
            assert all(other.kind != "rows" or other.index != task.index
                       for other in tasks[position + 1:])
    assert any(task.kind == "windows" and task.index == largest for task in tasks)


def test_longest_share_gives_each_task_to_the_least_loaded_thread():
    assert scoring._longest_share([5, 4, 3, 3, 3], 2) == 10   # 5+3 | 4+3+3
    assert scoring._longest_share([1, 1, 1, 1], 4) == 1
    assert scoring._longest_share([9, 1], 3) == 9


def test_a_failing_task_fails_the_frame_without_hanging(random_model, monkeypatch):
    import numba
    if numba.config.NUMBA_NUM_THREADS < 2:
        pytest.skip("NUMBA_NUM_THREADS caps the detector at one thread")
    detector = Detector(random_model, threads=2)
    frame = np.random.default_rng(3).integers(0, 256, (720, 1280, 3), dtype=np.uint8)
    detector.hits(frame)
    original = detector.scorer.run

    last = len(detector.plans((1280, 720))) - 1

    def run(task, *args):
        if task.index == last:  # the frame's last task, whichever thread takes it
            raise RuntimeError("task failed")
        return original(task, *args)

    monkeypatch.setattr(detector.scorer, "run", run)
    try:
        with pytest.raises(RuntimeError, match="task failed"):
            detector.hits(frame)
    finally:
        Detector(random_model, threads=1)  # restore the thread count for later tests


@pytest.mark.parametrize("threads", [1, 2])
def test_hits_do_not_depend_on_the_frame_sizes_seen_before(threads):
    """A detector fed frames of many sizes (more work arrays than it keeps) gives each frame
    the hits a new detector gives it.  Found by fuzzing: the arrays were once dropped in the
    middle of a frame, between computing a scale's cells and scoring them."""
    rng = np.random.default_rng(1)
    frames = []
    for _ in range(24):
        height, width = int(rng.integers(64, 400)), int(rng.integers(64, 720))
        frame = rng.integers(0, 256, (height, width, 3), dtype=np.uint8)
        frame[: height // 2] = rng.integers(0, 256)
        frames.append(frame)
    seasoned = Detector(threads=threads)
    for frame in frames + frames[:3]:     # the first sizes again, once their plans were dropped
        seen, new = seasoned.hits(frame), Detector(threads=threads).hits(frame)
        np.testing.assert_array_equal(seen.boxes, new.boxes)
        np.testing.assert_array_equal(seen.scores, new.scores)
    # A process fed endless new sizes keeps the plans of the last few only.
    assert len(seasoned._plans) == len(seasoned._all_windows) == PLANNED_SIZES
    assert len(seasoned._bands) <= PLANNED_SIZES


def test_box_sides_snap_to_the_frame_inside_the_search_band_only(random_model, data_dir):
    import cv2

    frame = cv2.imread(str(data_dir / "test_images" / "test1.jpg"))
    size = (frame.shape[1], frame.shape[0])
    snapping = Detector(random_model, threads=1)
    plain = Detector(random_model, DetectorConfig(boxes=BoxConfig(snap_sides=0.0)), threads=1)
    shaped = Detector(random_model, DetectorConfig(boxes=BoxConfig(refine=())), threads=1)
    # A blob over the car on the right of test1, taller than the search band:
    # the middle half of its refined box's rows reaches below the band.
    heat = np.zeros((720, 1280), np.float32)
    heat[380:620, 800:1000] = 5.0
    band = plan_scales(snapping.config, random_model.options, size)
    first, stop = min(p.roi[1] for p in band), max(p.roi[3] for p in band)
    assert 380 + 60 < stop < 620 - 60
    noisy = frame.copy()
    rng = np.random.default_rng(0)
    noisy[:first] = rng.integers(0, 256, noisy[:first].shape, dtype=np.uint8)
    noisy[stop:] = rng.integers(0, 256, noisy[stop:].shape, dtype=np.uint8)
    unsnapped = plain.boxes_from_heat(heat, (0, 0), size, frame).xyxy
    snapped = snapping.boxes_from_heat(heat, (0, 0), size, frame).xyxy
    assert len(snapped) == 1 and snapped[0, 1::2].tolist() == unsnapped[0, 1::2].tolist()
    top, bottom = snapped[0, 1], snapped[0, 3]
    assert bottom - (bottom - top) // 4 > stop
    assert snapped[0, ::2].tolist() != unsnapped[0, ::2].tolist()   # the sides moved
    assert snapping.boxes_from_heat(heat, (0, 0), size, noisy).xyxy.tolist() == snapped.tolist()
    # A grey or BGRA frame is taken as detection takes it; anything else is a one-line error.
    grey = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
    assert (snapping.boxes_from_heat(heat, (0, 0), size, grey).xyxy.tolist()
            == snapping.boxes_from_heat(heat, (0, 0), size,
                                        cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR)).xyxy.tolist())
    with pytest.raises(InputError, match="uint8"):
        snapping.boxes_from_heat(heat, (0, 0), size, frame.astype(np.float32))
    # Without a frame (or with snap_sides 0) the boxes are the heat's alone,
    # and so are boxes that were shape-corrected, not refined.
    assert snapping.boxes_from_heat(heat, (0, 0), size).xyxy.tolist() == unsnapped.tolist()
    assert (shaped.boxes_from_heat(heat, (0, 0), size, frame).xyxy.tolist()
            == shaped.boxes_from_heat(heat, (0, 0), size).xyxy.tolist())


def test_config_may_be_a_toml_file_and_nothing_else(random_model, tmp_path):
    """A path was taken as it was, and the first frame failed with an
    AttributeError deep in the planning."""
    from fastdet.errors import ConfigError

    path = tmp_path / "detector.toml"
    path.write_text("[heat]\nthreshold = 3\n[search]\ndecision_threshold = -0.5\n")
    for config in (path, str(path)):
        detector = Detector(random_model, config, threads=1, preload=False)
        assert detector.config.heat.threshold == 3
        assert detector.config.search.decision_threshold == -0.5
    detector.config = None
    assert detector.config == DetectorConfig()
    for wrong in ({"heat": {"threshold": 3}}, 5):
        with pytest.raises(ConfigError, match="config must be a DetectorConfig or a TOML file"):
            Detector(random_model, wrong, threads=1, preload=False)
        with pytest.raises(ConfigError, match="config must be a DetectorConfig or a TOML file"):
            detector.config = wrong
    with pytest.raises(ConfigError, match="missing.toml"):
        Detector(random_model, tmp_path / "missing.toml", threads=1, preload=False)


@pytest.mark.parametrize("threads", ["2", 1.5, True])
def test_threads_must_be_a_whole_number(random_model, threads):
    with pytest.raises(InputError, match="threads must be a whole number"):
        Detector(random_model, threads=threads, preload=False)


def test_bound_band_calls_follow_each_frame_and_size(random_model):
    """The scorer makes each band task's kernel arguments once and reuses them
    for the next frames (the converted band and the scores are refilled in
    place): frames of two sizes, in turns, must score exactly as a fresh
    detector scores each."""
    rng = np.random.default_rng(12)
    frames = [rng.integers(0, 256, shape, dtype=np.uint8)
              for shape in ((720, 1280, 3), (540, 960, 3), (720, 1280, 3), (540, 960, 3))]
    reused = Detector(model=random_model, threads=1)
    for frame in frames + frames[::-1]:
        expected = Detector(model=random_model, threads=1).hits(frame)
        got = reused.hits(frame)
        np.testing.assert_array_equal(got.scores, expected.scores)
        np.testing.assert_array_equal(got.boxes, expected.boxes)
    assert any(work.bound_bands for work in reused.scorer._workspace.values()
               if isinstance(work, scoring._ScaleWork))


def test_bound_band_calls_of_frames_that_are_gone_are_dropped(random_model):
    # prepare() converts each frame into a new array: a band scored into the
    # same score grid binds anew for each (a call bound to an earlier frame's
    # array would score that frame), and a scale keeps at most
    # _MAX_BOUND_BANDS of them.
    detector = Detector(model=random_model, threads=1)
    scorer = detector.scorer
    plans = detector.plans((1280, 720))
    plan = plans[0]
    scores = np.empty(plan.grid, np.float32)
    rng = np.random.default_rng(3)
    for _ in range(scoring._MAX_BOUND_BANDS + 5):
        frame = rng.integers(0, 256, (720, 1280, 3), dtype=np.uint8)
        scores[...] = random_model.bias
        scorer.score_band(scorer.prepare(frame, plans), plan, 0, plan.grid[0], scores,
                          dict.fromkeys(scoring.STAGES, 0.0))
        fresh = Detector(model=random_model, threads=1)
        expected = fresh.scorer.score_scale(fresh.scorer.prepare(frame, plans), plan,
                                            dict.fromkeys(scoring.STAGES, 0.0))
        np.testing.assert_array_equal(scores, expected)
    assert 0 < len(scorer._work(plan).bound_bands) <= scoring._MAX_BOUND_BANDS
