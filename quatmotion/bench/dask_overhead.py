"""Dask overhead against the local pool, on the codec job and the index job: the shared
models in every task or sent once as the batch's context, one clip or several per task.

``run(out, quick, seed)`` measures, on generated clips (no data folder needed), the wall time
of one batch of each job on 2 workers: a local process pool (kept warm from a first batch) and
a Dask ``LocalCluster`` of 2 single-threaded worker processes on loopback (warm likewise), the
fastest of 3 batches each. Jobs:

* ``index`` / ``index_chunked``: the per-clip job of ``quatmotion index build`` (read a BVH
  file, its motion features), one clip and :data:`CHUNK` clips per task.
* ``codec_models_in_tasks``: the per-clip job of ``quatmotion compress``
  (:func:`quatmotion.codec.writer.code_clip`: read the clip, encode, decode, repair) with
  the shared models in every task, as 0.3.0 sent them.
* ``codec_context`` / ``codec_context_chunked``: the same job with the models sent to each
  worker once as the batch's context (:meth:`quatmotion.parallel.Runner.map`, ``context=``;
  Dask ``Client.scatter(broadcast=True)``), as ``compress`` runs it; one clip and
  :data:`CHUNK` clips per task.

The overhead is ``dask / local - 1`` of the wall times; ``work_s`` is the time the
job itself ran in the workers (the rest of the wall time is the scheduler's). Timings on a
shared machine are noisy; the minimum of the repeats is the least disturbed.
"""

from __future__ import annotations

import dataclasses
import functools
import pathlib
import tempfile
import time
from typing import Any

from quatmotion._atomic import atomic_write_json
from quatmotion.bench import provenance
from quatmotion.bench.scale import (
    _write_clips,
    codec_clip_jobs,
    loopback_cluster,
    retrieval_features,
)
from quatmotion.codec.writer import code_clip
from quatmotion.parallel import Runner, shutdown_pools

REPEATS = 3
WORKERS = 2
CHUNK = 4


def _overhead(name: str, job: str) -> dict[str, Any]:
    """The headline of a job's Dask overhead (``jobs.JOB.overhead``, lower is better)."""
    return {
        "name": f"Dask overhead, {name}",
        "path": ["jobs", job, "overhead"],
        "unit": "",
        "better": "lower",
        "format": "percent",
    }


HEADLINES = [
    _overhead("codec job (models as context, 4 clips a task)", "codec_context_chunked"),
    _overhead("codec job (models as context)", "codec_context"),
    _overhead("codec job (models in every task)", "codec_models_in_tasks"),
    _overhead("index job (4 clips a task)", "index_chunked"),
    _overhead("index job", "index"),
]


def _fastest(runner: Runner, func: Any, items: list, context: Any, chunk: int) -> dict[str, Any]:
    runner = dataclasses.replace(runner, chunk_size=chunk)
    runner.run(func, items[: 2 * WORKERS], context=context)  # warm: imports, compiled kernels
    walls, work = [], []
    for _ in range(REPEATS):
        start = time.perf_counter()
        result = runner.run(func, items, context=context)
        walls.append(time.perf_counter() - start)
        work.append(result.stats.work_seconds)
        if not result.ok:
            raise RuntimeError(f"{getattr(func, '__name__', func)}: {result.failures[0]}")
    return {"wall_s": min(walls), "walls_s": walls, "work_s": work}


def run(out: pathlib.Path, quick: bool = False, seed: int = 0) -> dict:
    """Measure and write the JSON to ``out``; return it."""
    out = pathlib.Path(out)
    n_clips = 12 if quick else 48
    result: dict[str, Any] = provenance("dask_overhead", out, quick, seed)
    result.update({"workers": WORKERS, "clips": n_clips, "repeats": REPEATS})
    result["headlines"] = HEADLINES
    with tempfile.TemporaryDirectory() as folder:
        paths, frames = _write_clips(pathlib.Path(folder), n_clips, seed)
        tasks, models = codec_clip_jobs(paths, seed=seed)
        in_tasks = functools.partial(code_clip, models=models)
        jobs = {
            "index": (retrieval_features, paths, None, 1),
            "index_chunked": (retrieval_features, paths, None, CHUNK),
            "codec_models_in_tasks": (in_tasks, tasks, None, 1),
            "codec_context": (code_clip, tasks, models, 1),
            "codec_context_chunked": (code_clip, tasks, models, CHUNK),
        }
        rows: dict[str, Any] = {name: {"clips_per_task": job[3]} for name, job in jobs.items()}
        local = Runner.local(workers=WORKERS)
        for name, (func, items, context, chunk) in jobs.items():
            rows[name]["local"] = _fastest(local, func, items, context, chunk)
        shutdown_pools()
        with loopback_cluster(WORKERS) as cluster:
            dask = Runner.dask(cluster.scheduler_address)
            for name, (func, items, context, chunk) in jobs.items():
                rows[name]["dask"] = _fastest(dask, func, items, context, chunk)
        for row in rows.values():
            row["overhead"] = row["dask"]["wall_s"] / row["local"]["wall_s"] - 1.0
    result["frames"] = frames
    result["jobs"] = rows
    atomic_write_json(out, result)
    return result
