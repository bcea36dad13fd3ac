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
