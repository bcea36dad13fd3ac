"""Training data: a folder of crops, listed with labels and groups, split without leaks.

A data set is a folder with ``vehicles/`` and ``non-vehicles/`` subfolders
holding image crops (PNG/JPG, any nesting).  The first folder level below each
class is the crop's *group* (e.g. ``GTI_Far``).

Two hold-out splits are used:

* random: a stratified random 20 % of the crops;
* leak-free: within every group, crops in natural file-name order are cut
  into ``n_folds`` contiguous blocks and one block is held out.  GTI crops
  are consecutive video frames, so a random split puts near-duplicates of a
  test crop in the training set; contiguous blocks keep them on one side
  (only block boundaries can leak).
"""

from __future__ import annotations

import os
import re
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from ..detector.features import WINDOW
from ..errors import InputError
from ..files.atomic import is_temporary
from ..files.images import read_image

IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg"}
CLASS_FOLDERS = {"vehicles": 1, "non-vehicles": 0}


@dataclass
class Dataset:
    """Paths of labelled crops with their group (first sub-folder) names."""

    paths: list
    labels: np.ndarray
    groups: list

    def __len__(self):
        return len(self.paths)


def _natural_key(path):
    return [int(part) if part.isdigit() else part.lower()
            for part in re.split(r"(\d+)", str(path))]


def _image_files(folder):
    """Every PNG/JPG under ``folder``, at any depth, symbolic links to folders followed.

    ``Path.rglob`` does not follow linked folders (before Python 3.13), so
    a group linked in from elsewhere was left out without a word.  Each
    folder is entered once, so a link to a parent ends instead of looping.
    A folder that cannot be read is an error, not a group left out.
    """
    def refuse(error):
        raise InputError(f"cannot list {error.filename}: {error.strerror or error}")

    entered = set()
    for root, folders, files in os.walk(folder, onerror=refuse, followlinks=True):
        status = os.stat(root)
        if (status.st_dev, status.st_ino) in entered:
            folders[:] = []
            continue
        entered.add((status.st_dev, status.st_ino))
        root = Path(root)
        for name in files:
            # Temporary files of outputs being written (or left by a killed run) are no crops.
            if Path(name).suffix.lower() in IMAGE_SUFFIXES and not is_temporary(name):
                yield root / name


def list_dataset(data_dir, extra_negatives=()):
    """List the crops of a data set folder.

    Parameters
    ----------
    data_dir : str or Path
        Folder with ``vehicles/`` and ``non-vehicles/`` subfolders.
    extra_negatives : iterable of str or Path
        More folders of non-vehicle crops (e.g. mined hard negatives).

    Returns
    -------
    Dataset

    Raises
    ------
    InputError
        When a folder is missing or holds no PNG/JPG image.
    TypeError
        When ``extra_negatives`` is one path rather than an iterable of them.
    """
    if isinstance(extra_negatives, (str, bytes, os.PathLike)):
        # Iterated, a string is its characters: "/tmp/mined" listed "/", the whole file system.
        raise TypeError(f"extra_negatives must be an iterable of folders, not one "
                        f"{type(extra_negatives).__name__}: give [{str(extra_negatives)!r}]")
    data_dir = Path(data_dir)
    sources = [(data_dir / name, label, name) for name, label in CLASS_FOLDERS.items()]
    sources += [(Path(folder), 0, f"extra:{Path(folder).name}") for folder in extra_negatives]
    paths, labels, groups = [], [], []
    for folder, label, prefix in sources:
        if not folder.is_dir():
            raise InputError(f"training data folder not found: {folder}")
        found = sorted(_image_files(folder), key=_natural_key)
        if not found:
            raise InputError(f"no PNG/JPG images under {folder}")
        for path in found:
            relative = path.relative_to(folder).parts
            group = f"{prefix}/{relative[0]}" if len(relative) > 1 else prefix
            paths.append(path)
            labels.append(label)
            groups.append(group)
    return Dataset(paths, np.asarray(labels, dtype=np.int8), groups)


def source_of(group):
    """The source of a crop's group: the camera and collection it came from.

    ``vehicles/GTI_Far`` and ``non-vehicles/GTI`` are both ``GTI``,
    ``vehicles/KITTI_extracted`` is ``KITTI``, ``non-vehicles/Extras`` is
    ``Extras``: the part of the first folder's name before an underscore.
    Added negative folders (``extra:<name>``) are their own source.
    """
    if group.startswith("extra:"):
        return group.split("/")[0]
    return group.split("/")[-1].split("_")[0]


def random_split(labels, test_fraction=0.2, seed=0):
    """Stratified random split; returns a boolean test mask."""
    rng = np.random.default_rng(seed)
    test = np.zeros(len(labels), dtype=bool)
    for label in np.unique(labels):
        members = np.flatnonzero(labels == label)
        chosen = rng.choice(members, size=int(round(len(members) * test_fraction)), replace=False)
        test[chosen] = True
    return test


def leak_free_folds(groups, n_folds=5):
    """Fold index of every crop: contiguous blocks within each group.

    Crops are expected in natural file-name order within a group (as
    :func:`list_dataset` returns them).
    """
    groups = np.asarray(groups)
    folds = np.empty(len(groups), dtype=np.int64)
    for group in np.unique(groups):
        members = np.flatnonzero(groups == group)
        folds[members] = np.arange(len(members)) * n_folds // len(members)
    return folds


def load_crops(paths, threads=2):
    """Read crops as 64x64 BGR uint8 arrays (resized if another size)."""
    def read(path):
        image = read_image(path)
        if image.shape[:2] != (WINDOW, WINDOW):
            image = cv2.resize(image, (WINDOW, WINDOW), interpolation=cv2.INTER_AREA)
        return image

    with ThreadPoolExecutor(max_workers=max(1, threads)) as pool:
        return np.stack(list(pool.map(read, paths, chunksize=256)))
