"""Scale-out: batch throughput against workers, scheduler overhead, pose-index memory at size.

``run(out, quick, seed)`` measures, on generated clips (no data folder needed):

* **Throughput** of every batch job present, in clips/s and frames/s (frames of the clip
  files), on the schedulers of :mod:`quatmotion.parallel`: ``inline``, the local process pool
  with 1 and 2 workers, and a Dask ``LocalCluster`` on loopback with 1 and 2 worker processes.
  Each is the fastest of 3 runs (other jobs of a shared machine only slow a run down).
  Jobs: ``pose_features`` (the per-clip job of ``quatmotion pose index``: read a BVH file,
  prepare the 16-joint poses, GPD, project by the library's model) and
  ``retrieval_index_build`` (the per-clip job of ``quatmotion index build``: read the file,
  its motion features) and ``codec_compress`` (the per-clip job of ``quatmotion compress``:
  code one clip with the library's models, learned beforehand in the calling process, then
  decode it, repair the frames over the default 1 cm bound and measure it).
* **Scheduler overhead per clip**, in CPU time: the CPU of the whole process tree (this
  process: dispatch, and a LocalCluster's scheduler; the workers: unpickling, pickling,
  waiting loops) beyond the jobs' own CPU, per clip, and as a share of a clip's CPU
  (``cpu_overhead_*``; CPU time is not stretched by the other jobs of a shared machine).
  In wall time too: ``((wall - startup) * workers - work) / clips``, where
  ``work`` is the time the job itself ran in the workers and ``startup`` the time until the
  first clip started (pool start or Dask connection; reported apart, it is paid once per
  batch); as a share of a clip's work (the median time of the job over the clips, which
  leaves out the first calls in a fresh worker, reported as ``warmup_s``). The Dask cluster
  runs one untimed batch first, as a long-lived cluster would have; the local pool starts
  afresh for every batch, as it does in use. Per-clip CPU time is reported beside the wall
  time: on a shared machine the difference is time spent waiting for a core.
* **Speed-up**: 2-worker over 1-worker throughput, end to end and without the start-up, with
  one clip per task and eight (``*_chunk8``: what ``pose index`` sends in large libraries, as
  every task carries the projection model). Local pools are measured warm (kept from a first
  batch, as the second pass of ``pose index`` finds them); ``cold_start`` gives the seconds a
  fresh pool (forkserver, workers, first imports) or a fresh Dask cluster costs.
* **Cost model** for 100,000 clips on N workers with a core each:
  ``startup + clips * (work + overhead) / N`` from the measured per-clip CPU times (job and
  overhead, eight clips per task), against the serial HNSW insertion of ``pose index`` (its
  main process adds every pose to the graph, measured per pose below).
* **Pose index at size**: ``PoseLibrary.build_streamed``, then ``save``, over 10k, 100k and
  1M generated poses (quick: 10k and 30k), each in a fresh subprocess that reports its peak
  resident memory (``ru_maxrss`` over the whole build and save; per phase, and its largest
  worker, sampled every 0.05 s with psutil), the HNSW graph's own size (hnswlib's level-0
  record per pose), build and save times and
  the search latency (median and p95 of single queries, projection of the query's GPD
  included). The distance of these libraries is a PCA projection (scikit-learn) of the same
  rank instead of RDSR: RDSR's fit takes minutes on the sample whatever the library size, and
  the quantities measured here (memory, streaming, search) do not depend on which linear
  projection is learned.

Figures beside ``out``: ``<stem>_throughput.png``, ``<stem>_memory.png``,
``<stem>_cost.png``.
"""

from __future__ import annotations

import functools
import importlib.util
import json
import os
import pathlib
import subprocess
import sys
import tempfile
import time
from typing import Any

import numpy as np

from quatmotion._atomic import atomic_write_json
from quatmotion.bench import provenance
from quatmotion.codec import CompressSettings
from quatmotion.codec.writer import ClipTask, SharedModels, code_clip, plan_clip_tasks
from quatmotion.collection import ReadSettings, find_clips
from quatmotion.parallel import (
    Runner,
    available_cpus,
    imap_batch,
    run_batch,
    shutdown_pools,
)
from quatmotion.pose.data import PoseClip
from quatmotion.pose.library import (
    PoseLibrary,
    PoseSettings,
    load_pose_clip,
    project_gpd,
    projected_clip,
)
from quatmotion.retrieval.build import ClipJob, index_clip
from quatmotion.retrieval.index import ClipRecord
from quatmotion.synthetic import KINDS, generate_clip

FPS = 30.0
HEIGHT_CM = 170.0
RANK = 50
PROBE_CLIP_FRAMES = 300  # generated clips of the memory probes: 10 s at 30 fps
COST_MODEL_CLIPS = 100_000
COST_MODEL_WORKERS = (1, 2, 4, 8, 16, 32, 64)
CHUNKINGS = ((1, ""), (8, "_chunk8"))  # clips per task, row-name suffix
REPEATS = 3


def retrieval_features(path: str) -> ClipRecord:
    """The per-clip job of ``quatmotion index build`` on one BVH file (the default method's
    motion features), as the index build runs it."""
    source = find_clips([path])[0]
    return index_clip(ClipJob(source, ("motion",), ReadSettings(strict=False)))


def codec_clip_jobs(
    paths: list, *, max_error: float = 1.0, seed: int = 0
) -> tuple[list[ClipTask], SharedModels]:
    """The per-clip tasks ``compress`` hands to :mod:`quatmotion.parallel` for the clips of
    ``paths`` with the default method, and their shared models (fitted on the sample):
    :func:`~quatmotion.codec.writer.code_clip` over them, the models as the batch's context,
    is the batch step on its own."""
    settings = CompressSettings(max_error=max_error, seed=seed)
    return plan_clip_tasks(paths, settings, runner=Runner.inline())


def generated_pose_clip(spec: tuple[str, int, int], *, fps: float, height: float) -> PoseClip:
    """A procedural clip ``(kind, seed, n_frames)`` at ``fps``, prepared for a pose library
    (the loader of the memory probes: module level, so batch workers can run it)."""
    kind, seed, n_frames = spec
    motion = generate_clip(kind, int(seed), n_frames=int(n_frames), fps=fps)
    return PoseClip.from_motion(motion, fps=fps, height=height, name=f"{kind}_{seed}")


def _probe_specs(n_poses: int, seed: int) -> list[tuple[str, int, int]]:
    n_clips = -(-n_poses // PROBE_CLIP_FRAMES)
    specs = []
    for k in range(n_clips):
        frames = min(PROBE_CLIP_FRAMES, n_poses - k * PROBE_CLIP_FRAMES)
        specs.append((KINDS[k % len(KINDS)], seed * 1_000_003 + k, max(frames, 2)))
    return specs


def _model(dim: int, seed: int) -> dict[str, np.ndarray]:
    """A projection of the library's shape (the cost of projecting does not depend on it)."""
    rng = np.random.default_rng(seed)
    return {
        "scale": rng.uniform(0.5, 2.0, dim),
        "offset": rng.normal(size=dim) * 0.1,
        "W": rng.normal(size=(dim, RANK)) / np.sqrt(dim),
    }


def _write_clips(folder: pathlib.Path, n_clips: int, seed: int) -> tuple[list[str], int]:
    from quatmotion.io import write_bvh

    paths, frames = [], 0
    for k in range(n_clips):
        motion = generate_clip(KINDS[k % len(KINDS)], seed * 1000 + k, n_frames=480, fps=120.0)
        path = folder / f"clip_{k:04d}.bvh"
        write_bvh(motion, path)
        paths.append(str(path))
        frames += motion.n_frames
    return paths, frames


def _measure(job: Any, items: list, n_frames: int, **where: Any) -> dict[str, Any]:
    """The fastest of REPEATS batches of ``job`` over ``items`` (a shared machine's other jobs
    only ever slow a run down), with the wall times of all."""
    runs = [_measure_once(job, items, n_frames, **where) for _ in range(REPEATS)]
    best = max(runs, key=lambda row: row["clips_per_s"])
    return {**best, "wall_s_all_runs": [row["wall_s"] for row in runs]}


def _measure_once(job: Any, items: list, n_frames: int, **where: Any) -> dict[str, Any]:
    """One batch of ``job`` over ``items``: throughput, per-clip work, start-up, overhead."""
    seconds, cpu = [], []
    before = _tree_cpu_seconds()
    with imap_batch(job, items, window=len(items), **where) as stream:
        for outcome in stream:
            if outcome.ok:
                seconds.append(outcome.seconds)
                cpu.append(outcome.cpu_seconds)
        stats = stream.stats()
    after = _tree_cpu_seconds()
    n = len(items)
    # CPU of this process (dispatch; a LocalCluster's scheduler too) and of its descendants
    # (the workers) beyond the jobs' own: what running the batch cost on top of the work. CPU
    # time, unlike wall time, is not stretched by other jobs of a shared machine.
    tree_cpu = sum(after.get(pid, 0.0) - before.get(pid, 0.0) for pid in after)
    cpu_overhead = (tree_cpu - float(np.sum(cpu))) / n if after else None
    startup = stats.startup_seconds or 0.0
    steady = max(stats.wall_seconds - startup, 1e-9)
    work = float(np.median(seconds))  # a clip's job once the worker is warm
    # first calls in a fresh worker (Numba loading its cached kernels...): work above median
    warmup = float(np.sum(seconds)) - n * work
    # time the workers' slots held no job, per clip, once the first one started
    overhead = (steady * stats.workers - float(np.sum(seconds))) / n
    return {
        "scheduler": stats.scheduler,
        "workers": stats.workers,
        "clips": n,
        "failed": stats.n_failed,
        "wall_s": stats.wall_seconds,
        "startup_s": startup,
        "warmup_s": warmup,
        "clips_per_s": n / stats.wall_seconds,
        "frames_per_s": n_frames / stats.wall_seconds,
        "steady_clips_per_s": n / steady,
        "steady_frames_per_s": n_frames / steady,
        "work_per_clip_ms": 1e3 * work,
        "cpu_per_clip_ms": 1e3 * float(np.median(cpu)),
        # below 1 when the job waited for a core (other processes on a shared machine)
        "core_share": float(np.sum(cpu) / np.sum(seconds)),
        "overhead_per_clip_ms": 1e3 * overhead,
        "overhead_fraction": overhead / work,
        "cpu_overhead_per_clip_ms": None if cpu_overhead is None else 1e3 * cpu_overhead,
        "cpu_overhead_fraction": (
            None if cpu_overhead is None else cpu_overhead / float(np.median(cpu))
        ),
    }


def loopback_cluster(n_workers: int) -> Any:
    """A Dask ``LocalCluster`` of ``n_workers`` single-threaded worker processes on loopback
    (no dashboard, any free port): the cluster the benchmarks measure, a context manager."""
    from distributed import LocalCluster

    return LocalCluster(
        n_workers=n_workers,
        threads_per_worker=1,
        processes=True,
        host="127.0.0.1",
        scheduler_port=0,
        dashboard_address=None,
    )


def _tree_cpu_seconds() -> dict[int, float]:
    """CPU seconds (user + system) of this process and each descendant, by pid; empty
    without psutil."""
    if importlib.util.find_spec("psutil") is None:
        return {}
    import psutil

    me = psutil.Process()
    cpu = {}
    for proc in [me, *me.children(recursive=True)]:
        try:
            times = proc.cpu_times()
        except psutil.Error:
            continue
        cpu[proc.pid] = times.user + times.system
    return cpu


def _throughput(job: Any, items: list, n_frames: int, dask_ok: bool) -> dict[str, Any]:
    """Rows ``inline``, ``processes_N`` and ``dask_N`` (N = 1, 2), clips sent one per task and
    (``..._chunk8``) eight per task; ``cold_start`` of fresh pools; the 2/1 speed-ups."""
    rows: dict[str, Any] = {"inline": _measure(job, items, n_frames, scheduler="inline")}
    rows["cold_start"] = {}
    for n in (1, 2):
        # a fresh pool: the forkserver (first time only), n workers, their first imports
        shutdown_pools()
        cold = _measure_once(job, items[: 2 * n], 2 * n, scheduler="processes", workers=n)
        rows["cold_start"][f"processes_{n}_s"] = cold["startup_s"] + cold["warmup_s"]
    for n in (1, 2):
        for chunk, suffix in CHUNKINGS:
            rows[f"processes_{n}{suffix}"] = _measure(
                job, items, n_frames, scheduler="processes", workers=n, chunk_size=chunk
            )
    shutdown_pools()
    if dask_ok:
        for n in (1, 2):
            start = time.perf_counter()
            with loopback_cluster(n) as cluster:
                # A cluster outlives its batches: its workers import the job's modules once,
                # in a first batch, as the batches of a long-lived cluster would have.
                address = cluster.scheduler_address
                run_batch(job, items[: 2 * n], scheduler=address)
                rows["cold_start"][f"dask_{n}_s"] = time.perf_counter() - start
                for chunk, suffix in CHUNKINGS:
                    rows[f"dask_{n}{suffix}"] = _measure(
                        job, items, n_frames, scheduler=address, chunk_size=chunk
                    )
    for kind in ("processes", "dask"):
        for _, suffix in CHUNKINGS:
            one, two = rows.get(f"{kind}_1{suffix}"), rows.get(f"{kind}_2{suffix}")
            if one and two:
                rows[f"{kind}{suffix}_speedup"] = {
                    "end_to_end": two["clips_per_s"] / one["clips_per_s"],
                    "steady": two["steady_clips_per_s"] / one["steady_clips_per_s"],
                }
    return rows


class _MemorySampler:
    """Peak resident memory of this process per phase, and of its largest descendant (a batch
    worker), sampled with psutil every ``every`` seconds."""

    def __init__(self, every: float = 0.05) -> None:
        import threading

        self.phase = "learn"
        self.peak_mb: dict[str, float] = {}
        self.worker_peak_mb = 0.0
        self.available = importlib.util.find_spec("psutil") is not None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._sample, args=(every,), daemon=True)

    def _sample(self, every: float) -> None:
        import psutil

        me = psutil.Process()
        while not self._stop.wait(every):
            try:
                rss = me.memory_info().rss / 2**20
                self.peak_mb[self.phase] = max(self.peak_mb.get(self.phase, 0.0), rss)
                for child in me.children(recursive=True):
                    self.worker_peak_mb = max(self.worker_peak_mb, child.memory_info().rss / 2**20)
            except psutil.Error:
                continue

    def __enter__(self) -> _MemorySampler:
        if self.available:
            self._thread.start()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self._stop.set()
        if self.available:
            self._thread.join()


def _probe(n_poses: int, seed: int, workers: int | None) -> dict[str, Any]:
    """Build and save a pose library of ``n_poses`` generated poses; runs in its own process."""
    import resource

    from sklearn.decomposition import PCA

    base_rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    specs = _probe_specs(n_poses, seed)
    marks = {"start": time.perf_counter()}
    with _MemorySampler() as memory, tempfile.TemporaryDirectory() as folder:

        def progress(stage: str, done: int, total: int) -> None:
            if stage == "index" and "index" not in marks:
                marks["index"] = time.perf_counter()
                memory.phase = "index"

        library, failures = PoseLibrary.build_streamed(
            specs,
            functools.partial(generated_pose_clip, fps=FPS, height=HEIGHT_CM),
            PoseSettings(rank=RANK, seed=seed),
            runner=Runner.resolve(workers=workers),
            progress=progress,
            estimator=PCA(n_components=RANK, random_state=seed),
        )
        marks["built"] = time.perf_counter()
        memory.phase = "save"
        library.save(pathlib.Path(folder) / "poses.idx")
        marks["saved"] = time.perf_counter()
        file_mb = (pathlib.Path(folder) / "poses.idx").stat().st_size / 2**20
        memory.phase = "search"
    peak_rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    index = library.index
    # hnswlib's level-0 record per item: 2M links (4 B each) and a count, the vector, a label
    per_item = (2 * index.M * 4 + 4) + index.dim_ * 4 + 8
    graph_mb = index.n_items_ * per_item / 2**20
    # queries: poses of a clip not in the library, its features projected inside the timing
    rng = np.random.default_rng(seed + 1)
    query_clip = generated_pose_clip(("walk", 10**9 + seed, 240), fps=FPS, height=HEIGHT_CM)
    gpd = library.features(query_clip.poses)
    index.n_threads = 1
    latencies = []
    for r in rng.integers(0, len(gpd), 500):
        start = time.perf_counter()
        library.search(project_gpd(gpd[r : r + 1], library.model), 10)
        latencies.append(time.perf_counter() - start)
    lat = np.asarray(latencies) * 1e3
    phases = {f"peak_rss_{k}_mb": v for k, v in memory.peak_mb.items()}
    index_s = marks["built"] - marks.get("index", marks["built"])
    return {
        "poses": int(index.n_items_),
        "clips": len(library.clip_names),
        "failed": len(failures),
        "fit_poses": library.meta["fit_poses"],
        "rss_after_imports_mb": base_rss,
        "peak_rss_main_mb": peak_rss,
        **phases,
        "peak_rss_one_worker_mb": memory.worker_peak_mb if memory.available else None,
        "hnsw_graph_mb": graph_mb,
        "peak_rss_index_minus_graph_mb": memory.peak_mb.get("index", float("nan")) - graph_mb,
        "library_file_mb": file_mb,
        "learn_s": marks.get("index", marks["built"]) - marks["start"],
        "index_s": index_s,
        "save_s": marks["saved"] - marks["built"],
        "index_poses_per_s": index.n_items_ / max(index_s, 1e-9),
        "query_ms_median": float(np.median(lat)),
        "query_ms_p95": float(np.percentile(lat, 95)),
    }


def _run_probe(n_poses: int, seed: int) -> dict[str, Any]:
    code = (
        "import json, sys; from quatmotion.bench.scale import _probe; "
        f"print(json.dumps(_probe({n_poses}, {seed}, None)))"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False)
    if done.returncode != 0:
        return {"poses": n_poses, "error": done.stderr.strip().splitlines()[-1:]}
    return json.loads(done.stdout.strip().splitlines()[-1])


def _cost_model(rows: dict[str, Any], probes: list[dict[str, Any]]) -> dict[str, Any]:
    """Hours for COST_MODEL_CLIPS clips on N workers with a core each, from measured per-clip
    CPU costs (a dedicated core runs a clip in its CPU time; wall times here are stretched by
    the other jobs of the shared machine)."""
    one = rows["processes_1_chunk8"]  # pose index sends 8 clips per task in large libraries
    work = one["cpu_per_clip_ms"] / 1e3
    poses_per_clip = 480 / (120.0 / FPS)  # the benchmark clips after resampling
    model: dict[str, Any] = {
        "clips": COST_MODEL_CLIPS,
        "work_per_clip_s": work,
        "formula": (
            "startup + clips * (cpu work + cpu overhead) / N; pose index: at least the serial "
            "HNSW insertion of clips * poses per clip"
        ),
    }
    for kind in ("processes", "dask"):
        two = rows.get(f"{kind}_2_chunk8")
        if not two:
            continue
        overhead = max(two.get("cpu_overhead_per_clip_ms") or two["overhead_per_clip_ms"], 0) / 1e3
        startup = rows["cold_start"][f"{kind}_2_s"]
        hours = {
            n: (startup + COST_MODEL_CLIPS * (work + overhead) / n) / 3600
            for n in COST_MODEL_WORKERS
        }
        model[kind] = {"overhead_per_clip_s": overhead, "startup_s": startup, "hours": hours}
    insert = [p for p in probes if "index_poses_per_s" in p]
    if insert:
        # The index pass adds every pose to the graph in the main process, overlapping the
        # workers: however many workers, pose index takes at least this long (measured at the
        # largest size, wall time, so on a loaded machine an upper estimate).
        seconds_per_pose = 1.0 / insert[-1]["index_poses_per_s"]
        model["pose_index_insert_s_per_pose"] = seconds_per_pose
        model["pose_index_serial_insert_hours"] = (
            COST_MODEL_CLIPS * poses_per_clip * seconds_per_pose / 3600
        )
    return model


def _figures(out: pathlib.Path, result: dict[str, Any]) -> list[str]:
    from quatmotion.viz.figures import pyplot, save_figure

    plt = pyplot()
    names = []
    rows = result["throughput"]["pose_features"]
    fig, ax = plt.subplots(figsize=(6.5, 4.2))
    for kind, marker in (("processes", "o"), ("dask", "s")):
        name = "local pool" if kind == "processes" else "Dask LocalCluster"
        for _, suffix in CHUNKINGS:
            keys = [f"{kind}_{n}{suffix}" for n in (1, 2)]
            if all(k in rows for k in keys):
                per_task = "8 clips" if suffix else "1 clip"
                ax.plot(
                    [1, 2],
                    [rows[k]["steady_clips_per_s"] for k in keys],
                    marker=marker,
                    linestyle="-" if suffix else "--",
                    label=f"{name}, {per_task} per task",
                )
    base = rows["processes_1_chunk8"]["steady_clips_per_s"]
    ax.plot([1, 2], [base, 2 * base], color="grey", linestyle=":", label="linear (pool, 8/task)")
    ax.set_xticks([1, 2])
    ax.set_xlabel("workers")
    ax.set_ylabel("clips per second (after start-up)")
    ax.set_title("pose index feature job: throughput against workers")
    ax.legend(fontsize=7)
    names.append(save_figure(fig, out.with_name(f"{out.stem}_throughput.png")).name)

    probes = [p for p in result["pose_index_memory"] if "peak_rss_main_mb" in p]
    if probes:
        fig, ax = plt.subplots(figsize=(6, 4))
        x = [p["poses"] for p in probes]
        for key, style, label in (
            ("peak_rss_main_mb", "o-", "main process, whole build and save (ru_maxrss)"),
            ("peak_rss_learn_mb", "^:", "main process, learning on the sample"),
            ("peak_rss_index_mb", "s-", "main process, indexing pass"),
            ("peak_rss_index_minus_graph_mb", "D--", "indexing pass minus the HNSW graph"),
            ("hnsw_graph_mb", "x--", "HNSW graph itself"),
            ("peak_rss_one_worker_mb", "v:", "largest worker process"),
        ):
            if all(p.get(key) is not None for p in probes):
                ax.plot(x, [p[key] for p in probes], style, label=label)
        ax.set_xscale("log")
        ax.set_xlabel("poses indexed")
        ax.set_ylabel("memory (MiB)")
        ax.set_title("pose index build (streamed): peak memory against library size")
        ax.legend(fontsize=7)
        names.append(save_figure(fig, out.with_name(f"{out.stem}_memory.png")).name)

    cost = result["cost_model"]
    fig, ax = plt.subplots(figsize=(6, 4))
    for kind, label in (("processes", "local pools"), ("dask", "Dask")):
        if kind in cost:
            hours = cost[kind]["hours"]
            ax.plot([int(n) for n in hours], list(hours.values()), "o-", label=label)
    if "pose_index_serial_insert_hours" in cost:
        ax.axhline(
            cost["pose_index_serial_insert_hours"],
            color="k",
            linestyle="--",
            label="pose index: serial HNSW insertion",
        )
    ax.set_xscale("log", base=2)
    ax.set_yscale("log")
    ax.set_xlabel("workers (one core each)")
    ax.set_ylabel("hours")
    ax.set_title(f"model: pose features of {COST_MODEL_CLIPS:,} clips (4 s each)")
    ax.legend(fontsize=7)
    names.append(save_figure(fig, out.with_name(f"{out.stem}_cost.png")).name)
    return names


def run(out: pathlib.Path, quick: bool = False, seed: int = 0) -> dict:
    """Measure batch throughput, scheduler overhead and pose-index memory; write JSON to ``out``.

    Parameters
    ----------
    out : pathlib.Path
        JSON destination; the figures go beside it.
    quick : bool
        24 clips instead of 96 for throughput; memory probes at 10k and 30k poses instead of
        10k, 100k and 1M.
    seed : int
        Seeds the generated clips.

    Returns
    -------
    dict
        ``throughput`` (per job, per scheduler: ``clips_per_s``, ``frames_per_s``,
        ``overhead_per_clip_ms``, ``overhead_fraction``..., and ``*_speedup``),
        ``cost_model``, ``pose_index_memory`` (per size: ``peak_rss_main_mb``,
        ``hnsw_graph_mb``, ``query_ms_median``...).
    """
    out = pathlib.Path(out)
    dask_ok = importlib.util.find_spec("distributed") is not None
    n_clips = 24 if quick else 96
    result: dict[str, Any] = {
        **provenance("scale", out, quick, seed),
        "cpus_available": available_cpus(),
        "load_average": os.getloadavg(),
        "dask_available": dask_ok,
    }
    with tempfile.TemporaryDirectory() as folder:
        paths, n_frames = _write_clips(pathlib.Path(folder), n_clips, seed)
        gpd_dim = generated_pose_clip(("walk", 0, 4), fps=FPS, height=HEIGHT_CM).poses.gpd.shape[1]
        job = functools.partial(
            projected_clip,
            load=functools.partial(load_pose_clip, fps=FPS, height=HEIGHT_CM),
            model=_model(gpd_dim, seed),
        )
        tasks, models = codec_clip_jobs(paths, seed=seed)
        result["throughput"] = {
            "pose_features": _throughput(job, paths, n_frames, dask_ok),
            "retrieval_index_build": _throughput(retrieval_features, paths, n_frames, dask_ok),
            "codec_compress": _throughput(
                functools.partial(code_clip, models=models), tasks, n_frames, dask_ok
            ),
        }
    result["throughput_clips"] = {"clips": n_clips, "frames_per_clip": 480, "file_fps": 120}
    sizes = (10_000, 30_000) if quick else (10_000, 100_000, 1_000_000)
    result["pose_index_memory"] = [_run_probe(n, seed) for n in sizes]
    result["cost_model"] = _cost_model(
        result["throughput"]["pose_features"], result["pose_index_memory"]
    )
    result["figures"] = _figures(out, result)
    atomic_write_json(out, result)
    return result
