"""I/O and forward-kinematics throughput.

``run(out, quick, seed)`` measures, on the files of the data folder (``$QUATMOTION_DATA``, else
``<project root>/../shared/data``):

* **Parse throughput**, MB/s (10^6 bytes of file text per second, one thread; ``mb_per_s`` by
  wall clock, ``mb_per_s_cpu`` by process CPU time, which a loaded machine distorts less): every
  AMC file (skeletons read once beforehand, not timed) and every BVH file; ``quick`` takes a
  seeded random subset. The Numba kernels are compiled (or loaded from cache) before timing.
  Per-file rates go to the JSON and to a histogram ``<stem>_parse.png`` beside ``out``.
* **Write throughput**, MB/s of text written, on a subset (writers are not the hot path).
* **Forward kinematics**, frames/s on a 31-joint CMU skeleton: the longest CMU clip tiled to at
  least 100,000 frames, median of 5 runs (wall and CPU time), joints only and joints plus end
  sites.
* **Reference agreement**: the largest distance, in cm, between our forward kinematics and the
  reference positions (``reference/*.npz``), which the tests bound by 1e-3 cm.
"""

from __future__ import annotations

import pathlib
import statistics
import tempfile
import time
from collections.abc import Mapping
from typing import Any

import numpy as np

from quatmotion._atomic import atomic_write_json
from quatmotion.bench._provenance import provenance
from quatmotion.bench._tables import fmt, get, table
from quatmotion.datasets import catalogue, data_root
from quatmotion.io import (
    asf_bone_end_positions,
    find_asf_for_amc,
    read_amc,
    read_asf,
    read_bvh,
    write_amc,
    write_bvh,
)
from quatmotion.motion import Motion, forward_kinematics
from quatmotion.viz import pyplot, save_figure

FK_FRAMES = 100_000
REPEATS = 5


def _paths(root: pathlib.Path, collections: tuple[str, ...]) -> list[pathlib.Path]:
    """The clip files of these collections of the data folder, in the given order."""
    return [e.path for c in collections for e in catalogue(root, collection=c)]


def _subset(files: list[pathlib.Path], quick: bool, rng: np.random.Generator, n: int) -> list:
    if not quick or len(files) <= n:
        return files
    return [files[i] for i in sorted(rng.choice(len(files), size=n, replace=False))]


def _parse_rates(files: list[pathlib.Path], read) -> dict[str, Any]:
    sizes, seconds, frames = [], [], 0
    cpu_seconds = 0.0
    for path in files:
        size = path.stat().st_size
        start, cpu_start = time.perf_counter(), time.process_time()
        motion = read(path)
        seconds.append(time.perf_counter() - start)
        cpu_seconds += time.process_time() - cpu_start
        sizes.append(size)
        frames += motion.n_frames
    rates = np.asarray(sizes) / np.maximum(np.asarray(seconds), 1e-12) / 1e6
    return {
        "files": len(files),
        "megabytes": float(np.sum(sizes) / 1e6),
        "frames": frames,
        "seconds": float(np.sum(seconds)),
        "mb_per_s": float(np.sum(sizes) / 1e6 / max(np.sum(seconds), 1e-12)),
        "cpu_seconds": cpu_seconds,
        "mb_per_s_cpu": float(np.sum(sizes) / 1e6 / max(cpu_seconds, 1e-12)),
        "frames_per_s": float(frames / max(np.sum(seconds), 1e-12)),
        "per_file_mb_per_s": {p.name: float(r) for p, r in zip(files, rates, strict=True)},
    }


def _write_rate(motions: list[Motion], write, suffix: str) -> dict[str, Any]:
    total_bytes, total_seconds = 0, 0.0
    with tempfile.TemporaryDirectory() as folder:
        for k, motion in enumerate(motions):
            path = pathlib.Path(folder) / f"{k}{suffix}"
            start = time.perf_counter()
            write(motion, path)
            total_seconds += time.perf_counter() - start
            total_bytes += path.stat().st_size
    return {
        "files": len(motions),
        "megabytes": total_bytes / 1e6,
        "seconds": total_seconds,
        "mb_per_s": total_bytes / 1e6 / max(total_seconds, 1e-12),
    }


def _fk_rate(motion: Motion) -> dict[str, Any]:
    tiles = -(-FK_FRAMES // motion.n_frames)
    big = Motion(
        skeleton=motion.skeleton,
        fps=motion.fps,
        root_translation=np.tile(motion.root_translation, (tiles, 1)),
        rotations=np.tile(motion.rotations, (tiles, 1, 1)),
    )
    out: dict[str, Any] = {"joints": big.n_joints, "sites": big.skeleton.n_sites}
    out["frames"] = big.n_frames
    for label, sites in (("joints", False), ("joints_and_sites", True)):
        forward_kinematics(big.slice(0, 100), include_sites=sites)
        timings, cpu_timings = [], []
        for _ in range(REPEATS):
            start, cpu_start = time.perf_counter(), time.process_time()
            forward_kinematics(big, include_sites=sites)
            timings.append(time.perf_counter() - start)
            cpu_timings.append(time.process_time() - cpu_start)
        out[f"{label}_frames_per_s"] = big.n_frames / statistics.median(timings)
        out[f"{label}_frames_per_s_cpu"] = big.n_frames / statistics.median(cpu_timings)
    return out


def _reference_errors(root: pathlib.Path) -> dict[str, float]:
    errors = {}
    for reference in sorted((root / "reference").glob("*.npz")):
        ref = np.load(reference)
        source = root / str(ref["source"])
        if "positions_cm" in ref.files:
            expected = ref["positions_cm"]
            motion = read_amc(source, root / str(ref["skeleton"])).slice(0, len(expected))
            actual = asf_bone_end_positions(motion)
        else:
            expected = ref["positions_file_units"]
            motion = read_bvh(source).slice(0, len(expected))
            actual = forward_kinematics(motion).positions / motion.skeleton.extras["bvh_scale"]
        errors[reference.stem] = float(np.abs(actual - expected).max())
    return errors


def _figure(out: pathlib.Path, result: dict[str, Any]) -> str | None:
    plt = pyplot()
    from matplotlib.ticker import MaxNLocator

    figure, axis = plt.subplots(figsize=(7, 4))
    rates = {k: list(result["parse"][k]["per_file_mb_per_s"].values()) for k in ("amc", "bvh")}
    every = [r for kind in rates.values() for r in kind]
    bins = np.linspace(0.0, max(every, default=1.0) * 1.02, 31)  # one set of bins for both
    totals = []
    for kind, values in rates.items():
        if values:
            parse = result["parse"][kind]
            axis.hist(values, bins=bins, alpha=0.6, label=f"{kind.upper()}: {len(values)} files")
            totals.append(
                f"{kind.upper()} {parse['mb_per_s']:.1f} MB/s over {parse['megabytes']:.1f} MB"
            )
    axis.axvline(20.0, color="k", linestyle="--", linewidth=1, label="target: 20 MB/s")
    axis.set_xlabel(
        "parse throughput of one file (MB/s: 10^6 bytes of text per second, one thread)"
    )
    axis.set_ylabel("number of files")
    axis.yaxis.set_major_locator(MaxNLocator(integer=True))
    quick = " (quick run: a seeded subset)" if result.get("quick") else ""
    axis.set_title(
        f"Motion-file parse throughput per file{quick}\nall files together: {'; '.join(totals)}",
        fontsize=10,
    )
    axis.legend(fontsize=8)
    return save_figure(figure, out.with_name(f"{out.stem}_parse.png"), dpi=120).name


def summary_tables(data: Mapping[str, Any]) -> list[dict[str, Any]]:
    """The tables ``quatmotion report`` shows of a result (:mod:`quatmotion.bench._tables`)."""
    rows = []
    for step in ("parse", "write"):
        for kind in ("amc", "bvh"):
            entry = get(data, step, kind)
            if isinstance(entry, Mapping):
                rows.append(
                    (
                        f"{step} {kind.upper()}",
                        entry.get("files"),
                        entry.get("megabytes"),
                        entry.get("mb_per_s"),
                        entry.get("mb_per_s_cpu"),
                        entry.get("frames_per_s"),
                    )
                )
    tables = [
        table(
            "Throughput (one thread)",
            ("", "files", "MB", "MB/s (wall)", "MB/s (CPU)", "frames/s"),
            tuple(rows),
            "MB = 10^6 bytes of file text.",
        )
    ]
    fk = get(data, "forward_kinematics")
    if isinstance(fk, Mapping):
        tables.append(
            table(
                "Forward kinematics",
                ("clip", "joints", "end sites", "frames", "frames/s (joints)", "frames/s (+sites)"),
                (
                    (
                        fk.get("clip"),
                        fk.get("joints"),
                        fk.get("sites"),
                        fk.get("frames"),
                        fk.get("joints_frames_per_s"),
                        fk.get("joints_and_sites_frames_per_s"),
                    ),
                ),
                f"Largest distance to the reference positions: "
                f"{fmt(data.get('reference_max_error_cm'))} cm.",
            )
        )
    return tables


def run(out: pathlib.Path, quick: bool = False, seed: int = 0) -> dict:
    """Measure parse, write and forward-kinematics throughput; write JSON to ``out``.

    Parameters
    ----------
    out : pathlib.Path
        JSON destination; the figure ``<stem>_parse.png`` goes beside it.
    quick : bool
        A seeded subset of the files (about 20 AMC and 20 BVH) instead of all.
    seed : int
        Chooses the subset.

    Returns
    -------
    dict
        The JSON content: ``parse.amc`` / ``parse.bvh`` (``mb_per_s``...), ``write``,
        ``forward_kinematics`` (``joints_frames_per_s``...), ``reference_max_error_cm``.
    """
    out = pathlib.Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    root = data_root()
    rng = np.random.default_rng(seed)
    amcs = _paths(root, ("cmu", "hdm05"))
    bvhs = _paths(root, ("bandai1", "cmu_bvh"))
    amcs = _subset(amcs, quick, rng, 20)
    bvhs = _subset(bvhs, quick, rng, 20)
    skeletons = {}
    for amc in amcs:
        asf = find_asf_for_amc(amc)
        if asf not in skeletons:
            skeletons[asf] = read_asf(asf)
    asf_of = {amc: skeletons[find_asf_for_amc(amc)] for amc in amcs}
    # Compile or load the Numba kernels before any timing.
    if amcs:
        read_amc(amcs[0], asf_of[amcs[0]])
    if bvhs:
        read_bvh(bvhs[0])

    result: dict[str, Any] = {**provenance("io", out, quick, seed), "data": str(root)}
    result["parse"] = {
        "amc": _parse_rates(amcs, lambda p: read_amc(p, asf_of[p])),
        "bvh": _parse_rates(bvhs, read_bvh),
    }
    write_amcs = [read_amc(p, asf_of[p]) for p in amcs[:: max(1, len(amcs) // 5)]]
    write_bvhs = [read_bvh(p) for p in bvhs[:: max(1, len(bvhs) // 5)]]
    result["write"] = {
        "amc": _write_rate(write_amcs, write_amc, ".amc"),
        "bvh": _write_rate(write_bvhs, write_bvh, ".bvh"),
    }
    cmu = _paths(root, ("cmu",))
    if cmu:
        longest = max(cmu, key=lambda p: p.stat().st_size)
        result["forward_kinematics"] = {"clip": longest.name, **_fk_rate(read_amc(longest))}
    errors = _reference_errors(root)
    result["reference_errors_cm"] = errors
    result["reference_max_error_cm"] = max(errors.values()) if errors else None
    figure = _figure(out, result)
    result["figures"] = [figure] if figure else []
    result["tables"] = summary_tables(result)
    atomic_write_json(out, result)
    return result
