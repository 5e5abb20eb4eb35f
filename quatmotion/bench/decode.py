"""Runtime decoding (issue 22): whole clips, single poses at arbitrary times, and sizes in the
units others quote.

``run(out, quick, seed)`` writes JSON to ``out``.

* **Libraries**: ``walk_amc`` (the six CMU walks), ``hdm05`` and ``bandai1`` (short clips, one
  skeleton each), compressed by ``best``, ``spline`` and ``naive`` with every joint within 1 cm
  (the issue's setting).
* **Times** are CPU seconds of this thread (``time.thread_time``; wall seconds beside them),
  the minimum of repeated runs, so that other work on a shared machine counts as little as it
  can. Run it pinned to one core (``taskset -c 1``). Numba kernels are compiled (or loaded
  from the cache) on a small clip first, so "cold" means a freshly opened archive, not a
  cold compiler.
* **Whole-clip decode**, microseconds per frame: to local rotations and root translation
  (``Archive.read_rotations``) and to world positions (``Archive.read`` then forward
  kinematics); *cold* is the first pass over every clip of a freshly opened archive
  (skeletons and layouts parsed on the way), *cold, set up* the first pass over a freshly
  opened archive whose layouts and skeleton records were parsed first (the set-up cached,
  the clips' chunks not yet read), *warm* the best of three later passes.
* **Sampling**, microseconds: the first ``Archive.sample`` of each clip (decodes the clip; its
  layout already parsed), median and largest over the clips; then one pose per call at random
  times (all joints, and one joint), median over the calls; and per pose within one call of
  1000 times.
* **Sizes**: ratio against the source text and against float32 channels; bits per joint per
  frame; kilobytes per second of motion at the clip's frame rate; and, for ``walk_amc``
  resampled to 24 and 30 frames/s (the rates the industry's CMU figures use), the same plus
  the ratio against 10 float32 per bone and frame (ACL's raw size), at 1 cm on joints and
  0.02 cm on virtual vertices.
"""

from __future__ import annotations

import pathlib
import statistics
import time
from typing import Any

import numpy as np

from quatmotion import quat
from quatmotion._atomic import atomic_write_json
from quatmotion.bench._provenance import provenance
from quatmotion.codec import compress, open_archive
from quatmotion.datasets import data_root
from quatmotion.motion import Motion, forward_kinematics

DATASETS = ("walk_amc", "hdm05", "bandai1")
METHODS = ("best", "spline", "naive")
BOUND_CM = 1.0
RATES = (24.0, 30.0)
ACL_FLOATS_PER_BONE = 10


HEADLINES = [
    {
        "name": f"decode to rotations, {name}, warm",
        "path": ["datasets", name, "methods", "best", "rotations_us_per_frame_warm"],
        "unit": "µs/frame",
        "better": "lower",
        "format": "",
    }
    for name in DATASETS
] + [
    {
        "name": "sample, one pose per call (walk_amc)",
        "path": ["datasets", "walk_amc", "methods", "best", "sample_one_pose_us_median"],
        "unit": "µs",
        "better": "lower",
        "format": "",
    },
    {
        "name": "first sample of a clip (walk_amc)",
        "path": ["datasets", "walk_amc", "methods", "best", "first_sample_us_median"],
        "unit": "µs",
        "better": "lower",
        "format": "",
    },
]


def _timed(fn, repeats: int) -> tuple[float, float]:
    """Smallest CPU and wall seconds of ``repeats`` calls of ``fn``."""
    cpu, wall = [], []
    for _ in range(repeats):
        c, w = time.thread_time(), time.perf_counter()
        fn()
        cpu.append(time.thread_time() - c)
        wall.append(time.perf_counter() - w)
    return min(cpu), min(wall)


def _warm_up() -> None:
    from quatmotion.synthetic import generate_clip

    clip = generate_clip("walk", 0, n_frames=40)
    for method in METHODS:
        with open_archive(compress([clip], max_error=2.0, method=method).data) as a:
            a.read_rotations(0)
            forward_kinematics(a.read(0))
            a.sample(0, [0.01, 0.1])
            a.sample(0, 0.2, joints=[1])


def decode_figures(data: bytes, repeats: int = 3, seed: int = 0) -> dict[str, Any]:
    """Decode and sample timings of one archive's bytes (see the module docstring)."""
    with open_archive(data) as archive:
        frames = sum(c.n_frames for c in archive.entries)

        def rotations():
            for i in range(len(archive)):
                archive.read_rotations(i)

        def positions():
            for i in range(len(archive)):
                forward_kinematics(archive.read(i))

        cold_cpu, cold_wall = _timed(rotations, 1)
        warm_cpu, warm_wall = _timed(rotations, repeats)
        pos_cpu, pos_wall = _timed(positions, repeats)
    with open_archive(data) as fresh:
        for k in range(len(fresh.header.layouts)):
            fresh.layout(k)
        for k in range(len(fresh.header.skeletons)):
            fresh.skeleton(k)
        c = time.thread_time()
        for i in range(len(fresh)):
            fresh.read_rotations(i)
        set_up_cpu = time.thread_time() - c
    rng = np.random.default_rng(seed)
    first, single, single_joint, batch = [], [], [], []
    with open_archive(data) as archive:
        for k in range(len(archive.header.layouts)):
            archive.layout(k)
        for i, entry in enumerate(archive.entries):
            duration = (entry.n_frames - 1) / entry.fps
            c = time.thread_time()
            archive.sample(i, 0.5 * duration)
            first.append(time.thread_time() - c)
            times = rng.uniform(0.0, duration, 64)
            for t in times:
                c = time.thread_time()
                archive.sample(i, t)
                single.append(time.thread_time() - c)
            for t in times[:16]:
                c = time.thread_time()
                archive.sample(i, t, joints=[1])
                single_joint.append(time.thread_time() - c)
            many = rng.uniform(0.0, duration, 1000)
            cpu, _ = _timed(lambda i=i, many=many: archive.sample(i, many), repeats)
            batch.append(cpu / len(many))
    us = 1e6
    return {
        "frames": frames,
        "clips": len(first),
        "rotations_us_per_frame_cold": us * cold_cpu / frames,
        "rotations_us_per_frame_cold_set_up": us * set_up_cpu / frames,
        "rotations_us_per_frame_warm": us * warm_cpu / frames,
        "rotations_us_per_frame_cold_wall": us * cold_wall / frames,
        "rotations_us_per_frame_warm_wall": us * warm_wall / frames,
        "positions_us_per_frame_warm": us * pos_cpu / frames,
        "positions_us_per_frame_warm_wall": us * pos_wall / frames,
        "first_sample_us_median": us * statistics.median(first),
        "first_sample_us_max": us * max(first),
        "sample_one_pose_us_median": us * statistics.median(single),
        "sample_one_joint_us_median": us * statistics.median(single_joint),
        "sample_batched_us_per_pose_median": us * statistics.median(batch),
    }


def size_figures(result, motions: list[Motion], source_bytes: int) -> dict[str, Any]:
    """Sizes of a compression result in ratios, bits per joint per frame and kB/s."""
    joint_frames = sum(m.n_frames * m.skeleton.n_joints for m in motions)
    seconds = sum(m.n_frames / m.fps for m in motions)
    acl_raw = 4 * ACL_FLOATS_PER_BONE * joint_frames
    out = {
        "bytes": result.size,
        "ratio_raw_float32": sum(result.raw_bytes) / result.size,
        "ratio_10_floats_per_bone": acl_raw / result.size,
        "bits_per_joint_frame": 8 * result.size / joint_frames,
        "kB_per_second": result.size / 1000 / seconds,
        "fps": sorted({float(m.fps) for m in motions}),
        "max_joint_cm": float(max(e.max_joint for e in result.clip_errors)),
        "max_virtual_vertex_cm": float(max(e.max_virtual_vertex for e in result.clip_errors)),
    }
    if source_bytes:
        out["ratio_text"] = source_bytes / result.size
    return out


def resample(motion: Motion, fps: float) -> Motion:
    """``motion`` at ``fps``: frames at ``k / fps`` seconds, rotations by slerp and
    translations by lerp between the neighbouring frames."""
    T = motion.n_frames
    n = int(np.floor((T - 1) * fps / motion.fps + 1e-9)) + 1
    u = np.arange(n) * motion.fps / fps
    a = np.minimum(np.floor(u).astype(int), T - 1)
    b = np.minimum(a + 1, T - 1)
    f = u - a
    rot = quat.slerp(motion.rotations[a], motion.rotations[b], f[:, None])
    root = (1 - f[:, None]) * motion.root_translation[a] + f[:, None] * motion.root_translation[b]
    jt = motion.joint_translations
    if jt is not None:
        jt = (1 - f[:, None, None]) * jt[a] + f[:, None, None] * jt[b]
    return Motion(motion.skeleton, float(fps), root, rot, jt, motion.name)


def run(out: pathlib.Path, quick: bool = False, seed: int = 0) -> dict:
    from quatmotion.bench.compression import _load, _paths

    out = pathlib.Path(out)
    root = data_root()
    t_start = time.perf_counter()
    _warm_up()
    repeats = 1 if quick else 3
    result: dict[str, Any] = {
        **provenance("decode", out, quick, seed),
        "bound_cm": BOUND_CM,
        "headlines": HEADLINES,
        "datasets": {},
    }
    for name in DATASETS:
        paths = _paths(root, name, quick)
        motions, sizes = _load(paths)
        sources = [(s, p.suffix.lower().lstrip(".")) for s, p in zip(sizes, paths, strict=True)]
        entry: dict[str, Any] = {"clips": len(motions), "methods": {}}
        for method in METHODS:
            r = compress(motions, max_error=BOUND_CM, method=method, seed=seed, sources=sources)
            row = size_figures(r, motions, sum(sizes))
            row.update(decode_figures(r.data, repeats, seed))
            entry["methods"][method] = row
        if name == "walk_amc":
            resampled: dict[str, Any] = {}
            for fps in RATES:
                clips = [resample(m, fps) for m in motions]
                for label, kwargs in (
                    ("joints_1cm", {"max_error": 1.0}),
                    ("vertices_0.02cm", {"max_error": 0.02, "bound_on": "vertices"}),
                ):
                    r = compress(clips, method="best", seed=seed, **kwargs)
                    resampled[f"{fps:g}fps_{label}"] = size_figures(r, clips, 0)
            entry["resampled_best"] = resampled
        result["datasets"][name] = entry
        atomic_write_json(out, result)
    result["seconds"] = time.perf_counter() - t_start
    atomic_write_json(out, result)
    return result
