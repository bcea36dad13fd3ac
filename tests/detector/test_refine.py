"""Box refinement: heat features, the linear edge model and its fit."""

import numpy as np
import pytest

from fastdet.detector.boxes import BoxFinder
from fastdet.detector.config import BoxConfig, DetectorConfig, HeatConfig, load_config
from fastdet.detector.refine import LEVELS, N_FEATURES, heat_features, mirrored, refine_boxes
from fastdet.errors import ConfigError
from fastdet.training.refine import RefinementSamples, fit_refinement, refined_ious


def naive_features(heat, origin, box, threshold, frame_size):
    """The features by their definition, pixel by pixel."""
    x1, y1, x2, y2 = box
    w, h = x2 - x1, y2 - y1
    cx, cy = (x1 + x2) / 2, (y1 + y2) / 2
    mass = {}
    for y in range(y1, y2):
        for x in range(x1, x2):
            hy, hx = y - origin[1], x - origin[0]
            if 0 <= hy < heat.shape[0] and 0 <= hx < heat.shape[1]:
                mass[x, y] = max(float(heat[hy, hx]) - threshold, 0.0)
    peak = max(mass.values())
    flip = cx < frame_size[0] / 2
    out = [1.0]
    for level in LEVELS:
        inside = [p for p, m in mass.items() if m >= level * peak]
        left = (min(x for x, _ in inside) - cx) / w
        right = (max(x for x, _ in inside) + 1 - cx) / w
        if flip:
            left, right = -right, -left
        out += [left, (min(y for _, y in inside) - cy) / h, right,
                (max(y for _, y in inside) + 1 - cy) / h]
    total = sum(mass.values())
    mx = sum(m * (x + 0.5) for (x, _), m in mass.items()) / total
    my = sum(m * (y + 0.5) for (_, y), m in mass.items()) / total
    sx = np.sqrt(sum(m * (x + 0.5 - mx) ** 2 for (x, _), m in mass.items()) / total)
    sy = np.sqrt(sum(m * (y + 0.5 - my) ** 2 for (_, y), m in mass.items()) / total)
    return np.array(out + [(cx - mx if flip else mx - cx) / w, (my - cy) / h, sx / w, sy / h,
                           np.log(h / frame_size[1]), abs(cx - frame_size[0] / 2) / frame_size[1]])


@pytest.mark.parametrize("seed", range(4))
def test_heat_features_match_their_definition(seed):
    rng = np.random.default_rng(seed)
    heat = np.zeros((37, 53), np.float32)
    heat[5:30, 7:45] = rng.uniform(0, 6, (25, 38)).astype(np.float32)
    heat[12:20, 20:30] += 5
    origin = (100, 40)
    boxes = np.array([[107, 45, 145, 70], [110, 50, 131, 69], [95, 35, 160, 90]])
    for frame_size in ((320, 180), (200, 180)):   # the boxes right, then left of the middle
        got = heat_features(heat, origin, boxes, threshold=1.5, frame_size=frame_size)
        for row, box in zip(got, boxes):
            np.testing.assert_allclose(row, naive_features(heat, origin, box, 1.5, frame_size),
                                       atol=1e-9)


def test_a_flat_blob_filling_its_box():
    heat = np.full((20, 40), 3.0, np.float32)
    features = heat_features(heat, (0, 0), np.array([[0, 0, 40, 20]]), threshold=1.0,
                             frame_size=(80, 40))[0]
    assert features.shape == (N_FEATURES,)
    np.testing.assert_allclose(features[1:1 + 4 * len(LEVELS)], [-0.5, -0.5, 0.5, 0.5] * len(LEVELS))
    # Centred; the spread of a uniform distribution over the box: 1 / sqrt(12) of its side.
    np.testing.assert_allclose(features[-6:-2], [0, 0, np.sqrt(1 / 12 - 1 / 12 / 40 ** 2),
                                                 np.sqrt(1 / 12 - 1 / 12 / 20 ** 2)], atol=1e-9)
    # Half the frame high, its centre half a frame height left of the middle.
    np.testing.assert_allclose(features[-2:], [np.log(0.5), 0.5])
    # No heat above the threshold in the box: the same flat-blob features, nothing raised.
    empty = heat_features(np.zeros((20, 40), np.float32), (0, 0), np.array([[0, 0, 40, 20]]),
                          threshold=1.0, frame_size=(80, 40))[0]
    np.testing.assert_allclose(empty[1:1 + 4 * len(LEVELS)], features[1:1 + 4 * len(LEVELS)])
    np.testing.assert_allclose(empty[-2:], features[-2:])


def test_refine_boxes_places_edges_from_the_weights():
    boxes = np.array([[10, 20, 50, 40], [0, 0, 10, 10]])
    features = np.zeros((2, N_FEATURES))
    features[:, 0] = 1
    weights = np.zeros((4, N_FEATURES))
    weights[:, 0] = [-0.6, -0.25, 0.6, 0.75]      # wider, lower
    out = refine_boxes(boxes, features, weights, frame_width=40)
    np.testing.assert_allclose(out[0], [30 - 24, 30 - 5, 30 + 24, 30 + 15])
    # Crossed edges are put back in order.
    weights[:, 0] = [0.5, 0.5, -0.5, -0.5]
    np.testing.assert_allclose(refine_boxes(boxes, features, weights, 40)[1], [0, 0, 10, 10])


def test_boxes_left_of_the_middle_are_refined_mirrored():
    # The model widens boxes towards the middle of the frame (the side of a
    # car beside the road shows towards it): on the right it moves the left
    # edge, on the left the right edge.
    boxes = np.array([[60, 0, 80, 10], [20, 0, 40, 10]], dtype=float)
    assert mirrored(boxes, 100).tolist() == [False, True]
    features = np.zeros((2, N_FEATURES))
    features[:, 0] = 1
    weights = np.zeros((4, N_FEATURES))
    weights[:, 0] = [-1.0, -0.5, 0.5, 0.5]
    out = refine_boxes(boxes, features, weights, frame_width=100)
    np.testing.assert_allclose(out, [[50, 0, 80, 10], [20, 0, 50, 10]])


def test_fit_recovers_a_linear_relation():
    rng = np.random.default_rng(0)
    n = 400
    features = np.c_[np.ones(n), rng.normal(0, 0.3, (n, N_FEATURES - 1))]
    true = rng.normal(0, 0.1, (4, N_FEATURES))
    true[:, 0] = [-0.6, -0.5, 0.6, 0.5]         # edges stay in order
    boxes = np.tile([100.0, 50.0, 140.0, 80.0], (n, 1))
    offsets = features @ true.T
    truth = np.stack([120 + offsets[:, 0] * 40, 65 + offsets[:, 1] * 30,
                      120 + offsets[:, 2] * 40, 65 + offsets[:, 3] * 30], axis=1)
    samples = RefinementSamples(boxes, features, truth, np.full(n, 100.0))   # right of the middle
    np.testing.assert_allclose(fit_refinement(samples, ridge=1e-9), true, atol=1e-6)
    # The same boxes left of the middle, their truths mirrored: the same weights.
    def flip(b):
        return np.c_[100 - b[:, 2], b[:, 1], 100 - b[:, 0], b[:, 3]]
    mirror = RefinementSamples(flip(boxes), features, flip(truth), np.full(n, 100.0))
    np.testing.assert_allclose(fit_refinement(mirror, ridge=1e-9), true, atol=1e-6)
    # A heavy ridge keeps only the constant: the mean offsets.
    heavy = fit_refinement(samples, ridge=1e9)
    np.testing.assert_allclose(heavy[:, 1:], 0, atol=1e-6)
    np.testing.assert_allclose(heavy[:, 0], offsets.mean(axis=0), atol=1e-3)
    assert refined_ious(samples, fit_refinement(samples, ridge=1e-9)) == pytest.approx(1.0)
    assert fit_refinement(RefinementSamples(np.zeros((0, 4)), np.zeros((0, 0)),
                                            np.zeros((0, 4)), np.zeros(0))) == ()


def test_box_finder_refines_only_with_weights_and_heat():
    heat = np.zeros((60, 100), np.float32)
    heat[10:50, 20:80] = 4
    blob = np.array([[20, 10, 80, 50]], np.int32)
    weights = np.zeros((4, N_FEATURES))
    weights[:, 0] = [-0.25, -0.25, 0.25, 0.25]     # the middle half
    shaped = DetectorConfig(heat=HeatConfig(threshold=1),
                            boxes=BoxConfig(min_size=1, horizon_y=0, width_scale=1.5,
                                            height_scale=1, center_dy=0, refine=()))
    refined = DetectorConfig(heat=HeatConfig(threshold=1),
                             boxes=BoxConfig(min_size=1, horizon_y=0, width_scale=1.5,
                                             height_scale=1, center_dy=0,
                                             refine=tuple(map(tuple, weights))))
    size = (100, 60)
    peaks = np.array([4.0], np.float32)
    assert BoxFinder(refined).finish_boxes(blob, peaks, size, heat, (0, 0)).xyxy.tolist() == [
        [35, 20, 65, 40]]
    # Without the heat (or without weights): the shape correction.
    assert BoxFinder(refined).finish_boxes(blob, peaks, size).xyxy.tolist() == [[5, 10, 95, 50]]
    assert BoxFinder(shaped).finish_boxes(blob, peaks, size, heat, (0, 0)).xyxy.tolist() == [
        [5, 10, 95, 50]]


def test_refine_in_toml(tmp_path):
    rows = ",\n".join("[" + ", ".join(["0.1"] * N_FEATURES) + "]" for _ in range(4))
    path = tmp_path / "c.toml"
    path.write_text(f"[boxes]\nrefine = [\n{rows}\n]\n")
    assert load_config(path).boxes.refine == ((0.1,) * N_FEATURES,) * 4
    path.write_text("[boxes]\nrefine = [[1, 2], [3, 4]]\n")
    with pytest.raises(ConfigError, match=f"4 rows of {N_FEATURES} numbers"):
        load_config(path)
