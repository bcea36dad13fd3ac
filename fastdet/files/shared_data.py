"""Where the shared data set lives: one setting, ``FASTDET_DATA``.

Tests, benchmarks and the command line's defaults all find the training
crops, test images and test video through :func:`data_dir`.  Without the
variable it is ``../shared/data`` relative to the working directory (the
checkout's root, where the README's commands run), or failing that beside the
checkout this module was imported from.
"""

from __future__ import annotations

import os
from pathlib import Path

from ..errors import InputError

ENV_VAR = "FASTDET_DATA"

_RELATIVE_DEFAULT = Path("..") / "shared" / "data"
#: ``shared/`` beside the checkout, for an editable install used from elsewhere.
_CHECKOUT_DEFAULT = Path(__file__).resolve().parents[3] / "shared" / "data"


def data_dir(must_exist=True):
    """The shared data folder.

    Parameters
    ----------
    must_exist : bool
        Raise when the folder is missing instead of returning its path.

    Raises
    ------
    InputError
        Naming the folder and the setting, when it does not exist.
    """
    if ENV_VAR in os.environ:
        path = Path(os.environ[ENV_VAR]).expanduser()
    elif _RELATIVE_DEFAULT.is_dir() or not _CHECKOUT_DEFAULT.is_dir():
        path = _RELATIVE_DEFAULT
    else:
        path = _CHECKOUT_DEFAULT
    if must_exist and not path.is_dir():
        raise InputError(f"shared data not found at {path}: set {ENV_VAR} to the folder holding "
                         "vehicles/, non-vehicles/, test_images/ and test_video.mp4")
    return path
