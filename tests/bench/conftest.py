"""Fixtures the bench tests share."""

import cv2
import pytest


@pytest.fixture(scope="module")
def small_frames(data_dir):
    """Two test images at 640x360: frames for a short pipeline pass."""
    frames = []
    for name in ("test1.jpg", "test4.jpg"):
        image = cv2.imread(str(data_dir / "test_images" / name))
        assert image is not None, f"missing {name} in {data_dir / 'test_images'}"
        frames.append(cv2.resize(image, (640, 360)))
    return frames
