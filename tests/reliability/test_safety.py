"""No input makes fastdet run code or write outside the paths it was given."""

from __future__ import annotations

import io
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from fastdet.cli.app import EXIT_ERROR, main
from fastdet.errors import ModelError
from fastdet.detector.model import load_model


class TouchOnUnpickle:
    """An object whose unpickling would create a file: the canary of code execution."""

    def __init__(self, marker):
        self.marker = marker

    def __reduce__(self):
        return (Path.touch, (Path(self.marker),))


def test_a_model_holding_a_pickle_is_refused_unexecuted(tmp_path):
    marker = tmp_path / "executed"
    for member in ("weights", "metadata"):
        buffer = io.BytesIO()
        payload = np.array([TouchOnUnpickle(marker)], dtype=object)
        other = np.zeros(3, np.float32) if member == "metadata" else np.zeros(3, np.uint8)
        np.savez(buffer, **{member: payload,
                            ("metadata" if member == "weights" else "weights"): other})
        path = tmp_path / f"{member}.npz"
        path.write_bytes(buffer.getvalue())
        with pytest.raises(ModelError, match=str(path)):
            load_model(path)
    assert not marker.exists(), "loading a model ran code"


def test_detect_out_dir_keeps_outputs_inside(tmp_path, data_dir, capsys):
    # An image reached through '..' and a name that looks like a path: the
    # drawn image is the base name, inside --out-dir.
    images = tmp_path / "images" / "sub"
    images.mkdir(parents=True)
    shutil.copy(data_dir / "test_images" / "test1.jpg", images.parent / "a.jpg")
    out = tmp_path / "out"
    assert main(["detect", str(images / ".." / "a.jpg"), "--out-dir", str(out)]) == 0
    record = json.loads(capsys.readouterr().out.splitlines()[-1])
    assert Path(record["output"]) == out / "a.jpg"
    assert sorted(p.name for p in out.iterdir()) == ["a.jpg"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["images", "out"]


def test_detect_out_dir_refuses_a_planted_symlink(tmp_path, data_dir, capsys):
    out = tmp_path / "out"
    out.mkdir()
    victim = tmp_path / "victim.txt"
    victim.write_text("precious")
    (out / "test1.jpg").symlink_to(victim)
    assert main(["detect", str(data_dir / "test_images" / "test1.jpg"),
                 "--out-dir", str(out)]) == EXIT_ERROR
    assert "symbolic link" in capsys.readouterr().err
    assert victim.read_text() == "precious"
