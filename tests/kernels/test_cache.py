"""The kernel cache never stops fastdet: damaged, read-only, shared or foreign caches.

Each case runs ``fastdet --verbose detect`` in a subprocess with its own
``NUMBA_CACHE_DIR`` and checks that the detection succeeds, prints the boxes
a healthy cache gives, and says on stderr what it did about the cache.  The
default profile starts from a copy of this test process's own cache (filled
by a detection here) so that only the damaged kernels are compiled; the
slow cases compile everything, several times.
"""

from __future__ import annotations

import json
import os
import random
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from numba.core.caching import _CacheLocator

import fastdet
from fastdet.kernels import cache
from filesystems import read_only

ROOT = Path(__file__).resolve().parents[2]
PACKAGE = ROOT / "fastdet"
#: The fastdet command, run by this interpreter.
FASTDET = [sys.executable, "-c",
           "import sys; from fastdet.cli import console_main; console_main(sys.argv[1:])"]


@pytest.fixture(scope="module")
def image(data_dir):
    return data_dir / "test_images" / "test1.jpg"


@pytest.fixture(scope="module")
def filled_cache(image, tmp_path_factory):
    """A copy of this process's kernel cache, holding every kernel a detection needs."""
    import cv2

    fastdet.Detector(threads=1)(cv2.imread(str(image)))
    # Numba keeps each source folder's kernels in a subfolder named after it.
    subfolder = _CacheLocator.get_suitable_cache_subpath(cache.__file__)
    copy = tmp_path_factory.mktemp("filled") / "kernels"
    cache._copy_entries(cache.active_cache_dir() / subfolder, copy / subfolder)
    assert any(copy.rglob("*.nbc"))
    return copy


def copy_of(source, target):
    cache._copy_entries(source, target)
    return target


def detect(image, cache_dir, *extra_env, **env):
    """``fastdet --verbose detect IMAGE`` with ``cache_dir``: (boxes, stderr)."""
    environment = dict(os.environ, NUMBA_CACHE_DIR=str(cache_dir), **env)
    for name in extra_env:
        environment.pop(name, None)
    result = subprocess.run([*FASTDET, "--verbose", "detect", str(image), "--threads", "1"],
                            cwd=ROOT, env=environment, capture_output=True, text=True,
                            timeout=900)
    assert result.returncode == 0, result.stderr
    assert "Traceback" not in result.stderr, result.stderr
    return json.loads(result.stdout.splitlines()[-1])["boxes"], result.stderr


def counts(stderr):
    """(loaded, compiled) from the --verbose summary."""
    match = re.search(r"kernels: (\d+) loaded from the cache, (\d+) compiled", stderr)
    assert match, stderr
    return int(match.group(1)), int(match.group(2))


def kernel_files(folder):
    return sorted(p for p in folder.rglob("*.nb[ic]"))


def cache_files_in_package():
    return sorted(str(p) for p in PACKAGE.rglob("*.nb[ic]"))


@pytest.fixture(scope="module")
def expected_boxes(image, filled_cache, tmp_path_factory):
    boxes, stderr = detect(image, copy_of(filled_cache, tmp_path_factory.mktemp("healthy")))
    assert counts(stderr)[1] == 0, "the filled cache should hold every kernel"
    assert boxes
    return boxes


def damage(path, how, rng):
    """Cut a cache file short, empty it, or fill it with random bytes."""
    data = path.read_bytes()
    if how == "truncated":
        data = data[:rng.randrange(1, max(2, len(data)))]
    elif how == "empty":
        data = b""
    else:
        data = bytes(rng.randrange(256) for _ in range(len(data)))
    path.write_bytes(data)


def test_damaged_entries_are_compiled_again(image, filled_cache, expected_boxes, tmp_path):
    folder = copy_of(filled_cache, tmp_path / "kernels")
    # The index and data files of the labelling kernels, each damaged one of
    # three ways (a few kernels, so that only they are compiled again).
    victims = [p for p in kernel_files(folder) if p.name.startswith("label.")]
    assert len(victims) >= 3, kernel_files(folder)
    rng = random.Random(17)
    for k, path in enumerate(victims):
        damage(path, ("truncated", "empty", "garbage")[k % 3], rng)
    boxes, stderr = detect(image, folder)
    assert boxes == expected_boxes
    assert "is damaged" in stderr and "compiling it again" in stderr
    assert counts(stderr)[1] > 0
    # The entries were written afresh: the next run loads everything.
    boxes, stderr = detect(image, folder)
    assert boxes == expected_boxes
    assert "is damaged" not in stderr and counts(stderr)[1] == 0


def test_read_only_cache_is_used_without_writing(image, filled_cache, expected_boxes, tmp_path):
    folder = copy_of(filled_cache, tmp_path / "kernels")
    before = kernel_files(folder)
    package_before = cache_files_in_package()
    with read_only(folder):
        boxes, stderr = detect(image, folder)
    assert boxes == expected_boxes
    assert "is not writable" in stderr
    assert counts(stderr)[1] == 0  # its kernels still serve, from a copy
    assert kernel_files(folder) == before
    assert cache_files_in_package() == package_before, "kernels were cached in the package"


@pytest.mark.slow
def test_empty_read_only_cache_compiles_outside_the_package(image, expected_boxes, tmp_path):
    folder = tmp_path / "kernels"
    folder.mkdir()
    package_before = cache_files_in_package()
    with read_only(folder):
        boxes, stderr = detect(image, folder)
    assert boxes == expected_boxes
    assert "is not writable" in stderr and counts(stderr)[1] > 0
    assert not kernel_files(folder)
    assert cache_files_in_package() == package_before, "kernels were cached in the package"


@pytest.mark.slow
def test_every_file_truncated(image, expected_boxes, tmp_path):
    folder = tmp_path / "kernels"
    detect(image, folder)
    for path in kernel_files(folder):
        data = path.read_bytes()
        path.write_bytes(data[:len(data) // 2])
    boxes, stderr = detect(image, folder)
    assert boxes == expected_boxes and "is damaged" in stderr
    assert counts(detect(image, folder)[1])[1] == 0


@pytest.mark.slow
def test_two_processes_fill_an_empty_cache_at_once(image, expected_boxes, tmp_path):
    folder = tmp_path / "kernels"
    environment = dict(os.environ, NUMBA_CACHE_DIR=str(folder))
    command = [*FASTDET, "--verbose", "detect", str(image), "--threads", "1"]
    runs = [subprocess.Popen(command, cwd=ROOT, env=environment, stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True) for _ in range(2)]
    for run in runs:
        stdout, stderr = run.communicate(timeout=1800)
        assert run.returncode == 0, stderr
        assert json.loads(stdout.splitlines()[-1])["boxes"] == expected_boxes
        assert "is damaged" not in stderr
    assert not list(folder.rglob("*.tmp.*")), "a temporary file was left"
    boxes, stderr = detect(image, folder)
    assert boxes == expected_boxes
    assert counts(stderr)[1] == 0 and "is damaged" not in stderr


@pytest.mark.slow
def test_cache_of_another_cpu_is_not_loaded(image, expected_boxes, tmp_path):
    # One folder shared by two CPUs (NUMBA_CACHE_DIR is used as given): each
    # compiles its own entries, neither loads the other's.
    folder = tmp_path / "kernels"
    other = {"NUMBA_CPU_NAME": "haswell", "NUMBA_CPU_FEATURES": ""}
    boxes, stderr = detect(image, folder, **other)
    assert np.allclose([b["box"] for b in boxes], [b["box"] for b in expected_boxes])
    boxes, stderr = detect(image, folder, "NUMBA_CPU_NAME", "NUMBA_CPU_FEATURES")
    assert boxes == expected_boxes and counts(stderr)[1] > 0 and "is damaged" not in stderr
    assert counts(detect(image, folder, "NUMBA_CPU_NAME", "NUMBA_CPU_FEATURES")[1])[1] == 0


# -- loading without Numba's compile set-up (fastdet.kernels.cached_load) -------------------
_LOADS_WITHOUT_REGISTRIES = r"""
import json, re, sys
import cv2, numba
import numpy as np
import fastdet
from fastdet.kernels import cache, cached_load

image = cv2.imread(sys.argv[1])
boxes = fastdet.Detector(threads=1)(image).xyxy.tolist()
loaded, compiled = map(int, re.search(r"(\d+) loaded from the cache, (\d+) compiled",
                                      cache.summary()).groups())
assert loaded > 0 and compiled == 0, cache.summary()
light = cached_load._numba_version() in cached_load.CHECKED_NUMBA
# Numba's implementations of lists, sets, linear algebra, ... are what a
# refresh of the target imports; loading machine code needs none of them.
assert ("numba.np.arraymath" not in sys.modules) == light, light
assert ("numba.np.linalg" not in sys.modules) == light, light
assert "numba.cpython.hashing" in sys.modules

# Compiling still works in this process, and refreshes the target then:
# a fastdet kernel at a signature not in the cache ...
from fastdet.kernels.heat import accumulate_heat
boxes32 = np.array([[1, 2, 9, 7], [4, 0, 12, 5]], np.int32)
weights = np.array([0.5, 2.0], np.float32)
assert np.array_equal(accumulate_heat(boxes32.astype(np.int64), weights, 9, 13),
                      accumulate_heat(boxes32, weights, 9, 13))
# ... and a user's function that takes what a refresh installs: lists, sets,
# dicts of strings (the hash secret), random numbers, np.dot.
@numba.njit
def mixed(a, b, words):
    seen = set()
    counts = {}
    for w in words:
        seen.add(w)
        if w in counts:
            counts[w] += 1
        else:
            counts[w] = 1
    np.random.seed(3)
    return np.dot(a, b), len(seen), counts["car"], np.random.random()

a, b = np.arange(6.0).reshape(2, 3), np.arange(12.0).reshape(3, 4)
product, distinct, cars, random = mixed(a, b, numba.typed.List(["car", "van", "car"]))
np.random.seed(3)
assert np.allclose(product, a @ b) and distinct == 2 and cars == 2
assert random == np.random.random()
print(json.dumps(boxes))
"""


def test_cached_kernels_load_without_numba_registries(image, filled_cache, expected_boxes,
                                                      tmp_path):
    environment = dict(os.environ, NUMBA_CACHE_DIR=str(copy_of(filled_cache, tmp_path / "k")))
    result = subprocess.run([sys.executable, "-c", _LOADS_WITHOUT_REGISTRIES, str(image)],
                            cwd=ROOT, env=environment, capture_output=True, text=True,
                            timeout=900)
    assert result.returncode == 0, result.stderr[-3000:]
    boxes = json.loads(result.stdout.splitlines()[-1])
    assert [list(map(int, box)) for box in boxes] == [b["box"] for b in expected_boxes]


def test_cached_load_takes_numbas_path_for_unchecked_versions(monkeypatch):
    from fastdet.kernels import cached_load, heat

    numba_cache = next(v for v in vars(heat).values() if hasattr(v, "_cache"))._cache
    assert cached_load.supported(numba_cache) == (
        cached_load._numba_version() in cached_load.CHECKED_NUMBA)
    monkeypatch.setattr(cached_load.numba, "__version__", "0.99.0")
    assert not cached_load.supported(numba_cache)
    monkeypatch.setattr(cached_load.numba, "__version__", "not-a-version")
    assert not cached_load.supported(numba_cache)


def _in_fresh_process(code, **env):
    """Run ``code`` in a new interpreter from the checkout; the completed process."""
    return subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True,
                          env=dict(os.environ, **env), timeout=300)


def test_a_blocked_kernel_subfolder_never_sends_kernels_into_the_package(tmp_path):
    """The cache folder is writable but fastdet's kernel subfolder in it cannot be made
    (a file under its name): Numba then filed every kernel in ``__pycache__`` inside
    the package.  Now the folder counts as unwritable and a temporary copy is used."""
    (tmp_path / _CacheLocator.get_suitable_cache_subpath(cache.__file__)).write_text("a file")
    result = _in_fresh_process(
        "from fastdet.kernels import cache, convert\n"
        "print(cache.describe())\n"
        "print(convert._bgr_to_hls._cache._cache_path)\n", NUMBA_CACHE_DIR=str(tmp_path))
    assert result.returncode == 0, result.stderr
    described, kernels_in = result.stdout.splitlines()[-2:]
    assert "is not writable" in described, described
    assert not Path(kernels_in).is_relative_to(PACKAGE), kernels_in


def test_no_temporary_folder_and_an_unwritable_cache_compiles_uncached(tmp_path):
    """An unwritable cache folder and no temporary folder to copy it to (a read-only
    container without /tmp): importing the kernels raised FileNotFoundError.  Now they
    compile uncached, and work."""
    blocked = tmp_path / "a-file"
    blocked.write_text("not a folder")
    result = _in_fresh_process(
        "import tempfile\n"
        "def none(*args, **kwargs):\n"
        "    raise FileNotFoundError(2, 'No usable temporary directory found')\n"
        "tempfile.mkdtemp = none\n"
        "import numpy as np\n"
        "from fastdet.kernels import cache, convert\n"
        "print(type(convert._bgr_to_hls._cache).__name__)\n"
        "print(convert.bgr_to_hls(np.zeros((4, 16, 3), np.uint8)).shape)\n"
        "print(cache.describe())\n", NUMBA_CACHE_DIR=str(blocked))
    assert result.returncode == 0, result.stderr
    kind, shape, described = result.stdout.splitlines()[-3:]
    assert kind == "NullCache" and shape == "(4, 16, 3)", result.stdout
    assert "not cached" in described, described
    assert not list(tmp_path.rglob("*.nb[ic]"))
