"""Small training inputs the training, tuning and CLI tests share."""

from __future__ import annotations

import json

import cv2
import numpy as np


def make_crops(folder, label, count, rng):
    """``count`` 64x64 PNG crops in ``folder`` (created): dark noise, with a bright
    "car" rectangle of strong edges when ``label`` is 1."""
    folder.mkdir(parents=True)
    for i in range(count):
        crop = rng.integers(0, 60, (64, 64, 3), dtype=np.uint8)
        if label:
            crop[20:48, 8:56] = 220
        cv2.imwrite(str(folder / f"image{i:04d}.png"), crop)


def annotated_blocks(folder):
    """``a.png`` and ``b.png`` in ``folder``, 256x128 images with the same bright block,
    annotated as a car in a.png only; returns the annotation file's path."""
    truth = {}
    for name, annotated in (("a.png", True), ("b.png", False)):
        image = np.zeros((128, 256, 3), np.uint8)
        image[32:96, 64:128] = 250
        cv2.imwrite(str(folder / name), image)
        truth[name] = ([{"box": [64, 32, 128, 96], "label": "car", "difficult": False}]
                       if annotated else [])
    path = folder / "annotations.json"
    path.write_text(json.dumps({"images": truth}))
    return path
