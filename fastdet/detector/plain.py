"""Settings given as NumPy scalars, taken as the Python numbers they hold."""

from __future__ import annotations

import dataclasses

import numpy as np


def _plain(value):
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, (tuple, list)):
        return type(value)(_plain(item) for item in value)
    return value


def plain_numbers(settings):
    """Replace NumPy scalars in the fields of the frozen dataclass ``settings``
    (lists and tuples of them included) by the Python values they hold.

    A horizon, threshold or size computed with NumPy (``np.float32(0.55)``,
    ``np.int64(64)``) is then checked as the equal Python number is: the
    checks ask for ``int`` and ``float`` so that bools and strings are refused,
    and refused NumPy's too.  ``np.bool_`` becomes ``bool`` and is refused
    where a number is asked for, as ``True`` is.
    """
    for field in dataclasses.fields(settings):
        value = getattr(settings, field.name)
        plain = _plain(value)
        if plain is not value:
            object.__setattr__(settings, field.name, plain)
