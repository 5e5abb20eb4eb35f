"""Dask overhead against the local pool, on the codec job and the index job, with the shared
models in every task and as the batch's context.

``run(out, quick, seed)`` measures, on generated clips (no data folder needed), the wall time
of one batch of each job on 2 workers: a local process pool (kept warm from a first batch) and
a Dask ``LocalCluster`` of 2 single-threaded worker processes on loopback (warm likewise), the
fastest of 3 batches each. Jobs:

* ``index``: the per-clip job of ``quatmotion index build`` (read a BVH file, its motion
  features); it needs no shared model.
* ``codec_models_in_tasks``: the per-clip job of ``quatmotion compress``
  (:func:`quatmotion.codec.compress.code_clip`) with the layout's encoder and decoder models
  in every task, as 0.3.0 sends them.
* ``codec_context``: the same job with the models taken out of the tasks and sent once per
  batch as its context (:meth:`quatmotion.parallel.Runner.map`, ``context=``).

The overhead is ``dask / local - 1`` of the wall times. Timings on a shared machine are noisy;
the minimum of the repeats is the least disturbed.
"""

from __future__ import annotations

import dataclasses
import pathlib
import tempfile
import time
from typing import Any

from quatmotion._atomic import atomic_write_json
from quatmotion.bench import provenance
from quatmotion.bench.scale import _write_clips, codec_clip_jobs, retrieval_features
from quatmotion.codec.compress import ClipJob, CodedClip, code_clip
from quatmotion.parallel import Runner, shutdown_pools

REPEATS = 3
WORKERS = 2

HEADLINES = [
    {
        "name": "Dask overhead, codec job (models as context)",
        "path": ["jobs", "codec_context", "overhead"],
        "unit": "",
        "better": "lower",
        "format": "percent",
    },
    {
        "name": "Dask overhead, codec job (models in every task)",
        "path": ["jobs", "codec_models_in_tasks", "overhead"],
        "unit": "",
        "better": "lower",
        "format": "percent",
    },
    {
        "name": "Dask overhead, index job",
        "path": ["jobs", "index", "overhead"],
        "unit": "",
        "better": "lower",
        "format": "percent",
    },
]


def code_clip_with_models(job: ClipJob, models: dict[int, tuple[Any, Any]]) -> CodedClip:
    """:func:`code_clip` of a job sent without its models, which come from the batch's
    context (``layout -> (encoder model, decoder model)``)."""
    model, decoder_model = models[job.library.clips[0].layout]
    return code_clip(dataclasses.replace(job, model=model, decoder_model=decoder_model))


def split_models(jobs: list[ClipJob]) -> tuple[list[ClipJob], dict[int, tuple[Any, Any]]]:
    """The jobs without their models, and the models by layout (one per layout)."""
    models: dict[int, tuple[Any, Any]] = {}
    light = []
    for job in jobs:
        models.setdefault(job.library.clips[0].layout, (job.model, job.decoder_model))
        light.append(dataclasses.replace(job, model=None, decoder_model=None))
    return light, models


def _fastest(runner: Runner, func: Any, items: list, context: Any) -> dict[str, Any]:
    runner.run(func, items[: 2 * WORKERS], context=context)  # warm: imports, compiled kernels
    walls = []
    for _ in range(REPEATS):
        start = time.perf_counter()
        result = runner.run(func, items, context=context)
        walls.append(time.perf_counter() - start)
        if not result.ok:
            raise RuntimeError(f"{func.__name__}: {result.failures[0]}")
    return {"wall_s": min(walls), "walls_s": walls}


def run(out: pathlib.Path, quick: bool = False, seed: int = 0) -> dict:
    """Measure and write the JSON to ``out``; return it."""
    from distributed import LocalCluster

    out = pathlib.Path(out)
    n_clips = 12 if quick else 48
    result: dict[str, Any] = provenance("dask_overhead", out, quick, seed)
    result.update({"workers": WORKERS, "clips": n_clips, "repeats": REPEATS})
    result["headlines"] = HEADLINES
    with tempfile.TemporaryDirectory() as folder:
        paths, frames = _write_clips(pathlib.Path(folder), n_clips, seed)
        heavy = codec_clip_jobs(paths, seed=seed)
        light, models = split_models(heavy)
        jobs = {
            "index": (retrieval_features, paths, None),
            "codec_models_in_tasks": (code_clip, heavy, None),
            "codec_context": (code_clip_with_models, light, models),
        }
        rows: dict[str, Any] = {name: {} for name in jobs}
        local = Runner.local(workers=WORKERS)
        for name, (func, items, context) in jobs.items():
            rows[name]["local"] = _fastest(local, func, items, context)
        shutdown_pools()
        with LocalCluster(
            n_workers=WORKERS,
            threads_per_worker=1,
            processes=True,
            host="127.0.0.1",
            scheduler_port=0,
            dashboard_address=None,
        ) as cluster:
            dask = Runner.dask(cluster.scheduler_address)
            for name, (func, items, context) in jobs.items():
                rows[name]["dask"] = _fastest(dask, func, items, context)
        for row in rows.values():
            row["overhead"] = row["dask"]["wall_s"] / row["local"]["wall_s"] - 1.0
    result["frames"] = frames
    result["jobs"] = rows
    atomic_write_json(out, result)
    return result
