"""Benchmark of pose search across skeletons: a library of one skeleton, queries of another.

``run(out, quick, seed)`` builds pose libraries (:class:`~quatmotion.pose.library.PoseLibrary`,
default metric) of one skeleton family each and queries them with clips of other skeletons
whose motion kind the library holds:

* ``asf``: the first clip of each HDM05 class for each actor, with CMU subject 02's walks
  (02_01, 02_02), run (02_03) and punch (02_05), all ASF skeletons; queried with Bandai walks,
  run and kick, CMU BVH walks (B. Hahne's skeleton) and generated walks and run.
* ``bandai``: Bandai clips of 8 contents in 5 styles and its one kick; queried with CMU ASF and
  BVH walks and run, HDM05 kicks and generated walks and run.

Score: for each query clip, the share of its poses whose nearest indexed pose (HNSW, top 1)
belongs to a clip of the query's kind; for kicks, the 10 frames where a foot is highest, and
mirrored (the Bandai performer kicks with the right leg, HDM05's kickLFront with the left; a
pose distance is not mirror-invariant). Reported per query and library seed, and as the mean
over queries (``mean``: a library clip's kind is its HDM05 class or its file's content).
``mean_by_gait`` scores the same hits with HDM05's jogging counted as running and its
sneaking as walking (:data:`GAITS`): the kind a person names for those poses; it is reported
beside ``mean``, which stays the headline. Clips are resampled to 30 frames/s and put on the
canonical body of 170 cm, as ``quatmotion pose index`` does by default. Figure:
``<out stem>_bars.png``, one bar per query.
"""

from __future__ import annotations

import pathlib
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from quatmotion import io
from quatmotion._atomic import atomic_write_json
from quatmotion.bench._provenance import progress_log
from quatmotion.datasets import data_root
from quatmotion.motion import Motion
from quatmotion.pose.data import PoseClip
from quatmotion.pose.library import PoseLibrary, PoseSettings
from quatmotion.synthetic import generate_clip
from quatmotion.viz import pyplot, save_figure

__all__ = ["run"]

FPS = 30.0
HEIGHT_CM = 170.0
_STYLES = ("normal", "happy", "tired", "old", "proud")
_KICK_FRAMES = 10
#: Library kinds of the same gait as a query kind (``mean_by_gait``).
GAITS = {"jogLeftCircle4StepsRstart": "run", "sneak2StepsLStart": "walk"}

# (name, loader, kind, kick): a query clip
Query = tuple[str, Callable[[], Motion], str, bool]


def _libraries(root: pathlib.Path) -> dict[str, list[tuple[pathlib.Path, str]]]:
    hdm = root / "hdm05" / "clips"
    asf = []
    for folder in sorted(hdm.iterdir()):
        seen: set[str] = set()
        for path in sorted(folder.glob("*.amc")):
            actor = path.stem.split("_")[1]
            if actor not in seen:
                seen.add(actor)
                asf.append((path, "kick" if folder.name.startswith("kick") else folder.name))
    cmu = root / "cmu" / "02"
    asf += [(cmu / "02_01.amc", "walk"), (cmu / "02_02.amc", "walk")]
    asf += [(cmu / "02_03.amc", "run"), (cmu / "02_05.amc", "punch")]
    bandai_clips = root / "bandai1" / "clips"
    bandai = [
        (bandai_clips / f"dataset-1_{content}_{style}_001.bvh", content)
        for content in ("walk", "run", "punch", "bow", "bye", "dance-short", "guide", "slash")
        for style in _STYLES
    ]
    bandai.append((bandai_clips / "dataset-1_kick_normal_001.bvh", "kick"))
    return {"asf": asf, "bandai": [(p, k) for p, k in bandai if p.is_file()]}


def _queries(root: pathlib.Path) -> dict[str, list[Query]]:
    bandai = root / "bandai1" / "clips"
    kick = root / "hdm05" / "clips" / "kickLFront1Reps"

    def read(path: pathlib.Path) -> Callable[[], Motion]:
        return lambda: io.read_motion(path)

    def gen(kind: str, seed: int) -> Callable[[], Motion]:
        return lambda: generate_clip(kind, seed)

    generated: list[Query] = [
        ("generated walk 3", gen("walk", 3), "walk", False),
        ("generated walk 1", gen("walk", 1), "walk", False),
        ("generated run 3", gen("run", 3), "run", False),
    ]
    return {
        "asf": [
            *[
                (f"bandai walk {s}", read(bandai / f"dataset-1_walk_{s}_001.bvh"), "walk", False)
                for s in ("normal", "active", "sad")
            ],
            ("bandai run", read(bandai / "dataset-1_run_normal_001.bvh"), "run", False),
            ("bandai kick", read(bandai / "dataset-1_kick_normal_001.bvh"), "kick", True),
            ("cmu bvh 07_01", read(root / "cmu_bvh" / "07" / "07_01.bvh"), "walk", False),
            ("cmu bvh 08_02", read(root / "cmu_bvh" / "08" / "08_02.bvh"), "walk", False),
            *generated,
        ],
        "bandai": [
            ("cmu 02_01", read(root / "cmu" / "02" / "02_01.amc"), "walk", False),
            ("cmu 03_02", read(root / "cmu" / "03" / "03_02.amc"), "walk", False),
            ("cmu 02_03", read(root / "cmu" / "02" / "02_03.amc"), "run", False),
            ("cmu bvh 07_01", read(root / "cmu_bvh" / "07" / "07_01.bvh"), "walk", False),
            ("cmu bvh 08_03", read(root / "cmu_bvh" / "08" / "08_03.bvh"), "walk", False),
            ("hdm05 kick bd", read(sorted(kick.glob("HDM_bd_*.amc"))[1]), "kick", True),
            ("hdm05 kick dg", read(sorted(kick.glob("HDM_dg_*.amc"))[1]), "kick", True),
            *generated,
        ],
    }


def _score(
    library: PoseLibrary, kinds: np.ndarray, motion: Motion, kind: str, kick: bool
) -> tuple[float, float]:
    """Share of the query's poses whose nearest indexed pose is of its kind, and the same with
    :data:`GAITS` counted as their gait."""
    query = library.prepare_query(motion)
    rows = np.arange(len(query))
    if kick:
        query = query.mirrored()
        feet = np.maximum(query.local[:, 12, 1], query.local[:, 15, 1])
        rows = np.argsort(-feet)[:_KICK_FRAMES]
    ids, _ = library.search(library.project_poses(query.poses[rows]), 1)
    found = kinds[library.clip_of[ids[:, 0]]]
    gait = np.array([GAITS.get(k, k) for k in found])
    return float(np.mean(found == kind)), float(np.mean(gait == kind))


def _library_entry(
    name: str,
    files: list[tuple[pathlib.Path, str]],
    queries: list[Query],
    seeds: list[int],
    log: Callable[[str], None],
) -> dict[str, Any]:
    """One library's results (:func:`run`): built once per seed, scored on its queries."""
    clips = [
        PoseClip.from_motion(io.read_motion(path), fps=FPS, height=HEIGHT_CM) for path, _ in files
    ]
    loaded = [(q, load(), kind, kick) for q, load, kind, kick in queries]
    entry: dict[str, Any] = {
        "clips": len(clips),
        "poses": int(sum(len(c) for c in clips)),
        "build_seconds": [],
        "scores": {q: [] for q, *_ in loaded},
        "scores_by_gait": {q: [] for q, *_ in loaded},
    }
    kinds = np.array([k for _, k in files])
    for library_seed in seeds:
        t0 = time.perf_counter()
        library = PoseLibrary.build_in_memory(clips, PoseSettings(seed=library_seed))
        entry["build_seconds"].append(time.perf_counter() - t0)
        entry["metric"] = library.metric
        for q, motion, kind, kick in loaded:
            strict, by_gait = _score(library, kinds, motion, kind, kick)
            entry["scores"][q].append(strict)
            entry["scores_by_gait"][q].append(by_gait)
        log(f"{name} library, seed {library_seed}: {entry['scores']}")
    entry["mean"] = float(np.mean([np.mean(v) for v in entry["scores"].values()]))
    entry["mean_by_gait"] = float(np.mean([np.mean(v) for v in entry["scores_by_gait"].values()]))
    log(f"{name} library: mean {entry['mean']:.3f} (by gait {entry['mean_by_gait']:.3f})")
    return entry


def run(out: pathlib.Path, quick: bool = False, seed: int = 0, verbose: bool = True) -> dict:
    """Run the benchmark, write JSON to ``out`` and the bar chart beside it.

    Parameters
    ----------
    out : pathlib.Path
        JSON output; the figure is ``<out stem>_bars.png``.
    quick : bool
        One library seed instead of three.
    seed : int
        First library seed (the others follow it).
    verbose : bool
        Print progress lines.

    Returns
    -------
    dict
        Per library: its clips and poses, the build seconds and metric, ``scores`` (query ->
        one share per seed), ``scores_by_gait`` and ``mean`` / ``mean_by_gait`` (over queries and
        seeds).
    """
    out = pathlib.Path(out)
    start = time.perf_counter()
    log = progress_log(verbose)

    root = data_root()
    seeds = [seed] if quick else [seed, seed + 1, seed + 2]
    results: dict[str, Any] = {
        "benchmark": "pose_skeletons",
        "quick": quick,
        "seeds": seeds,
        "fps": FPS,
        "height_cm": HEIGHT_CM,
        "libraries": {},
        "headlines": [
            {
                "name": f"{name} library{what}",
                "path": ["libraries", name, key],
                "unit": "",
                "better": "higher",
                "format": "",
            }  # fmt: skip
            for key, what in (
                ("mean", " queried with other skeletons, top-1 of the right kind"),
                ("mean_by_gait", ", jogging counted as running, sneaking as walking"),
            )
            for name in ("asf", "bandai")
        ],
    }
    queries = _queries(root)
    for name, files in _libraries(root).items():
        results["libraries"][name] = _library_entry(name, files, queries[name], seeds, log)
    results["figures"] = [str(_figure(out, results))]
    results["seconds"] = time.perf_counter() - start
    atomic_write_json(out, results)
    return results


def _figure(out: pathlib.Path, results: dict[str, Any]) -> pathlib.Path:
    plt = pyplot()
    libraries = results["libraries"]
    fig, axes = plt.subplots(1, len(libraries), figsize=(6 * len(libraries), 4), squeeze=False)
    for ax, (name, entry) in zip(axes[0], libraries.items(), strict=True):
        labels = list(entry["scores"])
        means = [np.mean(entry["scores"][q]) for q in labels]
        ax.bar(range(len(labels)), means, color="tab:blue")
        ax.set_xticks(range(len(labels)), labels, rotation=60, ha="right", fontsize=8)
        ax.set_ylim(0, 1)
        ax.set_ylabel("top-1 pose of the query's kind (share)")
        ax.set_title(f"{name} library ({entry['metric']}): mean {entry['mean']:.2f}")
    return save_figure(fig, out.with_name(f"{out.stem}_bars.png"))
