"""Synthetic roads whose lane lines meet at a known row (the horizon tests)."""

import cv2
import numpy as np


def road(width, height, horizon, seed=0, dashed=False):
    """A grey road with noise and two bright lane lines meeting at row ``horizon * height``."""
    rng = np.random.default_rng(seed)
    image = rng.integers(60, 90, (height, width, 3), dtype=np.uint8)
    image[: int(horizon * height)] = (150, 140, 120)   # sky: flat
    vanish = (width / 2, horizon * height)
    thickness = max(1, round(height / 120))
    for bottom in (0.1 * width, 0.9 * width):
        top_y = horizon * height + 0.08 * height     # the lines stop short of the horizon
        t = (top_y - vanish[1]) / (height - vanish[1])
        start = (bottom, height - 1)
        end = (vanish[0] + t * (bottom - vanish[0]), top_y)
        pieces = 6 if dashed else 1
        for k in range(pieces):
            a, b = k / pieces, (k + (0.6 if dashed else 1.0)) / pieces
            p = [round(start[i] + a * (end[i] - start[i])) for i in (0, 1)]
            q = [round(start[i] + b * (end[i] - start[i])) for i in (0, 1)]
            cv2.line(image, tuple(p), tuple(q), (230, 230, 230), thickness, cv2.LINE_AA)
    return image
