"""The bundled model and default config on the test images, at three frame sizes.

The test images are never trained or tuned on, so these are held-out
figures; the sizes check that the frame-relative search finds the same cars
whatever the resolution.
"""

import json

import cv2
import numpy as np
import pytest

from fastdet.detector.detector import Detector
from fastdet.detector.geometry import iou_matrix
from fastdet.evaluation.matching import FALSE_POSITIVE
from fastdet.evaluation.metrics import evaluate

SIZES = ((1280, 720), (960, 540), (1920, 1080))


@pytest.fixture(scope="module")
def test_images(data_dir):
    folder = data_dir / "test_images"
    annotations = json.loads((folder / "annotations.json").read_text())["images"]
    return {name: cv2.imread(str(folder / name)) for name in annotations}, {
        name: [{**obj, "box": [float(v) for v in obj["box"]]} for obj in objects]
        for name, objects in annotations.items()}


@pytest.fixture(scope="module")
def detections(test_images):
    """Boxes per size and image, scaled back to the images' 1280x720."""
    images, _ = test_images
    detector = Detector(threads=1)
    out = {}
    for size in SIZES:
        scale = size[0] / 1280
        for name, image in images.items():
            resized = image if scale == 1 else cv2.resize(
                image, size, interpolation=cv2.INTER_AREA if scale < 1 else cv2.INTER_LINEAR)
            found = detector(resized)
            out[size, name] = (found.xyxy / scale, found.score)
    return out


@pytest.mark.parametrize("size", SIZES)
def test_every_car_at_every_size_and_nothing_but_vehicles(test_images, detections, size):
    _, annotations = test_images
    report = evaluate({name: detections[size, name] for name in annotations}, annotations)
    assert report.recall == 1.0
    # The boxes' sides snapped to the image's edges ([boxes] snap_sides): 0.858,
    # 0.838 and 0.875 at the three sizes (0.814, 0.800 and 0.833 without).
    assert report.mean_iou >= 0.83
    if size == (1280, 720):
        assert report.mean_iou >= 0.85
    # Any box the rule counts as false lies on a difficult vehicle: the box on
    # the truck behind the barrier of test5 (at 1280x720 49 % of its area lies
    # inside the truck's box, 52 % before the sides snapped; half is the
    # rule's line), and nothing else.
    assert report.fp <= 1
    for name, match in report.per_image.items():
        false = detections[size, name][0][match.labels == FALSE_POSITIVE]
        hard = np.array([o["box"] for o in annotations[name] if o["difficult"]]).reshape(-1, 4)
        if len(false):
            assert len(hard) and (iou_matrix(false, hard).max(axis=1) >= 0.3).all(), name


def test_the_same_cars_at_every_size(test_images, detections):
    _, annotations = test_images
    for name, objects in annotations.items():
        cars = np.array([obj["box"] for obj in objects if not obj["difficult"]]).reshape(-1, 4)
        matched = []
        for size in SIZES:
            boxes = detections[size, name][0]
            iou = iou_matrix(boxes, cars) if len(boxes) else np.zeros((0, len(cars)))
            # The box that found each car (every car is found, see above).
            matched.append(boxes[iou.argmax(axis=0)] if len(boxes) else np.zeros((0, 4)))
        for other in matched[1:]:
            # The same box, give or take the rounding at another resolution.
            assert (np.diag(iou_matrix(matched[0], other)) >= 0.6).all(), name
