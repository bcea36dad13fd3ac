"""The seed-faithful reference detector against fastdet's Detector.

Both detectors get the same random linear model and configuration; the
reference computes features with scikit-image / OpenCV / numpy per window and
scores them with scikit-learn, fastdet with its Numba kernels, so agreement
checks fastdet's feature maps, window scoring, heat and labelling against an
independent implementation on a real road image.
"""

from __future__ import annotations

import os
import sys
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from fastdet.detector.config import BoxConfig, DetectorConfig, HeatConfig, ScaleConfig, SearchConfig
from fastdet.detector.detector import Detector
from fastdet.detector.features import FeatureLayout, FeatureOptions
from fastdet.detector.model import Model

#: Box filters without fastdet's shape correction and refinement, which the published
#: pipeline lacks.
PUBLISHED_BOXES = BoxConfig(width_scale=1.0, height_scale=1.0, center_dy=0.0, refine=())

REPO_ROOT = Path(__file__).resolve().parents[2]
# benchmarks/ is not an installed package; make it importable however pytest
# was started.
if str(REPO_ROOT) not in sys.path:
    sys.path.insert(0, str(REPO_ROOT))

from benchmarks.reference import ReferenceDetector, sklearn_classifier  # noqa: E402

#: Float32 (fastdet) against float64 (scikit-learn) arithmetic: observed
#: differences are below 2e-5 relative (6.5e-5 absolute on scores up to ~300);
#: a wrongly ordered HOG block already gives ~0.3.
RELATIVE_TOLERANCE = 1e-3


def data_dir():
    """The shared data directory: ``$FASTDET_DATA`` or ``<repo>/../shared/data``.

    Fails the calling test (never skips it) when the test images are missing.
    """
    path = Path(os.environ.get("FASTDET_DATA", REPO_ROOT.parent / "shared" / "data"))
    if not (path / "test_images").is_dir():
        pytest.fail(f"test data not found: {path / 'test_images'} does not exist "
                    f"(set FASTDET_DATA to the directory holding test_images/)")
    return path


def load_frame(name):
    """A test image as a BGR uint8 array."""
    path = data_dir() / "test_images" / name
    frame = cv2.imread(str(path))
    if frame is None:
        pytest.fail(f"cannot read test image {path}")
    return frame


def random_model(options=FeatureOptions(), seed=0):
    """A linear model with small random weights: every feature matters a little."""
    rng = np.random.default_rng(seed)
    length = FeatureLayout(options).length
    return Model(weights=rng.normal(size=length).astype(np.float32) * 0.01, bias=-0.5,
                 options=options)


def fastdet_window_scores(detector, frame):
    """fastdet's score grid of every scale plan of ``frame``."""
    plans = detector.plans((frame.shape[1], frame.shape[0]))
    # Detector.score_scale takes a frame prepared once for all scales where
    # the detector has ``prepare``; older versions took the frame itself.
    prepared = detector.prepare(frame) if hasattr(detector, "prepare") else frame
    return [detector.score_scale(prepared, plan) for plan in plans]


def assert_scores_agree(reference_grids, fast_grids):
    """Same grids, equal to RELATIVE_TOLERANCE; returns the max abs difference."""
    assert len(reference_grids) == len(fast_grids)
    worst = 0.0
    for index, (reference, fast) in enumerate(zip(reference_grids, fast_grids)):
        assert reference.shape == fast.shape, f"scale {index}"
        difference = np.abs(reference - fast.astype(np.float64))
        allowed = RELATIVE_TOLERANCE * np.maximum(np.abs(reference), 1.0)
        assert np.all(difference <= allowed), (
            f"scale {index}: max abs difference {difference.max():.3g} at window "
            f"{np.unravel_index(difference.argmax(), difference.shape)}")
        worst = max(worst, float(difference.max()))
    return worst


def threshold_in_a_gap(grids, quantile):
    """A decision threshold near ``quantile`` of the scores, far from any score.

    Picking it midway between two well-separated scores keeps float32/float64
    rounding from making a window a hit for one detector only.
    """
    scores = np.sort(np.concatenate([grid.ravel() for grid in grids]).astype(np.float64))
    start = int(quantile * (scores.size - 1))
    for i in range(start, scores.size - 1):
        if scores[i + 1] - scores[i] > 1e-3 * max(1.0, abs(scores[i])):
            return float((scores[i] + scores[i + 1]) / 2)
    raise AssertionError("no gap in the score distribution")


#: Two scales over a small region: keeps the slow reference quick for the
#: option and heat variants.  Odd region sizes exercise partial cells.
SMALL_SEARCH = SearchConfig(scales=(ScaleConfig(64, 0.5, (600, 1279), (380, 590)),
                                    ScaleConfig(96, 0.75, (700, 1280), (370, 610))))


def test_sklearn_classifier_equals_the_model():
    model = random_model()
    scaler, classifier = sklearn_classifier(model)
    features = np.random.default_rng(1).uniform(0, 255, (5, model.weights.size))
    np.testing.assert_allclose(classifier.decision_function(scaler.transform(features)),
                               model.decision_function(features), rtol=1e-12)


@pytest.mark.parametrize("image", ["test1.jpg", "test4.jpg"])
def test_window_scores_match_fastdet(image):
    frame = load_frame(image)
    model = random_model()
    reference_grids = ReferenceDetector(model).window_scores(frame)
    fast_grids = fastdet_window_scores(Detector(model), frame)
    assert len(reference_grids) == 5  # every default scale fits a 1280x720 frame
    # Observed: max abs difference ~2.6e-5 on scores up to ~125 (1.7e-5 relative).
    assert_scores_agree(reference_grids, fast_grids)


@pytest.mark.parametrize("options", [
    FeatureOptions(color_space="HLS", hog_channel="gray", orientations=11, block_norm="L1",
                   spatial_size=16, hist_bins=24),
    FeatureOptions(color_space="LUV", hog_channel=1, cells_per_block=3, block_norm="L2",
                   spatial_size=0, hist_bins=16),
    FeatureOptions(color_space="HSV", pixels_per_cell=16, cells_per_block=1,
                   block_norm="L1-sqrt", spatial_size=8, hist_bins=0),
    FeatureOptions(color_space="RGB", use_hog=False, spatial_size=64, hist_bins=7),
], ids=["gray-HLS-L1", "channel1-LUV-cpb3", "HSV-ppc16-nohist", "RGB-nohog"])
def test_window_scores_match_fastdet_for_feature_variants(options):
    frame = load_frame("test1.jpg")
    model = random_model(options, seed=3)
    config = DetectorConfig(search=SMALL_SEARCH)
    reference_grids = ReferenceDetector(model, config).window_scores(frame)
    fast_grids = fastdet_window_scores(Detector(model, config), frame)
    assert len(reference_grids) == 2
    assert_scores_agree(reference_grids, fast_grids)


def compare_detections(frame, model, config):
    """Hits, heat map and final boxes of both detectors must agree."""
    reference = ReferenceDetector(model, config)
    fast = Detector(model, config)
    reference_boxes, reference_scores = reference.hits(frame)
    fast_hits = fast.hits(frame)
    assert len(reference_boxes) > 0
    np.testing.assert_array_equal(reference_boxes, fast_hits.boxes)
    np.testing.assert_allclose(reference_scores, fast_hits.scores, rtol=RELATIVE_TOLERANCE)
    np.testing.assert_allclose(reference.heatmap(frame), fast.heatmap(frame), rtol=1e-5,
                               atol=1e-5)
    reference_detections = reference(frame)
    fast_detections = fast(frame)
    assert len(fast_detections) > 0
    np.testing.assert_array_equal(reference_detections.xyxy, fast_detections.xyxy)
    np.testing.assert_allclose(reference_detections.score, fast_detections.score, rtol=1e-5)


@pytest.mark.parametrize("image", ["test1.jpg", "test4.jpg"])
def test_detections_match_fastdet(image):
    frame = load_frame(image)
    model = random_model()
    fast_grids = fastdet_window_scores(Detector(model), frame)
    # The reference merges hits the published way: no blob splitting.
    config = DetectorConfig(search=SearchConfig(
        decision_threshold=threshold_in_a_gap(fast_grids, 0.95)),
        heat=HeatConfig(threshold=1.0, weighting="count", split=False, peak_fraction=0.0),
        boxes=PUBLISHED_BOXES)
    compare_detections(frame, model, config)


@pytest.mark.parametrize("heat", [
    HeatConfig(threshold=1.5, weighting="area", connectivity=4, split=False, peak_fraction=0.0),
    HeatConfig(threshold=2.0, weighting="margin", connectivity=8, split=False, peak_fraction=0.0),
], ids=["area-4", "margin-8"])
def test_detections_match_fastdet_for_heat_variants(heat):
    frame = load_frame("test4.jpg")
    model = random_model(seed=5)
    config = DetectorConfig(search=SMALL_SEARCH)
    fast_grids = fastdet_window_scores(Detector(model, config), frame)
    search = replace(SMALL_SEARCH, decision_threshold=threshold_in_a_gap(fast_grids, 0.7))
    compare_detections(frame, model, DetectorConfig(search=search, heat=heat,
                                                    boxes=PUBLISHED_BOXES))
