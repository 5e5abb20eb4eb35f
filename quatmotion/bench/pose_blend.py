"""Transition decision under labels judged on the blended transition (issue 20).

``run(out, quick, seed)``: for each data set (``hdm05``, ``cmu``, ``bandai``, prepared and split
as :mod:`quatmotion.bench.pose` does, except that a data set whose every-third-group test side
has fewer than 10 clips holds out every other group) and each of ``n_seeds`` seeds
(``seed`` .. ``seed + n_seeds - 1``), good and bad transition pairs of the training and of
the test subjects are labelled by
:func:`quatmotion.pose.blend_labels.blended_transition_labels` (natural percentiles fitted on
the training clips, reused on the test clips); every registered method of
:data:`quatmotion.pose.methods.METHODS` (aliases once), the feet-only baseline ``FEET`` among
them, and the row ``"pose index default"`` (what ``quatmotion pose index`` ships, trained on
its own pairs) and ``"pose search --transitions"`` (the transition judge a library learns
and stores, on its own blended labels of the training clips) are fitted on the training pairs
and scored on the test pairs by transition precision (docs/metrics.md). Reported per method: mean
and standard deviation over seeds, the share of good labels among decided candidates, and,
for comparison, the transition precision of the same methods on *near* pairs only (Eq. 35
mean joint distance under 10 cm, the paper's tau; candidates reach 25 cm).

Quick mode: one seed, fewer clips and pairs, and the RDSR / Xing learners (minutes per fit on
a shared machine) left out and listed in ``not_run``.
"""

from __future__ import annotations

import pathlib
import time
import traceback
from typing import Any

import numpy as np

from quatmotion._atomic import atomic_write_json
from quatmotion.bench._provenance import progress_log, provenance
from quatmotion.bench.pose import (
    INDEX_DEFAULT,
    TARGET_FPS,
    _index_default_entry,
    _load,
    _methods,
    _split,
    near_precision,
)
from quatmotion.datasets import data_root
from quatmotion.pose import evaluate, labels
from quatmotion.pose.blend_labels import GOOD_RATIO, blended_transition_labels
from quatmotion.pose.data import PoseData

__all__ = ["run"]

INDEX_JUDGE = "pose search --transitions"  # the row of the judge a library stores
NEAR_CM = 10.0  # "near pairs": Eq. 35 mean joint distance under this (the paper's tau)
_SLOW = ("RDSR", "Xing")
_DATASETS = ("hdm05", "cmu", "bandai")
_MIN_TEST_CLIPS = 10


def _split_blend(clips: list) -> tuple[list[int], list[int]]:
    """:func:`quatmotion.bench.pose._split` (every third group held out), or every other group
    when that leaves fewer than ``_MIN_TEST_CLIPS`` test clips (CMU's subjects: 4 clips, 2
    test pairs)."""
    train, test = _split(clips)
    if len(test) >= _MIN_TEST_CLIPS:
        return train, test
    groups = sorted({c.group for c in clips})
    test_groups = set(groups[1::2])
    train = [i for i, c in enumerate(clips) if c.group not in test_groups]
    test = [i for i, c in enumerate(clips) if c.group in test_groups]
    return train, test


def _headlines(datasets: tuple[str, ...]) -> list[dict[str, Any]]:
    """The shipped default's and the feet baseline's precision per data set (mean over seeds)."""
    rows = []
    for kind in datasets:
        for method, key, what in (
            (INDEX_DEFAULT, "precision", "pose index default"),
            ("FEET", "precision", "FEET baseline"),
            (INDEX_DEFAULT, "near_precision", "pose index default, near pairs"),
            (INDEX_JUDGE, "precision", "pose search --transitions"),
            (INDEX_JUDGE, "near_precision", "pose search --transitions, near pairs"),
            ("FEET", "near_precision", "FEET baseline, near pairs"),
        ):
            rows.append({
                "name": f"{kind} transition precision, {what}",
                "path": ["datasets", kind, "summary", method, key, "mean"],
                "unit": "", "better": "higher", "format": "",
            })  # fmt: skip
    return rows


def _one_seed(
    clips: list, train: list[int], test: list[int], methods: dict, quick: bool, seed: int, log: Any
) -> dict[str, Any]:
    rng = np.random.default_rng(seed)
    local = [c.local for c in clips]
    world = [c.world for c in clips]
    n_pairs = 150 if quick else 500
    n_queries = 800 if quick else 2500
    t0 = time.perf_counter()
    tr, reference = blended_transition_labels(
        local, world, TARGET_FPS, clips=train, n_positive=n_pairs, n_negative=n_pairs,
        n_queries=n_queries, random_state=rng,
    )  # fmt: skip
    te, _ = blended_transition_labels(
        local, world, TARGET_FPS, clips=test, reference=reference, n_positive=n_pairs,
        n_negative=n_pairs, n_queries=n_queries, random_state=rng,
    )  # fmt: skip
    label_s = time.perf_counter() - t0
    offsets = labels.ClipOffsets(np.array([len(c.local) for c in clips]))
    all_poses = PoseData.concat([c.poses for c in clips])
    train_ids = np.concatenate([offsets.starts[c] + np.arange(len(clips[c].local)) for c in train])
    unlabeled = rng.permutation(train_ids)[: (1500 if quick else 5000)]

    def pair_ids(tp: Any) -> np.ndarray:
        p = tp.pairs
        return np.stack([offsets(p[:, 0], p[:, 1]), offsets(p[:, 2], p[:, 3])], 1)

    tr_ids, te_ids = pair_ids(tr), pair_ids(te)
    test_a, test_b = all_poses[te_ids[:, 0]], all_poses[te_ids[:, 1]]
    near = te.mean_distance < NEAR_CM
    out: dict[str, Any] = {
        "label_seconds": label_s,
        "natural_reference": reference.tolist(),
        "train_pairs": len(tr),
        "test_pairs": len(te),
        "test_near_pairs": int(near.sum()),
        "test_good_share_of_decided": float(np.mean(te.cloud_distance <= GOOD_RATIO)),
        "methods": {},
    }
    for name, factory in methods.items():
        try:
            t0 = time.perf_counter()
            method = factory(random_state=seed).fit(
                all_poses[unlabeled], all_poses[tr_ids[:, 0]], all_poses[tr_ids[:, 1]], tr.labels
            )
            fit_s = time.perf_counter() - t0
            d = np.asarray(method.distances(test_a, test_b), dtype=np.float64)
            entry = {
                "precision": evaluate.transition_precision(d, te.labels)[0],
                "fit_seconds": fit_s,
            }
            entry.update(near_precision(d, te.labels, near))
        except Exception as exc:  # one broken method must not sink the benchmark
            entry = {
                "error": f"{type(exc).__name__}: {exc}",
                "trace": traceback.format_exc(limit=3),
            }
        out["methods"][name] = entry
    entry = _index_default_entry(
        clips, train, train_ids, all_poses, test_a, test_b, te.labels,
        n_unlabeled=len(unlabeled), n_pairs=n_pairs, seed=seed, near=near,
    )  # fmt: skip
    out["methods"][INDEX_DEFAULT] = entry
    out["methods"][INDEX_JUDGE] = _index_judge_entry(
        clips, train, test_a, test_b, te.labels, n_pairs=n_pairs, n_unlabeled=len(unlabeled),
        seed=seed, near=near,
    )  # fmt: skip
    log(
        f"  seed {seed}: {len(tr)} train / {len(te)} test pairs ({int(near.sum())} near), "
        f"labels {label_s:.0f} s; FEET {out['methods'].get('FEET', {}).get('precision')}"
    )
    return out


def _index_judge_entry(
    clips: list,
    train: list[int],
    test_a: PoseData,
    test_b: PoseData,
    test_labels: np.ndarray,
    *,
    n_pairs: int,
    n_unlabeled: int,
    seed: int,
    near: np.ndarray,
) -> dict[str, Any]:
    """What ``quatmotion pose search --transitions`` ranks by: the transition judge a library
    learns (:func:`quatmotion.pose.library.transitions.learn_transitions`, on the training
    clips, its own labels and seed), read back from the arrays the library stores, scored on
    the test pairs."""
    from quatmotion.pose.library import learn_transitions, transition_judge

    try:
        t0 = time.perf_counter()
        arrays, judged = learn_transitions(
            [clips[i].pose_clip for i in train], n_pairs=n_pairs, n_unlabeled=n_unlabeled,
            seed=seed, say=lambda _m: None,
        )  # fmt: skip
        judge = transition_judge(arrays)
        if judge is None:
            return {"error": str(judged.get("transitions"))}
        fit_s = time.perf_counter() - t0
        d = judge.distances(test_a, test_b)
        entry = {
            "precision": evaluate.transition_precision(d, test_labels)[0],
            "fit_seconds": fit_s, "transitions": judged["transitions"],
        }  # fmt: skip
        entry.update(near_precision(d, test_labels, near))
        return entry
    except Exception as exc:  # one broken method must not sink the benchmark
        return {"error": f"{type(exc).__name__}: {exc}", "trace": traceback.format_exc(limit=3)}


def _summary(per_seed: list[dict[str, Any]]) -> dict[str, Any]:
    names = list(per_seed[0]["methods"])
    summary: dict[str, Any] = {}
    for name in names:
        row: dict[str, Any] = {}
        for key in ("precision", "near_precision"):
            values = [s["methods"][name].get(key) for s in per_seed]
            values = [v for v in values if v is not None]
            if values:
                row[key] = {
                    "mean": float(np.mean(values)),
                    "std": float(np.std(values)),
                    "n": len(values),
                }
        errors = [s["methods"][name]["error"] for s in per_seed if "error" in s["methods"][name]]
        if errors:
            row["errors"] = errors[:1]
        summary[name] = row
    return summary


def _best(summary: dict[str, Any], key: str) -> dict[str, Any] | None:
    """The method of the highest mean ``key``, with its mean and spread."""
    rows = [(row[key]["mean"], name) for name, row in summary.items() if key in row]
    if not rows:
        return None
    _, name = max(rows)
    return {"method": name, **summary[name][key]}


def run(
    out: pathlib.Path,
    quick: bool = False,
    seed: int = 0,
    datasets: tuple[str, ...] = _DATASETS,
    n_seeds: int | None = None,
    verbose: bool = True,
    only: tuple[str, ...] | None = None,
) -> dict:
    """Run the benchmark (module docstring), write JSON to ``out``, return it.

    ``n_seeds`` defaults to 1 in quick mode, else 5. ``only`` names the registered methods to
    run (default all; the ``pose index default`` row always runs).
    """
    out = pathlib.Path(out)
    t_start = time.perf_counter()
    log = progress_log(verbose)

    n_seeds = (1 if quick else 5) if n_seeds is None else n_seeds
    methods = _methods()
    if only is not None:
        unknown = sorted(set(only) - set(methods))
        if unknown:
            raise ValueError(f"unknown methods {unknown}; choose from {sorted(methods)}")
        methods = {n: f for n, f in methods.items() if n in only}
    not_run = [n for n in methods if quick and any(n.endswith(s) for s in _SLOW)]
    methods = {n: f for n, f in methods.items() if n not in not_run}
    results: dict[str, Any] = {
        **provenance("pose_blend", out, quick, seed),
        "seeds": list(range(seed, seed + n_seeds)),
        "near_cm": NEAR_CM,
        "not_run": not_run,
        "headlines": _headlines(datasets),
        "datasets": {},
        "skipped": {},
    }
    root = data_root()
    loaded: dict[str, tuple[list, list[int], list[int]]] = {}
    for kind in datasets:
        try:
            clips = _load(kind, root, quick)
        except Exception as exc:
            results["skipped"][kind] = f"{type(exc).__name__}: {exc}"
            continue
        train, test = _split_blend(clips)
        loaded[kind] = (clips, train, test)
        log(f"{kind}: {len(clips)} clips ({len(train)} train, {len(test)} test)")
    per_seed: dict[str, list[dict[str, Any]]] = {kind: [] for kind in loaded}
    # seeds outermost: a run stopped early has every data set, each seed written as it ends
    for s in range(seed, seed + n_seeds):
        for kind, (clips, train, test) in loaded.items():
            try:
                per_seed[kind].append(_one_seed(clips, train, test, methods, quick, s, log))
            except Exception as exc:
                results["skipped"][f"{kind} seed {s}"] = f"{type(exc).__name__}: {exc}"
            if per_seed[kind]:
                summary = _summary(per_seed[kind])
                results["datasets"][kind] = {
                    "summary": summary,
                    "best": _best(summary, "precision"),
                    "best_near": _best(summary, "near_precision"),
                    "per_seed": per_seed[kind],
                }
            atomic_write_json(out, results)
    results["seconds"] = time.perf_counter() - t_start
    atomic_write_json(out, results)
    return results
