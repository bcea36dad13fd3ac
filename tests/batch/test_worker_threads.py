"""A worker whose nanny sets NUMBA_NUM_THREADS after Numba was imported (a cold cache)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

SCRIPT = """
import os, sys
import numba                                  # imported first, as in a spawned worker
default = numba.config.NUMBA_NUM_THREADS      # every core
# Then the nanny's environment: a count other than the default, on any machine.
os.environ["NUMBA_NUM_THREADS"] = str(default + 1)
from fastdet.batch.worker import adopt_thread_count
if sys.argv[1] == "pool started":
    numba.set_num_threads(1)
if sys.argv[1] != "not adopted":
    adopt_thread_count()
numba.set_num_threads(1)                      # what a Detector does: starts the pool
@numba.njit
def f(x):                                     # a compile reads the environment again
    return x + 1
f(1)
print(numba.config.NUMBA_NUM_THREADS - default)
"""


@pytest.mark.parametrize("case", ["adopted", "pool started", "not adopted"])
def test_the_worker_thread_count_survives_a_compile(case):
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_NUM_THREADS"}
    result = subprocess.run([sys.executable, "-c", SCRIPT, case], capture_output=True,
                            text=True, env=env, timeout=300)
    if case == "not adopted":   # the failure adopt_thread_count prevents
        assert result.returncode != 0 and "Cannot set NUMBA_NUM_THREADS" in result.stderr
        return
    assert result.returncode == 0, result.stderr[-2000:]
    # Adopted before the pool started: the nanny's count; after: the pool's own.
    assert result.stdout.strip() == ("1" if case == "adopted" else "0")
