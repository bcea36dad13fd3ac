"""An install that leaves nothing behind: fastdet in a fresh virtual environment.

The README's set-up commands run ``pip install .`` and later
``pip install -e '.[test]'`` in the same environment.  Compiled kernels once
went into ``site-packages/fastdet/kernels/__pycache__``, which pip's uninstall
does not know, so the leftover folder shadowed the editable install as a
namespace package.  These steps, in a new environment, pin that down:
install the wheel, detect (which compiles and caches the kernels), check that
nothing was written inside the installed package, uninstall, check that no
file of fastdet is left, then install in editable mode and import fastdet
from outside the checkout.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def run(command, cwd=None, env=None, timeout=900):
    """Run ``command``; fail the test with its output when it fails."""
    result = subprocess.run([str(part) for part in command], cwd=cwd, env=env,
                            capture_output=True, text=True, timeout=timeout)
    if result.returncode != 0:
        pytest.fail(f"{' '.join(map(str, command))} exited {result.returncode}:\n"
                    f"{result.stdout[-3000:]}\n{result.stderr[-3000:]}", pytrace=False)
    return result.stdout


def site_packages(python):
    return Path(run([python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"])
                .strip())


def recorded_files(python, site):
    """Files pip's RECORD lists for the installed fastdet, as absolute paths."""
    info = next(site.glob("fastdet-*.dist-info"))
    rows = (info / "RECORD").read_text().splitlines()
    return {(site / row.split(",")[0]).resolve() for row in rows if row}


def test_install_detect_uninstall_editable(tmp_path, data_dir):
    venv = tmp_path / "venv"
    run([sys.executable, "-m", "venv", venv])
    python = venv / "bin" / "python"
    env = {key: value for key, value in os.environ.items()
           if not key.startswith(("NUMBA_", "FASTDET_CACHE", "PYTHON"))}
    env["FASTDET_DATA"] = str(Path(data_dir).resolve())
    # The kernels' cache goes to the user's cache folder: here one of the test's own.
    env["XDG_CACHE_HOME"] = str(tmp_path / "user-cache")
    outside = tmp_path / "elsewhere"
    outside.mkdir()
    pip = [python, "-m", "pip", "install", "--quiet", "--disable-pip-version-check"]

    run(pip + [REPO], env=env)
    site = site_packages(python)
    image = Path(data_dir).resolve() / "test_images" / "test1.jpg"
    output = run([venv / "bin" / "fastdet", "detect", image], cwd=outside, env=env)
    assert '"boxes": [{"box"' in output

    installed = {p.resolve() for p in (site / "fastdet").rglob("*") if p.is_file()}
    assert installed, "fastdet is not in site-packages"
    written = installed - recorded_files(python, site)
    assert written == set(), f"files written inside the installed package: {sorted(written)}"
    cached = list((tmp_path / "user-cache" / "fastdet" / "kernels").rglob("*.nbi"))
    assert cached, "no compiled kernel was cached in the user's cache folder"

    run([python, "-m", "pip", "uninstall", "--yes", "fastdet"], env=env)
    left = [p for p in site.iterdir() if p.name.lower().startswith("fastdet")]
    assert left == [], f"left in site-packages after uninstall: {left}"

    run(pip + ["--no-deps", "-e", REPO], env=env)
    where = run([python, "-c", "import fastdet, fastdet.kernels.blocks; print(fastdet.__file__)"],
                cwd="/", env=env)
    assert Path(where.strip()) == REPO / "fastdet" / "__init__.py"
