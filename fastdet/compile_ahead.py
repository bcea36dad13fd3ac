"""The kernel compile's plan: the families, their split over two processes, and the helper process.

A first run (nothing in the kernel cache for this fastdet, Numba and CPU)
compiles every kernel family a detection runs, about 15 s of CPU on the
development machine, and :func:`fastdet.kernels.warmup.warm` spreads that
over this process and a helper process.  This module holds what both sides
share and imports nothing heavy (no NumPy, no Numba): so the ``fastdet``
command can start the helper as its very first step (:func:`start_early`),
and the helper compiles while this process is still importing NumPy, OpenCV
and Numba (0.4-0.5 s on the development machine, one core otherwise idle).
"""

from __future__ import annotations

import atexit
import hashlib
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from ._version import __version__

#: Seconds each family took to compile (empty cache, a process of its own,
#: Numba's own helpers included), measured on an AMD EPYC (Zen 3, AVX2, two
#: vCPUs) on 2026-12-02, medians of three rounds of ``fastdet warmup --families
#: F --processes 1``, with the collector held back during compiles
#: (:mod:`fastdet.kernels.compile_gc`) and only the variants a detection runs
#: (see ``_colour_maps``, ``_score_window_rows`` and ``_cell_rows_u8_fast``; the
#: per-pixel tails of the conversion and the cells are the family "tails").
#: The previous weights (Zen 4, 2026-11-28) predate the refinement's side
#: snapping: refine 1.66 against 3.13 here, while most families took
#: 1.0-1.3 times as long here; with them a cold detection's own process
#: compiled 11.6 s against the helper's 8.8 s of these.
#: :func:`split_families` balances two processes with these weights.
COMPILE_WEIGHTS = {"label": 6.28, "track": 5.13, "split": 4.69, "hog_api": 4.46, "refine": 3.13,
                   "colour": 3.11, "tails": 2.68, "score": 2.66, "heat": 2.29, "resize": 1.98,
                   "hog": 1.45, "smooth": 0.62, "convert": 0.37}

#: The families every detection with the default feature options runs.
DETECTION_FAMILIES = ("convert", "resize", "hog", "score", "colour", "heat", "label", "refine")

#: Seconds a helper process started once this one has imported fastdet
#: needs before it compiles (Python, NumPy, Numba, fastdet).
HELPER_START_SECONDS = 0.8

#: The same, for a helper started before this process's own imports
#: (:func:`start_early`): the two import side by side and start compiling
#: together.
EARLY_HELPER_START_SECONDS = 0.0

#: Overrides the user cache folder (the kernels go in its ``kernels/`` subfolder).
CACHE_ENV_VAR = "FASTDET_CACHE_DIR"

#: How the name of every kernel folder of this fastdet version begins (then
#: Numba's version, the CPU's name and a digest of its features; see
#: :func:`fastdet.kernels.cache.cache_key`).
CACHE_KEY_PREFIX = f"fastdet-{__version__}-numba-"


#: Seconds of each family's weight that a process compiling several pays
#: once: Numba's set-up for its first compile and the small helpers several
#: families call.  Compiled one after another in one process, each family
#: after the first took about this much less than its weight: 0.25-0.46 s on
#: the Zen 3 of the first weights, 0-0.17 s on the Zen 4 of 2026-11-28 (convert
#: 0.17-0.18 s after another family against 0.32 s alone, HOG 0.95-1.12 s
#: against 1.11-1.15 s).
SHARED_SECONDS = 0.15


def group_seconds(names):
    """Expected seconds one process takes to compile the families ``names`` one after another."""
    total = sum(COMPILE_WEIGHTS.get(name, 1.0) for name in names)
    return total - SHARED_SECONDS * max(len(names) - 1, 0)


def split_families(names, helper_start=HELPER_START_SECONDS):
    """``(here, helper)``: ``names`` in two groups that finish as close together as can be.

    Every way of splitting the few families is tried (an exact partition of
    :func:`group_seconds`; a greedy split of the weights left the helper
    0.8-0.9 s behind on a cold detection), with the helper's group starting
    ``helper_start`` seconds late.  Ties go to the split with fewer families
    in the helper.  Each group lists its families heaviest first.
    """
    ordered = sorted(names, key=lambda n: (-COMPILE_WEIGHTS.get(n, 1.0), n))
    best_key, best = None, (ordered, [])
    for mask in range(1 << len(ordered)):
        helper = [name for k, name in enumerate(ordered) if mask >> k & 1]
        here = [name for k, name in enumerate(ordered) if not mask >> k & 1]
        end = max(group_seconds(here), helper_start + group_seconds(helper))
        key = (round(end, 6), len(helper), mask)
        if best_key is None or key < best_key:
            best_key, best = key, (here, helper)
    return best


#: The helper's program: its path without the working directory (which
#: ``-c`` puts first), with the folder this fastdet came from first unless
#: the path has it already, then :func:`fastdet.kernels.warmup.main`.
_HELPER_CODE = ("import sys; sys.path[:] = [p for p in sys.path if p]; "
                "sys.path.insert(0, sys.argv[1]) if sys.argv[1] not in sys.path else None; "
                "from fastdet.kernels.warmup import main; sys.exit(main(sys.argv[2:]))")


def start_helper(names):
    """A Python process compiling the families ``names`` into the kernel cache.

    The child imports the same fastdet files as this process: Numba files a
    kernel's cache entries under its source folder, so kernels compiled from
    another copy (``python -m`` puts the working directory first, and run
    from a checkout with fastdet installed that is the checkout's copy) would
    be filed where this process never looks.  It finds the cache folder as
    this process does (``NUMBA_CACHE_DIR``, inherited, or the same key) and
    prints one JSON line of seconds per family.
    """
    package_root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    return subprocess.Popen([sys.executable, "-c", _HELPER_CODE, package_root, *names],
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)


def cache_base():
    """The folder every build's kernel folder lives in (see :mod:`fastdet.kernels.cache`)."""
    from platformdirs import user_cache_dir

    base = os.environ.get(CACHE_ENV_VAR) or user_cache_dir("fastdet", appauthor=False)
    return Path(base) / "kernels"


def _writable(folder):
    try:
        folder.mkdir(parents=True, exist_ok=True)
        tempfile.TemporaryFile(dir=folder).close()
    except OSError:
        return False
    return True


def nothing_cached():
    """Whether this fastdet has certainly no compiled kernels yet, in a folder it can write.

    Cheap (no Numba): with ``NUMBA_CACHE_DIR``, fastdet's kernel subfolder
    in it (named as Numba names it: the source folder's name and a SHA-1 of
    its path) does not exist; otherwise no folder of this fastdet version
    exists in :func:`cache_base`, for any Numba or CPU.  Anything less sure
    (another CPU's kernels of this version, say) is left to
    :func:`fastdet.kernels.warmup.cold_families`, after the imports.  An
    unwritable folder counts as cached: there each process compiles into a
    folder of its own, and a helper's work would be lost.
    """
    given = os.environ.get("NUMBA_CACHE_DIR")
    if given:
        kernels = os.path.join(os.path.dirname(os.path.abspath(__file__)), "kernels")
        subfolder = "kernels_" + hashlib.sha1(kernels.encode()).hexdigest()
        return not (Path(given) / subfolder).exists() and _writable(Path(given))
    base = cache_base()
    try:
        if any(entry.name.startswith(CACHE_KEY_PREFIX) for entry in os.scandir(base)):
            return False
    except FileNotFoundError:
        pass
    except OSError:
        return False
    return _writable(base)


# The helper start_early started, and the families it compiles, until warm() takes it.
_early = {"helper": None, "names": ()}


def start_early(names=DETECTION_FAMILIES):
    """Start the helper for its share of ``names`` now, if nothing is compiled yet.

    For the ``fastdet`` command's first step, before it imports the rest of
    fastdet: on a machine with two or more cores and a kernel cache this
    fastdet has never filled (:func:`nothing_cached`), the helper compiles
    its share (:func:`split_families` with
    :data:`EARLY_HELPER_START_SECONDS`) while this process imports, and
    :func:`fastdet.kernels.warmup.warm` waits for it (:func:`take_early`).
    A helper nobody took is stopped when this process exits.

    Returns
    -------
    list of str
        The families the helper compiles (empty: no helper started).
    """
    if _early["helper"] is not None or (os.cpu_count() or 1) < 2 or not nothing_cached():
        return []
    _, remote = split_families(names, EARLY_HELPER_START_SECONDS)
    if not remote:
        return []
    helper = start_helper(remote)
    _early.update(helper=helper, names=tuple(remote))
    atexit.register(_stop_untaken, helper)
    return list(remote)


def take_early(names):
    """``(helper, families)`` of the helper :func:`start_early` started, for a warm-up of ``names``.

    Taken once, and only if it compiles some of ``names`` (``families``:
    those); otherwise ``None``, and a helper nobody takes is stopped at exit.
    """
    helper = _early["helper"]
    remote = [name for name in _early["names"] if name in names]
    if helper is None or not remote:
        return None
    _early.update(helper=None, names=())
    return helper, remote


def _stop_untaken(helper):
    if helper.poll() is None and _early["helper"] is helper:
        helper.terminate()
        helper.wait()
