"""The kernel compile's plan: the split over two processes, the "nothing cached" check, the
helper the fastdet command starts before its imports."""

import hashlib
import itertools
import json
import os
import subprocess
import sys

import pytest

from fastdet import compile_ahead
from fastdet.compile_ahead import (
    COMPILE_WEIGHTS,
    DETECTION_FAMILIES,
    SHARED_SECONDS,
    group_seconds,
    nothing_cached,
    split_families,
)

#: The helper's families for a detection on a cold cache, as start_early splits them.
EARLY_HELPER = split_families(DETECTION_FAMILIES, compile_ahead.EARLY_HELPER_START_SECONDS)[1]


def _end(here, helper, start):
    return max(group_seconds(here), start + group_seconds(helper))


def test_group_seconds_counts_the_shared_part_once():
    assert group_seconds([]) == 0
    assert group_seconds(["label"]) == COMPILE_WEIGHTS["label"]
    assert group_seconds(["label", "hog"]) == pytest.approx(
        COMPILE_WEIGHTS["label"] + COMPILE_WEIGHTS["hog"] - SHARED_SECONDS)
    assert group_seconds(["never-measured"]) == 1.0


@pytest.mark.parametrize("names", [DETECTION_FAMILIES, tuple(COMPILE_WEIGHTS),
                                   ("label", "heat"), ("convert",), ()])
@pytest.mark.parametrize("start", [0.0, 0.8, 3.0])
def test_the_split_ends_soonest(names, start):
    here, helper = split_families(names, start)
    assert sorted(here + helper) == sorted(names)
    best = _end(here, helper, start)
    # Checked against every split, enumerated here in another way.
    for size in range(len(names) + 1):
        for other in itertools.combinations(names, size):
            rest = [name for name in names if name not in other]
            assert best <= _end(rest, list(other), start) + 1e-9


def test_a_helper_that_starts_later_gets_less():
    early = split_families(DETECTION_FAMILIES, 0.0)[1]
    late = split_families(DETECTION_FAMILIES, compile_ahead.HELPER_START_SECONDS)[1]
    assert group_seconds(late) < group_seconds(early)
    # Both leave the two processes less than the lightest family apart.
    for start, (here, helper) in ((0.0, split_families(DETECTION_FAMILIES, 0.0)),
                                  (0.8, split_families(DETECTION_FAMILIES, 0.8))):
        gap = abs(group_seconds(here) - start - group_seconds(helper))
        assert gap < min(COMPILE_WEIGHTS[name] for name in DETECTION_FAMILIES)


def test_nothing_cached_with_a_numba_cache_dir(tmp_path, monkeypatch):
    folder = tmp_path / "cache"
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(folder))
    assert nothing_cached()            # missing: created, writable
    assert folder.is_dir()
    (folder / "someone_elses_kernels_0123").mkdir()
    assert nothing_cached()            # another package's entries do not count
    kernels = os.path.join(os.path.dirname(compile_ahead.__file__), "kernels")
    (folder / ("kernels_" + hashlib.sha1(kernels.encode()).hexdigest())).mkdir()
    assert not nothing_cached()


def test_nothing_cached_in_the_user_cache(tmp_path, monkeypatch):
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    monkeypatch.setenv(compile_ahead.CACHE_ENV_VAR, str(tmp_path / "user"))
    assert nothing_cached()
    kernels = tmp_path / "user" / "kernels"
    (kernels / "fastdet-0.0.1-numba-0.1-other").mkdir()      # another fastdet version
    assert nothing_cached()
    (kernels / (compile_ahead.CACHE_KEY_PREFIX + "0.1-someCPU-abc")).mkdir()
    assert not nothing_cached()        # this version, maybe another CPU: not sure, so not cold


def test_an_unwritable_cache_counts_as_cached(tmp_path, monkeypatch):
    # A helper there would compile into a folder of its own, lost to this process.
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(blocker / "cache"))
    assert not nothing_cached()
    monkeypatch.delenv("NUMBA_CACHE_DIR")
    monkeypatch.setenv(compile_ahead.CACHE_ENV_VAR, str(blocker))
    assert not nothing_cached()


def test_nothing_cached_knows_where_numba_files_the_kernels(tmp_path):
    """After a real compile into the folder, the check (which names Numba's
    subfolder without Numba) says cached."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    check = [sys.executable, "-c", "from fastdet.compile_ahead import nothing_cached; "
             "print(nothing_cached())"]
    before = subprocess.run(check, capture_output=True, text=True, env=env, timeout=120)
    assert before.stdout.strip() == "True", before.stderr[-2000:]
    compiled = subprocess.run([sys.executable, "-m", "fastdet.kernels.warmup", "convert"],
                              capture_output=True, text=True, env=env, timeout=900)
    assert compiled.returncode == 0, compiled.stderr[-2000:]
    after = subprocess.run(check, capture_output=True, text=True, env=env, timeout=120)
    assert after.stdout.strip() == "False", after.stderr[-2000:]


def test_start_early_needs_two_cores_and_an_empty_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setattr(os, "cpu_count", lambda: 1)
    assert compile_ahead.start_early() == []
    monkeypatch.setattr(os, "cpu_count", lambda: 2)
    monkeypatch.setattr(compile_ahead, "nothing_cached", lambda: False)
    assert compile_ahead.start_early() == []
    assert compile_ahead.take_early(DETECTION_FAMILIES) is None


_EARLY = r"""
import json, os, sys
from fastdet import compile_ahead
started = compile_ahead.start_early()
again = compile_ahead.start_early()          # one helper per process
unrelated = compile_ahead.take_early(["no-such-family"])
taken = None
if sys.argv[1] == "take":
    helper, names = compile_ahead.take_early(list(compile_ahead.DETECTION_FAMILIES))
    out, _ = helper.communicate(timeout=900)
    taken = {"names": names, "code": helper.returncode,
             "report": json.loads(out.decode().strip().splitlines()[-1])}
    assert compile_ahead.take_early(list(compile_ahead.DETECTION_FAMILIES)) is None
print(json.dumps({"started": started, "again": again, "unrelated": unrelated,
                  "taken": taken, "pid": compile_ahead._early["helper"].pid
                  if compile_ahead._early["helper"] else None}))
"""


def _run_early(tmp_path, mode, timeout):
    """The report of :data:`_EARLY` run in a fresh process on an empty cache."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    done = subprocess.run([sys.executable, "-c", _EARLY, mode], capture_output=True,
                          text=True, env=env, timeout=timeout)
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


@pytest.mark.skipif((os.cpu_count() or 1) < 2, reason="the helper starts on 2+ cores only")
def test_the_early_helper_compiles_its_share_once(tmp_path):
    result = _run_early(tmp_path, "take", 900)
    assert result["started"] == EARLY_HELPER and result["again"] == []
    assert result["unrelated"] is None
    assert result["taken"]["names"] == EARLY_HELPER and result["taken"]["code"] == 0
    assert sorted(result["taken"]["report"]) == sorted(EARLY_HELPER)


@pytest.mark.skipif((os.cpu_count() or 1) < 2, reason="the helper starts on 2+ cores only")
def test_a_helper_nobody_took_is_stopped_at_exit(tmp_path):
    pid = _run_early(tmp_path, "leave", 120)["pid"]
    assert pid is not None
    with pytest.raises(ProcessLookupError):
        os.kill(pid, 0)


@pytest.mark.parametrize("argv, starts", [
    (["detect", "x.jpg"], True),
    (["-v", "run", "clip.mp4"], True),
    (["--debug", "eval", "a.json", "images"], True),
    (["detect", "--help"], False),
    (["train", "data"], False),
    (["warmup"], False),
    ([], False),
])
def test_the_command_starts_early_only_for_detecting_verbs(argv, starts, monkeypatch):
    import fastdet.cli as cli

    calls = []
    monkeypatch.setattr(compile_ahead, "start_early", lambda: calls.append(True) or [])
    cli._compile_ahead(argv)
    assert bool(calls) == starts


@pytest.mark.skipif((os.cpu_count() or 1) < 2, reason="the helper starts on 2+ cores only")
def test_a_cold_fastdet_detect_compiles_with_the_early_helper(tmp_path, data_dir):
    """The whole command on an empty cache: the helper started before the imports
    compiles its share, the detection is the usual one, a second run compiles nothing."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    command = [sys.executable, "-c", "import sys; from fastdet.cli import console_main; "
               "console_main(sys.argv[1:])", "-v", "detect",
               str(data_dir / "test_images" / "test1.jpg")]
    first = subprocess.run(command, capture_output=True, text=True, env=env, timeout=900)
    assert first.returncode == 0, first.stderr[-3000:]
    assert (f"compiling kernels in two processes: {', '.join(EARLY_HELPER)} in a second one, "
            "started before fastdet's imports") in first.stderr
    second = subprocess.run(command, capture_output=True, text=True, env=env, timeout=900)
    assert second.returncode == 0, second.stderr[-3000:]
    assert "compiling kernels" not in second.stderr and ", 0 compiled" in second.stderr
    assert json.loads(first.stdout)["boxes"] == json.loads(second.stdout)["boxes"]
