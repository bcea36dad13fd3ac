"""The horizon estimate (``[search] horizon = "auto"``): synthetic roads, real frames, config."""

import cv2
import numpy as np
import pytest

from fastdet.detector.config import DEFAULT_HORIZON, DetectorConfig, SearchConfig
from fastdet.detector.detector import Detector
from fastdet.detector.horizon import (FRAME_STEP, FRAMES, HorizonEstimate, estimate_horizon,
                                      frame_horizon, resolve_horizon)
from fastdet.errors import ConfigError, InputError
from road_images import road

AUTO = DetectorConfig.from_dict({"search": {"horizon": "auto"}})
#: Rows where the two cameras' lane lines meet, measured by hand on their
#: frames (README, "Configuration"): 416 of 720 and 310 of 540.
TEST_VIDEO_HORIZON = 416 / 720
OTHER_CAMERA_HORIZON = 310 / 540


@pytest.mark.parametrize("size", [(1280, 720), (853, 480), (1920, 1080), (333, 211)])
@pytest.mark.parametrize("horizon", [0.45, 0.58, 0.66])
def test_lane_lines_meeting_give_their_row(size, horizon):
    found = frame_horizon(road(*size, horizon))
    assert found is not None and abs(found - horizon) < 0.01


def test_dashed_lines_and_grey_frames_too():
    image = road(960, 540, 0.52, dashed=True)
    assert abs(frame_horizon(image) - 0.52) < 0.01
    grey = cv2.cvtColor(road(960, 540, 0.6), cv2.COLOR_BGR2GRAY)
    assert abs(frame_horizon(grey) - 0.6) < 0.01


def test_no_lane_lines_no_horizon():
    rng = np.random.default_rng(1)
    assert frame_horizon(np.full((360, 640, 3), 100, np.uint8)) is None
    flat = rng.integers(90, 100, (360, 640, 3), dtype=np.uint8)
    cv2.rectangle(flat, (100, 250), (500, 300), (250, 250, 250), -1)   # edges across only
    assert frame_horizon(flat) is None


def test_one_side_alone_crosses_nothing():
    image = road(960, 540, 0.55)
    image[:, 480:] = 75       # the right lane line gone
    assert frame_horizon(image) is None


def test_bad_images_are_refused():
    with pytest.raises(ValueError, match="uint8"):
        frame_horizon(np.zeros((100, 100, 3), np.float32))


@pytest.mark.parametrize("shape", [(1, 1, 3), (8, 100), (10, 10000, 3), (10000, 10, 3)])
def test_images_too_small_for_lane_lines_have_no_horizon(shape):
    """A thumbnail in a folder of images stopped ``fastdet detect --horizon auto``
    with an internal error; it has no horizon, as a frame without lane lines."""
    assert frame_horizon(np.zeros(shape, np.uint8)) is None
    estimate = estimate_horizon([np.zeros(shape, np.uint8)])
    assert estimate.fraction is None and estimate.frames_seen == 1


def test_a_video_takes_the_median_of_its_frames():
    frames = [road(640, 360, h, seed=i) for i, h in enumerate((0.50, 0.51, 0.52, 0.70))]
    estimate = estimate_horizon(frames + [None])
    assert estimate.frames == estimate.frames_seen == 4
    assert abs(estimate.fraction - 0.515) < 0.01
    low, high = estimate.spread
    assert low < estimate.fraction < high


def test_too_few_frames_with_lines_give_none():
    blank = np.full((360, 640, 3), 80, np.uint8)
    estimate = estimate_horizon([road(640, 360, 0.5)] + [blank] * 5)
    assert estimate.fraction is None and (estimate.frames, estimate.frames_seen) == (1, 6)
    assert "no horizon found" in estimate.describe()
    assert estimate_horizon([]).fraction is None


def test_numeric_horizons_read_no_frame():
    def frames():
        raise AssertionError("frames read for a numeric horizon")
        yield  # pragma: no cover

    config = DetectorConfig()
    assert resolve_horizon(config, frames()) == (config, None)


def test_resolving_moves_the_horizon_line_of_the_box_filter_with_it():
    config, estimate = resolve_horizon(AUTO, [road(1280, 720, 0.5)])
    assert abs(config.search.horizon - 0.5) < 0.01
    assert config.search.horizon == estimate.fraction
    shift = (config.search.horizon - DEFAULT_HORIZON) * 720
    assert config.horizon_line() == pytest.approx(380 + shift)
    assert AUTO.horizon_line() == DetectorConfig().horizon_line() == 380.0
    near, estimate = resolve_horizon(AUTO, [road(1280, 720, DEFAULT_HORIZON + 0.012)])
    assert abs(estimate.fraction - DEFAULT_HORIZON - 0.012) < 0.005
    assert near.search.horizon == DEFAULT_HORIZON     # within DEFAULT_SNAP: the default
    fallback, estimate = resolve_horizon(AUTO, [])
    assert estimate.fraction is None and fallback.search.horizon == DEFAULT_HORIZON
    assert fallback.horizon_line() == 380.0
    # A numeric horizon moves it too; a line that is set stays where it is.
    assert DetectorConfig().with_horizon(0.5).horizon_line() == pytest.approx(380 - 0.08 * 720)
    fixed = DetectorConfig.from_dict({"boxes": {"horizon_y": 300}})
    assert fixed.with_horizon(0.5).horizon_line() == 300.0


def test_the_box_filter_drops_boxes_above_the_moved_line():
    from fastdet.detector.boxes import BoxFinder

    box = np.array([[600, 300, 660, 350]])           # bottom at 350, above 380
    assert not BoxFinder(DetectorConfig()).box_filter(box, (1280, 720))[0]
    assert BoxFinder(DetectorConfig().with_horizon(0.5)).box_filter(box, (1280, 720))[0]


def test_config_takes_auto_and_numbers_only():
    assert AUTO.search.auto_horizon and not DetectorConfig().search.auto_horizon
    with pytest.raises(ConfigError, match='a number or "auto"'):
        SearchConfig(horizon="up")
    with pytest.raises(ConfigError, match=r"\(0, 1\)"):
        SearchConfig(horizon=1.5)


def test_a_detector_searches_resolved_horizons_only(data_dir):
    frame = cv2.imread(str(data_dir / "test_images" / "test1.jpg"))
    detector = Detector(config=AUTO, threads=1)
    assert detector.auto_horizon
    with pytest.raises(ConfigError, match="resolve_horizon"):
        detector(frame)
    estimate = detector.resolve_horizon([road(1280, 720, 0.5)])
    assert abs(detector.config.search.horizon - 0.5) < 0.01
    top = min(plan.roi[1] for plan in detector.plans((1280, 720)))
    # Another camera: resolved again from "auto", not from the last horizon.
    detector.resolve_horizon([road(1280, 720, 0.62)])
    assert abs(detector.config.search.horizon - 0.62) < 0.01
    assert min(plan.roi[1] for plan in detector.plans((1280, 720))) > top
    assert isinstance(estimate, HorizonEstimate)
    # Assigning a numeric config ends "auto".
    detector.config = DetectorConfig()
    assert not detector.auto_horizon and detector.resolve_horizon([frame]) is None
    assert len(detector(frame)) > 0


def _video_frames(path, shift=0):
    capture = cv2.VideoCapture(str(path))
    frames = []
    for index in range(FRAME_STEP * FRAMES):
        ok, frame = capture.read()
        if not ok:
            break
        if index % FRAME_STEP == 0:
            moved = np.zeros_like(frame)
            if shift > 0:
                moved[:-shift] = frame[shift:]
            elif shift < 0:
                moved[-shift:] = frame[:shift]
            else:
                moved = frame
            frames.append(moved)
    return frames


@pytest.mark.parametrize("video, truth, rows", [
    ("test_video.mp4", TEST_VIDEO_HORIZON, 720),
    ("other_camera/solidYellowLeft_lanes.mp4", OTHER_CAMERA_HORIZON, 540)])
@pytest.mark.parametrize("shift", [0, 40, -40])
def test_real_videos_horizons_within_eight_pixels(data_dir, video, truth, rows, shift):
    """The cameras' first frames, and the same frames moved up and down by
    ``shift`` rows at 720 (a camera pitched up or down by about 3 degrees)."""
    moved = round(shift * rows / 720)
    estimate = estimate_horizon(_video_frames(data_dir / video, moved))
    assert estimate.frames >= 0.8 * estimate.frames_seen
    assert abs(estimate.fraction - (truth - moved / rows)) < 0.015


@pytest.mark.parametrize("make", [
    lambda image: cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)[:, :, None],   # (H, W, 1)
    lambda image: cv2.cvtColor(image, cv2.COLOR_BGR2BGRA),                # BGRA
    lambda image: np.asfortranarray(cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)),
    lambda image: np.dstack([cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)] * 2)[:, :, 0],  # strided
], ids=["grey-1-channel", "bgra", "grey-fortran", "grey-view"])
def test_frames_detection_takes_have_a_horizon(make):
    """(H, W, 1) frames, which a detector takes, reached OpenCV's colour
    conversion, which refused them with its own message."""
    image = road(640, 360, 0.52)
    expected = frame_horizon(cv2.cvtColor(image, cv2.COLOR_BGR2GRAY))
    assert expected is not None
    assert frame_horizon(make(image)) == expected
    assert estimate_horizon([make(image)]).fraction == expected


@pytest.mark.parametrize("frame", [np.zeros((100, 100, 2), np.uint8),
                                   np.zeros((100, 100, 5), np.uint8),
                                   np.zeros((1, 100, 100, 3), np.uint8),
                                   np.zeros(100, np.uint8),
                                   np.zeros((100, 100, 3), np.uint16),
                                   [[0] * 100] * 100],
                         ids=["2-channels", "5-channels", "4d", "1d", "uint16", "list"])
def test_frames_detection_refuses_are_input_errors(frame):
    with pytest.raises(InputError, match="a frame must"):
        frame_horizon(frame)
    with pytest.raises(InputError, match="a frame must"):
        estimate_horizon([frame])


@pytest.mark.parametrize("shape", [(360, 640, 3), (360, 640), (360, 640, 4)])
def test_one_frame_not_in_a_list_is_a_type_error(shape):
    """Iterated, one frame's pixel rows were taken for 360 frames too small to
    have a horizon: the estimate silently found none."""
    frame = np.zeros(shape, np.uint8)
    with pytest.raises(TypeError, match=r"pass \[frame\]"):
        estimate_horizon(frame)
    with pytest.raises(TypeError, match=r"pass \[frame\]"):
        Detector(config=AUTO, threads=1, preload=False).resolve_horizon(frame)


def test_a_stack_of_frames_is_frames():
    frames = np.stack([road(640, 360, 0.52), road(640, 360, 0.52, seed=1)])
    assert estimate_horizon(frames).frames_seen == 2
    assert estimate_horizon(frames[:, :, :, 0]).frames_seen == 2   # grey (N, H, W)


@pytest.mark.parametrize("estimate", [0.55, None, "auto"])
@pytest.mark.parametrize("config", [AUTO, None], ids=["auto", "numeric"])
def test_take_horizon_takes_only_estimates(config, estimate):
    """A number (or None) failed on ``.fraction`` with an AttributeError when the
    horizon was "auto", and was silently ignored when it was a number."""
    detector = Detector(config=config, threads=1, preload=False)
    with pytest.raises(TypeError, match="needs a HorizonEstimate"):
        detector.take_horizon(estimate)
