"""Tests of the execution layer: the same results in input order on every scheduler, a bad item
reported while the rest complete, a killed worker's item retried without loss or duplicate.

The Dask tests start a real ``distributed.LocalCluster`` (2 worker processes, loopback, free
ports) inside the test process and close it at the end.
"""

from __future__ import annotations

import os
import pathlib
import pickle
import signal
import socket
import subprocess
import sys
import textwrap
import threading
import time

import numpy as np
import pytest

from quatmotion.errors import FormatError
from quatmotion.parallel import (
    SCHEDULER_ENV,
    Runner,
    Scheduler,
    SchedulerError,
    imap_batch,
    resolve_scheduler,
    run_batch,
)

# --- job functions: module level, so that worker processes can unpickle them -----------------


def clip_features(seed: int) -> np.ndarray:
    """A deterministic stand-in for a clip job; earlier items take longer, so workers finish
    them in another order than the input's."""
    time.sleep(0.002 * (8 - seed % 8))
    rng = np.random.default_rng(seed)
    frames = rng.standard_normal((40 + seed % 7, 12))
    return frames @ frames.T  # BLAS, whose thread count the layer fixes


def features_or_format_error(arg: tuple[int, str]) -> int:
    seed, path = arg
    if path.endswith("bad.amc"):
        raise FormatError("frame 3 has 61 values, expected 62\nmore detail", path, line=7)
    return seed * seed


def die_on_first_attempt(arg: tuple[int, str, int]) -> int:
    """Kill this worker process the first time the victim item runs (a marker file says it
    ran), as the OOM killer or a crash in C code would."""
    seed, marker, victim = arg
    if seed == victim and not os.path.exists(marker):
        pathlib.Path(marker).touch()
        os.kill(os.getpid(), signal.SIGKILL)
    time.sleep(0.01)
    return seed * seed


def die_always(arg: tuple[int, int]) -> int:
    seed, victim = arg
    if seed == victim:
        os.kill(os.getpid(), signal.SIGKILL)
    time.sleep(0.01)
    return seed


def thread_counts(_item: object) -> list[int]:
    from threadpoolctl import threadpool_info

    return [info["num_threads"] for info in threadpool_info()]


class Model:
    """A stand-in for a shared model: counts, per process, how often it was unpickled."""

    loads = 0

    def __init__(self, scale: float) -> None:
        self.scale = scale
        self.table = np.arange(50_000, dtype=np.float64)  # large enough to matter per task

    def __setstate__(self, state: dict) -> None:
        Model.loads += 1
        self.__dict__.update(state)


def scaled_with_context(seed: int, model: Model) -> tuple[float, int, int, int]:
    """The item through the batch's context; which process and which copy ran it."""
    return seed * model.scale + model.table[seed], os.getpid(), id(model), Model.loads


def results_bytes(results: list) -> list[bytes]:
    # Each result pickled on its own: a pickled *list* also encodes which of its arrays share a
    # dtype object, which differs between arrays made here and arrays received from workers.
    return [pickle.dumps(r) for r in results]


# --- scheduler names -----------------------------------------------------------------------


def test_scheduler_names_resolve_and_the_environment_is_the_fallback() -> None:
    assert resolve_scheduler(workers=1, environ={}) == Scheduler("inline")
    assert resolve_scheduler(workers=3, environ={}) == Scheduler("processes", workers=3)
    assert resolve_scheduler(environ={}).n_workers >= 1
    dask = resolve_scheduler("127.0.0.1:8786", environ={})
    assert dask == Scheduler("dask", address="tcp://127.0.0.1:8786")
    assert resolve_scheduler("tls://[::1]:9000").address == "tls://[::1]:9000"
    from_env = resolve_scheduler(workers=1, environ={SCHEDULER_ENV: "tcp://head:8786"})
    assert from_env.address == "tcp://head:8786" and from_env.workers == 1
    # an explicit option wins over the environment
    explicit = resolve_scheduler("processes", environ={SCHEDULER_ENV: "tcp://head:8786"})
    assert explicit.kind == "processes"
    assert "2 processes" in Scheduler("processes", workers=2).describe()


@pytest.mark.parametrize(
    ("name", "expected"),
    [
        ("http://head:8786", "unsupported protocol 'http'"),
        ("tcp://head", "'tcp://head' is not HOST:PORT"),
        ("tcp://head:99999", "'tcp://head:99999' is not a scheduler address"),
        ("tcp://:8786", "is not HOST:PORT"),
        ("threads", "'threads' is not HOST:PORT"),
    ],
)
def test_bad_scheduler_addresses_are_named_in_one_line(name: str, expected: str) -> None:
    with pytest.raises(SchedulerError, match=expected) as info:
        resolve_scheduler(name)
    assert "\n" not in str(info.value)
    with pytest.raises(SchedulerError, match=f"{SCHEDULER_ENV} '{name}'"):
        resolve_scheduler(environ={SCHEDULER_ENV: name})


def test_bad_worker_counts_and_unpicklable_jobs_are_refused() -> None:
    with pytest.raises(SchedulerError, match="workers must be a positive integer, got 0"):
        run_batch(clip_features, [1], workers=0)
    with pytest.raises(SchedulerError, match="inline scheduler runs one item at a time"):
        run_batch(clip_features, [1], workers=2, scheduler="inline")
    with pytest.raises(TypeError, match="cannot be pickled"):
        run_batch(lambda x: x, [1], workers=2)
    with pytest.raises(ValueError, match="chunk_size"):
        run_batch(clip_features, [1], chunk_size=0)


def test_an_unreachable_dask_scheduler_is_a_clear_error() -> None:
    pytest.importorskip("distributed")
    with socket.socket() as probe:  # a free loopback port nothing listens on
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    address = f"tcp://127.0.0.1:{port}"
    start = time.perf_counter()
    with pytest.raises(SchedulerError, match=f"cannot reach the Dask scheduler at {address}"):
        run_batch(clip_features, [1, 2], scheduler=address, connect_timeout=1.0)
    assert time.perf_counter() - start < 15


# --- local execution -----------------------------------------------------------------------


def test_inline_and_local_pools_give_the_same_bytes_in_input_order() -> None:
    seeds = list(range(24))
    expected = [clip_features(s) for s in seeds]
    inline = run_batch(clip_features, seeds, workers=1)
    assert inline.stats.scheduler.startswith("inline")
    one = run_batch(clip_features, seeds, scheduler="processes", workers=1)
    two = run_batch(clip_features, seeds, workers=2)
    chunked = run_batch(clip_features, seeds, workers=2, chunk_size=5)
    for result in (inline, one, two, chunked):
        assert result.ok and result.stats.n_done == len(seeds) == result.stats.n_items
        assert results_bytes(result.results) == results_bytes(expected)
    assert two.stats.workers == 2
    assert two.stats.work_seconds > 0


def test_progress_counts_every_finished_item_once() -> None:
    calls: list[tuple[int, int]] = []
    items = [(k, "bad.amc" if k == 4 else f"{k}.amc") for k in range(10)]
    result = run_batch(
        features_or_format_error, items, workers=2, progress=lambda d, t: calls.append((d, t))
    )
    assert calls == [(d, 10) for d in range(11)]
    assert result.stats.n_done == 10


@pytest.mark.parametrize("workers", [1, 2])
def test_a_bad_item_is_reported_in_one_line_and_the_rest_complete(workers: int) -> None:
    items = [(k, "clips/bad.amc" if k == 3 else f"clips/{k:02d}.amc") for k in range(8)]
    result = run_batch(features_or_format_error, items, workers=workers)
    assert not result.ok
    assert result.results == [k * k if k != 3 else None for k in range(8)]
    [failure] = result.failures
    assert failure.index == 3 and failure.item == items[3]
    assert failure.message == "clips/bad.amc:7: frame 3 has 61 values, expected 62"
    assert "Traceback" in failure.detail
    assert result.stats.n_failed == 1
    assert "7 done, 1 failed" in result.stats.summary()


def test_workers_run_single_threaded() -> None:
    result = run_batch(thread_counts, range(4), workers=2)
    assert result.ok
    assert all(count == 1 for counts in result.results for count in counts)


def test_a_killed_worker_loses_and_duplicates_no_item(tmp_path: pathlib.Path) -> None:
    marker = str(tmp_path / "killed")
    items = [(k, marker, 5) for k in range(16)]
    indices = []
    with imap_batch(die_on_first_attempt, items, workers=2) as stream:
        values = []
        for outcome in stream:
            indices.append(outcome.index)
            values.append(outcome.value)
        stats = stream.stats()
    assert os.path.exists(marker)  # the worker really died
    assert indices == list(range(16))
    assert values == [k * k for k in range(16)]
    assert stats.n_failed == 0 and stats.retried >= 1


def test_an_item_that_always_kills_its_worker_fails_alone(tmp_path: pathlib.Path) -> None:
    items = [(k, 6) for k in range(12)]
    result = run_batch(die_always, items, workers=2, retries=1)
    assert result.results == [k if k != 6 else None for k in range(12)]
    [failure] = result.failures
    assert failure.index == 6
    assert "worker process died running it (2 times; gave up)" in failure.message


def test_a_stream_holds_at_most_window_items_ahead() -> None:
    window = 3
    done = 0

    def count(d: int, _total: int) -> None:
        nonlocal done
        done = d

    ahead = []
    stream = imap_batch(clip_features, range(30), workers=2, window=window, progress=count)
    for outcome in stream:
        ahead.append(done - outcome.index)
    assert max(ahead) <= window
    assert stream.stats().n_done == 30


# --- the batch context ----------------------------------------------------------------------


def _check_context_results(outcomes: list, n: int, *, most_loads: int = 1) -> None:
    assert [o.index for o in outcomes] == list(range(n))
    assert [o.value[0] for o in outcomes] == [k * 2.5 + k for k in range(n)]
    by_process: dict[int, set[int]] = {}
    for o in outcomes:
        _, pid, copy, loads = o.value
        by_process.setdefault(pid, set()).add(copy)
        if pid != os.getpid():
            # each worker process unpickled the context once (not once per task)
            assert 1 <= loads <= most_loads
    # one copy per process (a loaded Dask worker may fetch the broadcast twice: most_loads)
    assert all(1 <= len(copies) <= most_loads for copies in by_process.values())


@pytest.mark.parametrize("runner", [Runner.inline(), Runner.local(workers=2)], ids=str)
def test_a_batch_context_reaches_every_item_and_is_read_once_per_worker(runner: Runner) -> None:
    outcomes = list(runner.map(scaled_with_context, range(20), context=Model(2.5)))
    _check_context_results(outcomes, 20)
    # A second batch with another context on the kept pool sees the new one, not the cached one.
    again = runner.run(scaled_with_context, range(4), context=Model(1.0))
    assert again.ok and [v[0] for v in again.results] == [k * 1.0 + k for k in range(4)]


def test_runner_map_without_context_calls_the_job_with_the_item_alone() -> None:
    result = Runner.local(workers=2).run(clip_features, range(6))
    assert result.ok
    assert results_bytes(result.results) == results_bytes(
        run_batch(clip_features, range(6)).results
    )
    with pytest.raises(SchedulerError):
        Runner.dask("processes")


# --- Dask -----------------------------------------------------------------------------------


def test_dask_sends_the_batch_context_to_each_worker_once(dask_cluster: str) -> None:
    outcomes = list(
        Runner.dask(dask_cluster).map(scaled_with_context, range(20), context=Model(2.5))
    )
    # A loaded machine's Dask may fetch the broadcast key a second time (a worker asks a peer
    # before its own copy lands); one copy is used per process and nothing is sent per task.
    _check_context_results(outcomes, 20, most_loads=2)
    distributed = pytest.importorskip("distributed")
    with distributed.Client(dask_cluster, set_as_default=False) as client:
        result = Runner.dask(client).run(scaled_with_context, range(6), context=Model(2.5))
        assert result.ok and result.stats.workers == 2
        assert client.status == "running"  # a caller's client is left open


def test_dask_gives_the_local_bytes_in_input_order_and_reports_bad_items(dask_cluster: str) -> None:
    seeds = list(range(24))
    local = run_batch(clip_features, seeds, workers=2)
    dask = run_batch(clip_features, seeds, scheduler=dask_cluster)
    assert dask.ok and dask.stats.workers == 2
    assert results_bytes(dask.results) == results_bytes(local.results)
    assert dask.stats.retried is None
    items = [(k, "clips/bad.amc" if k == 3 else f"clips/{k:02d}.amc") for k in range(8)]
    mixed = run_batch(features_or_format_error, items, scheduler=dask_cluster, chunk_size=2)
    assert mixed.results == [k * k if k != 3 else None for k in range(8)]
    assert [f.message for f in mixed.failures] == [
        "clips/bad.amc:7: frame 3 has 61 values, expected 62"
    ]


def test_dask_loses_and_duplicates_no_item_when_a_worker_is_killed(
    dask_cluster: str, tmp_path: pathlib.Path
) -> None:
    marker = str(tmp_path / "killed")
    items = [(k, marker, 5) for k in range(16)]
    indices = []
    values = []
    for outcome in imap_batch(die_on_first_attempt, items, scheduler=dask_cluster):
        indices.append(outcome.index)
        values.append(outcome.value)
    assert os.path.exists(marker)
    assert indices == list(range(16))
    assert values == [k * k for k in range(16)]


def test_dask_builds_the_same_pose_library_as_the_local_pool(dask_cluster: str) -> None:
    import functools

    from sklearn.decomposition import PCA

    from quatmotion.bench.scale import generated_pose_clip
    from quatmotion.parallel import Runner
    from quatmotion.pose.library import PoseLibrary, PoseSettings

    specs = [(kind, seed, 30 + 5 * seed) for seed, kind in enumerate(["walk", "kick"] * 3)]
    specs[3] = ("moonwalk", 3, 40)  # a bad clip among good ones

    def build(runner: Runner) -> tuple[PoseLibrary, list]:
        return PoseLibrary.build_streamed(
            specs,
            functools.partial(generated_pose_clip, fps=30.0, height=170.0),
            PoseSettings(fit_poses=100, rank=6, n_unlabeled=100, n_pairs=20, flush_poses=64),
            runner=runner,
            estimator=PCA(n_components=6, random_state=0),
        )

    local, local_failures = build(Runner.local(workers=2))
    dask, dask_failures = build(Runner.dask(dask_cluster))
    assert [f.index for f in dask_failures] == [f.index for f in local_failures] == [3]
    assert dask.index.to_bytes() == local.index.to_bytes()
    assert dask.clip_names == local.clip_names
    np.testing.assert_array_equal(dask.frame_of, local.frame_of)


def test_dask_and_the_local_pool_write_the_same_qmz_bytes(
    dask_cluster: str, tmp_path: pathlib.Path
) -> None:
    """Library-mode compression: the models are learned in the calling process, the clips
    coded as per-clip jobs; inline, on a 2-process pool and on Dask the file is the same, and
    the bound holds on every clip."""
    import dataclasses

    from quatmotion import codec
    from quatmotion.synthetic import generate_clip

    clips = [
        dataclasses.replace(generate_clip(kind, seed, n_frames=90), name=f"{kind}_{seed}")
        for seed, kind in enumerate(["walk", "kick", "squat"])
    ]
    files = {}
    for name, runner in (
        ("inline", Runner.inline()),
        ("pool", Runner.local(workers=2)),
        ("dask", Runner.dask(dask_cluster)),
    ):
        settings = codec.CompressSettings(max_error=1.0)
        result = codec.Archive.build(clips, tmp_path / f"{name}.qmz", settings, runner=runner)
        assert max(e.max_joint for e in result.details["clip_errors"]) <= 1.0
        files[name] = (tmp_path / f"{name}.qmz").read_bytes()
    assert files["pool"] == files["inline"] == files["dask"]


def worker_pid(_item: object) -> int:
    time.sleep(0.05)  # long enough for both workers to take items
    return os.getpid()


def test_a_kept_pool_whose_worker_died_while_idle_is_replaced() -> None:
    first = run_batch(worker_pid, range(6), workers=2)
    # a worker of the kept pool dies between two batches (the OOM killer, say)
    victim = first.results[0]
    os.kill(victim, signal.SIGKILL)
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline and os.path.exists(f"/proc/{victim}"):
        time.sleep(0.05)
    time.sleep(0.5)  # for the pool's manager thread to see it
    second = run_batch(worker_pid, range(6), workers=2)
    assert second.ok
    assert victim not in second.results


def touch_marker(arg: tuple[int, str]) -> int:
    seed, folder = arg
    time.sleep(0.05)
    pathlib.Path(folder, str(seed)).touch()
    return seed


def test_a_stream_closed_early_runs_no_more_items_and_the_pool_serves_again(
    tmp_path: pathlib.Path,
) -> None:
    items = [(k, str(tmp_path)) for k in range(40)]
    with imap_batch(touch_marker, items, workers=2) as stream:
        for outcome in stream:
            if outcome.index == 2:
                break
    time.sleep(0.5)
    started = len(list(tmp_path.iterdir()))
    assert 3 <= started <= 3 + 3  # what was yielded, plus at most workers + 1 in flight
    again = run_batch(touch_marker, items[:6], workers=2)
    assert again.ok and again.results == list(range(6))


# --- scripts: the main module and the workers ----------------------------------------------


def run_script(tmp_path: pathlib.Path, text: str) -> subprocess.CompletedProcess[str]:
    script = tmp_path / "script.py"
    script.write_text(textwrap.dedent(text))
    return subprocess.run(
        [sys.executable, str(script)],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, SCHEDULER_ENV: ""},
    )


def test_a_script_calling_a_batch_at_its_top_level_runs_once_on_the_pool(
    tmp_path: pathlib.Path,
) -> None:
    # No `if __name__ == "__main__":` guard: the workers must not re-run the script (they did,
    # and died starting pools of their own: "its worker process died running it").
    done = run_script(
        tmp_path,
        """
        import os
        from quatmotion.parallel import run_batch

        print("script ran in", os.getpid())
        result = run_batch(abs, [-1, 2, -3, 4, -5], workers=2)
        print("results", result.results, result.stats.scheduler)
        """,
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.count("script ran in") == 1
    assert "results [1, 2, 3, 4, 5] local pool of 2 processes" in done.stdout
    assert "leaked" not in done.stderr and "Traceback" not in done.stderr


def test_a_guarded_script_may_define_the_job_and_the_items_of_a_batch(
    tmp_path: pathlib.Path,
) -> None:
    done = run_script(
        tmp_path,
        """
        import dataclasses
        from quatmotion.parallel import run_batch

        @dataclasses.dataclass(frozen=True)
        class Item:
            value: int

        def square(x):
            return x * x

        if __name__ == "__main__":
            print("jobs", run_batch(square, [1, 2, 3], workers=2).results)
            print("items", run_batch(repr, [Item(1), Item(2)], workers=2).results)
        """,
    )
    assert done.returncode == 0, done.stderr
    assert "jobs [1, 4, 9]" in done.stdout
    assert "items ['Item(value=1)', 'Item(value=2)']" in done.stdout


def test_an_unguarded_script_whose_job_needs_it_is_told_about_the_guard(
    tmp_path: pathlib.Path,
) -> None:
    done = run_script(
        tmp_path,
        """
        from quatmotion.parallel import run_batch

        def square(x):
            return x * x

        print(run_batch(square, [1, 2], workers=2).failures[0])
        """,
    )
    assert done.returncode == 0, done.stderr
    assert 'under `if __name__ == "__main__":`' in done.stdout


def test_an_item_that_cannot_be_pickled_fails_alone() -> None:
    items = [1, 2, threading.Lock(), 4]
    result = run_batch(repr, items, workers=2)
    assert [f.index for f in result.failures] == [2]
    assert "cannot be sent to a worker process" in result.failures[0].message
    assert result.results[:2] == ["1", "2"] and result.results[3] == "4"
