"""Tests for ``fastdet.detector.features``: option validation, the feature layout, and
the contract that training features (``crop_features``) are exactly the
features the detector scores for each window (``Detector.score_scale``)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from naive import opencv_hls
from skimage.feature import hog as skimage_hog

from fastdet.detector.config import DetectorConfig, ScaleConfig, SearchConfig
from fastdet.detector.detector import Detector
from fastdet.detector.features import (
    WINDOW,
    FeatureLayout,
    FeatureOptions,
    color_planes,
    convert_color,
    crop_features,
    features_of_crops,
    hog_blocks,
    hog_input,
)
from fastdet.detector.model import Model
from fastdet.errors import ConfigError

#: Option variants (overrides of the defaults) the detector is checked with.
VARIANTS = {
    "default": {},
    "gray": {"hog_channel": "gray"},
    "channel1": {"hog_channel": 1},
    "spatial16": {"spatial_size": 16},
    "hist16": {"hist_bins": 16},
    "no-hog": {"use_hog": False},
    "orientations11": {"orientations": 11},
    "L1": {"block_norm": "L1"},
}

#: Further variants: other colour spaces, cell and block sizes, group mixes.
MORE_VARIANTS = {
    "HSV-ppc16-cpb3-spatial8-hist7": {"color_space": "HSV", "pixels_per_cell": 16,
                                      "cells_per_block": 3, "spatial_size": 8, "hist_bins": 7},
    "LUV-ppc4-L2-channel0": {"color_space": "LUV", "pixels_per_cell": 4, "block_norm": "L2",
                             "hog_channel": 0},
    "RGB-hog-only-L1sqrt": {"color_space": "RGB", "spatial_size": 0, "hist_bins": 0,
                            "block_norm": "L1-sqrt"},
    "LAB-spatial64-cpb1": {"color_space": "LAB", "spatial_size": 64, "cells_per_block": 1},
    "HLS-hist-only": {"color_space": "HLS", "use_hog": False, "spatial_size": 0},
}

ALL_VARIANTS = {**VARIANTS, **MORE_VARIANTS}


# -- helpers ----------------------------------------------------------------
def read_bgr(path):
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        pytest.fail(f"cannot read test image {path} (missing or unreadable; "
                    f"set FASTDET_DATA to the shared data folder)", pytrace=False)
    return image


@pytest.fixture(scope="module")
def crops(data_dir):
    """Two real 64x64 vehicle crops (vehicles/GTI_Far) and a random one."""
    folder = data_dir / "vehicles" / "GTI_Far"
    paths = sorted(folder.glob("*.png"))[:2]
    if len(paths) < 2:
        pytest.fail(f"expected PNG crops in {folder}", pytrace=False)
    rng = np.random.default_rng(0)
    return [read_bgr(p) for p in paths] + [rng.integers(0, 256, (64, 64, 3), dtype=np.uint8)]


def random_model(options, seed=0):
    layout = FeatureLayout(options)
    rng = np.random.default_rng(seed)
    return Model(weights=(rng.normal(size=layout.length) * 0.01).astype(np.float32),
                 bias=float(rng.normal()), options=options)


def single_window_detector(model):
    scale = ScaleConfig(64, 0.0, (0, 64), (0, 64))
    config = DetectorConfig(search=SearchConfig(scales=(scale,), reference_size=(64, 64)))
    return Detector(model, config=config)


def score_tolerance(model, features):
    """1e-4 relative to the size of the terms summed into a score."""
    terms = abs(model.bias) + np.abs(model.weights.astype(np.float64)) @ np.abs(features)
    return 1e-4 * terms


def scaled_planes(frame, plan, options):
    """The detector's images of one scale: the region of interest converted
    to the colour space (and grey), then resized to ``plan.scaled_size``."""
    x0, y0, x1, y1 = plan.roi
    converted, grey = color_planes(np.ascontiguousarray(frame[y0:y1, x0:x1]), options)
    converted = cv2.resize(converted, plan.scaled_size, interpolation=cv2.INTER_LINEAR)
    if grey is not None:
        grey = cv2.resize(grey, plan.scaled_size, interpolation=cv2.INTER_LINEAR)
    return converted, grey


def whole_image_blocks(converted, grey, options):
    """HOG block map of a whole (scaled) image, or None without HOG."""
    if not options.use_hog:
        return None
    return hog_blocks(hog_input(converted, grey, options), options)


def box_average(pixels, size):
    """Mean of each (64 / size)-pixel square tile, in float64."""
    f = pixels.shape[0] // size
    return pixels.astype(np.float64).reshape(size, f, size, f, 3).mean(axis=(1, 3))


def explicit_window_features(converted, blocks, options, iy, ix, step_cells):
    """Window (iy, ix)'s features built by hand from ``fastdet.detector.features``
    functions: HOG blocks of the whole image (``whole_image_blocks``) sliced
    for the window, the window's converted pixels box-averaged (exact means),
    and np.histogram of each channel of those pixels over 0..256."""
    layout = FeatureLayout(options)
    ppc = options.pixels_per_cell
    y0, x0 = iy * step_cells * ppc, ix * step_cells * ppc
    pixels = converted[y0:y0 + WINDOW, x0:x0 + WINDOW]
    assert pixels.shape == (WINDOW, WINDOW, 3)
    parts = []
    if options.use_hog:
        n = layout.blocks_per_window
        by, bx = iy * step_cells, ix * step_cells
        window_blocks = blocks[by:by + n, bx:bx + n]
        assert window_blocks.shape == layout.hog_shape
        parts.append(window_blocks.ravel())
    if options.spatial_size:
        size = options.spatial_size
        parts.append(box_average(pixels, size).ravel())
    if options.hist_bins:
        for c in range(3):
            counts, _ = np.histogram(pixels[:, :, c], bins=options.hist_bins, range=(0, 256))
            parts.append(counts)
    features = np.concatenate([np.asarray(p, dtype=np.float64) for p in parts])
    assert features.shape == (layout.length,)
    return features


# -- FeatureOptions -------------------------------------------------------
@pytest.mark.parametrize("field, value", [
    ("color_space", "XYZ"),
    ("color_space", "ycrcb"),
    ("hog_channel", 3),
    ("hog_channel", -1),
    ("hog_channel", "grey"),
    ("hog_channel", True),
    ("hog_channel", 1.0),
    ("orientations", 0),
    ("orientations", 181),
    ("orientations", 9.0),
    ("orientations", True),
    ("pixels_per_cell", 0),
    ("pixels_per_cell", 7),
    ("pixels_per_cell", -8),
    ("pixels_per_cell", 128),
    ("cells_per_block", 0),
    ("cells_per_block", 9),
    ("cells_per_block", 2.0),
    ("block_norm", "L3"),
    ("block_norm", "l2-hys"),
    ("spatial_size", 24),
    ("spatial_size", -1),
    ("spatial_size", 128),
    ("spatial_size", "32"),
    ("hist_bins", 257),
    ("hist_bins", -1),
    ("hist_bins", 16.5),
])
def test_invalid_option_raises_naming_it(field, value):
    with pytest.raises(ValueError, match=field):
        FeatureOptions(**{field: value})
    with pytest.raises(ValueError, match=field):
        FeatureOptions.from_dict({**FeatureOptions().to_dict(), field: value})


def test_cells_per_block_limit_follows_pixels_per_cell():
    FeatureOptions(pixels_per_cell=16, cells_per_block=4)
    with pytest.raises(ValueError, match="cells_per_block"):
        FeatureOptions(pixels_per_cell=16, cells_per_block=5)


def test_all_groups_disabled_is_rejected():
    with pytest.raises(ValueError, match="feature group"):
        FeatureOptions(use_hog=False, spatial_size=0, hist_bins=0)


@pytest.mark.parametrize("overrides", list(ALL_VARIANTS.values()), ids=list(ALL_VARIANTS))
def test_valid_options_round_trip_through_dict(overrides):
    options = FeatureOptions(**overrides)
    data = options.to_dict()
    assert FeatureOptions.from_dict(data) == options
    assert FeatureOptions.from_dict(dict(data)).to_dict() == data


@pytest.mark.parametrize("key", ["colour_space", "window", "hog_channels", "Orientations"])
def test_from_dict_rejects_unknown_keys_by_name(key):
    data = {**FeatureOptions().to_dict(), key: 1}
    with pytest.raises(ValueError, match=key):
        FeatureOptions.from_dict(data)


@pytest.mark.parametrize("data", [None, [1], "HLS", {1: 2}])
def test_from_dict_of_no_table_is_a_config_error(data):
    """A model's metadata is any JSON: a list failed with "sequence item 0:
    expected str instance, int found", ``None`` with "not iterable"."""
    with pytest.raises(ConfigError, match="must be a table|unknown feature option"):
        FeatureOptions.from_dict(data)


def test_from_dict_fills_missing_keys_with_defaults():
    assert FeatureOptions.from_dict({"hist_bins": 16}) == FeatureOptions(hist_bins=16)


# -- FeatureLayout ------------------------------------------------------------
def test_default_layout_lengths():
    layout = FeatureLayout(FeatureOptions())
    assert layout.hog_shape == (7, 7, 108)
    assert layout.spatial_shape == (32, 32, 3)
    assert layout.hist_shape == (3, 32)
    assert layout.sizes == (5292, 3072, 96)
    assert layout.length == 8460


@pytest.mark.parametrize("overrides", list(ALL_VARIANTS.values()), ids=list(ALL_VARIANTS))
def test_layout_lengths_follow_the_options(overrides):
    o = FeatureOptions(**overrides)
    channels = 3 if o.hog_channel == "all" else 1
    n = 64 // o.pixels_per_cell - o.cells_per_block + 1
    hog = n * n * channels * o.cells_per_block ** 2 * o.orientations if o.use_hog else 0
    expected = (hog, 3 * o.spatial_size ** 2, 3 * o.hist_bins)
    layout = FeatureLayout(o)
    assert layout.sizes == expected
    assert layout.length == sum(expected)
    crop = np.random.default_rng(1).integers(0, 256, (64, 64, 3), dtype=np.uint8)
    assert crop_features(crop, o).shape == (layout.length,)


@pytest.mark.parametrize("overrides", list(ALL_VARIANTS.values()), ids=list(ALL_VARIANTS))
def test_layout_split_round_trip(overrides):
    layout = FeatureLayout(FeatureOptions(**overrides))
    vector = np.arange(layout.length, dtype=np.float64)
    hog, spatial, hist = layout.split(vector)
    assert hog.shape == layout.hog_shape
    assert spatial.shape == layout.spatial_shape
    assert hist.shape == layout.hist_shape
    joined = np.concatenate([hog.ravel(), spatial.ravel(), hist.ravel()])
    np.testing.assert_array_equal(joined, vector)


@pytest.mark.parametrize("length_change", [-1, 1])
def test_layout_split_rejects_wrong_length(length_change):
    layout = FeatureLayout(FeatureOptions())
    with pytest.raises(ValueError):
        layout.split(np.zeros(layout.length + length_change))
    with pytest.raises(ValueError):
        layout.split(np.zeros((1, layout.length)))


# -- crop_features ------------------------------------------------------------
@pytest.mark.parametrize("crop", [
    np.zeros((64, 64), np.uint8),
    np.zeros((64, 64, 4), np.uint8),
    np.zeros((63, 64, 3), np.uint8),
    np.zeros((64, 64, 3), np.float32),
])
def test_crop_features_rejects_non_crops(crop):
    with pytest.raises(ValueError):
        crop_features(crop, FeatureOptions())


def test_crop_features_hog_part_is_skimage_hog_per_channel(crops):
    # Pins the HOG feature order: blocks row by row, each (channel, cell_y, cell_x, bin).
    options = FeatureOptions(color_space="YCrCb")
    for crop in crops:
        hog, _, _ = FeatureLayout(options).split(crop_features(crop, options))
        converted = cv2.cvtColor(crop, cv2.COLOR_BGR2YCrCb)
        per_channel = hog.reshape(7, 7, 3, 2, 2, 9)
        for c in range(3):
            expected = skimage_hog(converted[:, :, c], orientations=9, pixels_per_cell=(8, 8),
                                   cells_per_block=(2, 2), block_norm="L2-Hys",
                                   feature_vector=False)
            np.testing.assert_allclose(per_channel[:, :, c], expected, rtol=0, atol=1e-5)


def test_crop_features_spatial_and_histogram_parts(crops):
    options = FeatureOptions(color_space="HSV", spatial_size=16, hist_bins=16)
    crop = crops[0]
    _, spatial, hist = FeatureLayout(options).split(crop_features(crop, options))
    converted = cv2.cvtColor(crop, cv2.COLOR_BGR2HSV)
    np.testing.assert_allclose(spatial, box_average(converted, 16), rtol=1e-6, atol=1e-4)
    for c in range(3):
        np.testing.assert_array_equal(
            hist[c], np.histogram(converted[:, :, c], bins=16, range=(0, 256))[0])
    assert hist.sum() == 3 * 64 * 64


def test_features_of_crops_stacks_crop_features(crops):
    options = FeatureOptions(hog_channel="gray")
    stacked = features_of_crops(iter(crops), options)
    assert stacked.dtype == np.float32
    assert stacked.shape == (len(crops), FeatureLayout(options).length)
    for row, crop in zip(stacked, crops):
        np.testing.assert_array_equal(row, crop_features(crop, options))


@pytest.mark.parametrize("overrides", list(ALL_VARIANTS.values()), ids=list(ALL_VARIANTS))
def test_explicit_window_features_of_a_crop_are_crop_features(crops, overrides):
    # The hand-built window features used below are the training features.
    options = FeatureOptions(**overrides)
    for crop in crops:
        converted, grey = color_planes(crop, options)
        blocks = whole_image_blocks(converted, grey, options)
        np.testing.assert_allclose(explicit_window_features(converted, blocks, options, 0, 0, 1),
                                   crop_features(crop, options), rtol=0, atol=1e-6)


# -- training features == detection features ---------------------------------
@pytest.mark.parametrize("overrides", list(ALL_VARIANTS.values()), ids=list(ALL_VARIANTS))
def test_single_window_score_equals_decision_function_of_crop_features(crops, overrides):
    options = FeatureOptions(**overrides)
    model = random_model(options)
    detector = single_window_detector(model)
    (plan,) = detector.plans((64, 64))
    assert plan.grid == (1, 1)
    assert plan.roi == (0, 0, 64, 64) and plan.scaled_size == (64, 64)
    np.testing.assert_array_equal(plan.boxes, [[0, 0, 64, 64]])
    for crop in crops:
        score = detector.score_scale(detector.prepare(crop), plan)
        assert score.shape == (1, 1)
        features = crop_features(crop, options)
        expected = model.decision_function(features)
        tol = score_tolerance(model, features.astype(np.float64))
        assert abs(float(score[0, 0]) - expected) <= tol, (
            f"detector score {float(score[0, 0])!r} != decision_function {expected!r} "
            f"(tolerance {tol:.3g})")


@pytest.fixture(scope="module")
def frame(data_dir):
    image = read_bgr(data_dir / "test_images" / "test1.jpg")
    assert image.shape == (720, 1280, 3)
    return image


SCALES = (
    ScaleConfig(96, 0.5, (100, 700), (380, 620)),
    ScaleConfig(48, 0.75, (600, 1000), (400, 500)),
    ScaleConfig(64, 0.0, (0, 1280), (400, 531)),
    ScaleConfig(77, 0.25, (901, 1280), (371, 577)),
)


@pytest.mark.parametrize("overrides", list(ALL_VARIANTS.values()), ids=list(ALL_VARIANTS))
def test_every_window_score_equals_explicit_window_features(frame, overrides):
    options = FeatureOptions(**overrides)
    model = random_model(options, seed=3)
    config = DetectorConfig(search=SearchConfig(scales=SCALES, reference_size=(1280, 720)))
    detector = Detector(model, config=config)
    plans = detector.plans((1280, 720))
    assert len(plans) == len(SCALES)
    prepared = detector.prepare(frame)
    weights = model.weights.astype(np.float64)
    for plan in plans:
        scores = detector.score_scale(prepared, plan)
        assert scores.shape == plan.grid and scores.dtype == np.float32
        converted, grey = scaled_planes(frame, plan, options)
        blocks = whole_image_blocks(converted, grey, options)
        for iy in range(plan.grid[0]):
            for ix in range(plan.grid[1]):
                features = explicit_window_features(converted, blocks, options, iy, ix,
                                                    plan.step_cells)
                expected = model.bias + weights @ features
                tol = score_tolerance(model, features)
                assert abs(float(scores[iy, ix]) - expected) <= tol, (
                    f"scale {plan.roi} window ({iy}, {ix}): score {float(scores[iy, ix])!r} "
                    f"!= explicit {expected!r} (tolerance {tol:.3g})")


def test_window_scores_on_a_random_odd_sized_frame():
    options = FeatureOptions()
    model = random_model(options, seed=5)
    rng = np.random.default_rng(5)
    image = rng.integers(0, 256, (203, 317, 3), dtype=np.uint8)
    scales = (ScaleConfig(64, 0.5, (0, 317), (0, 203)), ScaleConfig(50, 0.75, (13, 290), (7, 180)))
    config = DetectorConfig(search=SearchConfig(scales=scales, reference_size=(317, 203)))
    detector = Detector(model, config=config)
    weights = model.weights.astype(np.float64)
    plans = detector.plans((317, 203))
    assert len(plans) == 2
    for plan in plans:
        scores = detector.score_scale(detector.prepare(image), plan)
        converted, grey = scaled_planes(image, plan, options)
        blocks = whole_image_blocks(converted, grey, options)
        for iy in range(plan.grid[0]):
            for ix in range(plan.grid[1]):
                features = explicit_window_features(converted, blocks, options, iy, ix,
                                                    plan.step_cells)
                expected = model.bias + weights @ features
                assert abs(float(scores[iy, ix]) - expected) <= score_tolerance(model, features)


@pytest.mark.parametrize("width", [64, 1280, 8, 13, 1283])
@pytest.mark.parametrize("space", ["HLS", "YCrCb"])
def test_convert_color_equals_opencv(width, space):
    # HLS takes fastdet's own kernel at every width (its vector blocks and its
    # OpenCV-scalar tail), equal to OpenCV's AVX2 code on every CPU; other
    # spaces cv2.
    def opencv(image):
        if space == "HLS":
            return opencv_hls(image)
        return cv2.cvtColor(np.ascontiguousarray(image), getattr(cv2, f"COLOR_BGR2{space}"))

    rng = np.random.default_rng(width)
    image = rng.integers(0, 256, (37, width, 3), dtype=np.uint8)
    np.testing.assert_array_equal(convert_color(image, space), opencv(image))
    region = rng.integers(0, 256, (20, width + 16, 3), dtype=np.uint8)[:, 8:8 + width]
    np.testing.assert_array_equal(convert_color(region, space), opencv(region))
