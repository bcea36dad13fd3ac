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


def _python_would_use(source):
    """Python's own verdict on ``source``'s ``.pyc`` (importlib's validators), for comparison."""
    from importlib import _bootstrap_external as external

    data = _compiled(source).read_bytes()
    try:
        flags = external._classify_pyc(data, source.name, {})
        if flags & 0b1:
            if flags & 0b10:
                external._validate_hash_pyc(
                    data, importlib.util.source_hash(source.read_bytes()), source.name, {})
        else:
            info = source.stat()
            external._validate_timestamp_pyc(data, int(info.st_mtime), info.st_size, source.name, {})
    except ImportError:
        return False
    return True


def test_hash_based_pyc_files_are_judged_by_their_hash(tmp_path):
    # pip and compileall write these under SOURCE_DATE_EPOCH (reproducible builds).
    package = _package(tmp_path)
    checked = package / "a.py"
    unchecked = package / "sub" / "b.py"
    for source in package.rglob("*.py"):
        mode = (py_compile.PycInvalidationMode.UNCHECKED_HASH if source == unchecked
                else py_compile.PycInvalidationMode.CHECKED_HASH)
        py_compile.compile(str(source), invalidation_mode=mode, doraise=True)
    assert stale_modules(package) == []
    # Same size, another time stamp: still the same hash.
    later = checked.stat().st_mtime + 10
    os.utime(checked, (later, later))
    assert stale_modules(package) == []
    checked.write_text("VALUE = 2\n")
    unchecked.write_text("VALUE = 3\n")
    # Python checks the one hash and not the other.
    assert stale_modules(package) == [checked]
    for source in package.rglob("*.py"):
        assert _python_would_use(source) == (source not in stale_modules(package))


def test_under_source_date_epoch_each_module_is_compiled_once(tmp_path, monkeypatch):
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "1700000000")
    package = _package(tmp_path)
    assert compile_package(package)["compiled"] == 4
    flags = {int.from_bytes(_compiled(p).read_bytes()[4:8], "little") for p in package.rglob("*.py")}
    assert flags == {0b11}
    assert compile_package(package)["compiled"] == 0
    assert all(_python_would_use(p) for p in package.rglob("*.py"))


def test_pyc_files_of_another_python_are_stale(tmp_path):
    package = _package(tmp_path)
    compile_package(package)
    foreign = package / "a.py"
    data = bytearray(_compiled(foreign).read_bytes())
    data[0] ^= 0xFF
    _compiled(foreign).write_bytes(bytes(data))
    assert stale_modules(package) == [foreign]
    assert not _python_would_use(foreign)
    assert compile_package(package)["compiled"] == 1
    assert _python_would_use(foreign)
