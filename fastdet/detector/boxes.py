"""Heat to boxes: hits -> heat map -> labelled blobs -> split, shaped, filtered boxes.

Heat is piecewise constant between window edges, so the kernels sum it on
the grid of cells the window edges cut, and threshold and label it on the
runs of identical rows and columns (:mod:`fastdet.kernels.heat`,
:mod:`fastdet.kernels.label`).  Python here only keeps the settings and
splits the few blobs that hold two car-sized peaks.
"""

from __future__ import annotations

import math

import numpy as np

from ..kernels.heat import box_heat_region
from ..kernels.label import (
    component_boxes,
    heat_blobs,
    label_components,
    split_component,
    split_levels,
)
from ..kernels.refine import snap_box_sides
from .detections import Detections
from .refine import heat_features, refine_boxes

#: Sub-sampling of the cheap first pass that decides whether a heat blob splits.
_SPLIT_PROBE = 4
#: Fractions of the way from the heat threshold to a blob's peak at which it is split.
_SPLIT_LEVELS = np.linspace(0.2, 0.8, 5)


class BoxFinder:
    """The ``[heat]`` and ``[boxes]`` steps of a :class:`~fastdet.detector.config.DetectorConfig`.

    Parameters
    ----------
    config : DetectorConfig
    """

    def __init__(self, config):
        self.config = config
        self._heat_blob_params = None

    def heat_weights(self, hits, plans):
        """Heat each hit adds, per ``heat.weighting`` (``plans``: the frame's scale plans)."""
        weighting = self.config.heat.weighting
        if weighting in ("margin", "margin_area"):
            threshold = self.config.search.decision_threshold
            if hits.scores.dtype == np.float32:
                # What NumPy computes for a Python float, in one call (each
                # NumPy call right after a frame's search costs 10-30 us of
                # cold caches).
                weights = hits.scores - np.float32(threshold)
            else:
                weights = (hits.scores - threshold).astype(np.float32)
        else:
            weights = np.ones(len(hits.scores), dtype=np.float32)
        if weighting in ("area", "margin_area") and len(hits.scores):
            per_scale = np.array([plan.heat_weight for plan in plans], dtype=np.float32)
            weights = weights * per_scale[hits.scale_index]
        return weights

    def heat_region(self, hits, frame_size, plans):
        """Heat of the hits over their bounding region.

        Returns
        -------
        heat : ndarray of float32, shape (y1 - y0, x1 - x0)
        origin : tuple of int
            ``(x0, y0)`` of the region in the frame.
        """
        width, height = frame_size
        if len(hits.scores) == 0:
            return np.zeros((0, 0), np.float32), (0, 0)
        heat, x0, y0 = box_heat_region(hits.boxes, self.heat_weights(hits, plans),
                                       width, height)
        return heat, (x0, y0)

    def heat_components(self, heat, origin, frame_size=None):
        """Boxes and peak heat of each blob (refined and split per ``[heat]``).

        ``heat`` is float32 or float64 (other dtypes are taken as float64).
        """
        if heat.size == 0:
            return np.zeros((0, 4), np.int32), np.zeros(0, np.float32)
        # The kernel's settings, kept while the config and frame size stay:
        # Python work here costs more than the kernel's per-blob work.
        params = self._heat_blob_params
        if params is None or params[0] is not self.config or params[1] != frame_size:
            cfg = self.config.heat
            min_size = -1
            if cfg.split:
                scale = 1.0
                if frame_size is not None:
                    ref_w, ref_h = self.config.search.reference_size
                    scale = math.sqrt(frame_size[0] / ref_w * frame_size[1] / ref_h)
                min_size = int(round(cfg.split_min_size * scale))
            params = self._heat_blob_params = (
                self.config, frame_size, min_size,
                (float(cfg.threshold), cfg.connectivity == 8, bool(cfg.peak_fraction > 0),
                 np.float32(cfg.peak_fraction), min_size, _SPLIT_PROBE, _SPLIT_LEVELS))
        if heat.dtype != np.float32 and heat.dtype != np.float64:
            heat = heat.astype(np.float64)
        # One kernel thresholds and labels the heat on its grid of constant
        # cells, measures the blobs and probes which of them split.
        boxes, peaks, probed, n_probed = heat_blobs(heat, origin[0], origin[1], *params[3])
        if n_probed:
            boxes, peaks = self._split_blobs(heat, origin, boxes, peaks, probed, params[2])
        return boxes, peaks

    def _split_blobs(self, heat, origin, boxes, peaks, probed, min_size):
        """Replace blobs with two car-sized peaks by one box per peak.

        Heat is piecewise constant over window steps of 8+ pixels, so a
        quarter-resolution probe (run by ``heat_blobs``) finds out cheaply
        whether a blob splits at all; the ``probed`` ones are split here at
        full resolution.
        """
        cfg = self.config.heat
        labels, count = label_components(heat > cfg.threshold, cfg.connectivity)
        whole = component_boxes(labels, count)
        shift = np.array([origin[0], origin[1], origin[0], origin[1]], dtype=np.int32)
        out_boxes, out_peaks = [], []
        for k in range(len(peaks)):
            parts = boxes[:0]
            if probed[k]:
                x1, y1, x2, y2 = whole[k]
                region = heat[y1:y2, x1:x2]
                mask = np.ascontiguousarray(labels[y1:y2, x1:x2] == k + 1)
                # The same levels the kernel's probe used (one definition).
                levels = split_levels(np.float32(peaks[k]), float(cfg.threshold), _SPLIT_LEVELS)
                parts = split_component(np.ascontiguousarray(region), mask.view(np.uint8), levels,
                                        min_size, min_size, cfg.connectivity)
                # A seed that won no pixel yields an empty box; it is no car.
                parts = parts[(parts[:, 2] > parts[:, 0]) & (parts[:, 3] > parts[:, 1])]
            if len(parts) < 2:
                out_boxes.append(boxes[k:k + 1])
                out_peaks.append(peaks[k:k + 1])
                continue
            out_peaks.append(np.array([region[py1:py2, px1:px2][mask[py1:py2, px1:px2]].max()
                                       for px1, py1, px2, py2 in parts], dtype=np.float32))
            out_boxes.append(parts + np.array([x1, y1, x1, y1], dtype=np.int32) + shift)
        return np.concatenate(out_boxes), np.concatenate(out_peaks)

    def finish_boxes(self, boxes, peaks, frame_size, heat=None, origin=(0, 0), frame=None,
                     readable=None):
        """Refine or shape-correct, snap, then filter blob boxes into :class:`Detections`.

        With ``[boxes] refine`` weights and the ``heat`` (and its
        ``origin``) the boxes came from, each box's edges are placed by the
        refinement model (:mod:`fastdet.detector.refine`) and, given the
        ``frame``, their sides then snap to its edges (``[boxes]
        snap_sides``), reading only the pixels inside ``readable`` (``(x0,
        y0, x1, y1)``, default the whole frame); otherwise the shape
        correction is applied.
        """
        weights = self.config.boxes.refine
        if weights and heat is not None and len(boxes):
            features = heat_features(heat, origin, boxes, self.config.heat.threshold,
                                     frame_size)
            boxes = _clipped(refine_boxes(boxes, features, weights, frame_size[0]), frame_size)
            # Only refined boxes: their sides lie near the car's, within the
            # reach searched.  Snapping the shape-corrected ones lowered the
            # F1 of fastdet tune's settings (0.832 -> 0.793 for the best).
            if frame is not None and self.config.boxes.snap_sides:
                boxes = self.snap_sides(frame, boxes, readable)
        else:
            boxes = self.reshape_boxes(boxes, frame_size)
        keep = self.box_filter(boxes, frame_size)
        # _clipped gives int32 boxes of at least a pixel; blob boxes are int32 and
        # valid too, peaks float32.
        return Detections.of_valid(boxes[keep], peaks[keep])

    def snap_sides(self, frame, boxes, readable=None):
        """``boxes`` (int32) with their sides on the frame's edges
        (:func:`~fastdet.kernels.refine.snap_box_sides`, ``[boxes] snap_sides``)."""
        height, width = frame.shape[:2]
        limits = np.array(readable if readable is not None else (0, 0, width, height), np.int64)
        snapped = np.empty((len(boxes), 4), np.int64)
        snap_box_sides(np.ascontiguousarray(frame), np.ascontiguousarray(boxes, np.int64),
                       float(self.config.boxes.snap_sides), limits, snapped)
        return snapped.astype(np.int32)

    def reshape_boxes(self, boxes, frame_size):
        """Apply the ``[boxes]`` shape correction about each box centre, clipped to the frame."""
        cfg = self.config.boxes
        if cfg.width_scale == 1 and cfg.height_scale == 1 and cfg.center_dy == 0:
            return boxes
        xyxy = boxes.astype(np.float64)
        cx = (xyxy[:, 0] + xyxy[:, 2]) / 2
        cy = (xyxy[:, 1] + xyxy[:, 3]) / 2
        half_w = (xyxy[:, 2] - xyxy[:, 0]) * cfg.width_scale / 2
        height = xyxy[:, 3] - xyxy[:, 1]
        half_h = height * cfg.height_scale / 2
        cy = cy + cfg.center_dy * height
        return _clipped(np.stack([cx - half_w, cy - half_h, cx + half_w, cy + half_h], axis=1),
                        frame_size)

    def box_filter(self, boxes, frame_size):
        """Boolean mask of the boxes that pass the ``[boxes]`` sanity filters."""
        cfg = self.config.boxes
        ref_w, ref_h = self.config.search.reference_size
        kx, ky = frame_size[0] / ref_w, frame_size[1] / ref_h
        min_size = cfg.min_size * math.sqrt(kx * ky)
        horizon = self.config.horizon_line() * ky
        keep = []
        # Plain Python over a frame's few boxes (see _clipped).
        for x1, y1, x2, y2 in np.asarray(boxes).tolist():
            width, height = x2 - x1, y2 - y1
            aspect = width / max(height, 1)
            keep.append(width >= min_size and height >= min_size
                        and cfg.min_aspect <= aspect <= cfg.max_aspect and y2 > horizon)
        return np.array(keep, dtype=bool)


def _clipped(boxes, frame_size):
    """Float boxes rounded to whole pixels and clipped to the frame, as int32."""
    width, height = frame_size
    out = []
    # Plain Python over a frame's few boxes: the dozen NumPy calls this took
    # on arrays of a handful of rows cost more, with the GIL held, which a
    # thread scoring another frame waits for.  round() rounds half to even,
    # as np.round does.
    for x1, y1, x2, y2 in boxes.tolist():
        x1 = min(max(round(x1), 0), width - 1)
        y1 = min(max(round(y1), 0), height - 1)
        # A box keeps at least one pixel after rounding and clipping.
        out.append((x1, y1, min(max(round(x2), x1 + 1), width),
                    min(max(round(y2), y1 + 1), height)))
    return np.array(out, np.int32).reshape(-1, 4)
