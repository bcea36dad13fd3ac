"""fastdet.kernels.compile_gc: the collector is held back while fastdet kernels compile."""

from __future__ import annotations

import gc
import json
import os
import subprocess
import sys

import pytest
from numba.core import event

from fastdet.kernels import compile_gc


class _Kernel:
    """Stands in for a dispatcher: what the listener reads of one."""

    def __init__(self, module):
        self.py_func = type("F", (), {"__module__": module})()


def _event(status, module):
    return event.Event("numba:compile", status, data={"dispatcher": _Kernel(module)})


@pytest.fixture
def thresholds():
    saved = gc.get_threshold()
    gc.set_threshold(600, 9, 8)
    yield (600, 9, 8)
    gc.set_threshold(*saved)


def test_raised_for_the_outermost_fastdet_compile_and_restored(thresholds):
    hold = compile_gc.CompileCollectorHold((40_000, 30, 900))
    hold.notify(_event(event.EventStatus.START, "fastdet.kernels.label"))
    assert gc.get_threshold() == (40_000, 30, 900)
    # A kernel it calls compiles inside it: still held, until the outer one ends.
    hold.notify(_event(event.EventStatus.START, "fastdet.kernels.inner"))
    hold.notify(_event(event.EventStatus.END, "fastdet.kernels.inner"))
    assert gc.get_threshold() == (40_000, 30, 900)
    hold.notify(_event(event.EventStatus.END, "fastdet.kernels.label"))
    assert gc.get_threshold() == thresholds


def test_other_packages_compiles_are_left_alone(thresholds):
    hold = compile_gc.CompileCollectorHold()
    for module in ("numba.np.arraymath", "mypackage.fastdet", None):
        hold.notify(_event(event.EventStatus.START, module))
        assert gc.get_threshold() == thresholds
        hold.notify(_event(event.EventStatus.END, module))
    # An end without its start (registered mid-compile) changes nothing.
    hold.notify(_event(event.EventStatus.END, "fastdet.kernels.label"))
    assert gc.get_threshold() == thresholds


_COMPILE_ONE_FAMILY = r"""
import gc, json, sys
import numba
from numba.core import event
import fastdet.kernels
from fastdet.kernels import warmup

seen = []

class Recorder(event.Listener):
    # Registered after fastdet's listener, so it runs after it on a start.
    def on_start(self, ev):
        module = getattr(ev.data["dispatcher"].py_func, "__module__", "")
        seen.append([module, list(gc.get_threshold())])
    def on_end(self, ev):
        pass

event.register("numba:compile", Recorder())
before = list(gc.get_threshold())
warmup.FAMILIES["convert"]()
numba.njit(cache=False)(lambda x: x + 1)(1)
print(json.dumps({"before": before, "after": list(gc.get_threshold()), "seen": seen}))
"""


def test_a_kernel_compile_runs_with_the_raised_thresholds(tmp_path):
    """In a fresh process and kernel cache: while a family compiles, the thresholds are
    raised; afterwards, and for a function of another package, they are Python's."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    completed = subprocess.run([sys.executable, "-c", _COMPILE_ONE_FAMILY], capture_output=True,
                               text=True, env=env, timeout=600)
    assert completed.returncode == 0, completed.stderr[-3000:]
    result = json.loads(completed.stdout.strip().splitlines()[-1])
    *during_family, (last_module, last) = result["seen"]
    assert any(module.startswith("fastdet.") for module, _ in during_family)
    # Numba's own functions compiled inside a kernel's compile are held back with it.
    assert all(seen == list(compile_gc.COMPILE_THRESHOLDS) for _, seen in during_family)
    assert last_module == "__main__" and last == result["before"]
    assert result["after"] == result["before"]
