"""Motion compression (issue 10; the QSSD paper's section 5.1): every codec on four data sets.

``run(out, quick, seed)`` writes JSON to ``out`` and PNG figures beside it
(``<stem>_rd_<dataset>.png``: ratio against ARMS and against max joint error;
``<stem>_size.png``: ratio against collection size, the paper's Fig. 3).

* **Data sets** (from the data folder): ``walk`` = CMU 02_01, 02_02, 03_01-03_04 (AMC) plus the
  ``cmu_bvh`` walks; ``walk_amc`` = the six AMC clips alone (the issue's and the paper's
  basis for the walk targets); ``mixed`` = every CMU AMC clip; ``hdm05``; ``bandai1``.
* **Table 3 rows** per data set and codec at the lossy point: every joint within 5 cm, and
  ARMS at most 1.33 cm (walk, hdm05, bandai1) or 1.92 cm (mixed): the codec's quality knob is
  lowered until the ARMS holds. Sizes are whole files; ratios against the source text and
  against raw float32 channels; compression ms per frame (amortised, dictionary learning
  included); decompression microseconds per frame to local rotations and root translation
  (``Archive.read_rotations``) and to positions (plus forward kinematics), median of 5 runs.
  For QSSD and K-SVD the compression time includes learning the dictionary once (the ARMS
  search reuses it between tries).
* **Bounded points** on ``walk_amc``: every joint within 1 cm, within 0.1 cm; every virtual
  vertex within 0.02 cm.
* **Rate-distortion curves**: ``best`` and ``spline`` at bounds 20, 10, 5, 2, 1 cm; ``naive``,
  ``qssd`` and ``ksvd`` along their own quality knob without a bound (what they give without
  repair: their max errors show the glitches and flips they smooth or cut across); ratio
  against ARMS and against the max joint error.
* **Ratio against collection size** (Fig. 3): the first 1, 2, 4... clips of walk and mixed at
  the 5 cm bound.

``quick`` uses four clips per set (not ``walk``), two bounds, three dictionary iterations and
one decoding run: a smoke run of every code path in a few minutes, not numbers to quote.

The data sets (and the collection-size curves) are the items of a
:class:`quatmotion.parallel.Runner` (by default a local pool on the available cores, or
``QUATMOTION_SCHEDULER``); each item's compressions run inline in its worker, so compression
times are single-process per frame on every runner, and the bytes are the same on every one.
The ARMS search tries the x0.7 steps of the knob in the order :func:`search_quality_step` picks
(the same step as trying them in turn, in fewer encodes), and the sparse codecs learn each
layout's dictionary once per data set (the codec's fit cache), reused by every later try.
"""

from __future__ import annotations

import pathlib
import statistics
import time
from typing import Any

import numpy as np

from quatmotion._atomic import atomic_write_json
from quatmotion.codec import Archive, CompressSettings
from quatmotion.codec.methods import METHODS, SparseMethod
from quatmotion.codec.methods.sparse import cached_fit_seconds, clear_fit_cache
from quatmotion.codec.metrics import collection_errors
from quatmotion.codec.writer import build_library
from quatmotion.collection import BuildReport
from quatmotion.datasets import catalogue, data_root
from quatmotion.io import read_motion
from quatmotion.motion import forward_kinematics
from quatmotion.parallel import Runner
from quatmotion.viz import pyplot, save_figure

ORDER = ("best", "spline", "naive", "qssd", "ksvd")
WALK_AMC = ("02_01", "02_02", "03_01", "03_02", "03_03", "03_04")
ARMS_TARGET = {"walk": 1.33, "walk_amc": 1.33, "mixed": 1.92, "hdm05": 1.33, "bandai1": 1.33}
PAPER = {  # Table 3 of the paper: (ratio, ARMS, DR, compression ms/frame, decompression ms/frame)
    "walk": {"qssd": (62, 1.33, 2.64, 42.5, 0.8), "ksvd": (62, 5.86, 6.22, 23.9, 0.7)},
    "mixed": {"qssd": (55, 1.92, 2.91, 48.4, 0.7), "ksvd": (55, 6.25, 8.70, 25.0, 0.6)},
}


def _paths(root: pathlib.Path, name: str, quick: bool) -> list[pathlib.Path]:
    cmu = [e for e in catalogue(root, collection="cmu")]
    if name in ("walk", "walk_amc"):
        amc = [e.path for e in cmu if e.name in WALK_AMC]
        bvh = [e.path for e in catalogue(root, collection="cmu_bvh")] if name == "walk" else []
        paths = amc + bvh
        return (amc[:2] + bvh[:2]) if quick else paths
    if name == "mixed":
        paths = [e.path for e in cmu]
    else:
        paths = [e.path for e in catalogue(root, collection=name)]
    return paths[:: max(1, len(paths) // 4)][:4] if quick else paths


def _load(paths):
    return [read_motion(p) for p in paths], [p.stat().st_size for p in paths]


def compress_in_memory(motions, sources, scheduler=None, **settings: Any) -> BuildReport:
    """The clips given in memory compressed to bytes (``report.details["data"]``) with
    :class:`CompressSettings` of ``settings`` (no bound unless one is given), their sources'
    sizes and formats (``sources``) stored for the ratios."""
    return build_library(
        motions,
        None,
        CompressSettings(**{"max_error": None, **settings}),
        runner=Runner.of(None, scheduler),
        source_sizes=sources,
    )


def _row(result: BuildReport, source_bytes: int, decode_runs: int) -> dict[str, Any]:
    details = result.details
    size = len(details["data"])
    errors = collection_errors(details["clip_errors"])
    frames = errors.frames
    to_rotations, to_positions = [], []
    with Archive.open(details["data"]) as archive:
        for _ in range(decode_runs):
            t = time.perf_counter()
            for i in range(len(archive)):
                archive.read_rotations(i)
            to_rotations.append(time.perf_counter() - t)
            t = time.perf_counter()
            for i in range(len(archive)):
                forward_kinematics(archive.read(i))
            to_positions.append(time.perf_counter() - t)
    return {
        "bytes": size,
        "ratio_text": source_bytes / size,
        "ratio_raw": sum(details["raw_bytes"]) / size,
        "arms_cm": errors.arms,
        "distortion_rate": errors.distortion_rate,
        "max_joint_cm": errors.max_joint,
        "max_virtual_vertex_cm": errors.max_virtual_vertex,
        "compress_ms_per_frame": 1e3 * details["seconds"] / frames,
        "decompress_us_per_frame_rotations": 1e6 * statistics.median(to_rotations) / frames,
        "decompress_us_per_frame_positions": 1e6 * statistics.median(to_positions) / frames,
        "corrected_values": int(sum(details["corrections"])),
        "quality": details["quality"],
        "frames": frames,
        "clips": len(details["clip_errors"]),
    }


QUALITY_STEP = 0.7
"""The lossy point's knob is ``default * QUALITY_STEP ** k``, ``k`` below :data:`QUALITY_STEPS`."""
QUALITY_STEPS = 8


def search_quality_step(arms_of, arms_target: float, steps: int = QUALITY_STEPS) -> tuple[int, int]:
    """The first step ``k`` (knob ``default * QUALITY_STEP ** k``) whose ARMS holds the target,
    as trying ``k = 0, 1, 2...`` in turn would find it where the ARMS grows with the knob, in
    fewer tries: ``k = 0`` first, then a secant on log-ARMS against log-knob (slope 1 until two
    steps are measured) names the next step inside the bracket of a miss and a hit, until they
    are adjacent (at most one try more than the fixed steps when they stop within two steps,
    fewer when they go further). ``arms_of(k)`` encodes once; ``steps - 1`` when no step holds.

    Returns ``(k, tries)``."""
    measured: dict[int, float] = {}

    def arms(k: int) -> float:
        if k not in measured:
            measured[k] = float(arms_of(k))
        return measured[k]

    if arms(0) <= arms_target:
        return 0, 1
    miss, hit = 0, steps  # ``steps``: no step has held (yet)
    while hit - miss > 1:
        below = [k for k in measured if k <= miss]
        above = [k for k in measured if k >= hit]
        a = max(below)
        others = sorted(k for k in below if k != a)
        b = min(above) if above else (others[-1] if others else None)
        la = np.log(max(measured[a], 1e-12))
        if b is None:
            slope = 1.0  # ARMS proportional to the knob
        else:
            lb = np.log(max(measured[b], 1e-12))
            slope = (la - lb) / ((a - b) * np.log(QUALITY_STEP)) if la != lb else 1.0
            if not np.isfinite(slope) or slope <= 0:
                slope = 1.0
        # log ARMS(k) ~ la + slope * (k - a) * log(step): the first k predicted to hold
        predicted = a + (np.log(arms_target) - la) / (slope * np.log(QUALITY_STEP))
        k = int(min(max(np.ceil(predicted - 1e-9), miss + 1), hit - 1))
        if arms(k) <= arms_target:
            hit = k
        else:
            miss = k
    return (hit if hit < steps else steps - 1), len(measured)


def _lossy_point(motions, sources, method, arms_target, seed, decode_runs, scheduler=None):
    """5 cm bound; the quality knob lowered in steps of x0.7 (:func:`search_quality_step`) to
    the first step whose ARMS target holds."""
    q0 = METHODS[method].default_quality
    source_bytes = sum(s for s, _ in sources)
    sparse = isinstance(METHODS[method], SparseMethod)
    if sparse:
        clear_fit_cache()  # the first try learns the dictionaries; their time is counted below
    results: dict[int, tuple] = {}

    def arms_of(k: int) -> float:
        result = compress_in_memory(
            motions,
            sources,
            scheduler,
            max_error=5.0,
            method=method,
            quality=q0 * QUALITY_STEP**k,
            seed=seed,
        )
        results[k] = (result, collection_errors(result.details["clip_errors"]))
        return results[k][1].arms

    # The sparse codecs' coarse (1 in 8 frames) model floors their ARMS: two steps only.
    k, tries = search_quality_step(arms_of, arms_target, 2 if sparse else QUALITY_STEPS)
    if k not in results:  # no step held and the last was never tried
        arms_of(k)
        tries += 1
    result, errors = results[k]
    out = _row(result, source_bytes, decode_runs)
    if sparse:
        out["dictionary_seconds"] = cached_fit_seconds()
        if k > 0:  # the reported try reused the first try's dictionaries: count their learning
            out["compress_ms_per_frame"] += 1e3 * out["dictionary_seconds"] / out["frames"]
    out["arms_target_cm"] = arms_target
    out["arms_target_met"] = bool(errors.arms <= arms_target)
    out["encodes"] = tries
    return out


def _figure_rd(name: str, curves: dict[str, list[dict]], path: pathlib.Path) -> None:
    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for method in ORDER:
        pts = curves.get(method, [])
        if not pts:
            continue
        for ax, key in zip(axes, ("arms_cm", "max_joint_cm"), strict=True):
            xs = [p[key] for p in pts]
            ys = [p["ratio_text"] for p in pts]
            ax.plot(xs, ys, "o-", label=method, lw=2.2 if method == "best" else 1.2)
    from matplotlib.ticker import LogLocator, ScalarFormatter

    for ax, label in zip(axes, ("ARMS (cm)", "max joint error (cm)"), strict=True):
        ax.set_xlabel(label)
        ax.set_ylabel("compression ratio against the source text")
        ax.set_xscale("log")
        ax.set_yscale("log")
        for axis in (ax.xaxis, ax.yaxis):
            # plain numbers at 1, 2, 5 x 10^k: the default labels every minor tick and overlaps
            axis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
            axis.set_major_formatter(ScalarFormatter())
            axis.set_minor_formatter(plt.NullFormatter())
        ax.grid(True, which="both", alpha=0.3)
        ax.legend()
    axes[0].set_title(f"{name}: ratio against ARMS")
    axes[1].set_title(f"{name}: ratio against max joint error")
    save_figure(fig, path)


def _figure_sizes(sizes: dict[str, dict[str, list[dict]]], path: pathlib.Path) -> None:
    plt = pyplot()
    fig, axes = plt.subplots(1, len(sizes), figsize=(5.5 * len(sizes), 4.2), squeeze=False)
    for ax, (name, curves) in zip(axes[0], sizes.items(), strict=True):
        for method, pts in curves.items():
            ax.plot([p["frames"] for p in pts], [p["ratio_text"] for p in pts], "o-", label=method)
        ax.set_xscale("log")
        ax.set_xlabel("frames in the collection")
        ax.set_ylabel("compression ratio against the source text")
        ax.set_title(f"{name}: ratio against collection size (5 cm bound)")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend()
    save_figure(fig, path)


def _configure(quick: bool) -> None:
    """The sparse codecs' dictionary options for this run (in every worker process)."""
    for name in ("qssd", "ksvd"):
        METHODS[name] = SparseMethod(name, max_iter=3) if quick else SparseMethod(name)


def _datasets(quick: bool) -> tuple[str, ...]:
    if quick:
        return ("walk_amc", "mixed", "hdm05", "bandai1")
    return ("walk_amc", "walk", "mixed", "hdm05", "bandai1")


def _sources(paths, sizes) -> list[tuple[int, str]]:
    return [(s, p.suffix.lower().lstrip(".")) for s, p in zip(sizes, paths, strict=True)]


def _dataset_entry(name: str, quick: bool, seed: int, out: pathlib.Path, scheduler) -> dict:
    """One data set's Table 3 rows, rate-distortion curves (and figure) and bounded points."""
    _configure(quick)
    decode_runs = 1 if quick else 5
    bounds = (10.0, 2.0) if quick else (20.0, 10.0, 5.0, 2.0, 1.0)
    paths = _paths(data_root(), name, quick)
    motions, sizes = _load(paths)
    source = sum(sizes)
    entry: dict[str, Any] = {
        "clips": len(motions),
        "frames": sum(m.n_frames for m in motions),
        "source_bytes": source,
        "table3": {},
        "rd": {},
    }
    sources = _sources(paths, sizes)
    for method in ORDER:
        entry["table3"][method] = _lossy_point(
            motions, sources, method, ARMS_TARGET[name], seed, decode_runs, scheduler
        )
        curve = []
        if method in ("best", "spline"):
            for bound in bounds:
                r = compress_in_memory(
                    motions, sources, scheduler, max_error=bound, method=method, seed=seed
                )
                row = _row(r, source, 1)
                row["bound_cm"] = bound
                curve.append(row)
        else:
            # the sparse codecs reuse the dictionaries their lossy point learned
            q0 = METHODS[method].default_quality
            for factor in (4.0, 1.0) if quick else (4.0, 2.0, 1.0, 0.5, 0.25):
                r = compress_in_memory(
                    motions, sources, scheduler, method=method, quality=q0 * factor, seed=seed
                )
                row = _row(r, source, 1)
                row["quality"] = q0 * factor
                curve.append(row)
        entry["rd"][method] = curve
    _figure_rd(name, entry["rd"], out.with_name(f"{out.stem}_rd_{name}.png"))
    if name == "walk_amc":
        bounded = {}
        for label, kwargs in (
            ("joints_1cm", {"max_error": 1.0}),
            ("joints_0.1cm", {"max_error": 0.1}),
            ("vertices_0.02cm", {"max_error": 0.02, "bound_on": "vertices"}),
        ):
            bounded[label] = {
                method: _row(
                    compress_in_memory(
                        motions, sources, scheduler, method=method, seed=seed, **kwargs
                    ),
                    source,
                    1,
                )
                for method in ("best", "spline")
            }
        entry["bounded"] = bounded
    clear_fit_cache()  # a worker's next data set learns its own
    return entry


def _size_curves(name: str, quick: bool, seed: int, scheduler) -> dict[str, list[dict]]:
    """Ratio against collection size (the first 1, 2, 4... clips) at the 5 cm bound."""
    paths = _paths(data_root(), name, quick)
    motions, sizes = _load(paths)
    sources = _sources(paths, sizes)
    counts = [n for n in (1, 2, 4, 8, 16, 32) if n < len(paths)] + [len(paths)]
    curves: dict[str, list[dict]] = {}
    for method in ("best", "spline", "naive"):
        pts = []
        for n in counts:
            r = compress_in_memory(
                motions[:n], sources[:n], scheduler, max_error=5.0, method=method, seed=seed
            )
            pts.append(_row(r, sum(sizes[:n]), 1))
        curves[method] = pts
    return curves


def _part(item: tuple[str, str], context: tuple) -> dict:
    """One item of the run (``("dataset" | "sizes", name)``), in a worker of the run's
    runner; its compressions run in that process (the data sets are the parallel unit)."""
    kind, name = item
    quick, seed, out = context
    if kind == "dataset":
        return _dataset_entry(name, quick, seed, pathlib.Path(out), "inline")
    return _size_curves(name, quick, seed, "inline")


def run(
    out: pathlib.Path, quick: bool = False, seed: int = 0, runner: Runner | None = None
) -> dict:
    """Every part of the benchmark on ``runner`` (default :meth:`Runner.resolve`: a local
    process pool on the available cores, or ``QUATMOTION_SCHEDULER``), one data set per item:
    the same JSON (but for the times) and figures on every runner."""
    out = pathlib.Path(out)
    t_start = time.perf_counter()
    runner = runner or Runner.resolve()
    result: dict[str, Any] = {"quick": quick, "seed": seed, "paper_table3": PAPER, "datasets": {}}
    items = [("dataset", name) for name in _datasets(quick)]
    items += [("sizes", name) for name in (("mixed",) if quick else ("walk", "mixed"))]
    sizes_curves: dict[str, dict[str, list[dict]]] = {}
    for outcome in runner.map(_part, items, context=(quick, seed, str(out))):
        kind, name = outcome.item
        if not outcome.ok:
            raise RuntimeError(f"compression bench, {kind} {name}: {outcome.failure}")
        if kind == "dataset":
            result["datasets"][name] = outcome.value
            atomic_write_json(out, result)  # partial results survive an interrupted run
        else:
            sizes_curves[name] = outcome.value
    result["collection_size"] = sizes_curves
    _figure_sizes(sizes_curves, out.with_name(f"{out.stem}_size.png"))
    result["seconds"] = time.perf_counter() - t_start
    atomic_write_json(out, result)
    return result
