"""Shared fixtures: the data set (via FASTDET_DATA) and small synthetic inputs."""

import sys
from pathlib import Path

import pytest

# Tests import their naive references as ``from naive import ...``.
sys.path.insert(0, str(Path(__file__).parent))

from fastdet.files.shared_data import data_dir as _data_dir  # noqa: E402


@pytest.fixture(scope="session")
def data_dir():
    """The shared data folder; a missing folder fails the test loudly."""
    try:
        return _data_dir()
    except Exception as exc:  # noqa: BLE001 - turned into a test failure
        pytest.fail(str(exc), pytrace=False)


# -- Hypothesis profiles -----------------------------------------------------
# "ci" (the default) keeps every fuzz target to a few dozen examples, the
# same ones every run (derandomized: a CI failure reproduces); "long"
# explores, with fresh random examples each run:
#     python -m pytest tests/fuzz --hypothesis-profile=long
# (the option of Hypothesis's pytest plugin, which loads the profile after
# this file has chosen the default).  Deadlines are off: the first example of
# a target may compile kernels, and the machine is shared.
from hypothesis import HealthCheck, settings  # noqa: E402

settings.register_profile("ci", max_examples=30, deadline=None, print_blob=True,
                          derandomize=True,
                          suppress_health_check=[HealthCheck.too_slow,
                                                 HealthCheck.data_too_large])
settings.register_profile("long", parent=settings.get_profile("ci"), max_examples=3000,
                          derandomize=False)
settings.load_profile("ci")
