"""A seed-faithful reference detector: fastdet's search, computed the published way.

The published (Udacity-style) Python vehicle detectors find cars like this,
per search scale:

1. crop the region of interest, convert its colour space, resize it so a
   window becomes 64 pixels;
2. run ``skimage.feature.hog(..., feature_vector=False)`` once per channel
   on the whole scaled region ("HOG once per scale, sub-sample windows");
3. for each window, in Python: slice that window's HOG blocks, cut the
   window's pixels and compute the spatial (each window averaged down to ``S x S``) and
   colour-histogram (``np.histogram``) features, stack them, then call
   ``scaler.transform`` and the scikit-learn SVM on that single window;
4. add every hit window to a heat map, threshold it, label it with
   ``scipy.ndimage.label`` and take each component's bounding box.  fastdet's
   own refinements (``heat.peak_fraction``, ``heat.split``, the ``[boxes]``
   shape correction) are not part of the published pipeline and are ignored.

:class:`ReferenceDetector` does exactly that, but from a fastdet
:class:`~fastdet.detector.model.Model` and :class:`~fastdet.detector.config.DetectorConfig`:
regions, resized sizes, steps and window grids come from
:func:`fastdet.detector.plan.plan_scales`, features are stacked in fastdet's
:class:`~fastdet.detector.features.FeatureLayout` order, and the scikit-learn objects
are built from the model's weights (the model has the training scaler folded
in, so the scaler here is the identity).  Its results therefore equal
:class:`fastdet.detector.detector.Detector`'s up to float rounding, while its cost per
window is that of the published code: it is the slow peer in benchmarks and
an independent check of the fast kernels.

Only validation and configuration are shared with fastdet (``plan_scales``,
``convert_color``, ``as_bgr_frame``, the option/config dataclasses); no
fastdet kernel runs here.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import scipy.ndimage
import skimage.feature
from sklearn.preprocessing import StandardScaler
from sklearn.svm import LinearSVC

from fastdet.detector.config import DetectorConfig
from fastdet.detector.detections import Detections
from fastdet.detector.features import WINDOW, FeatureLayout, convert_color
from fastdet.detector.frames import as_bgr_frame
from fastdet.detector.model import Model, load_model
from fastdet.detector.plan import plan_scales


def sklearn_classifier(model):
    """The scikit-learn scaler and linear SVM equivalent to a fastdet model.

    Parameters
    ----------
    model : Model

    Returns
    -------
    scaler : StandardScaler
        Fitted with mean 0 and scale 1 (the identity): fastdet models already
        have the training scaler folded into their weights and bias.
    classifier : LinearSVC
        With ``coef_`` and ``intercept_`` set to the model's weights and bias,
        so ``classifier.decision_function(x)`` is ``model.decision_function(x)``.
    """
    length = model.weights.size
    # Fitting on the rows -1 and +1 yields mean exactly 0 and std exactly 1
    # through the public API, instead of setting fitted attributes by hand.
    scaler = StandardScaler().fit(np.stack([-np.ones(length), np.ones(length)]))
    classifier = LinearSVC()
    classifier.coef_ = model.weights.astype(np.float64).reshape(1, -1)
    classifier.intercept_ = np.array([model.bias], dtype=np.float64)
    classifier.classes_ = np.array([0, 1])
    classifier.n_features_in_ = length
    return scaler, classifier


class ReferenceDetector:
    """Slow, straightforward detector with the same results as ``fastdet.Detector``.

    Parameters
    ----------
    model : Model or str or Path
        A fastdet model or a model file.
    config : DetectorConfig, optional
        Search, heat and box settings; fastdet's defaults if omitted.

    Notes
    -----
    Window scores are float64 (scikit-learn's arithmetic) where fastdet's
    are float32, so they agree to about 1e-5 relative, and a window whose
    margin is within that of ``search.decision_threshold`` may be a hit for
    one detector and not the other.

    Examples
    --------
    >>> reference = ReferenceDetector(load_model("model.npz"))  # doctest: +SKIP
    >>> reference(cv2.imread("test1.jpg")).xyxy                  # doctest: +SKIP
    """

    def __init__(self, model, config=None):
        if not isinstance(model, Model):
            model = load_model(model)
        self.model = model
        self.config = config or DetectorConfig()
        self.options = model.options
        self.layout = FeatureLayout(model.options)
        self.scaler, self.classifier = sklearn_classifier(model)
        self._plans = {}

    def plans(self, frame_size):
        """fastdet's scale plans for frames of ``(width, height)`` (cached)."""
        plans = self._plans.get(frame_size)
        if plans is None:
            plans = self._plans[frame_size] = plan_scales(self.config, self.options, frame_size)
        return plans

    # -- features -------------------------------------------------------------
    def scale_hog(self, converted, grey=None):
        """skimage HOG blocks of a whole scaled region, one call per channel.

        Parameters
        ----------
        converted : ndarray of uint8, shape (H, W, 3)
            The scaled region in the model's colour space.
        grey : ndarray of uint8, shape (H, W), optional
            The scaled region's grey image; needed for ``hog_channel='gray'``.

        Returns
        -------
        ndarray of float64, shape (Hb, Wb, C, cpb, cpb, orientations)
            Per block, the channels' blocks stacked so that ``blocks[by, bx]``
            read row-major is fastdet's block vector, ordered
            ``(channel, cell_y, cell_x, bin)``.
        """
        options = self.options
        if options.hog_channel == "all":
            channels = [converted[:, :, c] for c in range(3)]
        elif options.hog_channel == "gray":
            channels = [grey]
        else:
            channels = [converted[:, :, options.hog_channel]]
        ppc, cpb = options.pixels_per_cell, options.cells_per_block
        per_channel = [skimage.feature.hog(channel, orientations=options.orientations,
                                           pixels_per_cell=(ppc, ppc),
                                           cells_per_block=(cpb, cpb),
                                           block_norm=options.block_norm, feature_vector=False)
                       for channel in channels]
        # skimage gives (Hb, Wb, cpb, cpb, bins) per channel; the channel axis
        # goes right after the block position to match fastdet's block order.
        return np.stack(per_channel, axis=2)

    def window_features(self, hog_blocks, converted, top, left, block_y, block_x):
        """Feature vector of one window, the way the published code builds it.

        Parameters
        ----------
        hog_blocks : ndarray or None
            :meth:`scale_hog` of the scale (``None`` without the HOG group).
        converted : ndarray of uint8, shape (H, W, 3)
            Colour-converted scaled region.
        top, left : int
            Window's top-left pixel in ``converted``.
        block_y, block_x : int
            Window's top-left block in ``hog_blocks``.

        Returns
        -------
        ndarray of float64, shape (F,)
            ``[hog, spatial, histogram]`` in :class:`FeatureLayout` order.
        """
        options = self.options
        window = converted[top:top + WINDOW, left:left + WINDOW]
        parts = []
        if options.use_hog:
            n = self.layout.blocks_per_window
            parts.append(hog_blocks[block_y:block_y + n, block_x:block_x + n].ravel())
        if options.spatial_size:
            # The published code resizes each window to the spatial size; fastdet
            # defines that resize as the exact mean of each square tile.
            size = options.spatial_size
            factor = WINDOW // size
            parts.append(window.reshape(size, factor, size, factor, 3).mean(axis=(1, 3)).ravel())
        if options.hist_bins:
            parts.extend(np.histogram(window[:, :, c], bins=options.hist_bins, range=(0, 256))[0]
                         for c in range(3))
        return np.concatenate(parts).astype(np.float64)

    # -- stage 1: windows -----------------------------------------------------
    def score_scale(self, frame, plan):
        """SVM margins of every window of one scale, one scikit-learn call each.

        Parameters
        ----------
        frame : ndarray of uint8, shape (H, W, 3)
            BGR frame.
        plan : fastdet.detector.plan.ScalePlan

        Returns
        -------
        ndarray of float64, shape ``plan.grid``
        """
        options = self.options
        x0, y0, x1, y1 = plan.roi
        region = frame[y0:y1, x0:x1]
        # Convert, then resize: the published code's order (and fastdet's).
        converted = cv2.resize(convert_color(region, options.color_space), plan.scaled_size,
                               interpolation=cv2.INTER_LINEAR)
        grey = None
        if options.hog_channel == "gray":
            grey = cv2.resize(cv2.cvtColor(region, cv2.COLOR_BGR2GRAY), plan.scaled_size,
                              interpolation=cv2.INTER_LINEAR)
        hog_blocks = self.scale_hog(converted, grey) if options.use_hog else None
        step_px = plan.step_cells * options.pixels_per_cell
        scores = np.empty(plan.grid, dtype=np.float64)
        for iy in range(plan.grid[0]):
            for ix in range(plan.grid[1]):
                features = self.window_features(hog_blocks, converted, iy * step_px,
                                                ix * step_px, iy * plan.step_cells,
                                                ix * plan.step_cells)
                # Per window, as published: scale, then ask the SVM.
                scaled_features = self.scaler.transform(features.reshape(1, -1))
                scores[iy, ix] = self.classifier.decision_function(scaled_features)[0]
        return scores

    def window_scores(self, frame):
        """Margins of every window of every scale.

        Parameters
        ----------
        frame : ndarray
            BGR uint8 image (grey and BGRA accepted, as by fastdet).

        Returns
        -------
        list of ndarray of float64
            One ``(ny, nx)`` grid per scale plan, in plan order.
        """
        frame = as_bgr_frame(frame)
        return [self.score_scale(frame, plan)
                for plan in self.plans((frame.shape[1], frame.shape[0]))]

    def _hits_by_scale(self, frame):
        """Hit boxes, their margins and the index of their scale plan."""
        threshold = self.config.search.decision_threshold
        plans = self.plans((frame.shape[1], frame.shape[0]))
        boxes, scores, scale_index = [], [], []
        for index, grid in enumerate(self.window_scores(frame)):
            # Row-major over the grid, like plan.boxes and fastdet's hits.
            hit = np.flatnonzero(grid.ravel() > threshold)
            boxes.append(plans[index].boxes[hit])
            scores.append(grid.ravel()[hit])
            scale_index.append(np.full(hit.size, index, dtype=np.int64))
        if not boxes:
            return np.zeros((0, 4), np.int32), np.zeros(0), np.zeros(0, np.int64)
        return np.concatenate(boxes), np.concatenate(scores), np.concatenate(scale_index)

    def hits(self, frame):
        """Every window whose margin exceeds ``search.decision_threshold``.

        Parameters
        ----------
        frame : ndarray
            BGR uint8 image.

        Returns
        -------
        boxes : ndarray of int32, shape (N, 4)
            Frame pixels, ordered by scale then row-major over each grid.
        scores : ndarray of float64, shape (N,)
        """
        boxes, scores, _ = self._hits_by_scale(as_bgr_frame(frame))
        return boxes, scores

    # -- stage 2: heat and boxes ------------------------------------------------
    def heat_weights(self, scores, scale_index, frame_size):
        """Heat each hit adds, per ``heat.weighting`` (see ``HeatConfig``)."""
        weighting = self.config.heat.weighting
        if weighting == "count":
            return np.ones(scores.size)
        if weighting == "margin":
            return scores - self.config.search.decision_threshold
        per_scale = np.array([plan.heat_weight for plan in self.plans(frame_size)])
        if weighting == "margin_area":
            return (scores - self.config.search.decision_threshold) * per_scale[scale_index]
        return per_scale[scale_index]

    def heatmap(self, frame):
        """Full-frame heat map of one frame.

        Returns
        -------
        ndarray of float64, shape (H, W)
        """
        frame = as_bgr_frame(frame)
        size = (frame.shape[1], frame.shape[0])
        boxes, scores, scale_index = self._hits_by_scale(frame)
        heat = np.zeros(frame.shape[:2], dtype=np.float64)
        for (x1, y1, x2, y2), weight in zip(boxes.tolist(),
                                            self.heat_weights(scores, scale_index, size)):
            heat[y1:y2, x1:x2] += weight
        return heat

    def box_filter(self, boxes, frame_size):
        """Boolean mask of the boxes that pass the ``[boxes]`` sanity filters.

        Same rules as ``fastdet.detector.boxes.BoxFinder.box_filter``: minimum width
        and height, allowed aspect ratio, and a bottom edge below the
        horizon line, all scaled from the reference frame size.
        """
        limits = self.config.boxes
        reference_w, reference_h = self.config.search.reference_size
        kx, ky = frame_size[0] / reference_w, frame_size[1] / reference_h
        min_size = limits.min_size * math.sqrt(kx * ky)
        width = boxes[:, 2] - boxes[:, 0]
        height = boxes[:, 3] - boxes[:, 1]
        aspect = width / np.maximum(height, 1)
        # Commits before the line followed the horizon set it in [boxes] alone.
        line = (self.config.horizon_line() if hasattr(self.config, "horizon_line")
                else limits.horizon_y)
        return ((width >= min_size) & (height >= min_size)
                & (aspect >= limits.min_aspect) & (aspect <= limits.max_aspect)
                & (boxes[:, 3] > line * ky))

    def __call__(self, frame):
        """Detect vehicles in one frame.

        Parameters
        ----------
        frame : ndarray
            BGR uint8 image.

        Returns
        -------
        Detections
            One box per connected component of the thresholded heat map that
            passes :meth:`box_filter`, scored by the component's peak heat.
        """
        frame = as_bgr_frame(frame)
        heat = self.heatmap(frame)
        connectivity = self.config.heat.connectivity
        structure = scipy.ndimage.generate_binary_structure(2, 2 if connectivity == 8 else 1)
        labels, count = scipy.ndimage.label(heat > self.config.heat.threshold,
                                            structure=structure)
        if count == 0:
            return Detections.empty()
        slices = scipy.ndimage.find_objects(labels)
        boxes = np.array([[xs.start, ys.start, xs.stop, ys.stop] for ys, xs in slices],
                         dtype=np.int32)
        peaks = np.asarray(scipy.ndimage.maximum(heat, labels, np.arange(1, count + 1)))
        keep = self.box_filter(boxes, (frame.shape[1], frame.shape[0]))
        return Detections(boxes[keep], peaks[keep])
