"""The kernel and fuzz tests again, with Numba checking every array index.

``NUMBA_BOUNDSCHECK=1`` compiles each kernel with a bounds check on every
array access (an ``IndexError`` instead of reading or writing past the end),
so kernels that pass their tests this way never read out of bounds on those
inputs.  The check changes the compiled code, so the run gets its own empty
``NUMBA_CACHE_DIR``: it compiles everything (several minutes on two cores),
hence ``slow``; CI runs it explicitly (``.ci/run``):

    python -m pytest -m slow tests/fuzz/test_boundscheck.py
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

TESTS = Path(__file__).resolve().parents[1]
CHECKED = [TESTS / "kernels", TESTS / "fuzz"]


@pytest.mark.slow
def test_kernel_and_fuzz_tests_pass_with_boundscheck(tmp_path):
    env = dict(os.environ, NUMBA_BOUNDSCHECK="1", NUMBA_CACHE_DIR=str(tmp_path / "numba"))
    # The default profile's tests only: this test is slow, so it does not run itself.
    command = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
               *map(str, CHECKED)]
    result = subprocess.run(command, cwd=TESTS.parent, env=env, capture_output=True, text=True,
                            timeout=3600)
    tail = "\n".join((result.stdout + result.stderr).splitlines()[-40:])
    assert result.returncode == 0, f"with NUMBA_BOUNDSCHECK=1:\n{tail}"
    assert " passed" in tail
