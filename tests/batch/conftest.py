"""The batch tests import their helpers as ``from batch_stubs import ...``."""

import sys
from pathlib import Path

import cv2
import pytest

sys.path.insert(0, str(Path(__file__).parent))


@pytest.fixture(scope="module")
def blocks_video(tmp_path_factory):
    """90 frames of two textured blocks, one leaving the picture (mp4v, 10 fps)."""
    from batch_stubs import two_blocks

    path = tmp_path_factory.mktemp("job") / "blocks.mp4"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 10.0, (200, 120))
    for frame in two_blocks(90):
        writer.write(frame)
    writer.release()
    return path
