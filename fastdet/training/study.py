"""``fastdet train --compare``: colour spaces x feature sets on both splits.

Features are extracted once per colour space with every group enabled; the
feature sets (HOG; HOG + spatial; HOG + spatial + histogram) are column
slices of that matrix, because a feature vector is laid out
``[hog, spatial, histogram]``.
"""

from __future__ import annotations

import dataclasses
import statistics
import time

import numpy as np

from ..detector.config import DetectorConfig
from ..detector.detector import Detector
from ..detector.features import COLOR_CODES, FeatureLayout, FeatureOptions, features_of_crops
from ..detector.model import Model
from ..errors import InputError
from .dataset import leak_free_folds, list_dataset, load_crops, random_split
from .train import _checked_C, _checked_integer, _fit_and_score, check_splits

FEATURE_SETS = {
    "HOG": {"spatial": False, "hist": False},
    "HOG + spatial": {"spatial": True, "hist": False},
    "HOG + spatial + hist": {"spatial": True, "hist": True},
}


@dataclasses.dataclass
class StudyRow:
    """One trained combination and its figures."""

    color_space: str
    feature_set: str
    feature_length: int
    random_accuracy: float
    leak_free_accuracy: float
    fit_seconds: float
    ms_per_1000_windows: float


def _subset(options, layout, wanted):
    """Options and column mask of one feature set."""
    sizes = layout.sizes
    mask = np.zeros(layout.length, dtype=bool)
    mask[:sizes[0]] = True
    if wanted["spatial"]:
        mask[sizes[0]:sizes[0] + sizes[1]] = True
    if wanted["hist"]:
        mask[sizes[0] + sizes[1]:] = True
    subset = dataclasses.replace(options, spatial_size=options.spatial_size if wanted["spatial"]
                                 else 0, hist_bins=options.hist_bins if wanted["hist"] else 0)
    return subset, mask


def _windows_cost(model, frame, repeat=5):
    """Milliseconds per 1,000 windows of a full default search on ``frame``."""
    detector = Detector(model, DetectorConfig(), threads=1)
    detector(frame)
    samples = []
    for _ in range(repeat):
        start = time.perf_counter()
        detector(frame)
        samples.append(time.perf_counter() - start)
    return statistics.median(samples) * 1e6 / detector.last_windows_scored


def compare(data_dir, base_options=None, color_spaces=None, C=1e-3, flip=False, seed=0,
            log=None):
    """Train one model per colour space and feature set; report both splits.

    Parameters
    ----------
    data_dir : str or Path
        Training data (``vehicles/`` and ``non-vehicles/``).
    base_options : FeatureOptions, optional
        HOG, spatial and histogram settings shared by every combination.
    color_spaces : iterable of str, optional
        Defaults to all seven.
    C : float
        LinearSVC regularisation, the same for every combination.
    flip : bool
        Flip augmentation of the training side.
    seed : int
    log : callable, optional

    Returns
    -------
    list of StudyRow

    Raises
    ------
    InputError
        Before any crop is read, as :func:`~.train.train` refuses them: a
        ``C`` that is not one finite number above 0, a ``seed`` outside
        ``0 .. 2**32 - 1`` and a data set with too few crops for its splits.
    """
    base = base_options or FeatureOptions()
    log = log or (lambda message: None)
    C = _checked_C(C)
    if isinstance(C, tuple):
        raise InputError("the study trains every combination with one C, not a grid")
    seed = _checked_integer("seed", seed, 0, 2**32 - 1)
    dataset = list_dataset(data_dir)
    labels = dataset.labels
    random_test = random_split(labels, seed=seed)
    folds = leak_free_folds(dataset.groups)
    # The crops are read, and features extracted for seven colour spaces, only for data that
    # can be fit and tested on.
    check_splits(data_dir, labels, folds, 0, random_test)
    leak_free_train = folds != 0
    crops = load_crops(dataset.paths)
    frame = np.random.default_rng(seed).integers(0, 256, (720, 1280, 3), dtype=np.uint8)
    rows = []
    for color_space in color_spaces or COLOR_CODES:
        options = dataclasses.replace(base, color_space=color_space, use_hog=True,
                                      spatial_size=base.spatial_size or 32,
                                      hist_bins=base.hist_bins or 32)
        layout = FeatureLayout(options)
        features = features_of_crops(crops, options)
        flips = features_of_crops(crops[:, :, ::-1], options) if flip else None
        for name, wanted in FEATURE_SETS.items():
            subset, mask = _subset(options, layout, wanted)
            x = features[:, mask]
            xf = None if flips is None else flips[:, mask]
            _, _, random_report, _ = _fit_and_score(x, labels, ~random_test, xf, C, seed)
            weights, bias, leak_report, _ = _fit_and_score(x, labels, leak_free_train, xf, C, seed)
            cost = _windows_cost(Model(weights, bias, subset), frame)
            row = StudyRow(color_space, name, int(mask.sum()), random_report["accuracy"],
                           leak_report["accuracy"],
                           random_report["fit_seconds"] + leak_report["fit_seconds"], cost)
            log(f"{color_space:6} {name:22} random {row.random_accuracy:.4f}  "
                f"leak-free {row.leak_free_accuracy:.4f}")
            rows.append(row)
    return rows


def format_markdown(rows):
    """The study as a markdown table."""
    lines = ["| colour space | features | length | random split | leak-free split | "
             "train s (both splits) | ms / 1,000 windows |",
             "|---|---|---:|---:|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r.color_space} | {r.feature_set} | {r.feature_length} | "
                     f"{100 * r.random_accuracy:.2f}% | {100 * r.leak_free_accuracy:.2f}% | "
                     f"{r.fit_seconds:.1f} | {r.ms_per_1000_windows:.2f} |")
    return "\n".join(lines)
