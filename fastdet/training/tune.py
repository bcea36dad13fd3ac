"""``fastdet tune``: choose the detection thresholds on annotated frames.

The decision threshold, the heat threshold, the heat weighting and the box
refinement interact, so they are chosen together by a grid search that
maximises detection quality on frames annotated for the purpose (the test
video's frames and the development frames of other footage, never the
evaluation images or held-out frames).  Windows are scored once per frame at
the lowest decision threshold of the grid; every combination then only
re-filters hits, re-accumulates heat and re-labels, which is cheap.  Last,
the box refinement model (:mod:`fastdet.training.refine`) is fitted to the
best setting's blobs; the refined setting competes with the others on the
same ranking.
"""

from __future__ import annotations

import dataclasses
import itertools
from dataclasses import dataclass

from ..detector.boxes import BoxFinder
from ..detector.config import DetectorConfig
from ..detector.detector import Detector
from ..detector.scoring import Hits
from ..errors import ConfigError, InputError
from ..evaluation.metrics import evaluate
from .mine import NO_ANNOTATED_FRAME, annotated_frames, check_sources, paired_sources
from .refine import fit_refinement, refinement_samples

#: Box shape corrections searched for the best threshold combinations.
SHAPE_GRID = {
    "width_scale": (1.0, 1.1, 1.2, 1.3, 1.4, 1.5, 1.6),
    "height_scale": (0.7, 0.75, 0.8, 0.85, 0.9, 0.95, 1.0),
    "center_dy": (-0.1, -0.05, 0.0, 0.05, 0.1),
}

#: How many of the best threshold combinations get a shape search.
SHAPE_CANDIDATES = 5

#: Smallest split-off part (``[heat] split_min_size``, reference pixels) tried
#: with the shape search: 32 is the smallest default window, 48 lets only
#: cars as wide as the third one be split apart.
SPLIT_GRID = (32.0, 48.0)

#: The grid ``fastdet tune`` searches by default.
DEFAULT_GRID = {
    "decision_threshold": (-0.5, -0.25, 0.0, 0.25, 0.5, 0.75, 1.0, 1.5),
    "heat_threshold": (0.0, 1.0, 2.0, 3.0, 4.0),
    "weighting": ("count", "area", "margin", "margin_area"),
    "peak_fraction": (0.0, 0.3, 0.5, 0.7),
}


@dataclass
class TuningResult:
    """One evaluated combination."""

    decision_threshold: float
    heat_threshold: float
    weighting: str
    peak_fraction: float
    width_scale: float
    height_scale: float
    center_dy: float
    precision: float
    recall: float
    ap: float
    mean_iou: float
    iou_p10: float = 0.0
    split_min_size: float = 48.0
    stability: int = 0
    neighbourhood_f1: float = 0.0
    refine: tuple = ()
    refine_samples: int = 0

    @property
    def f1(self):
        total = self.precision + self.recall
        return 0.0 if total == 0 else 2 * self.precision * self.recall / total

    def key(self):
        """Ranking: the F1 of the thresholds' neighbourhood, then F1, stability, box quality, AP."""
        return (round(self.neighbourhood_f1, 3), round(self.f1, 4), self.stability,
                round(self.mean_iou, 4), round(self.ap, 4))


def _subset(hits, keep):
    return Hits(hits.boxes[keep], hits.scores[keep], hits.scale_index[keep], hits.windows_scored)


def tune(model, sources, annotations, base_config=None, grid=None, log=None, jitter=()):
    """Grid-search the thresholds; returns results best first.

    Parameters
    ----------
    model : Model
    sources : iterable
        Videos (annotated as ``frame<N>``) and/or images, each a path or a
        ``(path, annotations)`` pair.
    annotations : dict
        From :func:`fastdet.evaluation.annotations.load_annotations`, for
        the sources given as bare paths.
    base_config : DetectorConfig, optional
        Scales and box filters used for every combination.
    grid : dict, optional
        Values per parameter; defaults to :data:`DEFAULT_GRID`.
    log : callable, optional
    jitter : iterable of float
        Horizon shifts, in rows of a ``search.reference_size`` frame: every
        annotated frame is also searched with the window grid moved by each
        of them, and each (frame, shift) counts as a frame of its own.  The
        grid steps 8-16 pixels, so where it falls on a car changes which
        windows frame it, and a camera's grid falls anywhere: settings chosen
        at one grid alone fit where it fell on the tuning frames' cars.

    Returns
    -------
    list of TuningResult
    """
    base = base_config or DetectorConfig()
    if base.search.auto_horizon:
        raise ConfigError('fastdet tune searches a numeric horizon: set [search] horizon to a '
                          'number, not "auto"')
    # A list: a generator of sources was used up by the check, leaving no frame to tune on.
    sources = list(sources)
    check_sources(sources)
    grid = grid or DEFAULT_GRID
    lowest = min(grid["decision_threshold"])
    lowest_config = dataclasses.replace(
        base, search=dataclasses.replace(base.search, decision_threshold=lowest))
    shifts = (0.0, *sorted({float(s) for s in jitter} - {0.0}))
    scoring = {shift: Detector(model, _moved(lowest_config, shift)) for shift in shifts}
    frames, truth = {}, {}
    for number, (source, truth_of) in enumerate(paired_sources(sources, annotations)):
        for key, frame in annotated_frames(source, truth_of):
            # Keyed by source too: two videos may both have a frame0010.
            # The frame too: the refined boxes' sides snap to its edges
            # ([boxes] snap_sides).
            for shift, detector in scoring.items():
                sample = (number, key) if not shift else (number, key, shift)
                frames[sample] = (detector.hits(frame), (frame.shape[1], frame.shape[0]), frame)
                truth[sample] = truth_of[key]
    if not frames:
        raise InputError(NO_ANNOTATED_FRAME)
    results = []
    for threshold, heat_threshold, weighting, fraction in itertools.product(
            grid["decision_threshold"], grid["heat_threshold"], grid["weighting"],
            grid["peak_fraction"]):
        shape = (base.boxes.width_scale, base.boxes.height_scale, base.boxes.center_dy)
        results.append(_evaluate(model, base, frames, truth, threshold, heat_threshold, weighting,
                                 fraction, base.heat.split_min_size, [shape])[0])
    _rate_stability(results, grid)
    results.sort(key=TuningResult.key, reverse=True)
    shapes = list(itertools.product(SHAPE_GRID["width_scale"], SHAPE_GRID["height_scale"],
                                    SHAPE_GRID["center_dy"]))
    for best, split in itertools.product(results[:SHAPE_CANDIDATES], SPLIT_GRID):
        shaped = _evaluate(model, base, frames, truth, best.decision_threshold,
                           best.heat_threshold, best.weighting, best.peak_fraction, split, shapes)
        for result in shaped:
            result.stability = best.stability
            result.neighbourhood_f1 = best.neighbourhood_f1
        results.extend(shaped)
    results.sort(key=TuningResult.key, reverse=True)
    refined = _refined(model, base, frames, truth, results[0])
    if refined is not None:
        results.append(refined)
        results.sort(key=TuningResult.key, reverse=True)
    if log:
        log(f"{len(results)} combinations on {len(frames)} annotated frames")
    return results


def _moved(config, rows):
    """``config`` searching ``rows`` reference-frame rows lower (higher when negative)."""
    if not rows:
        return config
    search = config.search
    if search.scales:
        scales = tuple(dataclasses.replace(scale, y=(scale.y[0] + rows, scale.y[1] + rows))
                       for scale in search.scales)
        return dataclasses.replace(config, search=dataclasses.replace(search, scales=scales))
    return config.with_horizon(search.horizon + rows / search.reference_size[1])


def _refined(model, base, frames, truth, best):
    """``best`` with a box refinement fitted to its blobs (None without samples)."""
    config = _config(base, best)
    detector = Detector(model, config)
    blobs = {key: (*_blobs(detector, hits, size, best.decision_threshold), size, frame)
             for key, (hits, size, frame) in frames.items()}
    samples = refinement_samples(detector.box_finder, {
        key: (boxes, heat, origin, size) for key, ((boxes, _), heat, origin, size, _)
        in blobs.items()}, truth)
    weights = fit_refinement(samples)
    if not len(weights):
        return None
    weights = tuple(tuple(float(v) for v in row) for row in weights)
    finder = BoxFinder(dataclasses.replace(config, boxes=dataclasses.replace(
        config.boxes, refine=weights)))
    predictions = {}
    for key, ((boxes, peaks), heat, origin, size, frame) in blobs.items():
        detections = finder.finish_boxes(boxes, peaks, size, heat, origin, frame)
        predictions[key] = (detections.xyxy, detections.score)
    report = evaluate(predictions, truth)
    return dataclasses.replace(best, precision=report.precision, recall=report.recall,
                               ap=report.ap, mean_iou=report.mean_iou, iou_p10=report.iou_p10,
                               refine=weights, refine_samples=len(samples))


def _config(base, result):
    """``base`` with a result's thresholds and shape correction."""
    return dataclasses.replace(
        base,
        search=dataclasses.replace(base.search, decision_threshold=result.decision_threshold),
        heat=dataclasses.replace(base.heat, threshold=result.heat_threshold,
                                 weighting=result.weighting, peak_fraction=result.peak_fraction,
                                 split_min_size=result.split_min_size),
        boxes=dataclasses.replace(base.boxes, width_scale=result.width_scale,
                                  height_scale=result.height_scale, center_dy=result.center_dy,
                                  refine=()))


def _blobs(detector, hits, size, threshold):
    """Blob boxes and peaks of one frame's hits above ``threshold``, and the heat."""
    kept = _subset(hits, hits.scores > threshold)
    heat, origin = detector.heat_region(kept, size)
    return detector.box_finder.heat_components(heat, origin, size), heat, origin


def _rate_stability(results, grid):
    """Rate, for each result, the neighbouring thresholds.

    ``neighbourhood_f1`` is the mean F1 of the setting and of its decision-
    and heat-threshold neighbours in the grid; ``stability`` counts the
    neighbours that score as well as the setting itself.  A few annotated
    frames cannot tell apart many settings that are all perfect on them, and
    a setting that is best on them alone, between neighbours that do worse,
    is a peak of those frames' noise: the one in the middle of a good region,
    furthest from the settings that fail, is the safest choice on unseen
    frames.  (The first build that ranked by F1 alone chose a decision
    threshold of -0.5 with no stable neighbour; it made two false positives
    on the test images that the tuning frames had not shown.)
    """
    decision = list(grid["decision_threshold"])
    heat = list(grid["heat_threshold"])
    f1 = {(r.decision_threshold, r.heat_threshold, r.weighting, r.peak_fraction): round(r.f1, 4)
          for r in results}
    for r in results:
        i, j = decision.index(r.decision_threshold), heat.index(r.heat_threshold)
        own = round(r.f1, 4)
        r.stability = 0
        scores = [own]
        for di, dj in ((-1, 0), (1, 0), (0, -1), (0, 1)):
            if 0 <= i + di < len(decision) and 0 <= j + dj < len(heat):
                neighbour = f1.get((decision[i + di], heat[j + dj], r.weighting, r.peak_fraction))
                if neighbour is not None:
                    scores.append(neighbour)
                    r.stability += neighbour >= own
        r.neighbourhood_f1 = sum(scores) / len(scores)


def _evaluate(model, base, frames, truth, threshold, heat_threshold, weighting, fraction,
              split_min_size, shapes):
    """Results of one threshold combination under each box shape correction."""
    config = dataclasses.replace(
        base,
        search=dataclasses.replace(base.search, decision_threshold=threshold),
        heat=dataclasses.replace(base.heat, threshold=heat_threshold, weighting=weighting,
                                 peak_fraction=fraction, split_min_size=split_min_size),
        boxes=dataclasses.replace(base.boxes, refine=()))
    detector = Detector(model, config)
    blobs = {key: (_blobs(detector, hits, size, threshold)[0], size)
             for key, (hits, size, _) in frames.items()}
    out = []
    for width_scale, height_scale, center_dy in shapes:
        shaped = BoxFinder(dataclasses.replace(config, boxes=dataclasses.replace(
            config.boxes, width_scale=width_scale, height_scale=height_scale,
            center_dy=center_dy)))
        predictions = {}
        for key, ((boxes, peaks), size) in blobs.items():
            detections = shaped.finish_boxes(boxes, peaks, size)
            predictions[key] = (detections.xyxy, detections.score)
        report = evaluate(predictions, truth)
        out.append(TuningResult(threshold, heat_threshold, weighting, fraction, width_scale,
                                height_scale, center_dy, report.precision, report.recall,
                                report.ap, report.mean_iou, report.iou_p10, split_min_size))
    return out


def tuned_config(base, result):
    """The :class:`DetectorConfig` a tuning result was scored with: ``base`` with its values."""
    config = _config(base or DetectorConfig(), result)
    return dataclasses.replace(config, boxes=dataclasses.replace(config.boxes,
                                                                 refine=tuple(result.refine)))


def tuned_values(result):
    """The settings tuning chooses, as nested ``{section: {key: value}}``."""
    return {
        "search": {"decision_threshold": result.decision_threshold},
        "heat": {"threshold": result.heat_threshold, "weighting": result.weighting,
                 "peak_fraction": result.peak_fraction, "split_min_size": result.split_min_size},
        # Explicitly none when not refined: the default refinement is fitted to the bundled
        # model, and the result was scored without it.
        "boxes": {"width_scale": result.width_scale, "height_scale": result.height_scale,
                  "center_dy": result.center_dy,
                  "refine": [list(row) for row in result.refine]},
    }


def as_toml(result, base=None):
    """A whole TOML config: ``base`` (a parsed config file) with the tuned values merged in.

    Written alone, the tuned keys would lose the base config's windows,
    horizon, box filters and ``[track]``, and the file would not reproduce
    the settings the result was scored with.
    """
    document = {section: dict(values) if isinstance(values, dict) else values
                for section, values in (base or {}).items()}
    for section, values in tuned_values(result).items():
        document.setdefault(section, {}).update(values)
    return toml_document(document)


def toml_document(document):
    """Nested dicts (as :func:`tomllib.loads` returns them) as TOML text.

    ``tomli_w`` writes floats so that they read back exactly: the file
    reproduces the scored setting.
    """
    import tomli_w

    return tomli_w.dumps(document)


def format_results(results, top=10):
    """Markdown table of the best combinations."""
    lines = ["| decision thr | heat thr | weighting | peak fraction | split min | width x | height x | "
             "centre dy | refined | precision | recall | F1 | neighbourhood F1 | stable neighbours | "
             "AP50 | mean IoU | "
             "IoU p10 |",
             "|---:|---:|---|---:|---:|---:|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in results[:top]:
        lines.append(f"| {r.decision_threshold:g} | {r.heat_threshold:g} | {r.weighting} | "
                     f"{r.peak_fraction:g} | {r.split_min_size:g} | {r.width_scale:g} | "
                     f"{r.height_scale:g} | "
                     f"{r.center_dy:g} | {'yes' if r.refine else 'no'} | {r.precision:.3f} | "
                     f"{r.recall:.3f} | {r.f1:.3f} | {r.neighbourhood_f1:.3f} | {r.stability} | "
                     f"{r.ap:.3f} | "
                     f"{r.mean_iou:.3f} | {r.iou_p10:.3f} |")
    return "\n".join(lines)
