"""Training on the shared data: feature extraction and one LinearSVC fit.

The crops are read in ``setup`` (PNG decoding is not fastdet's work); the
timed part is what ``fastdet train`` does per fit: fastdet's features of every
crop (the benchmarked model's feature options, else the defaults) and one
scaled LinearSVC fit.  Each
benchmark runs once (the fit alone takes about a minute).
"""

from __future__ import annotations

from fastdet.detector.features import FeatureOptions, features_of_crops
from fastdet.files.shared_data import data_dir
from fastdet.training.dataset import list_dataset, load_crops
from fastdet.training.train import fit_linear_svm

from ._common import bench_model

#: LinearSVC regularisation of ``fastdet train`` (its default C).
C = 1e-3


class Training:
    number = 1
    repeat = 1
    rounds = 1
    warmup_time = 0
    timeout = 1800

    def setup(self):
        dataset = list_dataset(data_dir())
        self.crops = load_crops(dataset.paths)
        self.labels = dataset.labels
        try:
            self.options = bench_model().options
        except NotImplementedError:  # no model: time the default feature set
            self.options = FeatureOptions()
        features_of_crops(self.crops[:8], self.options)  # compile or load kernels

    def time_feature_extraction(self):
        features_of_crops(self.crops, self.options)

    def time_features_and_one_fit(self):
        features = features_of_crops(self.crops, self.options)
        fit_linear_svm(features, self.labels, C=C)

    def track_crops(self):
        return len(self.labels)

    track_crops.unit = "crops"
