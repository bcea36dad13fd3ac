"""The kernel compile's plan: the order two processes share the families in, their claims,
the "nothing cached" check, the helper the fastdet command starts before its imports."""

import hashlib
import json
import os
import subprocess
import sys
import tempfile
import threading
from pathlib import Path

import pytest

from fastdet import compile_ahead
from fastdet.compile_ahead import (
    COMPILE_WEIGHTS,
    DETECTION_FAMILIES,
    FamilyClaims,
    compile_order,
    nothing_cached,
)


def test_compile_order_is_heaviest_first():
    order = compile_order(DETECTION_FAMILIES)
    assert sorted(order) == sorted(DETECTION_FAMILIES)
    weights = [COMPILE_WEIGHTS[name] for name in order]
    assert weights == sorted(weights, reverse=True) and weights[0] > weights[-1]
    # Unmeasured families weigh 1 s; equal weights go by name, so both
    # processes walk the same list.
    assert compile_order(["zz", "label", "aa", "convert"]) == ["label", "aa", "zz", "convert"]
    assert compile_order([]) == []


def test_each_family_is_claimed_once(tmp_path):
    mine = FamilyClaims()
    theirs = FamilyClaims(mine.folder)     # the helper's side of the same claims
    names = [f"family{k}" for k in range(50)]
    won = {id(mine): [], id(theirs): []}
    lock = threading.Lock()

    def take(claims):
        for name in names:
            if claims.claim(name):
                with lock:
                    won[id(claims)].append(name)

    threads = [threading.Thread(target=take, args=(claims,)) for claims in (mine, theirs) * 4]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert sorted(won[id(mine)] + won[id(theirs)]) == sorted(names)
    assert not mine.claim("family0") and not theirs.claim("family0")
    theirs.remove()                        # not its folder: kept
    assert os.path.isdir(mine.folder)
    mine.remove()
    assert not os.path.exists(mine.folder)
    assert not theirs.claim("new")         # claims gone: the helper takes nothing more


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
claims = compile_ahead._early["claims"].folder
if sys.argv[1] == "take":
    helper, names, taken_claims = compile_ahead.take_early(["resize", "heat"])
    out, _ = helper.communicate(timeout=900)
    taken_claims.remove()
    taken = {"names": names, "code": helper.returncode,
             "report": json.loads(out.decode().strip().splitlines()[-1])}
    assert compile_ahead.take_early(list(compile_ahead.DETECTION_FAMILIES)) is None
print(json.dumps({"started": started, "again": again, "unrelated": unrelated,
                  "taken": taken, "claims": claims, "pid": compile_ahead._early["helper"].pid
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
def test_the_early_helper_compiles_what_the_taker_leaves(tmp_path):
    # The taker needs two of the families and compiles none itself here: the
    # helper compiles both, skipping the rest, which the taker claimed.
    result = _run_early(tmp_path, "take", 900)
    assert result["started"] == compile_order(DETECTION_FAMILIES) and result["again"] == []
    assert result["unrelated"] is None
    assert result["taken"]["names"] == ["heat", "resize"] and result["taken"]["code"] == 0
    assert sorted(result["taken"]["report"]) == ["heat", "resize"]
    assert not os.path.exists(result["claims"])


@pytest.mark.skipif((os.cpu_count() or 1) < 2, reason="the helper starts on 2+ cores only")
def test_a_helper_nobody_took_is_stopped_at_exit(tmp_path):
    result = _run_early(tmp_path, "leave", 120)
    assert result["pid"] is not None
    with pytest.raises(ProcessLookupError):
        os.kill(result["pid"], 0)
    assert not os.path.exists(result["claims"])


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
    assert ("compiling kernels in two processes, each taking the next family as it finishes "
            "one (the second started before fastdet's imports)") in first.stderr
    second = subprocess.run(command, capture_output=True, text=True, env=env, timeout=900)
    assert second.returncode == 0, second.stderr[-3000:]
    assert "compiling kernels" not in second.stderr and ", 0 compiled" in second.stderr
    assert json.loads(first.stdout)["boxes"] == json.loads(second.stdout)["boxes"]


def test_no_early_helper_without_a_folder_for_its_claims(monkeypatch):
    monkeypatch.setattr(os, "cpu_count", lambda: 2)
    monkeypatch.setattr(compile_ahead, "nothing_cached", lambda: True)

    def no_folder():
        raise OSError("read-only /tmp")

    monkeypatch.setattr(compile_ahead, "FamilyClaims", no_folder)
    started = []
    monkeypatch.setattr(compile_ahead, "start_helper", lambda *args: started.append(args))
    assert compile_ahead.start_early() == [] and started == []
    assert compile_ahead.take_early(DETECTION_FAMILIES) is None


def test_no_early_helper_without_a_second_process(monkeypatch):
    monkeypatch.setattr(os, "cpu_count", lambda: 2)
    monkeypatch.setattr(compile_ahead, "nothing_cached", lambda: True)
    folders = []

    def no_process(names, claims):
        folders.append(claims.folder)
        raise OSError("no processes left")

    monkeypatch.setattr(compile_ahead, "start_helper", no_process)
    assert compile_ahead.start_early() == []
    assert len(folders) == 1 and not os.path.exists(folders[0])
    assert compile_ahead.take_early(DETECTION_FAMILIES) is None


def test_a_relative_cache_folder_is_made_absolute(tmp_path, monkeypatch):
    """NUMBA_CACHE_DIR is exported from it: a child started in another folder read it there."""
    from fastdet.compile_ahead import CACHE_ENV_VAR, cache_base

    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv(CACHE_ENV_VAR, "relative/cache")
    assert cache_base() == tmp_path / "relative" / "cache" / "kernels"
    assert cache_base().is_absolute()


def test_claims_of_a_killed_process_are_removed_by_the_next_cold_start(tmp_path, monkeypatch):
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    # A process that made its claims and was killed outright (no atexit).
    killed = subprocess.Popen([sys.executable, "-c",
                               "import os, sys, time; from fastdet.compile_ahead import "
                               "FamilyClaims; c = FamilyClaims(); c.claim('label'); "
                               "print(c.folder, flush=True); time.sleep(60)"],
                              stdout=subprocess.PIPE, text=True,
                              env=dict(os.environ, TMPDIR=str(tmp_path)))
    abandoned = Path(killed.stdout.readline().strip())
    assert abandoned.parent == tmp_path and (abandoned / "label").exists()
    assert abandoned.name.startswith(f"fastdet-compile-{killed.pid}-")
    running = FamilyClaims()                     # this process's: its maker runs
    killed.kill()
    killed.wait()
    killed.stdout.close()
    unrelated = tmp_path / "fastdet-compile-notapid-x"
    unrelated.mkdir()
    assert abandoned.exists()
    fresh = FamilyClaims()                       # the next cold start
    assert not abandoned.exists()
    assert os.path.isdir(running.folder) and os.path.isdir(fresh.folder) and unrelated.is_dir()
    running.remove()
    fresh.remove()
