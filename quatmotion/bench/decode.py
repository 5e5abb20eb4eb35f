"""Runtime decoding (issues 22 and 32): whole clips, one pose per call, batches, the first
sample of a clip, and sizes in the units others quote, beside the Animation Compression
Library's figures as issue 32 measured them.

``run(out, quick, seed)`` writes JSON to ``out``.

* **Libraries**: ``hdm05`` (the clips of one actor: the first in name order), ``walk_amc``
  (the CMU walks of subjects 02 and 03) and ``bandai1`` (short clips, one skeleton each),
  compressed by ``best`` with every joint within 1 cm and within 0.1 cm (:data:`BOUNDS`).
* **Error** is measured twice: as the file declares it (the largest of its clips'
  ``max_error``) and by an independent forward kinematics (:func:`independent_positions`:
  SciPy's rotation matrices, not the package's quaternion kernels) of the decoded clips
  against the clips read from their files, joints and end sites.
* **Times** are CPU seconds of this thread (``time.thread_time``; wall seconds beside them),
  the minimum of repeated runs, so that other work on a shared machine counts as little as it
  can. Run it pinned to one core (``taskset -c 1``). Numba kernels are compiled (or loaded
  from the cache) on a small clip first, so a "fresh" archive is one freshly opened, not a
  cold compiler.
* **Whole-clip decode**, microseconds per frame: to local rotations and root translation
  (``Archive.read_rotations``) and to world positions (``Archive.read`` then forward
  kinematics); *fresh* is the first pass over every clip of a freshly opened archive
  (skeletons and layouts parsed on the way), *warm* the best of later passes.
* **One pose per call**, microseconds: ``Archive.sample`` at random times by index and by
  name (median over the calls), and through a :class:`~quatmotion.codec.Sampler` bound to the
  clip where the archive has one; the *first sample* of each clip (median and largest over
  the clips, on an archive whose layouts are parsed); *batched*, per pose within one call of
  1,000 times.
* **Sizes**: bytes per frame, bits per joint per frame, kilobytes per second of motion at the
  clip's frame rate, ratio against 10 float32 per bone and frame (ACL's raw size).
* :data:`ACL` holds issue 32's table (ACL 2.1, C++, ``-O3 -march=native``, one core, CPU
  time, warm caches, on unseen HDM05 clips of one actor and four CMU walks of subject 02):
  the issue's measurement, quoted beside ours, not measured here.
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
from quatmotion.codec import Archive, CompressSettings
from quatmotion.collection import BuildReport
from quatmotion.datasets import data_root
from quatmotion.motion import Motion, forward_kinematics

DATASETS = ("hdm05", "walk_amc", "bandai1")
BOUNDS = (1.0, 0.1)
METHOD = "best"
ACL_FLOATS_PER_BONE = 10
BATCH = 1000

ACL = {
    "source": "issue 32's measurement (ACL 2.1, -O3 -march=native, one core, CPU time, warm)",
    "rows": [
        {"library": "hdm05", "setting": "threshold raised to match 1 cm", "bytes_per_frame": 26.5,
         "max_joint_cm": 0.84, "decode_us_per_frame": 0.55, "one_pose_us": 0.56},
        {"library": "walk_amc", "setting": "threshold raised to match 1 cm",
         "bytes_per_frame": 36.0, "max_joint_cm": 0.91, "decode_us_per_frame": 0.53,
         "one_pose_us": 0.53},
        {"library": "hdm05", "setting": "default (0.01 cm target)", "bytes_per_frame": 98.2,
         "max_joint_cm": 0.038, "decode_us_per_frame": 0.55, "one_pose_us": 0.57},
    ],
    "quatmotion_0.4.0": [
        {"library": "hdm05", "max_error": 1.0, "bytes_per_frame": 4.04, "max_joint_cm": 0.999,
         "decode_us_per_frame_warm": 3.92, "decode_us_per_frame_fresh": 4.25,
         "one_pose_us": 11.1, "batched_us_per_pose": 1.39},
        {"library": "walk_amc", "max_error": 1.0, "bytes_per_frame": 5.34,
         "max_joint_cm": 0.996, "decode_us_per_frame_warm": 2.55,
         "decode_us_per_frame_fresh": 5.45, "one_pose_us": 10.8, "batched_us_per_pose": 1.39},
        {"library": "hdm05", "max_error": 0.1, "bytes_per_frame": 13.7, "max_joint_cm": 0.100,
         "decode_us_per_frame_warm": 5.22, "decode_us_per_frame_fresh": 5.99,
         "one_pose_us": 11.4, "batched_us_per_pose": 1.76},
    ],
}  # fmt: skip

HEADLINES = [
    {
        "name": f"decode to rotations, {name}, {bound:g} cm, warm",
        "path": ["datasets", name, f"{bound:g}cm", "rotations_us_per_frame_warm"],
        "unit": "µs/frame",
        "better": "lower",
        "format": "",
    }
    for name in DATASETS
    for bound in BOUNDS
] + [
    {
        "name": f"{what}, hdm05, 1 cm",
        "path": ["datasets", "hdm05", "1cm", key],
        "unit": "µs",
        "better": "lower",
        "format": "",
    }
    for what, key in (
        ("one pose per call by index", "sample_index_us_median"),
        ("one pose per call by name", "sample_name_us_median"),
        ("first sample of a clip", "first_sample_us_median"),
        ("batched, per pose", "sample_batched_us_per_pose_median"),
    )
]


def independent_positions(motion: Motion) -> np.ndarray:
    """Joint and end-site positions ``(T, J + S, 3)`` cm of ``motion`` by forward kinematics
    written apart from the package's (SciPy rotation matrices, scalar-last quaternions), so
    that an error in the decoder's rotation kernels cannot hide in the measurement."""
    from scipy.spatial.transform import Rotation

    sk = motion.skeleton
    T, J = motion.n_frames, sk.n_joints
    q = np.asarray(motion.rotations, dtype=np.float64)
    local = Rotation.from_quat(q.reshape(-1, 4)[:, [1, 2, 3, 0]]).as_matrix().reshape(T, J, 3, 3)
    glob = np.empty_like(local)
    pos = np.empty((T, J, 3))
    glob[:, 0] = local[:, 0]
    pos[:, 0] = motion.root_translation
    offsets = motion.joint_translations
    for j in range(1, J):
        p = int(sk.parents[j])
        glob[:, j] = glob[:, p] @ local[:, j]
        o = offsets[:, j] if offsets is not None else np.broadcast_to(sk.offsets[j], (T, 3))
        pos[:, j] = pos[:, p] + np.einsum("tik,tk->ti", glob[:, p], o)
    sites = np.empty((T, len(sk.site_parents), 3))
    for s, p in enumerate(sk.site_parents):
        sites[:, s] = pos[:, p] + glob[:, p] @ sk.site_offsets[s]
    return np.concatenate((pos, sites), axis=1)


def _timed(fn, repeats: int) -> tuple[float, float]:
    """Smallest CPU and wall seconds of ``repeats`` calls of ``fn``."""
    cpu, wall = [], []
    for _ in range(repeats):
        c, w = time.thread_time(), time.perf_counter()
        fn()
        cpu.append(time.thread_time() - c)
        wall.append(time.perf_counter() - w)
    return min(cpu), min(wall)


def _per_call(fn, args: list, reps: int = 5) -> float:
    """Median CPU seconds of one call ``fn(*a)`` over ``args``, each timed as the mean of a
    run of ``reps`` calls (one call is below the clock's useful resolution)."""
    out = []
    for a in args:
        c = time.thread_time()
        for _ in range(reps):
            fn(*a)
        out.append((time.thread_time() - c) / reps)
    return statistics.median(out)


def _warm_up() -> None:
    from quatmotion.synthetic import generate_clip

    clip = generate_clip("walk", 0, n_frames=40)
    built = Archive.build([clip], None, CompressSettings(max_error=2.0, method=METHOD))
    with Archive.open(built.details["data"]) as a:
        a.read_rotations(0)
        forward_kinematics(a.read(0))
        a.sample(0, [0.01, 0.1])
        a.sample(0, 0.2)
        a.sample(a.names()[0], 0.2)
        a.sample(0, 0.2, joints=[1])
        if hasattr(a, "sampler"):
            a.sampler(0).pose(0.1)
            a.sampler(0).poses(np.array([0.1, 0.2]))


def decode_figures(data: bytes, repeats: int = 3, seed: int = 0) -> dict[str, Any]:
    """Decode and sample timings of one archive's bytes (see the module docstring)."""
    with Archive.open(data) as fresh:
        frames = sum(c.n_frames for c in fresh.entries)

        def rotations(archive=fresh):
            for i in range(len(archive)):
                archive.read_rotations(i)

        fresh_cpu, fresh_wall = _timed(rotations, 1)
    with Archive.open(data) as archive:

        def rotations_warm():
            rotations(archive)

        def positions():
            for i in range(len(archive)):
                forward_kinematics(archive.read(i))

        rotations_warm()
        warm_cpu, warm_wall = _timed(rotations_warm, repeats)
        pos_cpu, pos_wall = _timed(positions, repeats)
    rng = np.random.default_rng(seed)
    first, by_index, by_name, bound, batch = [], [], [], [], []
    with Archive.open(data) as archive:
        for k in range(len(archive.header.layouts)):
            archive.layout(k)
        names = archive.names()
        for i, entry in enumerate(archive.entries):
            duration = (entry.n_frames - 1) / entry.fps
            c = time.thread_time()
            archive.sample(i, 0.5 * duration)
            first.append(time.thread_time() - c)
            times = [(float(t),) for t in rng.uniform(0.0, duration, 32)]
            by_index.append(_per_call(lambda t, i=i: archive.sample(i, t), times))
            by_name.append(_per_call(lambda t, n=names[i]: archive.sample(n, t), times))
            if hasattr(archive, "sampler"):
                sampler = archive.sampler(i)
                bound.append(_per_call(sampler.pose, times))
            many = rng.uniform(0.0, duration, BATCH)
            cpu, _ = _timed(lambda i=i, many=many: archive.sample(i, many), repeats)
            batch.append(cpu / len(many))
    us = 1e6
    out = {
        "frames": frames,
        "clips": len(first),
        "rotations_us_per_frame_fresh": us * fresh_cpu / frames,
        "rotations_us_per_frame_warm": us * warm_cpu / frames,
        "rotations_us_per_frame_fresh_wall": us * fresh_wall / frames,
        "rotations_us_per_frame_warm_wall": us * warm_wall / frames,
        "positions_us_per_frame_warm": us * pos_cpu / frames,
        "positions_us_per_frame_warm_wall": us * pos_wall / frames,
        "first_sample_us_median": us * statistics.median(first),
        "first_sample_us_max": us * max(first),
        "sample_index_us_median": us * statistics.median(by_index),
        "sample_name_us_median": us * statistics.median(by_name),
        "sample_batched_us_per_pose_median": us * statistics.median(batch),
    }
    if bound:
        out["sampler_pose_us_median"] = us * statistics.median(bound)
    return out


def error_figures(data: bytes, motions: list[Motion]) -> dict[str, float]:
    """The largest error the file declares and the largest joint or end-site error measured
    by :func:`independent_positions`, centimetres."""
    measured = 0.0
    with Archive.open(data) as archive:
        declared = max(float(e.max_error) for e in archive.entries)
        for i, motion in enumerate(motions):
            d = np.linalg.norm(
                independent_positions(motion) - independent_positions(archive.read(i)), axis=-1
            )
            measured = max(measured, float(d.max()))
    return {"max_error_declared_cm": declared, "max_error_independent_cm": measured}


def size_figures(result: BuildReport, motions: list[Motion], source_bytes: int) -> dict[str, Any]:
    """Sizes of a build made in memory (``details["data"]``) in ratios, bytes per frame, bits
    per joint per frame and kB/s."""
    size, errors = len(result.details["data"]), result.details["clip_errors"]
    joint_frames = sum(m.n_frames * m.skeleton.n_joints for m in motions)
    seconds = sum(m.n_frames / m.fps for m in motions)
    acl_raw = 4 * ACL_FLOATS_PER_BONE * joint_frames
    out = {
        "bytes": size,
        "bytes_per_frame": size / sum(m.n_frames for m in motions),
        "ratio_raw_float32": sum(result.details["raw_bytes"]) / size,
        "ratio_10_floats_per_bone": acl_raw / size,
        "bits_per_joint_frame": 8 * size / joint_frames,
        "kB_per_second": size / 1000 / seconds,
        "fps": sorted({float(m.fps) for m in motions}),
        "max_joint_cm": float(max(e.max_joint for e in errors)),
        "max_virtual_vertex_cm": float(max(e.max_virtual_vertex for e in errors)),
    }
    if source_bytes:
        out["ratio_text"] = source_bytes / size
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


def _dataset_paths(root: pathlib.Path, name: str, quick: bool) -> list[pathlib.Path]:
    from quatmotion.bench.compression import _paths

    paths = _paths(root, name, False)
    if name == "hdm05":  # the clips of one actor (HDM_<actor>_...), as the issue measured
        actor = sorted(p.name.split("_")[1] for p in paths)[0]
        paths = [p for p in paths if p.name.split("_")[1] == actor]
    return paths[:: max(1, len(paths) // 4)][:4] if quick else paths


def run(out: pathlib.Path, quick: bool = False, seed: int = 0) -> dict:
    from quatmotion.bench.compression import _load, compress_in_memory

    out = pathlib.Path(out)
    root = data_root()
    t_start = time.perf_counter()
    _warm_up()
    repeats = 1 if quick else 3
    result: dict[str, Any] = {
        **provenance("decode", out, quick, seed),
        "method": METHOD,
        "bounds_cm": list(BOUNDS),
        "acl": ACL,
        "headlines": HEADLINES,
        "datasets": {},
    }
    for name in DATASETS:
        paths = _dataset_paths(root, name, quick)
        motions, sizes = _load(paths)
        entry: dict[str, Any] = {"clips": len(motions), "files": [p.name for p in paths]}
        for bound in BOUNDS:
            sources = [(s, p.suffix.lower().lstrip(".")) for s, p in zip(sizes, paths, strict=True)]
            r = compress_in_memory(motions, sources, max_error=bound, method=METHOD, seed=seed)
            row = size_figures(r, motions, sum(sizes))
            row.update(error_figures(r.details["data"], motions))
            row.update(decode_figures(r.details["data"], repeats, seed))
            entry[f"{bound:g}cm"] = row
            result["datasets"][name] = entry
            atomic_write_json(out, result)
    result["seconds"] = time.perf_counter() - t_start
    atomic_write_json(out, result)
    return result
