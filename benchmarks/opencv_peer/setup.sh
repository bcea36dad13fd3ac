#!/usr/bin/env bash
# Create the OpenCV-peer virtual environment: OpenCV 4 (the last major version
# with cv2.HOGDescriptor), numpy and scikit-learn, apart from fastdet's own
# environment, which keeps OpenCV 5 (the two wheels cannot share one).
#
#   bash benchmarks/opencv_peer/setup.sh          # idempotent
#
# Where: $FASTDET_OPENCV_PEER, default ~/.cache/fastdet/opencv-peer.  fastdet's
# benchmarks find the environment through the same variable.
set -euo pipefail

venv="${FASTDET_OPENCV_PEER:-${XDG_CACHE_HOME:-$HOME/.cache}/fastdet/opencv-peer}"
python="${PYTHON:-python3}"

if [ ! -x "$venv/bin/python" ]; then
    "$python" -m venv "$venv"
fi
"$venv/bin/python" -m pip install --quiet --disable-pip-version-check \
    "opencv-python-headless>=4.8,<5" "numpy>=1.24" "scikit-learn>=1.3"
"$venv/bin/python" -c "import cv2; assert hasattr(cv2, 'HOGDescriptor'); \
print('OpenCV peer ready:', cv2.__version__, 'at $venv')"
