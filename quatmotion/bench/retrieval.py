"""Content-based motion retrieval (QSSD paper section 5.2), every method in one run.

``quatmotion bench retrieval --out ret.json [--quick]``; from Python, ``run(...,
methods=...)`` scores a subset (the paper's methods cost most of the run: their dictionaries).
Leave-one-out on ``hdm05`` (class labels), ``bandai1`` (content labels) and generated
motions (their kind): each clip queries all the others; docs/metrics.md's TPR@20 (capped by class
size), precision@10, mAP over the full ranking and 1-NN accuracy, per class and averaged over
the queries that have a relevant clip; on bandai1 the share of the top 10 taken by a
neighbouring class (:data:`NEIGHBOURS`). Also the feature time per clip (index build seconds
per clip, by feature kind), query latency (median and p95, the query's features computed
inside the timing, from a loaded Motion: parsing is left out; the top :data:`TOP_N`, as
``search`` asks for, so the default's pruning counts) at each data set's size and on
synthetic libraries of 300, 1,000 and 10,000 clips, the share of full DTWs the default computed
there, and the Fig. 7 confusion matrices of the paper's method and the default, as PNG beside
the JSON. Its headline figures are listed under ``headlines``.

The synthetic libraries are built from the motion features of the real and generated clips,
each copy cropped (up to 20 % at each end), time-warped (x0.8-1.25) and jittered (1 cm), so
their lengths and contents are realistic; only their sizes matter for latency.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from multiprocessing import get_context
from pathlib import Path
from typing import Any

import numpy as np

from quatmotion._atomic import atomic_write_json
from quatmotion.motion import Motion
from quatmotion.retrieval.features import (
    FEATURE_FPS,
    HORIZON_S,
    clip_features,
    skeleton_fingerprint,
)
from quatmotion.retrieval.methods import DEFAULT_METHOD, METHODS, Library, QueryFeatures, Ranking
from quatmotion.retrieval.ranges import DEFAULT_TOP

__all__ = ["neighbour_share", "run", "retrieval_scores"]

TOP_N = DEFAULT_TOP  # as `search` asks for when no number is named
PRECISION_K = 10
KINDS = ("motion", "qssd", "ksvd")
PAPER = "paper-qssd"
SCALES = (300, 1_000, 10_000)
"""Sizes of the synthetic libraries the query latency is measured on (the issue's targets)."""


@dataclass
class _Dataset:
    name: str
    labels: list[str]
    motions: list[Motion]  # a sample of about 20, to time queries from a Motion
    features: list[dict[str, np.ndarray]]
    fingerprints: list[str]
    seconds: dict[str, list[float]]
    groups: list[str] | None = None  # actor or style: the label-learning splits


def _motion(source: tuple[str, str, str | None]) -> Motion:
    """A clip from ``("file", path, asf)`` or ``("generated", kind, seed)``."""
    what, a, b = source
    if what == "generated":
        from quatmotion.synthetic import generate_clip

        return generate_clip(a, int(b or 0))
    from quatmotion.io import read_motion

    return read_motion(a, b)


def _features_job(
    args: tuple[tuple[str, str, str | None], tuple[str, ...]],
) -> tuple[dict[str, np.ndarray], dict[str, float], str]:
    """Features of one clip and the seconds per kind (clips travel to workers as sources:
    motions hold read-only mappings that do not pickle)."""
    source, kinds = args
    motion = _motion(source)
    out: dict[str, np.ndarray] = {}
    secs: dict[str, float] = {}
    for kind in kinds:
        t0 = time.perf_counter()
        out.update(clip_features(motion, (kind,)))
        secs[kind] = time.perf_counter() - t0
    return out, secs, skeleton_fingerprint(motion.skeleton)


def _load(
    name: str, quick: bool, seed: int, log: Callable[[str], None], kinds: tuple[str, ...] = KINDS
) -> _Dataset:
    from quatmotion.datasets import catalogue

    sources: list[tuple[str, str, str | None]]
    if name == "synthetic":
        from quatmotion.synthetic import KINDS as MOTION_KINDS

        per_kind = 4 if quick else 12
        seeds = np.random.SeedSequence(seed).generate_state(per_kind * len(MOTION_KINDS))
        sources = [
            ("generated", k, str(int(seeds[i * per_kind + j])))
            for i, k in enumerate(MOTION_KINDS)
            for j in range(per_kind)
        ]
        labels = [s[1] for s in sources]
        groups = None
    else:
        entries = catalogue(collection=name)
        if quick:
            entries = entries[::4]
        sources = [
            ("file", str(e.path), str(e.skeleton_path) if e.skeleton_path else None)
            for e in entries
        ]
        labels = [e.label for e in entries]
        groups = [str(e.labels.get("actor") or e.labels.get("style") or "") for e in entries]
    log(f"{name}: {len(sources)} clips, computing features")
    workers = os.cpu_count() or 1
    # spawn, not fork: this process may already run OpenMP threads (Numba, BLAS)
    with ProcessPoolExecutor(max_workers=workers, mp_context=get_context("spawn")) as pool:
        results = list(pool.map(_features_job, [(s, kinds) for s in sources], chunksize=1))
    seconds = {k: [r[1][k] for r in results] for k in kinds}
    sample = [_motion(s) for s in sources[:: max(1, len(sources) // 20)]]
    return _Dataset(
        name,
        labels,
        sample,
        [r[0] for r in results],
        [r[2] for r in results],
        seconds,
        groups if groups and all(groups) else None,
    )


LEARNED = "dtw-fused-labels"


def label_learning(data: _Dataset) -> dict[str, Any] | None:
    """Learning from labels, measured on actors or styles not trained on: the groups (actor on
    hdm05, style on bandai1) sorted and dealt alternately into two halves; the model of
    ``dtw-fused-labels`` learned from one half's labels ranks the other half (leave-one-out
    inside it), against ``dtw-fused`` on the same clips, and the reverse. ``None`` without
    groups."""
    from quatmotion.retrieval.methods import fused_model

    if data.groups is None or LEARNED not in METHODS:
        return None
    names = sorted(set(data.groups))
    halves = (names[::2], names[1::2])
    out: dict[str, Any] = {"splits": []}
    for train, test in (halves, halves[::-1]):
        tr = [i for i, g in enumerate(data.groups) if g in train]
        te = [i for i, g in enumerate(data.groups) if g in test]
        labelled = Library(
            [data.features[i] for i in tr],
            [data.fingerprints[i] for i in tr],
            labels=[data.labels[i] for i in tr],
        )
        plain, learned = fused_model(labelled), fused_model(labelled, learned=True)
        feats, prints = [data.features[i] for i in te], [data.fingerprints[i] for i in te]
        labels = [data.labels[i] for i in te]
        split: dict[str, Any] = {"train": list(train), "test": list(test)}
        for method, key, model in (
            (DEFAULT_METHOD, "model:dtw-fused", plain),
            (LEARNED, "model:dtw-fused-labels", learned),
        ):
            library = Library(feats, prints, {key: model.to_bytes()})
            rankings = [
                METHODS[method].rank(library, QueryFeatures(f, p), exclude=i)
                for i, (f, p) in enumerate(zip(feats, prints, strict=True))
            ]
            scores = retrieval_scores(rankings, labels)
            split[method] = {k: scores[k] for k in ("map", "precision10", "nn1")}
        out["splits"].append(split)
    for method in (DEFAULT_METHOD, LEARNED):
        out[method] = {
            k: float(np.mean([s[method][k] for s in out["splits"]]))
            for k in ("map", "precision10", "nn1")
        }
    out["map_gain"] = out[LEARNED]["map"] - out[DEFAULT_METHOD]["map"]
    return out


def retrieval_scores(rankings: list[Ranking], labels: list[str]) -> dict[str, Any]:
    """docs/metrics.md's retrieval measures from leave-one-out rankings (query ``i`` is clip ``i``).

    Returns
    -------
    dict
        ``tpr20``, ``precision10``, ``map``, ``nn1`` averaged over the queries with at least
        one relevant clip, ``per_class`` (the same per query class), ``n_queries``, and
        ``confusion``: for each query class, the share of each class in the top 20.
    """
    lab = np.asarray(labels)
    classes = sorted(set(labels))
    per: dict[str, list[list[float]]] = {c: [] for c in classes}
    confusion = np.zeros((len(classes), len(classes)))
    for i, ranking in enumerate(rankings):
        ranked = lab[ranking.clips]
        relevant = ranked == lab[i]
        n_rel = int(np.sum(lab == lab[i])) - 1
        if n_rel == 0:
            continue
        hits = np.flatnonzero(relevant)
        ap = float(np.mean(np.arange(1, hits.size + 1) / (hits + 1))) * hits.size / n_rel
        per[labels[i]].append(
            [
                relevant[:TOP_N].sum() / min(TOP_N, n_rel),
                relevant[:PRECISION_K].mean() if relevant.size else 0.0,
                ap,
                float(relevant[0]) if relevant.size else 0.0,
            ]
        )
        top = ranked[: min(TOP_N, n_rel)]
        for c in top:
            confusion[classes.index(labels[i]), classes.index(str(c))] += 1.0 / max(len(top), 1)
    rows = [r for c in classes for r in per[c]]
    names = ("tpr20", "precision10", "map", "nn1")
    mean = np.mean(rows, axis=0) if rows else np.full(4, np.nan)
    counts = np.array([len(per[c]) for c in classes], dtype=float)
    confusion = confusion / np.maximum(counts[:, None], 1)
    return {
        **{n: float(v) for n, v in zip(names, mean, strict=True)},
        "n_queries": len(rows),
        "per_class": {
            c: {n: float(v) for n, v in zip(names, np.mean(per[c], axis=0), strict=True)}
            for c in classes
            if per[c]
        },
        "classes": classes,
        "confusion": confusion.tolist(),
    }


def _leave_one_out(data: _Dataset, method: str) -> tuple[dict[str, Any], list[float]]:
    library = Library(data.features, data.fingerprints)
    rankings: list[Ranking] = []
    times: list[float] = []
    for i in range(len(data.features)):
        query = QueryFeatures(data.features[i], data.fingerprints[i])
        t0 = time.perf_counter()
        rankings.append(METHODS[method].rank(library, query, exclude=i))
        times.append(time.perf_counter() - t0)
    scores = retrieval_scores(rankings, data.labels)
    if data.name in NEIGHBOURS:
        scores["neighbour_share10"] = neighbour_share(rankings, data.labels, NEIGHBOURS[data.name])
    return scores, times


def _latency(
    library: Library, motions: list[Motion], method: str, repeats: int
) -> dict[str, float]:
    # the library's packed arrays (and the default's model) are built once, before the timing
    METHODS[method].rank(library, QueryFeatures(library.features[0], library.fingerprints[0]))
    """Milliseconds of query features + ranking over ``repeats`` queries (after a warm-up):
    wall time, and the querying thread's processor time (on a shared machine the wall time
    also counts waiting for a core)."""
    from quatmotion.retrieval.search import query_features

    wall, cpu = [], []
    # queries spread over the sample (the data sets' clips differ in length by a factor of 3)
    picks = np.linspace(0, len(motions) - 1, repeats + 1).round().astype(int)
    for k, pick in enumerate(picks):
        motion = motions[pick]
        t0, c0 = time.perf_counter(), time.thread_time()
        METHODS[method].rank(library, query_features(motion, method), k=TOP_N)
        if k:
            wall.append(1e3 * (time.perf_counter() - t0))
            cpu.append(1e3 * (time.thread_time() - c0))
    return {
        "median_ms": float(np.median(wall)),
        "p95_ms": float(np.percentile(wall, 95)),
        "cpu_median_ms": float(np.median(cpu)),
        "cpu_p95_ms": float(np.percentile(cpu, 95)),
        "queries": len(wall),
        "clips": len(library),
        **_pruning(library, motions, method, picks),
    }


def _pruning(library: Library, motions: list[Motion], method: str, picks: Any) -> dict[str, float]:
    """For the default: the mean share of the library's clips whose full DTW was computed."""
    from quatmotion.retrieval.search import query_features

    if method != DEFAULT_METHOD or not len(library):
        return {}
    shares = [
        METHODS[method].distances(library, query_features(motions[p], method), k=TOP_N)[1]
        / len(library)
        for p in picks[1:]
    ]
    return {"full_dtw_share": float(np.mean(shares))}


def _warped(P: np.ndarray, idx: np.ndarray, rng: np.random.Generator, noise: float) -> np.ndarray:
    """Frames ``idx`` of ``P`` ``(T, d)`` with Gaussian jitter of ``noise``, float32."""
    rows = P.astype(np.float64)[idx.astype(int)]
    return (rows + rng.normal(0.0, noise, rows.shape)).astype(np.float32)


def neighbour_share(
    rankings: list[Ranking], labels: list[str], groups: tuple[tuple[str, ...], ...], k: int = 10
) -> dict[str, Any]:
    """Share of a query's top ``k`` taken by a *neighbouring* class: another class of the
    query's group in ``groups`` (e.g. walk against walk-left). Per query class and over all
    the queries of the groups' classes (``None`` when no query is in a group)."""
    lab = np.asarray(labels)
    per: dict[str, list[float]] = {}
    for i, ranking in enumerate(rankings):
        group = next((g for g in groups if labels[i] in g), None)
        if group is None:
            continue
        top = lab[ranking.clips[:k]]
        per.setdefault(labels[i], []).append(
            float(np.mean([(t in group) and t != labels[i] for t in top])) if top.size else 0.0
        )
    every = [v for vs in per.values() for v in vs]
    return {
        "all": float(np.mean(every)) if every else None,
        "per_class": {c: float(np.mean(v)) for c, v in sorted(per.items())},
    }


NEIGHBOURS: dict[str, tuple[tuple[str, ...], ...]] = {
    "bandai1": (("walk", "walk-left", "walk-right", "walk-back"), ("bye", "byebye")),
}
"""Per data set, the groups of classes whose confusion matters most (issue 19): walks that turn
or not, waving one hand or both."""


def _synthetic_library(
    sources: list[dict[str, np.ndarray]], prints: list[str], n: int, rng: np.random.Generator
) -> Library:
    from quatmotion.retrieval.features import motion_embedding

    feats, fps = [], []
    for _ in range(n):
        k = int(rng.integers(len(sources)))
        src = sources[k]
        F = src["frames"].astype(np.float64)
        T = len(F)
        a = int(rng.integers(0, max(1, T // 5)))
        b = T - int(rng.integers(0, max(1, T // 5)))
        idx = np.clip(np.round(np.arange(a, max(b, a + 1), rng.uniform(0.8, 1.25))), 0, T - 1)
        G = F[idx.astype(int)] + rng.normal(0.0, 1.0, (idx.size, F.shape[1]))
        # a stand-in for the velocity part: only the embedding's size and spread matter here
        V = np.gradient(G, axis=0) * FEATURE_FPS * HORIZON_S if len(G) > 1 else np.zeros_like(G)
        item = {
            "frames": G.astype(np.float32),
            "path": _warped(src["path"], idx, rng, 0.01),
            "embedding": motion_embedding(G, V).astype(np.float32),
        }
        for kind in ("qssd", "ksvd"):
            if kind in src:
                noisy = src[kind] + rng.normal(0.0, 1e-3, src[kind].shape)
                item[kind] = noisy / np.linalg.norm(noisy.reshape(5, -1), axis=1)[:, None, None]
        feats.append(item)
        fps.append(prints[k])
    return Library(feats, fps)


def _confusion_figure(path: Path, title: str, scores: dict[str, Any]) -> str:
    from quatmotion.viz.figures import pyplot, save_figure

    plt = pyplot()
    classes = scores["classes"]
    M = np.asarray(scores["confusion"])
    fig, ax = plt.subplots(figsize=(1.0 + 0.55 * len(classes), 0.8 + 0.5 * len(classes)))
    im = ax.imshow(M, vmin=0, vmax=1, cmap="Blues")
    ax.set_xticks(range(len(classes)), [c[:16] for c in classes], rotation=60, ha="right")
    ax.set_yticks(range(len(classes)), [c[:16] for c in classes])
    ax.set_xlabel("class of the retrieved clips (top 20, capped by class size)")
    ax.set_ylabel("query class")
    ax.set_title(title)
    for r in range(len(classes)):
        for c in range(len(classes)):
            if M[r, c] >= 0.005:
                ax.text(
                    c,
                    r,
                    f"{M[r, c]:.2f}",
                    ha="center",
                    va="center",
                    fontsize=7,
                    color="white" if M[r, c] > 0.6 else "black",
                )
    fig.colorbar(im, ax=ax, label="share of the retrieved clips")
    save_figure(fig, path)
    return path.name


def _headline(name: str, path: list[str], unit: str, better: str, fmt: str) -> dict[str, Any]:
    return {"name": name, "path": path, "unit": unit, "better": better, "format": fmt}


def _headlines(methods: list[str]) -> list[dict[str, Any]]:
    d = DEFAULT_METHOD
    out = [
        _headline(
            f"retrieval mAP, {ds} ({d})", ["datasets", ds, "methods", d, "map"], "", "higher", ""
        )
        for ds in ("hdm05", "bandai1", "synthetic")
    ]
    out.append(
        _headline(
            f"bandai1 neighbouring-class share of the top 10 ({d})",
            ["datasets", "bandai1", "methods", d, "neighbour_share10", "all"],
            "",
            "lower",
            "",
        )
    )
    out += [
        _headline(
            f"query p95 at {n:,} clips ({d}, {what})",
            ["scaling", str(n), d, key],
            "ms",
            "lower",
            "",
        )
        for n in SCALES
        for what, key in (("one core's processor time", "cpu_p95_ms"), ("wall", "p95_ms"))
    ]
    out += [
        _headline(
            f"mAP gain of labels learned on other {who} ({ds})",
            ["datasets", ds, "label_learning", "map_gain"],
            "",
            "higher",
            "",
        )
        for ds, who in (("hdm05", "actors"), ("bandai1", "styles"))
    ]
    out.append(
        _headline(
            "index build seconds a clip (motion)",
            ["datasets", "bandai1", "feature_seconds_per_clip", "motion"],
            "s",
            "lower",
            "",
        )
    )
    return out if d in methods else []


def _scored_methods(
    data: _Dataset, chosen: list[str], quick: bool, log: Callable[[str], None]
) -> dict[str, Any]:
    """Leave-one-out scores and query latency of each ``chosen`` method on one data set
    (``dtw-fused-labels`` is measured by :func:`label_learning` instead)."""
    library = Library(data.features, data.fingerprints)
    out: dict[str, Any] = {}
    for method in [m for m in chosen if m != LEARNED]:
        scores, times = _leave_one_out(data, method)
        repeats = 3 if method.startswith("paper") else (10 if quick else 50)
        scores["latency"] = _latency(library, data.motions, method, repeats)
        scores["rank_only_median_ms"] = float(1e3 * np.median(times))
        out[method] = scores
        log(
            f"  {data.name} {method}: mAP {scores['map']:.3f} P@10 {scores['precision10']:.3f} "
            f"TPR20 {scores['tpr20']:.3f} 1NN {scores['nn1']:.3f}, "
            f"{scores['latency']['median_ms']:.2f} ms"
        )
    return out


def run(
    out: Path, quick: bool = False, seed: int = 0, methods: list[str] | None = None
) -> dict[str, Any]:
    """Run the benchmark; write JSON to ``out`` and the figures beside it; return the dict.
    ``methods``: the names scored (default every method of ``METHODS``)."""
    from quatmotion.bench._provenance import provenance

    chosen = list(METHODS) if methods is None else [m for m in METHODS if m in methods]
    kinds = tuple(k for k in KINDS if any(k in METHODS[m].kinds for m in chosen))
    out = Path(out)
    t_start = time.perf_counter()

    def log(msg: str) -> None:
        print(f"[retrieval {time.perf_counter() - t_start:6.0f} s] {msg}", flush=True)

    rng = np.random.default_rng(seed)
    results: dict[str, Any] = provenance("retrieval", out, quick, seed)
    results.update(
        {
            "default_method": DEFAULT_METHOD,
            "methods": chosen,
            "headlines": _headlines(chosen),
            "datasets": {},
            "figures": [],
        }
    )
    sources: list[dict[str, np.ndarray]] = []
    prints: list[str] = []
    query_motions: list[Motion] = []
    for name in ("hdm05", "bandai1", "synthetic"):
        data = _load(name, quick, seed, log, kinds)
        res: dict[str, Any] = {
            "clips": len(data.labels),
            "feature_seconds_per_clip": {k: float(np.mean(v)) for k, v in data.seconds.items()},
        }
        res["methods"] = _scored_methods(data, chosen, quick, log)
        learning = label_learning(data)
        if learning is not None:
            res["label_learning"] = learning
            log(
                f"  {name} labels learned on other actors/styles: mAP "
                f"{learning[DEFAULT_METHOD]['map']:.3f} -> {learning[LEARNED]['map']:.3f}"
            )
        for method in [m for m in (PAPER, DEFAULT_METHOD) if m in chosen]:
            fig = out.with_name(f"{out.stem}_{name}_confusion_{method.replace('+', '_')}.png")
            results["figures"].append(
                _confusion_figure(
                    fig,
                    f"{name}: {method} (TPR@20 {res['methods'][method]['tpr20']:.2f})",
                    res["methods"][method],
                )
            )
        results["datasets"][name] = res
        sources += data.features
        prints += data.fingerprints
        query_motions += data.motions
        atomic_write_json(out, results)  # partial results survive a later failure
    results["scaling"] = {}
    for n in SCALES:
        library = _synthetic_library(sources, prints, n, rng)
        entry = {}
        for method in [m for m in chosen if m != LEARNED]:
            if method.startswith("paper") and quick:
                continue
            repeats = 3 if method.startswith("paper") else (5 if _unpruned(method) else 30)
            entry[method] = _latency(library, query_motions, method, repeats)
            log(f"  {n} clips {method}: {entry[method]['median_ms']:.2f} ms")
        results["scaling"][str(n)] = entry
    results["seconds"] = time.perf_counter() - t_start
    atomic_write_json(out, results)
    return results


def _unpruned(method: str) -> bool:
    """A DTW over every clip (slow at 10,000 clips: fewer timed queries)."""
    return method.startswith("dtw") and method not in (DEFAULT_METHOD, LEARNED)
