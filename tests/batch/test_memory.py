"""Workers reuse a freed frame's memory instead of faulting in new pages for every frame."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest
from distributed import Client, LocalCluster

import fastdet

#: Bytes of a 1280x720 BGR frame.
FRAME_BYTES = 1280 * 720 * 3
PAGE = os.sysconf("SC_PAGE_SIZE")


def page_faults_per_frame(frames=40):
    """Minor page faults of allocating, filling and freeing one frame-sized array, on average."""
    import resource

    import numpy as np

    np.ones(FRAME_BYTES, np.uint8)                  # the first may well fault
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(frames):
        np.ones(FRAME_BYTES, np.uint8)
    return (resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before) / frames


CHILD = """
import json
from fastdet.video.memory import reuse_freed_frames
from test_memory import page_faults_per_frame
before = page_faults_per_frame()
took = reuse_freed_frames()
print(json.dumps({"before": before, "took": took, "after": page_faults_per_frame()}))
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt: Linux only")
def test_frames_reuse_freed_memory_under_dasks_trim_threshold():
    # MALLOC_TRIM_THRESHOLD_ is what a Dask nanny gives its worker; glibc reads it at start.
    env = {**os.environ, "MALLOC_TRIM_THRESHOLD_": "65536",
           "PYTHONPATH": os.pathsep.join([os.path.dirname(__file__), *sys.path])}
    out = subprocess.run([sys.executable, "-c", CHILD], env=env, capture_output=True, text=True,
                         timeout=120, check=True).stdout
    result = json.loads(out)
    assert result["took"] is True
    # Every page of every frame faulted in again, then (nearly) none.
    assert result["before"] > 0.9 * FRAME_BYTES / PAGE
    assert result["after"] < 0.05 * FRAME_BYTES / PAGE


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt: Linux only")
def test_a_batch_worker_reuses_freed_frames(data_dir, tmp_path):
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address="127.0.0.1:0", env={"NUMBA_NUM_THREADS": "1"}) as cluster, \
            Client(cluster) as client:
        [fresh] = client.run(page_faults_per_frame).values()
        [record] = fastdet.batch(data_dir / "test_video.mp4", tmp_path, client, video=False)
        assert record["status"] == "done"
        [after] = client.run(page_faults_per_frame).values()
    assert fresh > 0.9 * FRAME_BYTES / PAGE          # Dask's setting, before the batch
    assert after < 0.05 * FRAME_BYTES / PAGE         # the batch's set-up changed it
