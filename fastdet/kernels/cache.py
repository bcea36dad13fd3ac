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
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import llvmlite.binding as llvm
import numba
from platformdirs import user_cache_dir

from .._version import __version__

#: Overrides the user cache folder (the kernels go in its ``kernels/`` subfolder).
CACHE_ENV_VAR = "FASTDET_CACHE_DIR"

#: First-run compile time of the kernels a detection needs (two processes,
#: see ``fastdet.kernels.warmup``), measured on the development machine;
#: what the first run announces (see ``fastdet.cli.common``).
TYPICAL_COMPILE_SECONDS = 15


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
    return f"fastdet-{__version__}-numba-{numba.__version__}-{name}-{digest}"


def kernel_cache_dir():
    """The folder compiled kernels are cached in (see the module notes)."""
    if os.environ.get("NUMBA_CACHE_DIR"):
        return Path(os.environ["NUMBA_CACHE_DIR"])
    base = os.environ.get(CACHE_ENV_VAR) or user_cache_dir("fastdet", appauthor=False)
    return Path(base) / "kernels" / cache_key()


def configure():
    """Point Numba's cache at :func:`kernel_cache_dir`; call before any kernel is defined.

    Numba picks a function's cache folder when its ``@njit(cache=True)``
    decorator runs; the environment variable is set as well so that Numba's
    reloads of its configuration, and processes started from this one,
    keep the same folder.
    """
    path = str(kernel_cache_dir())
    os.environ["NUMBA_CACHE_DIR"] = path
    numba.config.CACHE_DIR = path
    return Path(path)
