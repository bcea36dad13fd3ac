"""The kernel compile's plan: the families, how two processes share them, and the helper process.

A first run (nothing in the kernel cache for this fastdet, Numba and CPU)
compiles every kernel family a detection runs, about 15 s of CPU on the
development machine, and :func:`fastdet.kernels.warmup.warm` spreads that
over this process and a helper process: both go through the families
heaviest first, and each compiles the next one nobody has claimed
(:class:`FamilyClaims`), so they end together whatever this CPU's compile
times are.  This module holds what both sides
share and imports nothing heavy (no NumPy, no Numba): so the ``fastdet``
command can start the helper as its very first step (:func:`start_early`),
and the helper compiles while this process is still importing NumPy, OpenCV
and Numba (0.4-0.5 s on the development machine, one core otherwise idle).
"""

from __future__ import annotations

import atexit
import hashlib
import os
import shutil
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
#: "band" (its kernel alone: it calls the compiled code of "hog", "score" and
#: "colour", see fastdet.kernels.calls) was measured on an Intel Xeon (AVX-512)
#: on 2026-12-03, 0.25 s, and scaled by 1.4, about what the families above
#: took on the Zen 3 against the Xeon.
#: They set the order the two compiling processes take families in
#: (:func:`compile_order`): heaviest first, so that the last to be taken are
#: short and the two processes end close together.
COMPILE_WEIGHTS = {"label": 6.28, "track": 5.13, "split": 4.69, "hog_api": 4.46, "refine": 3.13,
                   "colour": 3.11, "tails": 2.68, "score": 2.66, "heat": 2.29, "resize": 1.98,
                   "hog": 1.45, "smooth": 0.62, "convert": 0.37, "band": 0.35}

#: The families every detection with the default feature options runs ("band"
#: calls the compiled code of "hog", "score" and "colour").
DETECTION_FAMILIES = ("convert", "resize", "hog", "score", "colour", "band", "heat", "label",
                      "refine")

#: Overrides the user cache folder (the kernels go in its ``kernels/`` subfolder).
CACHE_ENV_VAR = "FASTDET_CACHE_DIR"

#: How the name of every kernel folder of this fastdet version begins (then
#: Numba's version, the CPU's name and a digest of its features; see
#: :func:`fastdet.kernels.cache.cache_key`).
CACHE_KEY_PREFIX = f"fastdet-{__version__}-numba-"


def compile_order(names):
    """``names`` heaviest first (:data:`COMPILE_WEIGHTS`; unmeasured ones weigh 1 s,
    ties by name): the order in which both compiling processes take families.

    Taking the heaviest first leaves the light ones for last, where
    whichever process is free first takes them: the processes end within
    about the last family's time of each other, on any CPU.  A split fixed
    by weights measured on one machine does not: the weights of a Zen 3
    (AVX2) put label, heat and resize in the helper, which on a Zen 4 with
    AVX-512 (2026-12-02) compiled those for 7.4 s while this process had
    its share done in 5.9 s.
    """
    return sorted(names, key=lambda name: (-COMPILE_WEIGHTS.get(name, 1.0), name))


#: How a claims folder's name begins, in the temporary folder: then the
#: process id of the process that made it (and removes it when done).
CLAIMS_PREFIX = "fastdet-compile-"


def remove_abandoned_claims(folder=None):
    """Remove the claims folders (in ``folder``, default the temporary folder) of
    processes that no longer run.

    A process killed outright (SIGKILL, a lost machine) cannot remove its
    claims at exit; the next cold start does.  Only this user's folders, only
    those whose maker's process id is gone.
    """
    if os.name != "posix":  # os.kill(pid, 0) would end the process on Windows
        return
    folder = Path(folder or tempfile.gettempdir())
    try:
        entries = list(folder.glob(f"{CLAIMS_PREFIX}*-*"))
    except OSError:
        return
    for entry in entries:
        pid = entry.name[len(CLAIMS_PREFIX):].split("-", 1)[0]
        try:
            if not pid.isdigit() or entry.stat().st_uid != os.getuid() or _running(int(pid)):
                continue
        except OSError:  # gone meanwhile
            continue
        shutil.rmtree(entry, ignore_errors=True)


def _running(pid):
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (OSError, OverflowError):  # another user's process, or an id the OS refuses: keep
        return True
    return True


class FamilyClaims:
    """Which of two processes compiles which family: the first to claim it.

    A claim is a file created (``O_EXCL``) in a folder both processes know,
    so each family is compiled once, by the process that got there first.

    Parameters
    ----------
    folder : str, optional
        The folder of an existing set of claims (the helper's side); by
        default a new temporary one, removed by :meth:`remove`.
    """

    def __init__(self, folder=None):
        self.owned = folder is None
        if folder is None:
            remove_abandoned_claims()
            folder = tempfile.mkdtemp(prefix=f"{CLAIMS_PREFIX}{os.getpid()}-")
        self.folder = folder

    def claim(self, name):
        """Claim family ``name``; False if the other process has (or the claims are gone)."""
        try:
            os.close(os.open(os.path.join(self.folder, name),
                             os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o600))
        except OSError:  # FileExistsError: taken; anything else: the owner has finished
            return False
        return True

    def remove(self):
        """Remove the claims' folder, if this side made it."""
        if self.owned:
            shutil.rmtree(self.folder, ignore_errors=True)


#: The helper's program: its path without the working directory (which
#: ``-c`` puts first), with the folder this fastdet came from first unless
#: the path has it already, then :func:`fastdet.kernels.warmup.main` (argv:
#: ``--claims FOLDER FAMILY...``).
_HELPER_CODE = ("import sys; sys.path[:] = [p for p in sys.path if p]; "
                "sys.path.insert(0, sys.argv[1]) if sys.argv[1] not in sys.path else None; "
                "from fastdet.kernels.warmup import main; sys.exit(main(sys.argv[2:]))")


def start_helper(names, claims):
    """A Python process compiling, of the families ``names``, those it claims first.

    It goes through ``names`` in :func:`compile_order` and compiles each
    family it claims in ``claims`` (a :class:`FamilyClaims`) into the kernel
    cache, skipping those this process claimed.  The child imports the same
    fastdet files as this process: Numba files a kernel's cache entries
    under its source folder, so kernels compiled from another copy (``python
    -m`` puts the working directory first, and run from a checkout with
    fastdet installed that is the checkout's copy) would be filed where this
    process never looks.  It finds the cache folder as this process does
    (``NUMBA_CACHE_DIR``, inherited, or the same key) and prints one JSON
    line of seconds per family it compiled.

    A helper still running when this process exits is stopped then, and the
    claims removed (:func:`stop_helper`): a compile waited for returns only
    once its helper has ended, so such a helper's work was abandoned (Ctrl-C
    while the kernels compiled on a thread of their own), and it would
    otherwise go on for up to a family's compile.
    """
    package_root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    helper = subprocess.Popen([sys.executable, "-c", _HELPER_CODE, package_root, "--claims",
                               claims.folder, *names],
                              stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
    atexit.register(stop_helper, helper, claims)
    return helper


def stop_helper(helper, claims):
    """Stop ``helper`` if it is still running, and remove ``claims`` (if this side made them).

    Numba writes each cache file under a temporary name and renames it, so a
    helper stopped mid-compile leaves no broken cache entry.
    """
    if helper.poll() is None:
        helper.terminate()
        try:
            helper.wait(5)
        except subprocess.TimeoutExpired:
            helper.kill()
            helper.wait()
    claims.remove()


def cache_base():
    """The folder every build's kernel folder lives in (see :mod:`fastdet.kernels.cache`)."""
    from platformdirs import user_cache_dir

    base = os.environ.get(CACHE_ENV_VAR) or user_cache_dir("fastdet", appauthor=False)
    # Absolute: NUMBA_CACHE_DIR is exported from it, and a child process started in
    # another folder (the compile helper, a benchmark's peer) read a relative one there.
    return Path(os.path.abspath(base)) / "kernels"


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


# The helper start_early started, the families it may compile and their claims,
# until warm() takes it.
_early = {"helper": None, "names": (), "claims": None}


def start_early(names=DETECTION_FAMILIES):
    """Start the helper on ``names`` now, if nothing is compiled yet.

    For the ``fastdet`` command's first step, before it imports the rest of
    fastdet: on a machine with two or more cores and a kernel cache this
    fastdet has never filled (:func:`nothing_cached`), the helper starts
    compiling ``names`` heaviest first while this process imports; then
    :func:`fastdet.kernels.warmup.warm` takes it (:func:`take_early`) and
    compiles the families the helper has not claimed.  A helper nobody took
    is stopped when this process exits.

    Returns
    -------
    list of str
        The families the helper may compile, in its order (empty: no helper
        started).
    """
    if _early["helper"] is not None or (os.cpu_count() or 1) < 2 or not nothing_cached():
        return []
    if len(names) < 2:
        return []
    try:
        claims = FamilyClaims()
    except OSError:  # no temporary folder to be had: this process compiles alone
        return []
    ordered = compile_order(names)
    try:
        helper = start_helper(ordered, claims)
    except OSError:  # no second process to be had: likewise
        claims.remove()
        return []
    _early.update(helper=helper, names=tuple(ordered), claims=claims)
    return ordered


def take_early(names):
    """``(helper, families, claims)`` of the helper :func:`start_early` started, for a
    warm-up of ``names``.

    Taken once, and only if it may compile some of ``names`` (``families``:
    those); otherwise ``None``, and a helper nobody takes is stopped at exit.
    The taker claims the helper's families it does not need, so that the
    helper skips them.
    """
    helper, claims = _early["helper"], _early["claims"]
    shared = [name for name in _early["names"] if name in names]
    if helper is None or not shared:
        return None
    for name in _early["names"]:
        if name not in names:
            claims.claim(name)
    _early.update(helper=None, names=(), claims=None)
    return helper, shared, claims

