"""Synthetic videos whose answer is known, and a detector stub that finds their vehicles.

A "vehicle" is a rectangle of randomly coloured, fully saturated pixels on an
unsaturated noisy grey background.  :class:`BlockDetector` has the methods
:class:`fastdet.video.pipeline.VideoPipeline` uses and reports every saturated blob as
two identical hit windows, so the heat map (threshold 1) gives back exactly
the blob's bounding box.
"""

from __future__ import annotations

import cv2
import numpy as np

from fastdet.detector.detections import Detections
from fastdet.detector.scoring import Hits
from fastdet.kernels.heat import accumulate_heat
from fastdet.kernels.label import component_boxes, component_max, label_components

HEIGHT, WIDTH = 120, 200


def background(level=100, seed=0, height=HEIGHT, width=WIDTH):
    """Grey noise (no saturation) around ``level``."""
    rng = np.random.default_rng(seed)
    grey = np.clip(rng.normal(level, 6, (height, width)), 0, 255).astype(np.uint8)
    return np.repeat(grey[:, :, None], 3, axis=2)


def texture(height, width, seed=1):
    """Random bright colours with one channel at 0: saturation 255 everywhere."""
    rng = np.random.default_rng(seed)
    block = rng.integers(60, 256, (height, width, 3)).astype(np.uint8)
    zero = rng.integers(0, 3, (height, width))
    np.put_along_axis(block, zero[:, :, None], 0, axis=2)
    return block


def paint(frame, box, block):
    """Paint ``block`` at ``box`` (x1, y1, x2, y2) clipped to the frame; return the visible box."""
    x1, y1, x2, y2 = box
    h, w = frame.shape[:2]
    cx1, cy1, cx2, cy2 = max(x1, 0), max(y1, 0), min(x2, w), min(y2, h)
    if cx2 <= cx1 or cy2 <= cy1:
        return None
    frame[cy1:cy2, cx1:cx2] = block[cy1 - y1:cy2 - y1, cx1 - x1:cx2 - x1]
    return (cx1, cy1, cx2, cy2)


def moving_block(n_frames, start=(20, 40), velocity=(4, 1), size=(40, 30), seed=1):
    """Frames of one textured block moving at a constant velocity, and its true boxes.

    Returns
    -------
    frames : list of ndarray
    truth : list of tuple or None
        The visible box per frame (``None`` once it has left the picture).
    """
    block = texture(size[1], size[0], seed)
    frames, truth = [], []
    for i in range(n_frames):
        x = start[0] + velocity[0] * i
        y = start[1] + velocity[1] * i
        frame = background(seed=100 + i)
        truth.append(paint(frame, (x, y, x + size[0], y + size[1]), block))
        frames.append(frame)
    return frames, truth


class BlockDetector:
    """Detector stub: each saturated blob of at least ``min_area`` pixels is a vehicle.

    Attributes
    ----------
    calls : int
        Number of full searches (``hits`` calls).
    """

    def __init__(self, min_area=40):
        self.min_area = min_area
        self.calls = 0

    def hits(self, frame):
        self.calls += 1
        saturated = cv2.cvtColor(frame, cv2.COLOR_BGR2HSV)[..., 1] > 100
        labels, count = label_components(saturated, 8)
        boxes = component_boxes(labels, count)
        area = (boxes[:, 2] - boxes[:, 0]) * (boxes[:, 3] - boxes[:, 1])
        boxes = np.repeat(boxes[area >= self.min_area], 2, axis=0)
        n = len(boxes)
        return Hits(boxes.astype(np.int32), np.ones(n, np.float32), np.zeros(n, np.int64), 100)

    def heat_region(self, hits, frame_size):
        width, height = frame_size
        return accumulate_heat(hits.boxes, np.ones(len(hits.boxes), np.float32), height,
                               width), (0, 0)

    def boxes_from_heat(self, heat, origin, frame_size, frame=None):
        labels, count = label_components(heat > 1.0, 8)
        if count == 0:
            return Detections.empty()
        boxes = component_boxes(labels, count)
        boxes += np.array([origin[0], origin[1], origin[0], origin[1]], dtype=np.int32)
        return Detections(boxes, component_max(labels, count, heat))


def bundled_model_path():
    """The model for real-video tests: the bundled default, else ``$FASTDET_TEST_MODEL``.

    Returns ``None`` for the bundled model (``Detector()``'s default).
    """
    import os
    from importlib import resources

    import pytest

    if resources.files("fastdet").joinpath("data", "default_model.npz").is_file():
        return None
    if os.environ.get("FASTDET_TEST_MODEL"):
        return os.environ["FASTDET_TEST_MODEL"]
    pytest.fail("the bundled model fastdet/data/default_model.npz is missing (build it with "
                "tools/build_default_model.py, or set FASTDET_TEST_MODEL)", pytrace=False)
