"""Numba's first compile leaves ``scipy.linalg`` unimported, and BLAS still works after.

The process-wide checks run in fresh interpreters: this test process has
long imported both modules.
"""

import subprocess
import sys
import threading

import pytest

from fastdet.kernels.blas_check import short_check

_AFTER_A_DETECTION = r"""
import sys
import numba
import numpy as np
from numba.np import linalg
import fastdet

from fastdet.kernels.blas_check import import_numba_arraymath

full_check = linalg.ensure_blas
fastdet.Detector(threads=1)(np.zeros((360, 640, 3), np.uint8))
# Kernels loaded from the cache leave Numba's implementations unimported
# (fastdet.kernels.cached_load); a kernel missing from the cache calls this
# before Numba compiles it.
import_numba_arraymath()
assert "numba.np.arraymath" in sys.modules
assert "scipy.linalg" not in sys.modules, "the first kernel imported scipy.linalg"
import numba.np.arraymath as arraymath
assert arraymath._HAVE_BLAS is True
assert arraymath.ensure_blas is full_check and linalg.ensure_blas is full_check

@numba.njit
def product(a, b):
    return np.dot(a, b)

@numba.njit
def correlation(a, v):
    return np.correlate(a, v)

rng = np.random.default_rng(0)
a, b = rng.random((5, 3)), rng.random((3, 4))
assert np.allclose(product(a, b), a @ b)
assert np.allclose(correlation(a[:, 0], b[0]), np.correlate(a[:, 0], b[0]))
assert "scipy.linalg" in sys.modules
print("ok")
"""

_NUMBA_USED_FIRST = r"""
import numba
import numba.np.arraymath
from fastdet.kernels.blas_check import import_numba_arraymath
assert import_numba_arraymath() is False
print("ok")
"""


def run_fresh(code):
    completed = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                               timeout=600)
    assert completed.returncode == 0, completed.stderr[-3000:]
    assert completed.stdout.strip().splitlines()[-1] == "ok"


def test_the_first_compile_leaves_scipy_linalg_and_blas_calls_still_compile():
    run_fresh(_AFTER_A_DETECTION)


def test_numba_used_before_fastdet_is_left_alone():
    run_fresh(_NUMBA_USED_FIRST)


def test_the_short_check_answers_only_the_importing_thread():
    calls = []
    check = short_check(lambda: calls.append(threading.get_ident()), threading.get_ident())
    assert check() is None and calls == []
    other = threading.Thread(target=check)
    other.start()
    other.join()
    assert calls == [other.ident]


def test_the_short_check_without_scipy_fails_like_numba(monkeypatch):
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == "scipy" else real(name, *a))
    with pytest.raises(ImportError, match="scipy"):
        short_check(lambda: None, threading.get_ident())()
