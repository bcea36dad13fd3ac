"""Importing fastdet, and detecting, load nothing a detection does not need.

Each check runs in a fresh interpreter: the test process itself has long
imported scikit-learn, matplotlib and the rest.
"""

import json
import subprocess
import sys

import pytest

#: Top-level packages a detection never needs (training, figures, references,
#: video I/O, batch runs, progress bars, test tools).
NOT_NEEDED = ("sklearn", "matplotlib", "skimage", "av", "dask", "distributed", "tqdm", "pandas",
              "hypothesis", "motmetrics", "asv")

_PROBE = r"""
import json, sys
import fastdet
imported = sorted({name.split(".")[0] for name in sys.modules})
if sys.argv[1] == "cli detect":
    # The command line as `fastdet detect` builds it: every verb's parser.
    from fastdet.cli.app import build_parser
    build_parser()
    imported = sorted({name.split(".")[0] for name in sys.modules})
if sys.argv[1] == "detect":
    import numpy as np
    detector = fastdet.Detector(threads=1)
    detector(np.random.default_rng(0).integers(0, 256, (720, 1280, 3), dtype=np.uint8))
    imported = sorted({name.split(".")[0] for name in sys.modules})
print(json.dumps(imported))
"""


def loaded_packages(stage):
    completed = subprocess.run([sys.executable, "-c", _PROBE, stage], capture_output=True,
                               text=True, timeout=600)
    assert completed.returncode == 0, completed.stderr[-3000:]
    return set(json.loads(completed.stdout.strip().splitlines()[-1]))


@pytest.mark.parametrize("stage", ["detect", "cli detect"])
def test_nothing_a_detection_does_not_need(stage):
    loaded = loaded_packages(stage)
    assert "fastdet" in loaded and "numba" in loaded and "cv2" in loaded
    assert not loaded & set(NOT_NEEDED), sorted(loaded & set(NOT_NEEDED))


def test_importing_fastdet_imports_nothing_heavy():
    """Public names load on first use: the fastdet command starts compiling a cold
    cache before NumPy, OpenCV and Numba are imported (fastdet.compile_ahead)."""
    loaded = loaded_packages("import")
    assert "fastdet" in loaded
    heavy = {"numpy", "numba", "llvmlite", "cv2", "scipy", *NOT_NEEDED}
    assert not loaded & heavy, sorted(loaded & heavy)
