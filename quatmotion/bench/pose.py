"""Benchmark of pose distances (GPD paper sections 5-6) and of the ANN pose index.

``run(out, quick, seed)`` measures, on the real data of ``QUATMOTION_DATA``:

* **Transition decision** (section 5, Fig. 5): every method of
  :data:`quatmotion.pose.methods.METHODS` is fitted on training subjects (5000 unlabeled poses,
  500 positive + 500 negative pairs labelled by Kovar's windowed point-cloud distance, see
  :mod:`quatmotion.pose.labels`) and scored on pairs of other subjects by Eq. 36-37.
* **Features x learners** (Fig. 6): the ``FEATURE+LEARNER`` methods arranged as a matrix.
* **Rank sweep** (Fig. 4): GPD+RDSR at ranks :data:`RANKS`.
* **Unlabeled count sweep** (Fig. 7): GPD+RDSR and GPD+SDA with N' in :data:`UNLABELED_COUNTS`
  (N' = 0 is RDSR's Eq. 46 and SDA's LDA limit), and RDSR's label weight ``alpha`` over
  :data:`ALPHAS`. The sweeps run on ``sweep_datasets`` only.
* **Pose retrieval** (section 6, Fig. 8): k-means poses per subject, correct = same class and
  DTW phase within 10 %; methods trained on correct / other-class pairs of training subjects;
  precision at scopes 5..50 on the test subjects (results from the query's own clip excluded).
* Fit and query times of every method (aliases such as ``"RDSR"`` for ``"GPD+RDSR"`` run once).
  A method that raises is recorded with its error and the benchmark goes on.
* **ANN index**: hnswlib over 1,000,000 synthetic 50-dimensional "projected poses" (100,000 in
  quick mode): build time, median / p95 per-query latency (one query at a time, one thread)
  and recall@10 against exact search.

Datasets: ``hdm05`` (groups are actors, 11 classes), ``cmu`` (ASF subjects 01-03 and BVH
subjects 07-08; transition only, no classes), ``bandai`` (one performer: groups are *styles*,
classes are contents). Every third group in sorted order is held out for testing (HDM05: dg;
CMU: 03; Bandai: 5 of the 15 styles), the others train.
Clips are resampled to 30 frames/s and every body scaled to a 170 cm stature
(:func:`quatmotion.pose.skeleton16.stature16`; the paper normalises body height).
Figures: ``<out stem>_<dataset>_fig4_rank.png``, ``_fig5_transition``,
``_fig6_features_learners``, ``_fig7_unlabeled``, ``_fig8_retrieval``. A dataset whose folder
or reader is missing is skipped and listed in ``skipped``.
"""

from __future__ import annotations

import functools
import pathlib
import time
import traceback
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from quatmotion._atomic import atomic_write_json
from quatmotion.bench._pose_figures import figures
from quatmotion.bench._provenance import progress_log, provenance
from quatmotion.bench._tables import get, table
from quatmotion.datasets import ClipEntry, catalogue, data_root
from quatmotion.pose import evaluate, labels
from quatmotion.pose.data import PoseClip, PoseData
from quatmotion.pose.index import HNSWIndex, exact_knn, recall_at_k

TARGET_FPS = 30.0
BODY_HEIGHT = 170.0  # cm: every subject is scaled to this standing height
RANKS = (10, 20, 50, 100, 200)
UNLABELED_COUNTS = (0, 1000, 2000, 5000)
ALPHAS = (0.1, 1.0, 10.0, 100.0)
FEATURES = ("JO", "JC", "JRF", "GPD")
LEARNERS = ("L2", "LMS", "Xing", "SDA", "RDSR")
#: The row of what ``pose index`` ships, trained on its own pairs (see _index_default_entry).
INDEX_DEFAULT = "pose index default"


@dataclass
class Clip:
    """A clip prepared for the pose benchmark (30 fps, 170 cm body) with its split labels."""

    pose_clip: PoseClip
    group: str  # what the train/test split holds out: actor, subject or style
    cls: str  # the class retrieval scores by ("" when the collection has none)

    @property
    def local(self) -> NDArray[np.float64]:
        return self.pose_clip.local

    @property
    def world(self) -> NDArray[np.float64]:
        return self.pose_clip.world

    @property
    def poses(self) -> PoseData:
        return self.pose_clip.poses


def _prepare(entry: ClipEntry, group: str, cls: str) -> Clip | None:
    pose_clip = PoseClip.from_motion(entry.load(), fps=TARGET_FPS, height=BODY_HEIGHT)
    return Clip(pose_clip, group, cls) if len(pose_clip) >= 8 else None


def _load(kind: str, root: pathlib.Path, quick: bool) -> list[Clip]:
    if kind == "hdm05":
        entries = catalogue(root, collection="hdm05")
        if quick:  # a few clips per class and actor keep every split populated
            seen: dict[tuple[str, str], int] = {}
            kept = []
            for e in entries:
                key = (e.labels["class"], e.labels["actor"])
                if seen.get(key, 0) < 2:
                    kept.append(e)
                    seen[key] = seen.get(key, 0) + 1
            entries = kept
        prepared = [_prepare(e, e.labels["actor"], e.labels["class"]) for e in entries]
    elif kind == "cmu":
        entries = catalogue(root, collection=("cmu", "cmu_bvh"))
        prepared = [_prepare(e, e.path.parent.name, "") for e in entries]
        if quick:
            prepared = [c for c in prepared if c is not None][::2]
    elif kind == "bandai":
        entries = catalogue(root, collection="bandai1")
        if quick:
            entries = entries[::3]
        prepared = [_prepare(e, e.labels["style"], e.labels["content"]) for e in entries]
    else:
        raise ValueError(f"unknown dataset {kind!r}")
    return [c for c in prepared if c is not None]


def _split(clips: list[Clip]) -> tuple[list[int], list[int]]:
    """Hold out every third group (subject, or style for Bandai) in sorted order for testing."""
    groups = sorted({c.group for c in clips})
    test_groups = set(groups[2::3])
    train = [i for i, c in enumerate(clips) if c.group not in test_groups]
    test = [i for i, c in enumerate(clips) if c.group in test_groups]
    return train, test


def _methods() -> dict[str, Callable[..., Any]]:
    from quatmotion.pose.methods import METHODS

    # aliases ("RDSR" is "GPD+RDSR") share a factory: run each distinct method once
    unique: dict[str, Callable[..., Any]] = {}
    for name, factory in METHODS.items():
        if all(factory is not f for f in unique.values()):
            unique[name] = factory
    return unique


def _timed_fit(
    factory: Callable[..., Any], kwargs: dict[str, Any], *fit_args: Any
) -> tuple[Any, float]:
    t0 = time.perf_counter()
    method = factory(**kwargs).fit(*fit_args)
    return method, time.perf_counter() - t0


class _Task:
    """Training and test material of one dataset for one task."""

    def __init__(
        self,
        all_poses: PoseData,
        unlabeled: NDArray[np.int64],
        train_pairs: NDArray[np.int64],
        train_labels: NDArray[np.bool_],
    ) -> None:
        self.all = all_poses
        self.unlabeled = unlabeled
        self.train_pairs = train_pairs
        self.train_labels = train_labels

    def fit(
        self, factory: Callable[..., Any], n_unlabeled: int | None = None, **kwargs: Any
    ) -> tuple[Any, float]:
        unl = self.unlabeled if n_unlabeled is None else self.unlabeled[:n_unlabeled]
        return _timed_fit(
            factory,
            kwargs,
            self.all[unl],
            self.all[self.train_pairs[:, 0]],
            self.all[self.train_pairs[:, 1]],
            self.train_labels,
        )


def near_precision(
    d: NDArray[np.float64], labels: NDArray[np.bool_], near: NDArray[np.bool_] | None
) -> dict[str, float]:
    """``{"near_precision": ...}``: transition precision on the ``near`` pairs only, or ``{}``
    when there is no mask or the near pairs are all of one label."""
    if near is None or not (labels[near].any() and (~labels[near]).any()):
        return {}
    return {"near_precision": evaluate.transition_precision(d[near], labels[near])[0]}


def _index_default_entry(
    clips: list[Clip],
    train: list[int],
    train_pose_ids: NDArray[np.int64],
    all_poses: PoseData,
    test_a: PoseData,
    test_b: PoseData,
    test_labels: NDArray[np.bool_],
    *,
    n_unlabeled: int,
    n_pairs: int,
    seed: int,
    near: NDArray[np.bool_] | None = None,
) -> dict[str, Any]:
    """What ``quatmotion pose index`` ships, trained as it trains on the training clips: the
    registered default method on the library's own training set
    (:func:`quatmotion.pose.library.training_set`), scored on the test pairs."""
    from quatmotion.pose.library import DEFAULT_METRIC, training_set
    from quatmotion.pose.methods import METHODS

    try:
        t0 = time.perf_counter()
        method = METHODS[DEFAULT_METRIC](random_state=seed)
        unl, pairs, similar, source = training_set(
            [clips[i].pose_clip for i in train], n_unlabeled=n_unlabeled, n_pairs=n_pairs,
            seed=seed, dissimilar=method.uses_dissimilar,
        )  # fmt: skip
        ids = train_pose_ids
        method.fit(
            all_poses[ids[unl]], all_poses[ids[pairs[:, 0]]], all_poses[ids[pairs[:, 1]]], similar
        )
        fit_s = time.perf_counter() - t0
        d = np.asarray(method.distances(test_a, test_b), dtype=np.float64)
        prec, thr = evaluate.transition_precision(d, test_labels)
        entry = {
            "precision": prec, "threshold": thr, "fit_seconds": fit_s, "metric": DEFAULT_METRIC,
            "pairs_from": source, "positive_pairs": int(similar.sum()),
        }  # fmt: skip
        entry.update(near_precision(d, test_labels, near))
        return entry
    except Exception as exc:  # one broken method must not sink the benchmark
        return {"error": f"{type(exc).__name__}: {exc}", "trace": traceback.format_exc(limit=3)}


def _transition_experiment(
    clips: list[Clip],
    train: list[int],
    test: list[int],
    methods: dict[str, Callable[..., Any]],
    quick: bool,
    rng: np.random.Generator,
    log: Callable[[str], None],
    sweeps: bool = True,
) -> dict[str, Any]:
    local = [c.local for c in clips]
    world = [c.world for c in clips]
    n_pairs = 150 if quick else 500
    tr, thresholds = labels.transition_labels(
        local, world, TARGET_FPS, clips=train, n_positive=n_pairs, n_negative=n_pairs,
        n_queries=1500 if quick else 6000, random_state=rng,
    )  # fmt: skip
    te, _ = labels.transition_labels(
        local, world, TARGET_FPS, clips=test, thresholds=thresholds, n_positive=n_pairs,
        n_negative=n_pairs, n_queries=1500 if quick else 6000, random_state=rng,
    )  # fmt: skip
    clip_offsets = labels.ClipOffsets(np.array([len(c.local) for c in clips]))
    all_poses = PoseData.concat([c.poses for c in clips])
    train_pose_ids = np.concatenate(
        [clip_offsets.starts[c] + np.arange(len(clips[c].local)) for c in train]
    )
    n_unl = 1500 if quick else 5000
    unlabeled = rng.permutation(train_pose_ids)[:n_unl]
    tr_pairs, te_pairs = _pose_pairs(clip_offsets, tr.pairs), _pose_pairs(clip_offsets, te.pairs)
    task = _Task(all_poses, unlabeled, tr_pairs, tr.labels)
    default_unl = min(5000, len(unlabeled))
    # Fill the GPD cache once (timed) so no method's timing pays for the shared features.
    gpd_seconds = time.perf_counter()
    _ = all_poses.gpd
    gpd_seconds = time.perf_counter() - gpd_seconds
    test_a, test_b = all_poses[te_pairs[:, 0]], all_poses[te_pairs[:, 1]]

    result: dict[str, Any] = {
        "gpd_poses_per_second": len(all_poses) / max(gpd_seconds, 1e-9),
        "thresholds_cm": list(thresholds),
        "train": {"pairs": len(tr), "positive": int(tr.labels.sum()), "clips": len(train)},
        "test": {"pairs": len(te), "positive": int(te.labels.sum()), "clips": len(test)},
        "n_unlabeled": default_unl,
        "baseline_eq35_precision": evaluate.transition_precision(te.mean_distance, te.labels)[0],
        "methods": {},
    }
    scored = functools.partial(_scored, task, test_a=test_a, test_b=test_b, test_labels=te.labels)
    for name, factory in methods.items():
        entry = scored(factory, default_unl, full=True)
        log(f"  transition {name}: {entry.get('precision', entry.get('error'))}")
        result["methods"][name] = entry

    result["methods"][INDEX_DEFAULT] = _index_default_entry(
        clips, train, train_pose_ids, all_poses, test_a, test_b, te.labels,
        n_unlabeled=default_unl, n_pairs=n_pairs, seed=int(rng.integers(2**31)),
    )  # fmt: skip
    log(f"  transition {INDEX_DEFAULT}: {result['methods'][INDEX_DEFAULT].get('precision')}")

    if sweeps and "GPD+RDSR" in methods:
        result.update(_sweeps(methods, scored, default_unl, len(unlabeled), quick, log))
    return result


def _pose_pairs(clip_offsets: labels.ClipOffsets, pairs: np.ndarray) -> np.ndarray:
    """Transition pairs ``(clip, frame, clip, frame)`` as pose pairs (P, 2) into the clips
    joined."""
    return np.stack(
        [clip_offsets(pairs[:, 0], pairs[:, 1]), clip_offsets(pairs[:, 2], pairs[:, 3])], 1
    )


def _scored(
    task: _Task,
    factory: Callable[..., Any],
    n_unlabeled: int,
    *,
    test_a: PoseData,
    test_b: PoseData,
    test_labels: np.ndarray,
    full: bool = False,
    **params: Any,
) -> dict[str, Any]:
    """One method fitted on the task (``params`` to its factory) and scored on the test pairs:
    its precision and fit time (``full``: also its threshold, its query time and, on an error,
    the trace), or the error."""
    try:
        method, fit_s = task.fit(factory, n_unlabeled, **params)
        t0 = time.perf_counter()
        d = np.asarray(method.distances(test_a, test_b), dtype=np.float64)
        query_s = time.perf_counter() - t0
        prec, thr = evaluate.transition_precision(d, test_labels)
    except Exception as exc:  # one broken method or setting must not sink the benchmark
        error = {"error": f"{type(exc).__name__}: {exc}"}
        return {**error, "trace": traceback.format_exc(limit=3)} if full else error
    if not full:
        return {"precision": prec, "fit_seconds": fit_s}
    query_ms = 1e3 * query_s / len(test_labels)
    return {
        "precision": prec, "threshold": thr, "fit_seconds": fit_s, "query_ms_per_pair": query_ms,
    }  # fmt: skip


def _sweeps(
    methods: dict[str, Callable[..., Any]],
    scored: Callable[..., dict[str, Any]],
    default_unl: int,
    n_unlabeled: int,
    quick: bool,
    log: Callable[[str], None],
) -> dict[str, Any]:
    """RDSR's rank and label weight swept, and RDSR's and SDA's unlabeled poses."""
    rank_sweep = {}
    for r in RANKS[:3] if quick else RANKS:
        rank_sweep[str(r)] = scored(methods["GPD+RDSR"], default_unl, n_components=r)
        log(f"  rank {r}: {rank_sweep[str(r)]}")
    unl_sweep: dict[str, dict[str, Any]] = {}
    for name in ("GPD+RDSR", "GPD+SDA" if "GPD+SDA" in methods else "SDA"):
        if name not in methods:
            continue
        unl_sweep[name] = {}
        for n in UNLABELED_COUNTS:
            if n > n_unlabeled or (quick and n > 1000):
                continue
            unl_sweep[name][str(n)] = scored(methods[name], n)
            log(f"  unlabeled {name} {n}: {unl_sweep[name][str(n)]}")
    # RDSR's label weight: alpha scales S_W against the sparse-representation term
    alpha_sweep: dict[str, dict[str, Any]] = {}
    for alpha in ALPHAS[1:3] if quick else ALPHAS:
        alpha_sweep[str(alpha)] = scored(methods["GPD+RDSR"], default_unl, alpha=alpha)
        log(f"  alpha {alpha}: {alpha_sweep[str(alpha)]}")
    return {"rank_sweep": rank_sweep, "unlabeled_sweep": unl_sweep, "alpha_sweep": alpha_sweep}


def _retrieval_experiment(
    clips: list[Clip],
    train: list[int],
    test: list[int],
    methods: dict[str, Callable[..., Any]],
    quick: bool,
    seed: int,
    rng: np.random.Generator,
    log: Callable[[str], None],
) -> dict[str, Any]:
    local = [c.local for c in clips]
    class_names = sorted({c.cls for c in clips})
    group_names = sorted({c.group for c in clips})
    classes = np.array([class_names.index(c.cls) for c in clips])
    groups = np.array([group_names.index(c.group) for c in clips])
    # The paper took 200 k-means poses per subject over 15 subjects (3000). With one or two
    # test groups, 200 would leave a query only a handful of correct answers (same class, phase
    # within 10 %), so the test groups get more poses to keep precision@50 informative.
    train_per_group = 100 if quick else 200
    test_per_group = 300 if quick else 1000
    # k-means on body-frame poses with the Hip at the origin: facing and height ignored
    centred = [loc - loc[:, :1] for loc in local]
    train_set = labels.retrieval_set(
        centred, classes, groups, train_per_group, clips=train, random_state=seed
    )
    test_set = labels.retrieval_set(
        centred, classes, groups, test_per_group, clips=test, random_state=seed
    )
    n_pairs = 150 if quick else 500
    pairs, pair_labels = labels.retrieval_pairs(train_set, n_pairs, n_pairs, random_state=rng)
    clip_offsets = labels.ClipOffsets(np.array([len(c.local) for c in clips]))
    all_poses = PoseData.concat([c.poses for c in clips])
    _ = all_poses.gpd
    train_pose_ids = np.concatenate(
        [clip_offsets.starts[c] + np.arange(len(clips[c].local)) for c in train]
    )
    unlabeled = rng.permutation(train_pose_ids)[: (1500 if quick else 5000)]
    task = _Task(all_poses, unlabeled, pairs, pair_labels)
    q = np.arange(len(test_set))
    correct = test_set.correct(q, q)
    exclude = test_set.same_clip(q, q)
    scopes = evaluate.DEFAULT_SCOPES
    max_scope = min(max(scopes), int(np.min(np.count_nonzero(~exclude, axis=1))))
    scopes = tuple(s for s in scopes if s <= max_scope)
    base = all_poses[test_set.poses]
    result: dict[str, Any] = {
        "classes": class_names,
        "train_poses": len(train_set),
        "test_poses": len(test_set),
        "train_pairs": len(pair_labels),
        "scopes": list(scopes),
        "chance": float(correct[~exclude].mean()),
        # the best any distance can do: all available correct poses ranked first
        "oracle": evaluate.precision_at(
            evaluate.ranked_correct(~correct, correct, max_scope, exclude=exclude), scopes
        ).tolist(),
        "methods": {},
    }
    for name, factory in methods.items():
        try:
            method, fit_s = task.fit(factory)
            t0 = time.perf_counter()
            dist = np.asarray(method.pairwise(base, base), dtype=np.float64)
            query_s = time.perf_counter() - t0
            ranked = evaluate.ranked_correct(dist, correct, max_scope, exclude=exclude)
            prec = evaluate.precision_at(ranked, scopes)
            entry = {
                "precision_at": dict(zip(map(str, scopes), prec.tolist(), strict=True)),
                "fit_seconds": fit_s,
                "query_ms_per_query": 1e3 * query_s / len(test_set),
            }
        except Exception as exc:
            entry = {
                "error": f"{type(exc).__name__}: {exc}",
                "trace": traceback.format_exc(limit=3),
            }
        log(f"  retrieval {name}: {entry.get('precision_at', entry.get('error'))}")
        result["methods"][name] = entry
    return result


def _ann_benchmark(quick: bool, seed: int, log: Callable[[str], None]) -> dict[str, Any]:
    """hnswlib on synthetic projected poses: build time, latency, recall@10 vs exact."""
    rng = np.random.default_rng(seed)
    n, dim, n_queries, k = (100_000 if quick else 1_000_000), 50, 1000, 10
    # Projected poses lie near a low-dimensional manifold (a body has ~40 degrees of freedom
    # and motion is smooth): model them as a random smooth map of a 12-d latent plus noise.
    latent_dim = 12

    def sample(m: int) -> NDArray[np.float32]:
        z = rng.normal(size=(m, latent_dim))
        h = np.tanh(z @ proj1) @ proj2 + 0.05 * rng.normal(size=(m, dim))
        return h.astype(np.float32)

    proj1 = rng.normal(size=(latent_dim, 64)) / np.sqrt(latent_dim)
    proj2 = rng.normal(size=(64, dim)) / 8.0
    X = np.concatenate([sample(min(100_000, n - s)) for s in range(0, n, 100_000)])
    Q = sample(n_queries)
    params = {"M": 16, "ef_construction": 64, "ef_search": 64}
    t0 = time.perf_counter()
    index = HNSWIndex(**params, n_threads=-1, random_state=seed).fit(X)
    build_s = time.perf_counter() - t0
    log(f"  ann build {n}: {build_s:.1f} s")
    exact, _ = exact_knn(X, Q, k)
    out: dict[str, Any] = {
        "n_items": n,
        "dim": dim,
        "n_queries": n_queries,
        "build_seconds": build_s,
        "params": params,
        "latent_dim": latent_dim,
        "settings": [],
    }
    index.n_threads = 1
    for ef in (16, 32, 64, 128, 256):
        index.ef_search = ef
        approx, _ = index.query(Q, k)  # batch for recall
        lat = []
        for row in Q[:300]:
            t = time.perf_counter()
            index.query(row, k)
            lat.append(time.perf_counter() - t)
        entry = {
            "ef_search": ef,
            "recall_at_10": recall_at_k(approx, exact),
            "median_ms": 1e3 * float(np.median(lat)),
            "p95_ms": 1e3 * float(np.percentile(lat, 95)),
        }
        out["settings"].append(entry)
        log(f"  ann ef={ef}: {entry}")
    good = [s for s in out["settings"] if s["recall_at_10"] >= 0.95]
    out["chosen"] = min(good, key=lambda s: s["median_ms"]) if good else None
    out["meets_target"] = bool(good) and out["chosen"]["median_ms"] <= 2.0
    return out


def _figures(out: pathlib.Path, results: dict[str, Any]) -> list[str]:
    """The paper's Figs. 4 to 8 of ``results`` beside ``out`` (:mod:`._pose_figures`)."""
    return figures(out, results, FEATURES, LEARNERS)


def summary_tables(data: Mapping[str, Any]) -> list[dict[str, Any]]:
    """The tables ``quatmotion report`` shows of a result (:mod:`quatmotion.bench._tables`)."""
    tables = []
    for name, result in (get(data, "datasets") or {}).items():
        methods = get(result, "transition", "methods") or {}
        rows = sorted(
            (
                (m, e["precision"], e.get("fit_seconds"), e.get("query_ms_per_pair"))
                for m, e in methods.items()
                if isinstance(e, Mapping) and "precision" in e
            ),
            key=lambda row: -row[1],
        )
        if rows:
            tables.append(
                table(
                    f"{name}: transition precision (Eq. 37), best first",
                    ("method", "precision", "fit (s)", "query (ms/pair)"),
                    tuple(rows),
                    f"{get(result, 'transition', 'test', 'pairs')} test pairs.",
                )
            )
        retrieval = get(result, "retrieval", "methods") or {}
        scopes = [str(s) for s in (get(result, "retrieval", "scopes") or [])][:4]
        rows = [
            (m, *(e["precision_at"].get(s) for s in scopes))
            for m, e in retrieval.items()
            if isinstance(e, Mapping) and isinstance(e.get("precision_at"), Mapping)
        ]
        if rows and scopes:
            tables.append(
                table(
                    f"{name}: pose retrieval precision@s",
                    ("method", *(f"s={s}" for s in scopes)),
                    tuple(sorted(rows, key=lambda row: -(row[1] or 0.0))),
                )
            )
    chosen = get(data, "ann", "chosen")
    if isinstance(chosen, Mapping):
        tables.append(
            table(
                "Approximate pose index (HNSW)",
                ("items", "ef_search", "recall@10", "median ms", "p95 ms", "meets target"),
                (
                    (
                        get(data, "ann", "n_items"),
                        chosen.get("ef_search"),
                        chosen.get("recall_at_10"),
                        chosen.get("median_ms"),
                        chosen.get("p95_ms"),
                        get(data, "ann", "meets_target"),
                    ),
                ),
            )
        )
    return tables


def run(
    out: pathlib.Path,
    quick: bool = False,
    seed: int = 0,
    datasets: tuple[str, ...] = ("hdm05", "cmu", "bandai"),
    ann: bool = True,
    verbose: bool = True,
    sweep_datasets: tuple[str, ...] = ("hdm05",),
) -> dict:
    """Run the pose benchmark, write JSON to ``out`` and PNG figures next to it.

    Parameters
    ----------
    out : pathlib.Path
        JSON output path; figures are ``<stem>_<dataset>_fig*.png`` beside it.
    quick : bool
        Fewer clips, pairs, poses, sweep points and a 100,000-item ANN index.
    seed : int
        Seeds every random choice (pairs, unlabeled poses, k-means, synthetic index data).
    datasets : tuple of str
        Which of ``hdm05``, ``cmu``, ``bandai`` to run.
    ann : bool
        Also run the ANN index benchmark.
    sweep_datasets : tuple of str
        Datasets on which the rank and unlabeled-count sweeps run (each sweep point is a full
        RDSR fit on 1683-dimensional features, minutes each on a shared 2-core machine).
    verbose : bool
        Print progress lines.

    Returns
    -------
    dict
        The JSON payload: per dataset ``transition`` (per-method precision, thresholds, fit and
        query times, ``rank_sweep``, ``unlabeled_sweep``) and ``retrieval`` (precision@s), plus
        ``ann`` and ``figures``.
    """
    out = pathlib.Path(out)
    t_start = time.perf_counter()
    log = progress_log(verbose)

    root = data_root()
    results: dict[str, Any] = {
        **provenance("pose", out, quick, seed),
        "data_root": str(root),
        "fps": TARGET_FPS,
        "body_height_cm": BODY_HEIGHT,
        "datasets": {},
        "skipped": {},
    }
    methods = _methods()
    results["methods"] = list(methods)
    for kind in datasets:
        res = _dataset(kind, root, methods, quick, seed, kind in sweep_datasets, log)
        if isinstance(res, str):
            results["skipped"][kind] = res
            continue
        results["datasets"][kind] = res
        atomic_write_json(out, results)  # partial results survive a later failure
    if ann:
        results["ann"] = _ann_benchmark(quick, seed, log)
    results["figures"] = _figures(out, results)
    results["seconds"] = time.perf_counter() - t_start
    results["tables"] = summary_tables(results)
    atomic_write_json(out, results)
    return results


def _dataset(
    kind: str,
    root: pathlib.Path,
    methods: dict[str, Callable[..., Any]],
    quick: bool,
    seed: int,
    sweeps: bool,
    log: Callable[[str], None],
) -> dict[str, Any] | str:
    """The transition and retrieval experiments on one dataset, or why it was skipped."""
    rng = np.random.default_rng(seed)
    try:
        clips = _load(kind, root, quick)
    except Exception as exc:
        log(f"skip {kind}: {exc}")
        return f"{type(exc).__name__}: {exc}"
    if len(clips) < 4:
        return f"only {len(clips)} clips found under {root}"
    train, test = _split(clips)
    log(f"{kind}: {len(clips)} clips ({len(train)} train, {len(test)} test)")
    res: dict[str, Any] = {
        "clips": len(clips),
        "poses": int(sum(len(c.local) for c in clips)),
        "train_groups": sorted({clips[i].group for i in train}),
        "test_groups": sorted({clips[i].group for i in test}),
    }
    try:
        res["transition"] = _transition_experiment(
            clips, train, test, methods, quick, rng, log, sweeps=sweeps
        )
    except Exception as exc:
        res["transition_error"] = f"{type(exc).__name__}: {exc}"
        log(f"  transition failed: {exc}")
    if all(c.cls for c in clips):
        try:
            res["retrieval"] = _retrieval_experiment(
                clips, train, test, methods, quick, seed, rng, log
            )
        except Exception as exc:
            res["retrieval_error"] = f"{type(exc).__name__}: {exc}"
            log(f"  retrieval failed: {exc}")
    return res
