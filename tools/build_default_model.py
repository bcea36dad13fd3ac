"""Rebuild the bundled model from the shared data: train, mine, retrain, tune.

Run from the checkout's root (``FASTDET_DATA`` or ../shared/data)::

    python tools/build_default_model.py [--work DIR]

1. train a first model on ``vehicles/`` and ``non-vehicles/`` (flipped and
   jittered copies of the training crops, see ``fastdet.training.train``);
2. mine its false hits on the annotated frames of ``test_video.mp4``
   (``tests/data/test_video_annotations.json``, our own annotations; the test
   images are never used for training or tuning) at a low decision threshold,
   so borderline windows are found too;
3. retrain with those hard negatives, C chosen by cross-validation on the
   leak-free training folds -> ``fastdet/data/default_model.npz``;
4. tune the detection thresholds on the same annotated video frames and
   print them; they are the defaults in ``fastdet/config.py``.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from fastdet.cli.app import main as fastdet  # noqa: E402
from fastdet.detector.features import FeatureOptions  # noqa: E402
from fastdet.files.shared_data import data_dir  # noqa: E402

#: Feature options of the bundled model (chosen by the colour-space study).
OPTIONS = FeatureOptions()
#: Decision threshold used while mining: low, so borderline negatives are found too.
#: -1.0 finds 305 windows on the 17 annotated frames against 120 at -0.5; the
#: retrained model's leak-free accuracy is 99.39 % against 99.35 % with none.
MINING_THRESHOLD = -1.0
#: C values the final model chooses from by leak-free cross-validation.
C_GRID = (3e-4, 1e-3, 3e-3)


def run(*args):
    print("$ fastdet " + " ".join(str(a) for a in args), flush=True)
    code = fastdet([str(a) for a in args])
    if code:
        sys.exit(code)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", help="folder for intermediate files (default: a temp dir)")
    args = parser.parse_args()
    work = Path(args.work or tempfile.mkdtemp(prefix="fastdet-build-"))
    work.mkdir(parents=True, exist_ok=True)
    data = data_dir()
    video = data / "test_video.mp4"
    annotations = ROOT / "tests" / "data" / "test_video_annotations.json"
    options = ["--color-space", OPTIONS.color_space, "--orientations", OPTIONS.orientations,
               "--pixels-per-cell", OPTIONS.pixels_per_cell,
               "--cells-per-block", OPTIONS.cells_per_block, "--block-norm", OPTIONS.block_norm,
               "--spatial-size", OPTIONS.spatial_size, "--hist-bins", OPTIONS.hist_bins]
    first = work / "first.npz"
    run("train", data, "--out", first, *options)
    mining_config = work / "mining.toml"
    mining_config.write_text(f"[search]\ndecision_threshold = {MINING_THRESHOLD}\n")
    mined = work / "hard-negatives"
    run("mine", video, "--annotations", annotations, "--out", mined, "--model", first,
        "--config", mining_config, "--threads", 1)
    final = ROOT / "fastdet" / "data" / "default_model.npz"
    run("train", data, "--out", final, "--extra-negatives", mined, "--cv", "--C", *C_GRID,
        *options)
    run("tune", video, "--annotations", annotations, "--model", final,
        "--out", work / "tuned.toml")
    print(f"intermediate files in {work}")


if __name__ == "__main__":
    main()
