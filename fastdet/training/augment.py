"""Augmentation of training crops: flipped, jittered and photometrically changed copies.

Training crops only; held-out crops are scored as they are.  Besides a
horizontally flipped copy of every crop, training adds a *jittered* copy --
scaled about its centre by a random factor in ``JITTER_SCALE``, shifted by up
to ``JITTER_SHIFT`` pixels, mirrored half of the time, edges reflected -- and
with :class:`Photometric` settings (the default) the same copy is then seen
through another camera: its brightness, contrast and colour temperature
changed, blurred, its resolution reduced and JPEG-compressed, each effect
drawn at random.

Why: the sliding-window search never frames a vehicle as exactly as a
training crop does (windows step by a quarter to a half window, and
neighbouring scales differ by up to 1.75x), so the classifier should accept
a vehicle a little off-centre and off-scale.  And the shared crops come from
two cameras (GTI's and KITTI's), sharp and contrasty, while a small car far
away in another dashcam's frame is a few dozen pixels enlarged to 64: soft,
hazy, tinted.  Larger geometric jitter (scale 0.75-1.33, 16-pixel shifts)
costs held-out accuracy (98.65 % leak-free against 99.35 %), so that copy
stays close to the original.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from dataclasses import dataclass

import cv2
import numpy as np

from ..detector.plain import plain_numbers
from ..errors import ConfigError

#: Range of the random scale of a jittered training copy.
JITTER_SCALE = (0.8, 1.2)
#: Largest shift (pixels of the 64-pixel crop, each axis) of a jittered copy.
JITTER_SHIFT = 6.0


@dataclass(frozen=True)
class Photometric:
    """Ranges of the photometric changes of an augmented copy.

    Each effect is applied to a copy with probability ``probability``, its
    strength drawn uniformly from its range, in this order: colour
    temperature, brightness, contrast, blur, resolution, JPEG.  ``None``
    turns an effect off.

    Parameters
    ----------
    brightness : tuple of float
        Gain on all three channels.
    contrast : tuple of float
        Factor on each pixel's distance from the crop's mean grey (below 1:
        haze, low contrast).
    temperature : float
        Largest colour shift: red gains ``1 + t`` and blue ``1 - t`` for a
        ``t`` in ``[-temperature, temperature]``.
    blur : tuple of float
        Gaussian sigma in pixels of the 64-pixel crop.
    resolution : tuple of int
        Side the crop is shrunk to (area mean) before it is enlarged back to
        64 (bilinear), as the search enlarges a small far car's window.
    jpeg : tuple of int
        JPEG quality.
    probability : float
        Chance that each effect is applied.
    """

    brightness: tuple = (0.6, 1.4)
    contrast: tuple = (0.4, 1.2)
    temperature: float = 0.15
    blur: tuple = (0.5, 1.5)
    resolution: tuple = (20, 48)
    jpeg: tuple = (30, 90)
    probability: float = 0.5

    def __post_init__(self):
        # Plain Python numbers: the settings go into a model's report, which is JSON.
        plain_numbers(self)
        # Checked here, before any crop is read: brightness=(1,) failed in the middle
        # of the augmentation with an IndexError, probability="a" with NumPy's message,
        # and a reversed or negative range drew from it as given.
        for name, low, high in (("brightness", 0, None), ("contrast", 0, None),
                                ("blur", 0, None), ("resolution", 1, None), ("jpeg", 0, 100)):
            span = getattr(self, name)
            if span is None:
                continue
            if not (isinstance(span, (tuple, list)) and len(span) == 2
                    and all(_is_real(v) for v in span)):
                raise ConfigError(f"photometric.{name} must be a (low, high) pair of numbers "
                                  f"or None, got {span!r}")
            if not (low <= span[0] <= span[1] and (high is None or span[1] <= high)):
                limits = f">= {low}" if high is None else f"within {low}-{high}"
                raise ConfigError(f"photometric.{name} must be low <= high, {limits}, "
                                  f"got {span!r}")
            object.__setattr__(self, name, tuple(span))
        if self.temperature is not None and not (_is_real(self.temperature)
                                                 and 0 <= self.temperature <= 1):
            raise ConfigError(f"photometric.temperature must be a number in 0-1 or None, "
                              f"got {self.temperature!r}")
        if not (_is_real(self.probability) and 0 <= self.probability <= 1):
            raise ConfigError(f"photometric.probability must be a number in 0-1, "
                              f"got {self.probability!r}")

    def to_dict(self):
        """The settings as plain JSON-ready values (for a model's training report)."""
        return {name: list(value) if isinstance(value, tuple) else value
                for name, value in dataclasses.asdict(self).items()}


def _is_real(value):
    """A finite real number (bools are not numbers here; NumPy's are)."""
    return (isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))
            and math.isfinite(value))


def jitter_crops(crops, seed=0, scale=JITTER_SCALE, shift=JITTER_SHIFT, photometric=None):
    """Randomly scaled, shifted and mirrored copies of square crops.

    Parameters
    ----------
    crops : ndarray of uint8, shape (N, S, S, 3)
    seed : int
        Seed of the random draws (one scale, two shifts and a mirror coin per
        crop, in crop order, then the photometric draws), so a training run
        is reproducible.
    scale : tuple of float
        ``(low, high)`` of the uniform scale factor about the crop centre (>1
        zooms in).
    shift : float
        Largest absolute shift per axis, in pixels.
    photometric : Photometric, optional
        Also change each copy's look (:func:`photometric_crop`); ``None``
        keeps the pixels' values.

    Returns
    -------
    ndarray, same shape and dtype as ``crops``
    """
    crops = np.asarray(crops)
    rng = np.random.default_rng(seed)
    out = np.empty_like(crops)
    for i, crop in enumerate(crops):
        size = crop.shape[1]
        centre = size / 2
        factor = rng.uniform(*scale)
        dx, dy = rng.uniform(-shift, shift, 2)
        matrix = np.array([[factor, 0, centre - centre * factor + dx],
                           [0, factor, centre - centre * factor + dy]], np.float32)
        moved = cv2.warpAffine(crop, matrix, (size, crop.shape[0]), flags=cv2.INTER_LINEAR,
                               borderMode=cv2.BORDER_REFLECT)
        out[i] = moved[:, ::-1] if rng.random() < 0.5 else moved
    if photometric is not None:
        # A generator of its own, so the geometric draws stay those of ``seed``.
        looks = np.random.default_rng([seed, 1])
        for i in range(len(out)):
            out[i] = photometric_crop(out[i], photometric, looks)
    return out


def photometric_crop(crop, settings, rng):
    """One crop as another camera might have seen it.

    Parameters
    ----------
    crop : ndarray of uint8, shape (S, S, 3)
        BGR.
    settings : Photometric
    rng : numpy.random.Generator
        Every effect draws its coin and its strength, whether applied or
        not, so the draws of one crop never depend on another's.

    Returns
    -------
    ndarray of uint8, shape (S, S, 3)
    """
    # Every coin and strength is drawn, used or not, so that the draws of
    # one crop never depend on another's or on which effects are off.
    draws = rng.random(6) < settings.probability
    strengths = [rng.uniform(-1, 1), rng.random(), rng.random(), rng.random(), rng.random(),
                 rng.random()]
    on = [setting is not None and draw for setting, draw in zip(
        (settings.temperature, settings.brightness, settings.contrast, settings.blur,
         settings.resolution, settings.jpeg), draws)]
    image = crop.astype(np.float32)
    if on[0]:
        shift = settings.temperature * strengths[0]
        image *= np.array([1 - shift, 1.0, 1 + shift], np.float32)
    if on[1]:
        image *= _within(settings.brightness, strengths[1])
    if on[2]:
        mean = image.mean()
        image = mean + (image - mean) * _within(settings.contrast, strengths[2])
    out = np.clip(np.rint(image), 0, 255).astype(np.uint8)
    size = crop.shape[1]
    if on[3] and _within(settings.blur, strengths[3]) > 0:
        out = cv2.GaussianBlur(out, (0, 0), _within(settings.blur, strengths[3]))
    side = int(round(_within(settings.resolution, strengths[4]))) if on[4] else size
    if side < size:
        small = cv2.resize(out, (side, side), interpolation=cv2.INTER_AREA)
        out = cv2.resize(small, (size, size), interpolation=cv2.INTER_LINEAR)
    if on[5]:
        quality = int(round(_within(settings.jpeg, strengths[5])))
        ok, encoded = cv2.imencode(".jpg", out, [cv2.IMWRITE_JPEG_QUALITY, quality])
        out = cv2.imdecode(encoded, cv2.IMREAD_COLOR)
    return out


def _within(span, fraction):
    """The value a fraction of the way from ``span[0]`` to ``span[1]``."""
    return span[0] + (span[1] - span[0]) * fraction


def with_copies(features, copies, mask):
    """Rows ``mask`` of the features and of every augmented copy, stacked."""
    return np.concatenate([features[mask]] + [copy[mask] for copy in copies])


def copies_of(flips):
    """Augmented copies as a list (``flips`` may be None, an array or a list)."""
    if flips is None:
        return []
    if isinstance(flips, np.ndarray):
        return [flips]
    return list(flips)
