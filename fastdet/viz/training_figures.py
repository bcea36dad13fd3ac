"""Figures of training: the training report and the colour-space study."""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from .figure import check_output_path, new_figure, save_figure

# -- training report --------------------------------------------------------
#: Pixel size of :func:`training_report_figure`.
TRAINING_REPORT_SIZE = (1500, 520)


def training_report_figure(model_report, test_scores, test_labels, path):
    """Decision-score histograms, confusion matrix and accuracy figures of a training run.

    Parameters
    ----------
    model_report : dict
        :attr:`fastdet.detector.model.Model.report` (any keys; the known ones, such as
        ``random_split`` and ``leak_free_split``, are listed by name).
    test_scores : array_like of float, shape (N,)
        SVM margins of the held-out crops.
    test_labels : array_like, shape (N,)
        Their classes: 1 for vehicle; 0 (or -1) for non-vehicle.
    path : str or Path
        Output image file, :data:`TRAINING_REPORT_SIZE`.

    Returns
    -------
    Path

    Raises
    ------
    InputError
        When the scores and labels are empty, of different lengths, not
        finite, or the labels are not binary.
    """
    scores = np.asarray(test_scores, dtype=np.float64).reshape(-1)
    labels = np.asarray(test_labels).reshape(-1)
    if scores.size == 0 or scores.shape != labels.shape:
        raise InputError(f"need one label per test score, got {scores.size} scores and "
                         f"{labels.size} labels")
    if not np.all(np.isfinite(scores)):
        raise InputError("test scores must be finite")
    if not np.isin(labels.astype(np.float64), (-1, 0, 1)).all():
        raise InputError(f"test labels must be 1 (vehicle) or 0/-1 (non-vehicle), "
                         f"got values {np.unique(labels)[:5].tolist()}")
    check_output_path(path)
    vehicle = labels.astype(np.float64) == 1
    predicted = scores > 0
    true_pos = int(np.sum(vehicle & predicted))
    false_neg = int(np.sum(vehicle & ~predicted))
    false_pos = int(np.sum(~vehicle & predicted))
    true_neg = int(np.sum(~vehicle & ~predicted))

    figure = new_figure(*TRAINING_REPORT_SIZE)
    layout = figure.add_gridspec(1, 3, width_ratios=(1.5, 0.9, 1.3), left=0.05, right=0.99,
                                 bottom=0.12, top=0.9, wspace=0.25)
    axes = figure.add_subplot(layout[0])
    bins = np.linspace(scores.min(), scores.max(), 61) if np.ptp(scores) > 0 else 10
    for members, colour, name in ((vehicle, "tab:orange", "vehicles"),
                                  (~vehicle, "tab:blue", "non-vehicles")):
        axes.hist(scores[members], bins=bins, histtype="stepfilled", alpha=0.45, color=colour,
                  edgecolor=colour, linewidth=1.2, label=f"{name} ({int(members.sum())})")
    axes.axvline(0, color="black", linestyle="--", linewidth=1, label="decision boundary")
    cv = model_report.get("cross_validation")
    if isinstance(cv, dict) and isinstance(cv.get("threshold"), (int, float)) and cv["threshold"]:
        axes.axvline(cv["threshold"], color="tab:purple", linestyle=":", linewidth=1.5,
                     label=f"cross-validated threshold {cv['threshold']:+.3f}")
    # Log counts: the few misclassified crops near 0 are what matters, and
    # they would vanish next to the two tall modes on a linear axis.
    axes.set_yscale("log")
    axes.set_ylim(top=axes.get_ylim()[1] * 8)  # head-room for the legend
    axes.set_xlabel("SVM margin")
    axes.set_ylabel("test crops")
    axes.set_title("decision scores on the test split", fontsize=11)
    axes.legend(fontsize=9, loc="upper left", framealpha=0.9)

    axes = figure.add_subplot(layout[1])
    matrix = np.array([[true_pos, false_neg], [false_pos, true_neg]])
    rates = matrix / np.maximum(matrix.sum(axis=1, keepdims=True), 1)
    axes.imshow(rates, cmap="Blues", vmin=0, vmax=1)
    for row in range(2):
        for col in range(2):
            axes.text(col, row, f"{matrix[row, col]}\n{rates[row, col]:.1%}", ha="center",
                      va="center", fontsize=12, color="white" if rates[row, col] > 0.5 else "black")
    axes.set_xticks([0, 1], ["vehicle", "non-vehicle"])
    axes.set_yticks([0, 1], ["vehicle", "non-vehicle"])
    axes.set_xlabel("predicted (margin > 0)")
    axes.set_ylabel("true class")
    axes.set_title("confusion matrix", fontsize=11)

    axes = figure.add_subplot(layout[2])
    axes.set_axis_off()
    total = scores.size
    precision = true_pos / max(true_pos + false_pos, 1)
    recall = true_pos / max(true_pos + false_neg, 1)
    lines = [f"{'these test scores:':19}{total} crops",
             f"{'accuracy:':19}{(true_pos + true_neg) / total:.4f}",
             f"{'precision:':19}{precision:.4f}",
             f"{'recall:':19}{recall:.4f}",
             f"{'false positives:':19}{false_pos}",
             f"{'false negatives:':19}{false_neg}", "", "model report:"]
    lines += _report_lines(model_report)
    axes.text(0.0, 1.0, "\n".join(lines), va="top", ha="left", family="monospace", fontsize=10,
              transform=axes.transAxes)
    axes.set_title("accuracy figures", fontsize=11, loc="left")
    return save_figure(figure, path)


def _report_lines(report):
    """Readable lines of a training report: splits first, then other scalar entries."""
    lines = []
    for key, title in (("random_split", "random split"), ("leak_free_split", "leak-free split")):
        split = report.get(key)
        if isinstance(split, dict) and "accuracy" in split:
            detail = (f" ({split['test_crops']} test crops)" if "test_crops" in split else "")
            lines.append(f"{title + ':':19}{float(split['accuracy']):.4f}{detail}")
    cv = report.get("cross_validation")
    if isinstance(cv, dict) and "C" in cv:
        lines.append(f"{'cross-validated:':19}C {float(cv['C']):g}"
                     + (f", threshold {float(cv['threshold']):+.3f}" if "threshold" in cv else ""))
    for key, value in report.items():
        if (key in ("random_split", "leak_free_split") or value is None
                or isinstance(value, (dict, list))):
            continue
        text = f"{value:.4g}" if isinstance(value, float) else str(value)
        lines.append(f"{key.replace('_', ' ') + ':':19}{text}"[:46])
    return lines


def study_figure(rows, path):
    """Grouped bars of leak-free accuracy per colour space and feature set (PNG)."""
    spaces = list(dict.fromkeys(r.color_space for r in rows))
    sets = list(dict.fromkeys(r.feature_set for r in rows))
    figure = new_figure(1000, 450)
    axes = figure.add_subplot(1, 1, 1)
    width = 0.8 / len(sets)
    for k, name in enumerate(sets):
        values = [100 * next(r.leak_free_accuracy for r in rows
                             if r.color_space == s and r.feature_set == name) for s in spaces]
        axes.bar(np.arange(len(spaces)) + k * width, values, width, label=name)
    axes.set_xticks(np.arange(len(spaces)) + width * (len(sets) - 1) / 2, spaces)
    low = min(100 * r.leak_free_accuracy for r in rows)
    axes.set_ylim(max(low - 1, 80), 100)
    axes.set_ylabel("leak-free test accuracy (%)")
    axes.set_title("Colour space and feature set (LinearSVC, leak-free split)")
    axes.legend(loc="lower right")
    figure.tight_layout()
    return save_figure(figure, path)
