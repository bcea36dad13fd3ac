"""Byte-compiling fastdet's modules once (``fastdet warmup``, the start-up benchmark)."""

import importlib.util
import os
import py_compile
from pathlib import Path

from fastdet.cli import main
from fastdet.files.bytecode import compile_package, stale_modules


def _package(root):
    package = root / "pkg"
    (package / "sub").mkdir(parents=True)
    for name in ("__init__.py", "a.py", "sub/__init__.py", "sub/b.py"):
        (package / name).write_text("VALUE = 1\n")
    return package


def _compiled(source):
    return Path(importlib.util.cache_from_source(str(source)))


def test_writes_missing_pyc_files_once(tmp_path, monkeypatch):
    # Written even where Python itself would not write them.
    monkeypatch.setenv("PYTHONDONTWRITEBYTECODE", "1")
    package = _package(tmp_path)
    assert len(stale_modules(package)) == 4
    first = compile_package(package)
    assert first["compiled"] == 4 and first["ok"]
    assert all(_compiled(p).is_file() for p in package.rglob("*.py"))
    assert stale_modules(package) == []
    assert compile_package(package)["compiled"] == 0


def test_an_edited_module_is_compiled_again(tmp_path):
    package = _package(tmp_path)
    compile_package(package)
    edited = package / "sub" / "b.py"
    edited.write_text("VALUE = 22\n")
    # Another second stamped on it: the .pyc records whole seconds.
    later = edited.stat().st_mtime + 10
    os.utime(edited, (later, later))
    assert stale_modules(package) == [edited]
    assert compile_package(package)["compiled"] == 1


def test_a_read_only_installation_is_reported_not_raised(tmp_path, monkeypatch):
    package = _package(tmp_path)

    def refuse(*args, **kwargs):
        raise PermissionError(13, "Permission denied")

    # Root writes into read-only folders, so the refusal is what a user's install would say.
    monkeypatch.setattr(py_compile, "compile", refuse)
    figures = compile_package(package)
    assert figures["ok"] is False and figures["compiled"] == 4
    assert len(stale_modules(package)) == 4


def test_warmup_byte_compiles_fastdet(capsys):
    assert main(["warmup", "--families", "heat", "--processes", "1"]) == 0
    out = capsys.readouterr().out
    assert "python modules: " in out
    assert stale_modules(Path(__file__).resolve().parents[2] / "fastdet") == []
