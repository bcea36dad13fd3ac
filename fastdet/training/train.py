"""Training: LinearSVC on crop features, cross-validated C, the training report.

A data set is a folder with ``vehicles/`` and ``non-vehicles/`` subfolders
holding image crops (PNG/JPG, any nesting).  The first folder level below each
class is the crop's *group* (e.g. ``GTI_Far``).

Two hold-out splits are reported:

* random: a stratified random 20 % of the crops;
* leak-free: within every group, crops in natural file-name order are cut
  into ``n_folds`` contiguous blocks and one block is held out.  GTI crops
  are consecutive video frames, so a random split puts near-duplicates of a
  test crop in the training set; contiguous blocks keep them on one side
  (only block boundaries can leak).

The model that is returned (and shipped) is fit on the leak-free training
part, so its reported leak-free accuracy is an honest held-out figure.

Training crops are augmented by :mod:`fastdet.training.augment`; held-out
crops are scored as they are.

A third validation holds out whole *sources* (:func:`~.dataset.source_of`:
GTI, KITTI, the extras), one at a time: a model fit on the others scores
every crop of the held-out source.  Contiguous blocks still share a camera
with their training part; a source held out shares neither camera nor scene,
which is what a user's own dashcam brings.  KITTI holds only vehicles and the
extras only non-vehicles, so their figures are a recall and a true-negative
rate.
"""

from __future__ import annotations

import time

import numpy as np

from ..detector.features import FeatureLayout, FeatureOptions, features_of_crops
from ..detector.model import Model
from ..errors import InputError
from .augment import (
    JITTER_SCALE,
    JITTER_SHIFT,
    Photometric,
    copies_of,
    jitter_crops,
    with_copies,
)
from .dataset import leak_free_folds, list_dataset, load_crops, random_split, source_of


def fit_linear_svm(features, labels, C=0.001, seed=0):
    """StandardScaler + LinearSVC, with the scaler folded into the weights.

    Returns
    -------
    weights : ndarray of float32, shape (F,)
    bias : float
    """
    # Imported here: scikit-learn doubles fastdet's import time, and detection never needs it.
    from sklearn.preprocessing import StandardScaler
    from sklearn.svm import LinearSVC

    scaler = StandardScaler().fit(features)
    # Constant features have scale 1 in sklearn already; guard anyway.
    scale = np.where(scaler.scale_ > 0, scaler.scale_, 1.0)
    svc = LinearSVC(C=C, dual="auto", max_iter=5000, random_state=seed)
    svc.fit(scaler.transform(features), labels)
    coef = svc.coef_.ravel().astype(np.float64)
    weights = coef / scale
    bias = float(svc.intercept_[0] - np.dot(weights, scaler.mean_))
    return weights.astype(np.float32), bias


def _decision(weights, bias, features):
    return features.astype(np.float64) @ weights.astype(np.float64) + bias


def _confusion(scores, labels):
    predicted = scores > 0
    actual = labels == 1
    return {"tp": int(np.sum(predicted & actual)), "fp": int(np.sum(predicted & ~actual)),
            "tn": int(np.sum(~predicted & ~actual)), "fn": int(np.sum(~predicted & actual))}


def _fit_and_score(features, labels, train_mask, flips, C, seed):
    """Fit on ``train_mask`` (plus augmented copies) and score the rest.

    ``flips`` is None, one array of augmented features aligned with
    ``features``, or a list of such arrays.

    Returns
    -------
    weights, bias, report, test_scores
    """
    copies = copies_of(flips)
    train_x = with_copies(features, copies, train_mask)
    train_y = np.tile(labels[train_mask], 1 + len(copies))
    start = time.perf_counter()
    weights, bias = fit_linear_svm(train_x, train_y, C=C, seed=seed)
    seconds = time.perf_counter() - start
    test = ~train_mask
    scores = _decision(weights, bias, features[test])
    return weights, bias, {
        "accuracy": float(np.mean((scores > 0) == (labels[test] == 1))),
        "confusion": _confusion(scores, labels[test]),
        "train_crops": int(len(train_y)),
        "test_crops": int(test.sum()),
        "fit_seconds": round(seconds, 2),
    }, scores


def cross_validate(features, labels, folds, held_out_fold, flips, grid, seed=0, log=None):
    """Choose C and the decision threshold on the leak-free training folds.

    Every fold except ``held_out_fold`` (the final test fold) is held out in
    turn; the test fold is never looked at, so the final test accuracy stays
    an honest figure.

    Returns
    -------
    dict
        ``C`` (best mean held-out accuracy), ``threshold`` (the margin that
        maximises accuracy over the pooled out-of-fold scores of that C) and
        the per-C mean accuracies.
    """
    log = log or (lambda message: None)
    copies = copies_of(flips)
    inner = [fold for fold in np.unique(folds) if fold != held_out_fold]
    usable = folds != held_out_fold
    results = {}
    pooled = {}
    for C in grid:
        accuracies, scores, truth = [], [], []
        for fold in inner:
            train_mask = usable & (folds != fold)
            test_mask = folds == fold
            weights, bias = fit_linear_svm(
                with_copies(features, copies, train_mask),
                np.tile(labels[train_mask], 1 + len(copies)), C=C, seed=seed)
            fold_scores = _decision(weights, bias, features[test_mask])
            accuracies.append(float(np.mean((fold_scores > 0) == (labels[test_mask] == 1))))
            scores.append(fold_scores)
            truth.append(labels[test_mask])
        results[C] = float(np.mean(accuracies))
        pooled[C] = (np.concatenate(scores), np.concatenate(truth))
        log(f"cross-validation C={C:g}: mean leak-free accuracy {results[C]:.4f}")
    best = max(grid, key=lambda c: (results[c], -c))
    scores, truth = pooled[best]
    candidates = np.unique(np.round(scores, 3))
    accuracy = [np.mean((scores > t) == (truth == 1)) for t in candidates]
    top = np.max(accuracy)
    # Among equally accurate thresholds take the one nearest the SVM's own 0.
    threshold = float(min(candidates[np.asarray(accuracy) == top], key=abs))
    return {"grid": [float(c) for c in grid], "mean_accuracy": [results[c] for c in grid],
            "C": float(best), "threshold": threshold, "threshold_accuracy": float(top),
            "folds": [int(f) for f in inner]}


def source_holdout(features, labels, sources, flips, C, seed=0, log=None):
    """Hold out each source in turn: fit on the rest, score the held-out crops.

    Parameters
    ----------
    features, labels : ndarray
    sources : ndarray of str
        Source of every crop (:func:`~.dataset.source_of`); sources named
        ``extra:...`` (added negatives) are always trained on.
    flips : list of ndarray
        Augmented copies, as for :func:`cross_validate`.

    Returns
    -------
    dict
        Per held-out source: ``accuracy``, ``test_crops``, ``vehicles`` (how
        many of them are vehicles) and ``confusion``.
    """
    log = log or (lambda message: None)
    out = {}
    for source in sorted(set(sources.tolist())):
        if source.startswith("extra:"):
            continue
        _, _, report, _ = _fit_and_score(features, labels, sources != source, flips, C, seed)
        out[source] = {"accuracy": report["accuracy"], "test_crops": report["test_crops"],
                       "vehicles": int(labels[sources == source].sum()),
                       "confusion": report["confusion"]}
        log(f"source {source} held out: accuracy {report['accuracy']:.4f} "
            f"on {report['test_crops']} crops")
    return out


def check_source_holdout(labels, sources):
    """Raise :class:`InputError` unless every source can be held out with both classes left.

    Checked on the listing, before features are extracted: holding out a
    data set's only source (or the only one with vehicles) leaves nothing,
    or one class, to fit on.
    """
    labels = np.asarray(labels)
    sources = np.asarray(sources)
    held_out = sorted(s for s in set(sources.tolist()) if not s.startswith("extra:"))
    for source in held_out:
        rest = labels[sources != source]
        if len(np.unique(rest)) < 2:
            found = ", ".join(held_out)
            missing = ("" if not len(rest) else "vehicle " if not rest.any()
                       else "non-vehicle ")
            raise InputError(f"--source-holdout trains on the other sources while one is held "
                             f"out, but without {source} no {missing}crop is left (sources "
                             f"found: {found})")


def _checked_C(C):
    """``C`` as a float, or a grid as a tuple of floats; InputError if not finite and above 0."""
    grid = np.ndim(C) > 0
    values = list(C) if grid else [C]
    if grid and not values:
        raise InputError("C is an empty grid: give one value or several to cross-validate")
    for value in values:
        # Booleans are numbers to Python, and a string is no number even if it reads as one.
        number = (isinstance(value, (int, float, np.integer, np.floating))
                  and not isinstance(value, bool))
        if not (number and np.isfinite(value) and value > 0):
            raise InputError(f"C must be a finite number above 0, got {value!r}")
    values = [float(value) for value in values]
    return tuple(values) if grid else values[0]


def _checked_integer(name, value, low, high=None):
    """``value`` as an int within ``low .. high``, else an InputError naming ``name``."""
    whole = isinstance(value, (int, np.integer)) and not isinstance(value, bool)
    if not whole or value < low or (high is not None and value > high):
        span = (f"an integer of at least {low}" if high is None
                else f"an integer from {low} to {high}")
        raise InputError(f"{name} must be {span}, got {value!r}")
    return int(value)


def _checked_flag(name, value):
    """``value`` as a bool (NumPy's too), else an InputError: ``"no"`` was taken as true."""
    if not isinstance(value, (bool, np.bool_)):
        raise InputError(f"{name} must be True or False, got {value!r}")
    return bool(value)


def check_splits(data_dir, labels, folds, test_fold, random_test, cross_validated=False):
    """Raise :class:`InputError` unless every split has crops to test on and both classes to fit.

    Checked on the listing, before the crops are read: with one crop a
    class the leak-free test fold took every crop and the fit failed after
    feature extraction (an internal error), and with two a class the random
    split held out none, reporting an accuracy of NaN.

    Parameters
    ----------
    data_dir : str or Path
        Named in the message.
    labels : ndarray of int
    folds : ndarray of int
        Leak-free fold of every crop (:func:`~.dataset.leak_free_folds`).
    test_fold : int
    random_test : ndarray of bool
        The random split's test mask (:func:`~.dataset.random_split`).
    cross_validated : bool
        Also check every inner fold of :func:`cross_validate`.
    """
    labels = np.asarray(labels)
    few = f"too few crops in {data_dir}"

    def check_fit(train_mask, split):
        missing = [name for label, name in ((1, "vehicle"), (0, "non-vehicle"))
                   if not np.any(labels[train_mask] == label)]
        if missing:
            raise InputError(f"{few}: {split} leaves no {' and no '.join(missing)} crop to "
                             f"train on")

    if not random_test.any():
        raise InputError(f"{few}: the random split holds out 20 % of each class, which rounds "
                         f"to none of {int(labels.sum())} vehicles and "
                         f"{int((labels == 0).sum())} non-vehicles (it needs 3 of a class)")
    check_fit(~random_test, "the random split")
    test = folds == test_fold
    if not test.any():
        raise InputError(f"{few}: leak-free fold {test_fold} is empty (every group has fewer "
                         f"crops than folds); give fewer folds or test fold 0")
    check_fit(~test, f"holding out leak-free fold {test_fold}")
    if cross_validated:
        for fold in np.unique(folds[~test]):
            check_fit(~test & (folds != fold),
                      f"cross-validation holding out folds {test_fold} and {fold}")


def train(data_dir, options=None, C=0.001, flip=True, n_folds=5, test_fold=0, seed=0,
          extra_negatives=(), log=None, return_test_scores=False, jitter=True,
          photometric=Photometric(), hold_out_sources=False):
    """Train a model on a data set folder and report both splits.

    Parameters
    ----------
    data_dir : str or Path
        Folder with ``vehicles/`` and ``non-vehicles/``.
    options : FeatureOptions, optional
        Defaults to ``FeatureOptions()``.
    C : float or sequence of float
        LinearSVC regularisation; a sequence is a grid searched by
        :func:`cross_validate` on the leak-free training folds.
    flip : bool
        Add horizontally flipped copies of the training crops.
    jitter : bool
        Add a randomly scaled, shifted and mirrored copy of every training
        crop (:func:`jitter_crops`, seeded with ``seed``).
    photometric : Photometric or None
        Also change the jittered copy's brightness, contrast, colour, blur,
        resolution and JPEG quality (needs ``jitter``); ``None`` keeps its
        look.
    hold_out_sources : bool
        Also report :func:`source_holdout` (one more fit per source).
    n_folds, test_fold : int
        Leak-free split: which contiguous block of each group is held out.
    seed : int
        Seed of the random split and the solver.
    extra_negatives : iterable of paths
        Extra non-vehicle folders.
    log : callable, optional
        Receives progress lines.
    return_test_scores : bool
        Also return the leak-free test split's decision values and labels.

    Returns
    -------
    Model
        Fit on the leak-free training part; ``model.report`` has the figures.
    (scores, labels) : tuple of ndarray
        Only with ``return_test_scores``.

    Raises
    ------
    InputError
        Before any crop is read: for a ``C`` that is not a finite number
        above 0 (or an empty grid), ``n_folds`` below 2, a ``test_fold``
        outside ``0 .. n_folds - 1``, a ``seed`` outside ``0 .. 2**32 - 1``,
        flags that are not booleans, a data set folder that cannot be listed
        and one with too few crops for its splits (a split with no crop to
        test on, or a training part without both classes); later, for a crop
        that cannot be read.
    TypeError
        When ``options`` is not a :class:`FeatureOptions`, ``photometric``
        not a :class:`Photometric` or ``extra_negatives`` a single path.
    """
    options = FeatureOptions() if options is None else options
    if not isinstance(options, FeatureOptions):
        raise TypeError(f"options must be a FeatureOptions, got {type(options).__name__}"
                        + (" (FeatureOptions.from_dict reads a dict)"
                           if isinstance(options, dict) else ""))
    if photometric is not None and not isinstance(photometric, Photometric):
        raise TypeError(f"photometric must be a Photometric or None, got "
                        f"{type(photometric).__name__}")
    # Plain Python values: they go into the report, which the model file holds as JSON
    # (a NumPy float32 C trained, and then the model could not be saved).
    C = _checked_C(C)
    n_folds = _checked_integer("n_folds", n_folds, 2)
    test_fold = _checked_integer("test_fold", test_fold, 0, n_folds - 1)
    # LinearSVC takes seeds up to 2**32 - 1 only, and its fit comes after the features.
    seed = _checked_integer("seed", seed, 0, 2**32 - 1)
    flip, jitter, hold_out_sources, return_test_scores = (
        _checked_flag(name, value) for name, value in (
            ("flip", flip), ("jitter", jitter), ("hold_out_sources", hold_out_sources),
            ("return_test_scores", return_test_scores)))
    log = log or (lambda message: None)
    started = time.perf_counter()
    dataset = list_dataset(data_dir, extra_negatives)
    log(f"{len(dataset)} crops ({int(dataset.labels.sum())} vehicles) in {data_dir}")
    crop_sources = np.array([source_of(g) for g in dataset.groups])
    if hold_out_sources:
        check_source_holdout(dataset.labels, crop_sources)
    labels = dataset.labels
    folds = leak_free_folds(dataset.groups, n_folds)
    random_test = random_split(labels, seed=seed)
    check_splits(data_dir, labels, folds, test_fold, random_test, cross_validated=np.ndim(C) > 0)
    crops = load_crops(dataset.paths)
    loaded = time.perf_counter()
    features = features_of_crops(crops, options)
    copies = []
    if flip:
        copies.append(features_of_crops(crops[:, :, ::-1], options))
    if jitter:
        copies.append(features_of_crops(jitter_crops(crops, seed, photometric=photometric),
                                        options))
    flips = copies
    extracted = time.perf_counter()
    log(f"features: {features.shape[1]} per crop, {extracted - loaded:.1f} s")
    cv_report = None
    if np.ndim(C) > 0:
        cv_report = cross_validate(features, labels, folds, test_fold, flips, list(C), seed, log)
        C = cv_report["C"]
        log(f"chosen C={C:g}, decision threshold {cv_report['threshold']:+.3f}")

    _, _, random_report, _ = _fit_and_score(features, labels, ~random_test, flips, C, seed)
    log(f"random split: accuracy {random_report['accuracy']:.4f}")
    train_mask = folds != test_fold
    weights, bias, leak_free_report, test_scores = _fit_and_score(features, labels, train_mask,
                                                                  flips, C, seed)
    log(f"leak-free split: accuracy {leak_free_report['accuracy']:.4f}")
    sources = None
    if hold_out_sources:
        sources = source_holdout(features, labels, crop_sources, flips, C, seed, log)

    report = {
        "data": str(data_dir),
        "crops": len(dataset),
        "vehicles": int(labels.sum()),
        "feature_length": FeatureLayout(options).length,
        "C": C,
        "flip_augmentation": flip,
        "jitter_augmentation": ({"scale": list(JITTER_SCALE), "shift": JITTER_SHIFT, "seed": seed}
                                if jitter else None),
        "photometric_augmentation": (photometric.to_dict()
                                     if jitter and photometric is not None else None),
        "random_split": random_report,
        "leak_free_split": {**leak_free_report, "n_folds": n_folds, "test_fold": test_fold},
        "fit_on": "leak-free training part",
        "cross_validation": cv_report,
        "source_holdout": sources,
        "load_seconds": round(loaded - started, 2),
        "feature_seconds": round(extracted - loaded, 2),
        "total_seconds": round(time.perf_counter() - started, 2),
    }
    model = Model(weights=weights, bias=bias, options=options, report=report)
    if return_test_scores:
        return model, (test_scores, labels[~train_mask])
    return model
