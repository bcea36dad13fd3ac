"""fastdet's asv benchmark suite (``asv run --python=same --quick``) and its peers.

One module per area: ``bench_kernels`` (Numba kernels vs frame size),
``bench_hog`` (fastdet.hog vs scikit-image), ``bench_detect`` (per-frame
latency, the reference and OpenCV peers), ``bench_video`` (end-to-end frames
per second), ``bench_train`` (feature extraction and SVM fit) and
``bench_startup`` (cold and warm start-up).  ``reference.py`` and
``opencv_peer/`` are the peers.
"""
