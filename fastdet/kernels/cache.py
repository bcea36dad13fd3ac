"""Where compiled kernels are cached: the user's cache folder, never the installed package.

Numba's default puts ``cache=True`` code in ``__pycache__`` beside each source
file, i.e. inside ``site-packages/fastdet/kernels/`` for a normal install:
pip does not know those files, so an uninstall leaves a stray ``fastdet``
folder that shadows any later install, and a read-only install cannot cache
at all.  :func:`configure` points Numba at a per-user folder instead, keyed
by fastdet's and Numba's versions and the CPU the kernels are compiled for,
so that another version or another CPU never loads code built for a
different one (Numba's own index also keys each entry by the target's CPU
name and features; the folder keeps different builds apart on disk too).

The folder is, in order of precedence, ``NUMBA_CACHE_DIR`` (used as given),
``$FASTDET_CACHE_DIR/kernels/<key>``, or
``platformdirs.user_cache_dir("fastdet")/kernels/<key>``.

A cache never stops fastdet (what :func:`configure` arranges):

* a folder fastdet cannot write (read-only, another user's, a full disk)
  is replaced by a temporary folder of this process, deleted at exit, that
  starts as a copy of what the folder holds: a read-only cache filled
  beforehand (say, in a container image) still serves its kernels, and
  kernels it lacks are compiled and not kept.  Numba would otherwise fall
  back to ``__pycache__`` beside the sources, inside the installed package
  (which fastdet's kernels never use: with no temporary folder either, or
  a kernel subfolder Numba cannot use, they are compiled and not cached);
* an entry that cannot be loaded (files cut short by a full disk or a
  killed process, garbage) is dropped and its kernel compiled again; an
  entry that cannot be saved is not kept;
* several processes may share one folder: Numba writes every file to a
  temporary name and renames it into place, so a reader never sees half a
  file (two processes compiling at once may each write the same entry);
* entries of another CPU or another Numba are never loaded: the folder's
  key names both, and Numba's index keys every entry by its target CPU.

Each of these is logged on the ``fastdet.kernels`` logger (``fastdet
--verbose`` shows them), as is :func:`summary`.
"""

from __future__ import annotations

import atexit
import functools
import hashlib
import logging
import os
import shutil
import sys
import tempfile
from pathlib import Path

import llvmlite.binding as llvm
import numba
from numba.core import caching
from numba.core.caching import NullCache
from numba.core.dispatcher import Dispatcher

from ..compile_ahead import CACHE_KEY_PREFIX, cache_base
from . import cached_load
from .blas_check import import_numba_arraymath

log = logging.getLogger("fastdet.kernels")


#: First-run compile time of the kernels a detection needs (two processes,
#: see ``fastdet.kernels.warmup``); what the first run announces (see
#: ``fastdet.cli.common``).  A cold ``fastdet detect test1.jpg`` took 7.9-8.3 s
#: on the fastest machine measured (README, *Start-up*) and 11.3-13.5 s on an
#: AMD EPYC Zen 3 (2026-12-02, three runs of 3); the announcement said 8 s until then.
TYPICAL_COMPILE_SECONDS = 12


def target_cpu():
    """``(name, features)`` of the CPU Numba compiles for (``NUMBA_CPU_NAME`` / ``_FEATURES`` first)."""
    name = numba.config.CPU_NAME or llvm.get_host_cpu_name()
    features = numba.config.CPU_FEATURES
    if features is None:
        features = llvm.get_host_cpu_features().flatten()
    return name, features


def cache_key():
    """The folder name that keeps one build's compiled kernels apart from every other."""
    name, features = target_cpu()
    digest = hashlib.sha256(features.encode()).hexdigest()[:12]
    return f"{CACHE_KEY_PREFIX}{numba.__version__}-{name}-{digest}"


def kernel_cache_dir():
    """The folder compiled kernels are cached in (see the module notes)."""
    if os.environ.get("NUMBA_CACHE_DIR"):
        return Path(os.environ["NUMBA_CACHE_DIR"])
    return cache_base() / cache_key()


def _kernel_subfolder():
    """The subfolder of the cache folder Numba files this fastdet's kernels in (named
    after their source folder, as Numba's ``UserProvidedCacheLocator`` names it)."""
    return caching._CacheLocator.get_suitable_cache_subpath(__file__)


def _unusable(path):
    """Why fastdet cannot create files in ``path`` (``None`` when it can), as Numba checks it.

    Checked in the kernels' own subfolder too: when only that one cannot be
    made or written (a file or another user's folder under its name), Numba
    would file every kernel in ``__pycache__`` inside the installed package.
    A subfolder not there yet is left for Numba to make (an empty one would
    count as cached for :func:`fastdet.compile_ahead.nothing_cached`).
    """
    try:
        path.mkdir(parents=True, exist_ok=True)
        tempfile.TemporaryFile(dir=path).close()
        subfolder = path / _kernel_subfolder()
        if os.path.lexists(subfolder):
            tempfile.TemporaryFile(dir=subfolder).close()
    except OSError as exc:
        return exc.strerror or str(exc)
    return None


@functools.lru_cache(maxsize=None)
def _process_folder():
    """A temporary kernel folder for this process only, deleted at exit."""
    path = Path(tempfile.mkdtemp(prefix="fastdet-kernels-"))
    atexit.register(shutil.rmtree, path, ignore_errors=True)
    return path


#: What :func:`configure` chose: the folder, and why the configured one was not used.
_status = {"folder": None, "problem": None, "configured": None}


def configure():
    """Point Numba's cache at :func:`kernel_cache_dir`; call before any kernel is defined.

    Numba picks a function's cache folder when its ``@njit(cache=True)``
    decorator runs; the environment variable is set as well so that Numba's
    reloads of its configuration, and processes started from this one,
    keep the same folder.  A folder fastdet cannot write is replaced by a
    temporary one (see the module notes); loading and saving entries is
    made fault-tolerant.

    Returns
    -------
    Path
        The folder kernels are cached in for this process (the configured
        one, unused, when neither it nor a temporary folder can be written:
        the kernels are then not cached).
    """
    configured = kernel_cache_dir()
    path, problem = configured, _unusable(configured)
    if problem is not None:
        try:
            path = _process_folder()
        except OSError:
            # No temporary folder either (a read-only container without
            # /tmp): the kernels compile every run, uncached (see
            # _cache_only_in_the_cache_folder), rather than fastdet stopping.
            path = None
        else:
            _copy_entries(configured, path)
    _status.update(folder=path, problem=problem, configured=configured)
    os.environ["NUMBA_CACHE_DIR"] = str(path or configured)
    numba.config.CACHE_DIR = str(path or configured)
    _tolerate_damaged_entries()
    _cache_only_in_the_cache_folder()
    return path or configured


def _copy_entries(source, target):
    """Copy the cache files of ``source`` that can be read into ``target`` (writable copies)."""
    if not source.is_dir():
        return
    for entry in source.rglob("*.nb[ic]"):
        try:
            destination = target / entry.relative_to(source)
            destination.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(entry, destination)
        except OSError:
            continue


def active_cache_dir():
    """The folder this process caches kernels in (after :func:`configure`)."""
    return _status["folder"] or kernel_cache_dir()


def describe():
    """One line: where kernels are cached, and why not where configured if so."""
    if _status["problem"] is not None and _status["folder"] is None:
        return (f"kernel cache {_status['configured']} is not writable ({_status['problem']}) "
                "and there is no temporary folder: kernels are compiled every run, not cached")
    if _status["problem"] is not None:
        return (f"kernel cache {_status['configured']} is not writable ({_status['problem']}): "
                f"using a copy of it in {_status['folder']}, kept for this run only")
    return f"kernel cache: {active_cache_dir()}"


def _is_fastdet_kernel(cache):
    return getattr(getattr(cache, "_py_func", None), "__module__", "").startswith("fastdet.")


def _cache_only_in_the_cache_folder():
    """Leave a fastdet kernel uncached rather than cached anywhere but the cache folder.

    When Numba cannot use ``NUMBA_CACHE_DIR`` for a function it tries the
    next place on its list, ``__pycache__`` beside the source, that is
    inside the installed package, and raises ``RuntimeError`` from the
    decorator (at import) when it finds no place at all.  For fastdet's
    kernels either now means no cache: the kernel compiles at its first
    call in every run.  Other packages' functions are untouched.
    """
    if getattr(Dispatcher, "_fastdet_cache_guard", False):
        return
    enable = Dispatcher.enable_caching

    def enable_caching(self):
        if not getattr(self.py_func, "__module__", "").startswith("fastdet."):
            return enable(self)
        try:
            enable(self)
            locator = self._cache._impl.locator
        except RuntimeError:
            locator = None
        if not isinstance(locator, caching.UserProvidedCacheLocator):
            if not _status.get("uncached"):
                log.info("kernel cache %s cannot be used: kernels are compiled, not cached",
                         numba.config.CACHE_DIR)
            _status["uncached"] = True
            self._cache = NullCache()
        return None

    Dispatcher.enable_caching = enable_caching
    Dispatcher._fastdet_cache_guard = True


def _tolerate_damaged_entries():
    """Make Numba's cache of fastdet's kernels treat a damaged entry as a miss.

    ``numba.core.caching.Cache`` unpickles an entry's index and data files
    without a guard: a file cut short raises ``UnpicklingError`` (or
    ``EOFError``, ...) from the kernel's first call, in every later run.
    Here a failed load empties the kernel's index (``Cache.flush``, which
    Numba writes atomically) so the kernel is compiled and saved afresh, and
    a failed save leaves it uncached.  Other packages' caches are untouched.
    """
    if getattr(caching.Cache, "_fastdet_tolerant", False):
        return
    load, save = caching.Cache.load_overload, caching.Cache.save_overload

    def load_overload(self, sig, target_context):
        try:
            if _is_fastdet_kernel(self) and cached_load.supported(self):
                loaded = cached_load.load_cached(self, sig, target_context)
                if loaded is None:
                    # A miss: Numba compiles it next, maybe its first compile here.
                    import_numba_arraymath()
                return loaded
            import_numba_arraymath()
            return load(self, sig, target_context)
        except Exception as exc:  # noqa: BLE001 - any damaged entry is a miss
            if not _is_fastdet_kernel(self):
                raise
            log.info("kernel cache entry of %s in %s is damaged (%s: %s): compiling it again",
                     self._py_func.__name__, self.cache_path, type(exc).__name__, exc)
            try:
                self.flush()
            except Exception as flush_exc:  # noqa: BLE001
                log.info("cannot reset it (%s): it stays uncached", flush_exc)
                self.disable()
            import_numba_arraymath()      # before the compile that follows
            return None

    def save_overload(self, sig, data):
        try:
            save(self, sig, data)
        except Exception as exc:  # noqa: BLE001 - a kernel that cannot be cached still runs
            if not _is_fastdet_kernel(self):
                raise
            log.info("cannot cache %s in %s (%s: %s): it is compiled again next run",
                     self._py_func.__name__, self.cache_path, type(exc).__name__, exc)

    caching.Cache.load_overload = load_overload
    caching.Cache.save_overload = save_overload
    caching.Cache._fastdet_tolerant = True


def summary():
    """How many of fastdet's compiled kernels this process loaded from the cache and compiled."""
    hits = misses = 0
    for name, module in list(sys.modules.items()):
        if not name.startswith("fastdet.kernels.") or module is None:
            continue
        for value in vars(module).values():
            if isinstance(value, Dispatcher):
                hits += sum(value.stats.cache_hits.values())
                misses += sum(value.stats.cache_misses.values())
    return f"kernels: {hits} loaded from the cache, {misses} compiled ({active_cache_dir()})"
