"""``smallest_positive`` against numpy's masked minimum."""

import numpy as np
import pytest

from fastdet.kernels.reduce import smallest_positive


def masked_minimum(values):
    positive = values[values > 0]
    return np.float32(positive.min()) if positive.size else np.float32(np.inf)


@pytest.mark.parametrize("shape", [(0, 0), (1, 1), (3, 17), (7, 16), (31, 47), (270, 1280)])
@pytest.mark.parametrize("zeros", [0.0, 0.5, 1.0])
def test_matches_the_masked_minimum(shape, zeros):
    rng = np.random.default_rng(sum(shape))
    values = rng.exponential(3.0, shape).astype(np.float32)
    values[rng.random(shape) < zeros] = 0
    assert smallest_positive(values) == masked_minimum(values)


def test_tiny_subnormal_and_negative_values():
    values = np.array([[0.0, -1.0, 5.0, 2.0 ** -149, 3.0, -0.0, 1e-30] * 5], np.float32)
    assert smallest_positive(values) == np.float32(2.0 ** -149)
    values[values == np.float32(2.0 ** -149)] = 0
    assert smallest_positive(values) == np.float32(1e-30)


def test_a_strided_view_reads_only_its_own_pixels():
    values = np.full((8, 40), 7.0, np.float32)
    values[:, ::2] = 1.0
    assert smallest_positive(values[:, 1::2]) == 7.0
    assert smallest_positive(values[:, 0:33]) == 1.0
