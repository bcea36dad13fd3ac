"""fastdet.train, its data listing and the mining and tuning APIs refuse misuse at once.

Every refusal here once came only after the crops were read and their
features extracted -- as an exception of scikit-learn's or NumPy's, an
internal error of the command line, or not at all: a model whose report held
an accuracy of NaN, or one that could not be saved.
"""

from __future__ import annotations

import os

import numpy as np
import pytest

import fastdet.training.train as train_module
from fastdet.detector.detector import Detector
from fastdet.detector.features import FeatureLayout, FeatureOptions
from fastdet.detector.model import Model, load_model
from fastdet.errors import InputError
from fastdet.evaluation.annotations import load_annotations
from fastdet.training.dataset import list_dataset
from fastdet.training.mine import mine
from fastdet.training.study import compare
from fastdet.training.train import train
from fastdet.training.tune import tune
from training_inputs import annotated_blocks, make_crops

#: Small features and no augmentation: a fit of 20 crops takes a fraction of a second.
FAST = dict(options=FeatureOptions(spatial_size=16, hist_bins=16), flip=False, jitter=False)


def data_set(root, vehicles=10, non_vehicles=10):
    rng = np.random.default_rng(0)
    make_crops(root / "vehicles" / "GTI_Far", 1, vehicles, rng)
    make_crops(root / "non-vehicles" / "GTI", 0, non_vehicles, rng)
    return root


@pytest.fixture
def data(tmp_path):
    return data_set(tmp_path / "data")


@pytest.fixture
def no_crops_read(monkeypatch):
    """Fail the test if the crops are read: every refusal comes before that."""
    def read(paths, threads=2):
        raise AssertionError("the crops were read before the refusal")
    monkeypatch.setattr(train_module, "load_crops", read)


@pytest.mark.parametrize("arguments,message", [
    (dict(C=0), "C must be a finite number above 0, got 0"),
    (dict(C=-1e-3), "C must be a finite number above 0"),
    (dict(C=float("inf")), "C must be a finite number above 0, got inf"),
    (dict(C=float("nan")), "C must be a finite number above 0, got nan"),
    (dict(C="1"), "C must be a finite number above 0, got '1'"),
    (dict(C=True), "C must be a finite number above 0, got True"),
    (dict(C=()), "C is an empty grid"),
    (dict(C=[1e-3, float("nan")]), "C must be a finite number above 0, got nan"),
    (dict(n_folds=1), "n_folds must be an integer of at least 2, got 1"),
    (dict(n_folds=-1), "n_folds must be an integer of at least 2"),
    (dict(n_folds=2.5), "n_folds must be an integer of at least 2, got 2.5"),
    (dict(test_fold=5), "test_fold must be an integer from 0 to 4, got 5"),
    (dict(test_fold=-1), "test_fold must be an integer from 0 to 4, got -1"),
    (dict(seed=-1), "seed must be an integer from 0 to 4294967295"),
    (dict(seed=1.5), "seed must be an integer"),
    (dict(seed=None), "seed must be an integer"),
    (dict(seed=2**32), "seed must be an integer from 0 to 4294967295, got 4294967296"),
    (dict(flip="no"), "flip must be True or False, got 'no'"),
])
def test_train_refuses_bad_arguments_before_reading_crops(data, no_crops_read, arguments,
                                                          message):
    with pytest.raises(InputError, match="^" + message.replace("(", r"\(").replace(")", r"\)")):
        train(data, **{**FAST, **arguments})


@pytest.mark.parametrize("arguments,message", [
    (dict(options={"color_space": "HSV"}), "options must be a FeatureOptions, got dict"),
    (dict(options={}), "options must be a FeatureOptions, got dict"),
    (dict(photometric="strong", jitter=True), "photometric must be a Photometric or None"),
    (dict(extra_negatives="/tmp/mined"), "extra_negatives must be an iterable of folders"),
])
def test_train_refuses_arguments_of_other_types(data, no_crops_read, arguments, message):
    # A str of extra negatives was its characters: "/" listed the whole file system.
    with pytest.raises(TypeError, match=message):
        train(data, **{**FAST, **arguments})


@pytest.mark.parametrize("vehicles,non_vehicles,arguments,message", [
    (1, 1, {}, "the random split holds out 20 % of each class, which rounds to none"),
    (2, 2, {}, "the random split holds out"),      # once trained, with an accuracy of NaN
    (10, 10, dict(n_folds=50, test_fold=3), "leak-free fold 3 is empty"),
    (2, 10, dict(C=[1e-3, 1e-2]), "cross-validation holding out folds 0 and 2 leaves no "
                                  "vehicle crop to train on"),
])
def test_train_refuses_too_few_crops_for_its_splits(tmp_path, no_crops_read, vehicles,
                                                    non_vehicles, arguments, message):
    data = data_set(tmp_path / "small", vehicles, non_vehicles)
    with pytest.raises(InputError, match=f"^too few crops in {data}: {message}"):
        train(data, **{**FAST, **arguments})


def test_compare_refuses_too_few_crops_before_reading_them(tmp_path, monkeypatch):
    import fastdet.training.study as study

    monkeypatch.setattr(study, "load_crops", lambda paths: pytest.fail("crops were read"))
    with pytest.raises(InputError, match="too few crops"):
        compare(data_set(tmp_path / "one", 1, 1), color_spaces=["HLS"])
    with pytest.raises(InputError, match="C must be a finite number above 0"):
        compare(data_set(tmp_path / "ten"), C=0.0, color_spaces=["HLS"])


def test_numpy_numbers_give_a_model_that_saves(data, tmp_path):
    """np.float32 C and np.int64 folds trained, then the report was no JSON to save."""
    model = train(data, **{**FAST, "flip": np.bool_(False)}, C=np.float32(1e-3),
                  n_folds=np.int64(5), test_fold=np.int64(1), seed=np.int64(3))
    model.save(tmp_path / "m.npz")
    report = load_model(tmp_path / "m.npz").report
    assert type(report["C"]) is float and report["C"] == pytest.approx(1e-3)
    assert report["leak_free_split"]["n_folds"] == 5
    assert report["leak_free_split"]["test_fold"] == 1
    assert report["flip_augmentation"] is False


def test_linked_group_folders_are_read_and_a_link_loop_ends(data, tmp_path):
    """rglob left a linked group folder out without a word (and its crops untrained)."""
    other = data_set(tmp_path / "elsewhere", 4, 4)
    os.symlink(other / "vehicles" / "GTI_Far", data / "vehicles" / "KITTI_linked")
    os.symlink("..", data / "vehicles" / "GTI_Far" / "up")     # a loop: entered once
    dataset = list_dataset(data)
    linked = [g for g in dataset.groups if g == "vehicles/KITTI_linked"]
    assert len(linked) == 4
    assert len(dataset) == 24
    assert len(set(dataset.paths)) == 24


@pytest.fixture
def blocks(tmp_path):
    """a.png and b.png, their annotations and a model that calls every window a vehicle."""
    annotations = load_annotations(annotated_blocks(tmp_path))
    options = FeatureOptions()
    model = Model(np.zeros(FeatureLayout(options).length, np.float32), bias=100.0,
                  options=options)
    return [tmp_path / "a.png", tmp_path / "b.png"], annotations, model


def test_mine_takes_a_generator_of_sources(tmp_path, blocks):
    """The sources were gone through twice: a generator was used up by the check."""
    sources, annotations, model = blocks
    mined = mine(Detector(model, threads=1), (s for s in sources), annotations, tmp_path / "out")
    assert mined.frames == 2 and mined.saved


def test_tune_takes_a_generator_of_sources(blocks):
    sources, annotations, model = blocks
    grid = {"decision_threshold": (0.0,), "heat_threshold": (0.0,), "weighting": ("count",),
            "peak_fraction": (0.0,)}
    assert tune(model, (s for s in sources), annotations, grid=grid)


def test_mine_keeps_the_crops_of_two_sources_of_one_name(tmp_path):
    """day1/b.png and day2/b.png wrote their crops to one set of files: half were lost."""
    folders = [tmp_path / "day1", tmp_path / "day2"]
    pairs = []
    for folder in folders:
        folder.mkdir()
        pairs.append((folder / "b.png", load_annotations(annotated_blocks(folder))))
    options = FeatureOptions()
    model = Model(np.zeros(FeatureLayout(options).length, np.float32), bias=100.0,
                  options=options)
    detector = Detector(model, threads=1)
    one = mine(detector, pairs[:1], None, tmp_path / "one")
    both = mine(detector, pairs, None, tmp_path / "both")
    written = sorted(path.name for path in (tmp_path / "both").iterdir())
    assert len(both.saved) == len(written) == 2 * len(one.saved) > 0
    assert f"b_b.png_{0:03d}.png" in written and f"b-2_b.png_{0:03d}.png" in written
    with pytest.raises(InputError, match="b.png is given twice as a source"):
        mine(detector, [pairs[0], pairs[0]], None, tmp_path / "twice")
    assert not (tmp_path / "twice").exists()


@pytest.mark.parametrize("settings, message", [
    ({"brightness": (1,)}, r"photometric\.brightness must be a \(low, high\) pair"),
    ({"probability": "a"}, r"photometric\.probability must be a number in 0-1"),
    ({"probability": True}, r"photometric\.probability must be a number in 0-1"),
    ({"contrast": (1.2, 0.4)}, r"photometric\.contrast must be low <= high"),
    ({"jpeg": (30, 101)}, r"photometric\.jpeg must be low <= high, within 0-100"),
    ({"resolution": (0, 48)}, r"photometric\.resolution must be low <= high, >= 1"),
    ({"blur": (float("nan"), 1.0)}, r"photometric\.blur must be a \(low, high\) pair"),
    ({"temperature": 2.0}, r"photometric\.temperature must be a number in 0-1"),
])
def test_photometric_settings_are_checked_when_made(settings, message):
    """brightness=(1,) failed mid-augmentation with an IndexError, probability='a' with
    NumPy's message, and a reversed range was drawn from as given."""
    from fastdet.errors import ConfigError
    from fastdet.training.augment import Photometric

    with pytest.raises(ConfigError, match=message):
        Photometric(**settings)


def test_photometric_settings_of_numpy_numbers_go_into_a_json_report():
    import json

    import numpy as np

    from fastdet.training.augment import Photometric

    settings = Photometric(brightness=[np.float32(0.5), 1.5], probability=np.float64(0.25),
                           blur=None)
    assert json.loads(json.dumps(settings.to_dict())) == {
        **Photometric().to_dict(), "brightness": [0.5, 1.5], "probability": 0.25, "blur": None}
