"""Tests for the training augmentation in ``fastdet.training.train``."""

from __future__ import annotations

import numpy as np
import pytest

from fastdet.detector.features import FeatureOptions
from fastdet.training.augment import JITTER_SCALE, JITTER_SHIFT, jitter_crops
from fastdet.training.train import _fit_and_score, cross_validate, train
from training_inputs import make_crops


def square_crop(x0=24, y0=24, side=16):
    crop = np.zeros((64, 64, 3), np.uint8)
    crop[y0:y0 + side, x0:x0 + side] = 255
    return crop


def bright_box(crop):
    ys, xs = np.nonzero(crop[..., 0] > 127)
    return xs.min(), ys.min(), xs.max() + 1, ys.max() + 1


def test_jitter_keeps_shape_and_dtype_and_is_reproducible():
    crops = np.stack([square_crop(), square_crop(10, 30)])
    a = jitter_crops(crops, seed=3)
    b = jitter_crops(crops, seed=3)
    assert a.shape == crops.shape and a.dtype == np.uint8
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(jitter_crops(crops, seed=4), a)
    assert not np.array_equal(a, crops)


def test_jitter_moves_and_scales_within_its_bounds():
    crops = np.stack([square_crop()] * 200)
    out = jitter_crops(crops, seed=0)
    sides, centres = [], []
    for crop in out:
        x1, y1, x2, y2 = bright_box(crop)
        sides.append(x2 - x1)
        centres.append(((x1 + x2) / 2 - 32, (y1 + y2) / 2 - 32))
    sides, centres = np.array(sides), np.abs(np.array(centres))
    low, high = JITTER_SCALE
    # A 16-pixel square scaled by low..high, give or take the interpolated edge pixels.
    assert sides.min() >= int(16 * low) - 1 and sides.max() <= int(np.ceil(16 * high)) + 1
    assert sides.max() - sides.min() >= 4  # the scale does vary
    # The centre moves by the shift only (mirroring keeps a centred square centred).
    assert centres.max() <= JITTER_SHIFT + 1
    assert centres.max() >= JITTER_SHIFT / 2


def test_jitter_with_no_scale_or_shift_only_mirrors():
    crop = square_crop(4, 20)
    out = jitter_crops(np.stack([crop] * 20), seed=1, scale=(1.0, 1.0), shift=0.0)
    mirrored = crop[:, ::-1]
    kinds = {(np.array_equal(o, crop), np.array_equal(o, mirrored)) for o in out}
    assert kinds == {(True, False), (False, True)}


def test_copies_are_used_for_training_only():
    # 20 crops, 2 features; the copies of the held-out rows are poisoned (labels
    # flipped in feature space): if they were used they would break the model.
    rng = np.random.default_rng(0)
    labels = np.repeat([0, 1], 10).astype(np.int8)
    features = np.c_[labels * 4.0 + rng.normal(0, 0.3, 20), rng.normal(0, 1, 20)]
    copy = features + rng.normal(0, 0.1, features.shape)
    train_mask = np.ones(20, bool)
    train_mask[[0, 1, 18, 19]] = False
    copy[~train_mask, 0] = 4.0 - copy[~train_mask, 0] * 5
    _, _, report, _ = _fit_and_score(features, labels, train_mask, [copy], C=1.0, seed=0)
    assert report["train_crops"] == 2 * 16
    assert report["test_crops"] == 4
    assert report["accuracy"] == 1.0
    # A single array is accepted as one copy (the flip-only call of study.py).
    _, _, report, _ = _fit_and_score(features, labels, train_mask, copy, C=1.0, seed=0)
    assert report["train_crops"] == 2 * 16
    folds = np.arange(20) % 4
    cv = cross_validate(features, labels, folds, 0, [copy, copy], [0.1, 1.0])
    assert cv["C"] in (0.1, 1.0) and cv["folds"] == [1, 2, 3]


@pytest.mark.parametrize("jitter", [True, False])
def test_train_reports_its_augmentation(tmp_path, jitter):
    rng = np.random.default_rng(0)
    make_crops(tmp_path / "vehicles" / "GTI_Far", 1, 20, rng)
    make_crops(tmp_path / "non-vehicles" / "GTI", 0, 20, rng)
    options = FeatureOptions(spatial_size=16, hist_bins=16)
    model = train(tmp_path, options=options, jitter=jitter)
    report = model.report
    copies = 1 + 1 + int(jitter)  # the crop, its flip, its jittered copy
    assert report["leak_free_split"]["train_crops"] == copies * 32
    if jitter:
        assert report["jitter_augmentation"] == {"scale": list(JITTER_SCALE),
                                                 "shift": JITTER_SHIFT, "seed": 0}
    else:
        assert report["jitter_augmentation"] is None
    assert report["leak_free_split"]["accuracy"] == 1.0


def test_photometric_copies_keep_geometry_and_change_the_look():
    from fastdet.training.augment import Photometric

    crops = np.stack([square_crop()] * 50)
    plain = jitter_crops(crops, seed=5)
    looked = jitter_crops(crops, seed=5, photometric=Photometric())
    # The geometric draws are the same with and without the photometric ones.
    np.testing.assert_array_equal(jitter_crops(crops, seed=5), plain)
    assert looked.shape == crops.shape and looked.dtype == np.uint8
    np.testing.assert_array_equal(jitter_crops(crops, seed=5, photometric=Photometric()), looked)
    changed = [not np.array_equal(a, b) for a, b in zip(plain, looked)]
    assert sum(changed) > len(changed) // 2  # each effect at probability 0.5: most copies change
    # Brightness, contrast, colour and blur move values, never the square's centre much.
    for crop in looked:
        grey = crop.astype(float).mean(axis=2)
        ys, xs = np.nonzero(grey > grey.mean())
        assert abs(xs.mean() - 32) <= JITTER_SHIFT + 2 and abs(ys.mean() - 32) <= JITTER_SHIFT + 2


@pytest.mark.parametrize("effect, settings", [
    ("brightness", {"brightness": (0.5, 0.5)}),
    ("contrast", {"contrast": (0.5, 0.5)}),
    ("temperature", {"temperature": 0.2}),
    ("blur", {"blur": (1.5, 1.5)}),
    ("resolution", {"resolution": (16, 16)}),
    ("jpeg", {"jpeg": (10, 10)}),
])
def test_each_photometric_effect(effect, settings):
    from fastdet.training.augment import Photometric, photometric_crop

    rng = np.random.default_rng(0)
    crop = rng.integers(60, 200, (64, 64, 3), dtype=np.uint8)
    crop[16:48, 16:48] = (40, 120, 220)
    # Only this effect, always applied; the others never.
    neutral = dict.fromkeys(("brightness", "contrast", "temperature", "blur", "resolution",
                             "jpeg"))
    out = photometric_crop(crop, Photometric(**{**neutral, **settings}, probability=1.0),
                           np.random.default_rng(1))
    if effect == "jpeg":
        assert np.abs(out.astype(int) - crop).mean() > 1
        return
    before, after = crop.astype(float), out.astype(float)
    if effect == "brightness":
        np.testing.assert_allclose(after, np.round(before * 0.5), atol=1)
    elif effect == "contrast":
        assert after.std() == pytest.approx(before.std() * 0.5, rel=0.02)
        assert after.mean() == pytest.approx(before.mean(), abs=1)
    elif effect == "temperature":
        # Blue and red move in opposite directions, green stays.
        np.testing.assert_array_equal(out[..., 1], crop[..., 1])
        assert np.sign(after[..., 0].mean() - before[..., 0].mean()) == -np.sign(
            after[..., 2].mean() - before[..., 2].mean()) != 0
    else:  # blur and resolution smooth: less high-frequency energy
        def roughness(image):
            return np.abs(np.diff(image, axis=1)).mean()
        assert roughness(after) < 0.7 * roughness(before)


def test_source_of_groups():
    from fastdet.training.dataset import source_of

    assert [source_of(g) for g in ("vehicles/GTI_Far", "non-vehicles/GTI", "vehicles/KITTI_extracted",
                                    "non-vehicles/Extras", "extra:mined", "extra:mined/sub")] == [
        "GTI", "GTI", "KITTI", "Extras", "extra:mined", "extra:mined"]


def test_source_holdout_trains_without_the_source_it_scores():
    from fastdet.training.train import source_holdout

    # Source "b" is separable only by a feature the others never vary: a
    # model that had seen "b" would score it perfectly.
    rng = np.random.default_rng(0)
    labels = np.tile([0, 1], 30).astype(np.int8)
    sources = np.repeat(["a", "b", "extra:x"], 20)
    features = np.c_[np.where(sources == "b", 0.0, labels * 4.0) + rng.normal(0, 0.2, 60),
                     np.where(sources == "b", labels * 4.0, 0.0) + rng.normal(0, 0.2, 60)]
    report = source_holdout(features, labels, sources, [], C=1.0)
    assert set(report) == {"a", "b"}          # added negatives are never held out
    assert report["a"]["accuracy"] == 1.0
    assert report["b"]["accuracy"] < 0.8
    assert report["b"]["test_crops"] == 20 and report["b"]["vehicles"] == 10
