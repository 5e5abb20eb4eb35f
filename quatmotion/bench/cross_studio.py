"""Clip search across studios: queries from one studio, relevance by content in the others.

A library mixing the shared studios (bandai1, HDM05, CMU ASF and CMU BVH: four rigs, four
stages), every clip labelled by its content in a vocabulary the studios share
(:data:`CONTENT`: walk, run, kick, punch, bow; clips of other content stay in the library as
distractors). Each studio in turn gives the queries; a query is answered from the *other*
studios' clips alone, and a clip is relevant when its content is the query's. Scored per
query studio and over all queries: mAP, P@10 and the 1-NN hit rate (METRICS.md).

Every method runs on two bodies (:data:`quatmotion.retrieval.features.BODIES`): ``scaled``
(each rig's own 16 joints scaled to one stature) and ``canonical`` (every bone on one body),
with the default (``dtw-fused``) beside the plain DTW over stature-scaled 16-joint positions
(``dtw-positions``), the 0.4.0 default (``dtw-fused-route``) and the path DTW
(``dtw-heading``). ``--quick`` takes every other clip of
each studio.
"""

from __future__ import annotations

import os
import time
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path
from typing import Any

import numpy as np

from quatmotion._atomic import atomic_write_json
from quatmotion.bench._provenance import provenance

__all__ = ["CONTENT", "STUDIOS", "content_of", "run"]

STUDIOS = ("bandai1", "hdm05", "cmu", "cmu_bvh")
"""The shared studios, by catalogue collection."""
CONTENT: dict[str, tuple[str, ...]] = {
    "walk": ("walk", "slow walk", "brisk walk", "walk/stride", "sneak2StepsLStart"),
    "run": ("run", "dash", "run/jog", "jogLeftCircle4StepsRstart"),
    "kick": ("kick", "kickLFront1Reps"),
    "punch": ("punch", "punch/strike"),
    "bow": ("bow",),
}
"""Content classes the studios share, and each studio's labels for them."""
METHODS = ("dtw-fused", "dtw-positions", "dtw-fused-route", "dtw-heading")
DISTRACTORS = {"bandai1": ("bye", "guide", "call", "slash"), "hdm05": ("squat1Reps", "grabHighR")}
"""Labels kept in the library as content no other studio has (a query never wants them)."""


def content_of(label: str) -> str | None:
    """The shared content class of a studio's label, or None."""
    return next((c for c, labels in CONTENT.items() if label in labels), None)


def _features_job(args: tuple[str, str | None]) -> dict[str, dict[str, np.ndarray]]:
    from quatmotion.io import read_motion
    from quatmotion.retrieval.features import BODIES, clip_features

    path, asf = args
    motion = read_motion(path, asf)
    return {body: clip_features(motion, ("motion",), body=body) for body in BODIES}


def _entries(quick: bool) -> list[tuple[str, str, str | None, str]]:
    """(studio, path, asf, content or a distractor's label) of every clip taken."""
    from quatmotion.datasets import catalogue

    out = []
    for studio in STUDIOS:
        entries = catalogue(collection=studio)
        keep = [e for e in entries if content_of(e.label) or e.label in DISTRACTORS.get(studio, ())]
        if studio in DISTRACTORS:  # a few of each distractor label, not all
            seen: dict[str, int] = {}
            kept = []
            for e in keep:
                if content_of(e.label) is None:
                    seen[e.label] = seen.get(e.label, 0) + 1
                    if seen[e.label] > 6:
                        continue
                kept.append(e)
            keep = kept
        if quick:
            keep = keep[::2]
        for e in keep:
            asf = str(e.skeleton_path) if e.skeleton_path else None
            out.append((studio, str(e.path), asf, content_of(e.label) or f"other:{e.label}"))
    return out


def _scores(rankings: list[np.ndarray], query_content: list[str], contents: np.ndarray) -> dict:
    aps, p10, nn1 = [], [], []
    for ranking, content in zip(rankings, query_content, strict=True):
        relevant = contents[ranking] == content
        n_rel = int(relevant.sum())
        if n_rel == 0:
            continue
        hits = np.flatnonzero(relevant)
        aps.append(float(np.mean(np.arange(1, hits.size + 1) / (hits + 1))))
        p10.append(float(relevant[:10].mean()))
        nn1.append(float(relevant[0]))
    return {
        "map": float(np.mean(aps)) if aps else float("nan"),
        "precision10": float(np.mean(p10)) if p10 else float("nan"),
        "nn1": float(np.mean(nn1)) if nn1 else float("nan"),
        "n_queries": len(aps),
    }


def run(out: Path, quick: bool = False, seed: int = 0) -> dict[str, Any]:
    """Measure cross-studio retrieval (module docstring); write JSON to ``out``."""
    from quatmotion.retrieval.features import BODIES, BODY
    from quatmotion.retrieval.methods import METHODS as ALL
    from quatmotion.retrieval.methods import Library, QueryFeatures

    entries = _entries(quick)
    t0 = time.perf_counter()
    workers = os.cpu_count() or 1
    with ProcessPoolExecutor(max_workers=workers, mp_context=get_context("spawn")) as pool:
        features = list(pool.map(_features_job, [(e[1], e[2]) for e in entries], chunksize=2))
    seconds = time.perf_counter() - t0
    # positions compare across rigs: every clip under one fingerprint
    studios = np.array([e[0] for e in entries])
    contents = np.array([e[3] for e in entries])
    results: dict[str, Any] = {}
    for body in BODIES:
        for method in METHODS:
            per_studio: dict[str, Any] = {}
            all_rankings: list[np.ndarray] = []
            all_contents: list[str] = []
            all_targets: list[np.ndarray] = []
            for studio in STUDIOS:
                others = np.flatnonzero(studios != studio)
                wanted = set(contents[others])
                queries = [
                    i
                    for i in np.flatnonzero(studios == studio)
                    if not contents[i].startswith("other:") and contents[i] in wanted
                ]
                if not queries:
                    continue
                library = Library([features[i][body] for i in others], ["rig"] * len(others))
                rankings = []
                for i in queries:
                    ranking = ALL[method].rank(library, QueryFeatures(features[i][body], "rig"))
                    rankings.append(np.asarray(ranking.clips))
                per_studio[studio] = _scores(
                    rankings, [contents[i] for i in queries], contents[others]
                )
                all_rankings += rankings
                all_contents += [contents[i] for i in queries]
                all_targets += [contents[others]] * len(queries)
            pooled = [
                _scores([r], [c], t)
                for r, c, t in zip(all_rankings, all_contents, all_targets, strict=True)
            ]
            n = sum(p["n_queries"] for p in pooled)
            summary = {
                k: float(np.sum([p[k] * p["n_queries"] for p in pooled if p["n_queries"]]) / n)
                for k in ("map", "precision10", "nn1")
            }
            results[f"{method}@{body}"] = {**summary, "n_queries": n, "per_studio": per_studio}
    counts = {
        s: {c: int(np.sum((studios == s) & (contents == c))) for c in sorted(set(contents))}
        for s in STUDIOS
    }
    doc = {
        **provenance("cross_studio", out, quick, seed),
        "features_body": BODY,
        "clips": len(entries),
        "clips_per_studio_and_content": counts,
        "feature_seconds": seconds,
        "results": results,
        "headlines": [
            {"name": f"{key} mAP across studios", "value": value["map"]}
            for key, value in results.items()
        ],
    }
    atomic_write_json(out, doc)
    return doc
