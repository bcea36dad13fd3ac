"""A cold kernel cache is compiled once, in the client, before a local cluster's workers start."""

import contextlib
import json
import os
import subprocess
import sys

import pytest

import fastdet.batch as batch_package
from fastdet.batch import run_batch, worker
from fastdet.batch.settings import make_settings

_COLD = r"""
import contextlib, json
from fastdet.batch.settings import make_settings
from fastdet.batch.worker import compile_for_local_workers
from fastdet.detector.scoring import kernel_families
from fastdet.kernels.warmup import cold_families
entered = []
@contextlib.contextmanager
def notice():
    entered.append(True)
    yield
settings = make_settings()
families = [*kernel_families(settings.model().options), "smooth"]
before = cold_families(families)
seconds = compile_for_local_workers(settings, notice)
again = compile_for_local_workers(settings, notice)
print(json.dumps({"before": before, "after": cold_families(families), "seconds": seconds,
                  "again": again, "notices": len(entered),
                  "tracker": cold_families(["track"])}))
"""


def test_a_cold_cache_is_compiled_once_with_the_notice(tmp_path):
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    done = subprocess.run([sys.executable, "-c", _COLD], capture_output=True, text=True,
                          env=env, timeout=900)
    assert done.returncode == 0, done.stderr[-3000:]
    result = json.loads(done.stdout.strip().splitlines()[-1])
    assert "smooth" in result["before"] and "label" in result["before"]
    assert result["after"] == []
    assert result["tracker"] == ["track"]   # patch tracking only for --track
    assert result["seconds"] > 0 and result["again"] == 0.0
    assert result["notices"] == 1          # the warm second call says nothing


class _Stop(Exception):
    pass


@pytest.fixture
def recorded(monkeypatch):
    """Calls of the client-side compile; the cluster itself is never started."""
    calls = []
    monkeypatch.setattr(batch_package, "compile_for_local_workers",
                        lambda settings, notice: calls.append((settings, notice)))

    @contextlib.contextmanager
    def no_cluster(*args, **kwargs):
        raise _Stop
        yield  # pragma: no cover

    monkeypatch.setattr(batch_package, "batch_client", no_cluster)
    return calls


def test_only_a_local_cluster_compiles_in_the_client(recorded, blocks_video, tmp_path):
    notice = contextlib.nullcontext
    with pytest.raises(_Stop):
        run_batch([blocks_video], tmp_path / "local", compile_notice=notice)
    assert len(recorded) == 1 and recorded[0][1] is notice
    with pytest.raises(_Stop):
        run_batch([blocks_video], tmp_path / "remote", scheduler="tcp://127.0.0.1:9")
    assert len(recorded) == 1


def test_a_warm_cache_compiles_nothing(monkeypatch):
    monkeypatch.setattr(worker, "cold_families", lambda names: [])
    entered = []
    assert worker.compile_for_local_workers(make_settings(),
                                            lambda: entered.append(1)) == 0.0
    assert entered == []
