"""Compiled kernels: where Numba caches them, the word a command says when it compiles, and
``quatmotion warm-up`` (issue 17, item 8).

Numba compiles a kernel once per cache; a cold cache is the first run of a new install. The
tests that need a cold cache give a subprocess an empty ``NUMBA_CACHE_DIR`` and run commands
whose kernels compile in seconds (reading a file, forward kinematics).
"""

from __future__ import annotations

import importlib
import os
import pkgutil
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

import quatmotion
from quatmotion import _jit, warmup
from quatmotion.cli import app
from quatmotion.io import write_motion
from quatmotion.synthetic import generate_clip

COMPILING = "compiling kernels, once"


def _quatmotion(*args: object, cache: Path, cwd: Path) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, _jit.CACHE_ENV: str(cache)}
    return subprocess.run(
        [sys.executable, "-c", "from quatmotion.cli import main; main()", *map(str, args)],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )


# --- where the cache is ----------------------------------------------------------------------


def test_the_users_numba_cache_dir_is_kept(tmp_path: Path) -> None:
    env = {_jit.CACHE_ENV: str(tmp_path / "mine")}
    assert _jit.configure_cache(env, package_dir=tmp_path / "pkg") == str(tmp_path / "mine")
    assert env[_jit.CACHE_ENV] == str(tmp_path / "mine")


def test_a_writable_package_keeps_numbas_own_cache_beside_its_modules(tmp_path: Path) -> None:
    env: dict[str, str] = {}
    assert _jit.configure_cache(env, package_dir=tmp_path / "pkg") is None
    assert _jit.CACHE_ENV not in env


def test_a_read_only_install_caches_in_a_per_user_folder(tmp_path: Path) -> None:
    # A package folder that cannot hold __pycache__ (here: under a file, so that the test
    # holds when run as root, whom permission bits do not stop).
    blocker = tmp_path / "read-only"
    blocker.write_text("")
    env = {"XDG_CACHE_HOME": str(tmp_path / "home-cache")}
    chosen = _jit.configure_cache(env, package_dir=blocker / "quatmotion")
    if sys.platform.startswith("linux"):
        assert chosen == str(tmp_path / "home-cache" / "quatmotion" / "numba")
    assert chosen is not None and env[_jit.CACHE_ENV] == chosen
    assert Path(chosen).is_dir()
    # and when even the user's cache folder cannot be written: the temporary folder
    env = {"XDG_CACHE_HOME": str(blocker / "cache")}
    chosen = _jit.configure_cache(env, package_dir=blocker / "quatmotion")
    assert chosen is not None and chosen.startswith(str(Path(os.environ.get("TMPDIR", "/tmp"))))


def test_the_cache_folder_reaches_pool_workers(tmp_path: Path) -> None:
    # The environment is how the fork server and its workers learn the folder.
    done = subprocess.run(
        [
            sys.executable,
            "-c",
            "import os, quatmotion\n"
            "from quatmotion.parallel import run_batch\n"
            "print(run_batch(os.getenv, ['NUMBA_CACHE_DIR'] * 2, workers=2).results)",
        ],
        env={**os.environ, _jit.CACHE_ENV: str(tmp_path)},
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == repr([str(tmp_path)] * 2)


# --- saying so once -------------------------------------------------------------------------


def test_a_command_says_once_that_it_compiles_and_not_when_the_cache_has_them(
    tmp_path: Path,
) -> None:
    clip = tmp_path / "walk.bvh"
    write_motion(generate_clip("walk", seed=1, n_frames=30, fps=30.0), clip)
    cache = tmp_path / "cache"
    cold = _quatmotion("info", clip, cache=cache, cwd=tmp_path)
    assert cold.returncode == 0, cold.stderr
    assert cold.stderr.count(COMPILING) == 1, cold.stderr  # several kernels, one line
    assert str(cache) in cold.stderr
    warm = _quatmotion("info", clip, cache=cache, cwd=tmp_path)
    assert warm.returncode == 0, warm.stderr
    assert COMPILING not in warm.stderr
    assert warm.stdout == cold.stdout


# --- warm-up --------------------------------------------------------------------------------


def test_every_module_with_cached_kernels_is_warmed_up() -> None:
    from numba.core.dispatcher import Dispatcher

    found = set()
    for info in pkgutil.walk_packages(quatmotion.__path__, "quatmotion."):
        if info.name.startswith(("quatmotion.cli", "quatmotion.bench", "quatmotion.server")):
            continue
        module = importlib.import_module(info.name)
        for value in vars(module).values():
            if isinstance(value, Dispatcher) and value.py_func.__module__ == info.name:
                found.add(info.name)
    assert found == set(warmup.KERNEL_MODULES)


def test_the_warm_up_calls_every_cached_kernel() -> None:
    # In a fresh process (kernels this test process ran would count otherwise): after the
    # warm-up every kernel has a compiled or loaded signature, or is called by one that has (a
    # kernel loaded from the cache brings its callees' code; on a cold cache they compile on
    # their own); inlined helpers have none of their own: they are compiled into their callers.
    code = (
        "from quatmotion import warmup\n"
        "warmup.warm_up(workers=1)\n"  # every group in this process, to look at its kernels
        "kernels = warmup.cached_kernels()\n"
        "by_name = {k.__name__: k for k in kernels}\n"
        "todo = [k for k in kernels if k.signatures]\n"
        "ran, called = len(todo), set()\n"
        "while todo:\n"  # the kernels reached from those that ran, callees of callees too
        "    for name in todo.pop().py_func.__code__.co_names:\n"
        "        if name in by_name and name not in called:\n"
        "            called.add(name)\n"
        "            todo.append(by_name[name])\n"
        "for k in kernels:\n"
        "    if k.targetoptions.get('inline', 'never') != 'never' or k.signatures:\n"
        "        continue\n"
        "    if k.__name__ not in called:\n"
        "        print('never ran:', k.py_func.__module__, k.__name__)\n"
        "print('kernels', len(kernels), 'ran', ran)\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stderr[-3000:]
    assert "never ran" not in done.stdout, done.stdout
    assert "kernels" in done.stdout


def test_groups_are_stale_until_warmed_and_again_when_a_kernel_changes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(warmup, "_stamp", lambda group: tmp_path / f"{group}.json")
    assert warmup.stale_groups(["read"]) == ["read"]
    reports = warmup.warm_up(["read"])
    assert [r.group for r in reports] == ["read"]
    assert warmup.stale_groups(["read", "pose"]) == ["pose"]
    monkeypatch.setattr(warmup, "cache_key", lambda: "another numba, cpu or kernel source")
    assert warmup.stale_groups(["read"]) == ["read"]
    with pytest.raises(ValueError, match="unknown warm-up group"):
        warmup.stale_groups(["everything"])


def test_groups_compile_side_by_side_and_report_each(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # The stamps go to tmp_path; the kernels stay in the cache (the workers' too).
    monkeypatch.setattr(warmup, "_stamp", lambda group: tmp_path / f"{group}.json")
    seen: list[str] = []
    reports = warmup.warm_up(
        ["codec", "retrieval"], workers=2, report=lambda r: seen.append(r.group)
    )
    assert sorted(r.group for r in reports) == sorted(seen) == ["codec", "retrieval"]
    assert all(r.seconds > 0 for r in reports)
    # read ran first, here, and is stamped too; the two groups ran in workers
    assert warmup.stale_groups() == ["learn", "pose"]


def test_a_batch_on_the_pool_compiles_its_groups_first_and_says_so_once(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from quatmotion.cli import _kernels as cli_kernels

    calls: list[list[str]] = []

    def fake_warm_up(groups, report=None):  # the real one is tested above
        calls.append(list(groups))
        return []

    monkeypatch.setattr(warmup, "_stamp", lambda group: tmp_path / "no stamps yet" / group)
    monkeypatch.setattr(warmup, "warm_up", fake_warm_up)
    monkeypatch.setattr(cli_kernels, "_said", False)
    clips = [tmp_path / "walk.bvh"]
    write_motion(generate_clip("walk", seed=1, n_frames=30, fps=30.0), clips[0])
    runner = CliRunner()
    pool = runner.invoke(app, ["compress", *map(str, clips), "-o", str(tmp_path / "a.qmz")])
    assert pool.exit_code == 0, pool.output
    assert calls == [["read", "codec"]]
    assert pool.stderr.count(COMPILING) == 1
    inline = runner.invoke(
        app, ["compress", *map(str, clips), "-o", str(tmp_path / "b.qmz"), "--workers", "1"]
    )
    assert inline.exit_code == 0, inline.output
    assert calls == [["read", "codec"]]  # in this process: it compiles what it runs


def test_warm_up_says_what_it_did_and_nothing_to_do_when_warm(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv(_jit.CACHE_ENV, str(tmp_path))
    runner = CliRunner()
    monkeypatch.setattr(warmup, "stale_groups", lambda groups=warmup.GROUPS: [])
    done = runner.invoke(app, ["warm-up"])
    assert done.exit_code == 0, done.output
    assert "kernels compiled already" in done.stdout and str(tmp_path) in done.stdout

    def fake_warm_up(groups, report=None):
        out = [warmup.GroupReport(g, 1.5, 3 if g == "read" else 0, 2) for g in groups]
        for r in out:
            report(r)
        return out

    monkeypatch.setattr(warmup, "warm_up", fake_warm_up)
    done = runner.invoke(app, ["warm-up", "--again"])
    assert done.exit_code == 0, done.output
    lines = done.stdout.splitlines()
    assert lines[0].startswith(COMPILING)
    assert any(warmup.GROUPS["read"] in line and "3 compiled" in line for line in lines)
    assert any(warmup.GROUPS["pose"] in line and "all from the cache" in line for line in lines)
    assert lines[-1].startswith("kernels ready in") and "3 compiled" in lines[-1]


def test_listening_for_compiles_does_not_import_numba_until_something_does() -> None:
    # the notice is installed lazily: a command that runs no kernel never imports Numba
    code = (
        "import sys\n"
        "from quatmotion import _jit\n"
        "_jit.on_first_compile(lambda: print('compiling'))\n"
        "assert 'numba' not in sys.modules\n"
        "import numba\n"
        "assert _jit._listener_installed\n"
        "import types\n"
        "m = types.ModuleType('quatmotion.fake_kernels')\n"
        "exec('def f(x):\\n    return x + 1\\n', m.__dict__)\n"
        "sys.modules[m.__name__] = m\n"
        "f = numba.njit(m.f)\n"
        "f(1); f(2)\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert done.stdout.splitlines() == ["compiling"]
