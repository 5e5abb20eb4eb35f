"""Search inside long takes (``search --within``): are both ends of a segment found?

``quatmotion bench within --out within.json [--quick]``. A *take* is real clips of different
classes by one performer, joined one after the other (:func:`quatmotion.motion.join`: each
clip turned and moved to start where and as the previous one stopped); each segment is then
looked for with a clip of its class by *another* performer (HDM05: another actor; bandai1:
another style, the data set's performers), through the motion frames and
:func:`quatmotion.retrieval.distances.find_within`, as ``search --within`` does. Also the 30
generated cases of ``tests/test_retrieval_within.py`` (6 takes of 5 motions of 3 s).

Recall: the share of segments whose match has *both* ends within the tolerance of the
segment's (10 % of its length, and 0.5 s), with the refined ends (the default) and with the
warping path's ends alone; *inside*: the match lies within the segment give or take the 10 %.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from quatmotion._atomic import atomic_write_json
from quatmotion.bench._provenance import provenance
from quatmotion.motion import Motion, join
from quatmotion.retrieval.distances import find_within
from quatmotion.retrieval.features import feature_step, motion_frames

__all__ = ["run"]

SEGMENTS = 4  # clips per take
RELATIVE_TOLERANCE = 0.1  # of the segment's length
SECONDS_TOLERANCE = 0.5

HEADLINES = [
    {
        "name": f"--within both ends found, {name} (10 % of the segment)",
        "path": ["data", name, "refined", "both_ends_10pct"],
        "unit": "",
        "better": "higher",
        "format": "percent",
    }
    for name in ("hdm05", "bandai1", "generated")
]


def _performer(entry: Any) -> str:
    return str(entry.labels.get("actor") or entry.labels.get("style") or "")


def _real_cases(
    name: str, n_takes: int, rng: np.random.Generator
) -> list[tuple[Motion, list[int], list[Motion], list[str]]]:
    """Takes of ``SEGMENTS`` clips of different classes by one performer, and for each segment
    a query of its class by another performer: (take, segment starts + end, queries, classes)."""
    from quatmotion.datasets import catalogue

    entries = [e for e in catalogue(collection=name) if e.label and _performer(e)]
    by_performer: dict[str, list[Any]] = {}
    for e in entries:
        by_performer.setdefault(_performer(e), []).append(e)
    performers = sorted(p for p, es in by_performer.items() if len({e.label for e in es}) >= 4)
    cases = []
    for t in range(n_takes):
        who = performers[t % len(performers)]
        own = by_performer[who]
        classes = sorted({e.label for e in own})
        chosen = list(rng.choice(classes, SEGMENTS, replace=False))
        clips, queries = [], []
        for label in chosen:
            mine = [e for e in own if e.label == label]
            others = [e for e in entries if e.label == label and _performer(e) != who]
            if not others:
                break
            clips.append(mine[int(rng.integers(len(mine)))].load())
            queries.append(others[int(rng.integers(len(others)))].load())
        else:
            bounds = np.cumsum([0] + [c.n_frames for c in clips]).tolist()
            cases.append((join(clips, f"{name}_take_{t}"), bounds, queries, chosen))
    return cases


def _generated_cases() -> list[tuple[Motion, list[int], list[Motion], list[str]]]:
    """The 30 cases of tests/test_retrieval_within.py (same takes, same queries)."""
    from quatmotion.pose import skeleton16
    from quatmotion.synthetic import generate_clip
    from quatmotion.synthetic.motions import KINDS

    segment = 360
    joints = skeleton16.JOINTS_16

    def side(clip: Motion) -> str:
        world = skeleton16.world_positions16(clip)
        travel = {
            s: sum(float(np.ptp(world[:, joints.index(s + n), 1])) for n in ("Hand", "Foot"))
            for s in "LR"
        }
        return "l" if travel["L"] > travel["R"] else "r"

    rng = np.random.default_rng(0)
    cases = []
    for t in range(6):
        kinds = [str(k) for k in rng.choice(KINDS, 5, replace=False)]
        clips = [generate_clip(k, t * 100 + i, n_frames=segment) for i, k in enumerate(kinds)]
        queries = []
        for i, kind in enumerate(kinds):
            seed = 7_000 + 10 * t + i
            while side(query := generate_clip(kind, seed, n_frames=segment)) != side(clips[i]):
                seed += 1_000
            queries.append(query)
        bounds = [segment * i for i in range(6)]
        cases.append((join(clips, f"generated_take_{t}"), bounds, queries, kinds))
    return cases


def _score(cases: list[tuple[Motion, list[int], list[Motion], list[str]]]) -> dict[str, Any]:
    out: dict[str, Any] = {"segments": 0, "seconds_per_query": []}
    found: dict[str, dict[str, int]] = {
        mode: {"both_ends_10pct": 0, "both_ends_0.5s": 0, "inside": 0}
        for mode in ("refined", "path")
    }
    misses = []
    for take, bounds, queries, classes in cases:
        frames, _ = motion_frames(take)
        step = feature_step(take.fps)
        for k, query in enumerate(queries):
            lo, hi = bounds[k], bounds[k + 1]
            q, _ = motion_frames(query)
            out["segments"] += 1
            for mode in ("refined", "path"):
                t0 = time.perf_counter()
                _, start, stop = find_within(q, frames, refine=mode == "refined")
                if mode == "refined":
                    out["seconds_per_query"].append(time.perf_counter() - t0)
                a, b = min(start * step, take.n_frames), min(stop * step, take.n_frames)
                slack = RELATIVE_TOLERANCE * (hi - lo)
                err = max(abs(a - lo), abs(b - hi))
                found[mode]["both_ends_10pct"] += err <= slack
                found[mode]["both_ends_0.5s"] += err <= SECONDS_TOLERANCE * take.fps
                found[mode]["inside"] += lo - slack <= a and b <= hi + slack
                if mode == "refined" and err > slack:
                    misses.append(
                        {
                            "take": take.name,
                            "class": classes[k],
                            "segment": [lo, hi],
                            "found": [a, b],
                        }  # fmt: skip
                    )
    n = max(out["segments"], 1)
    for mode, counts in found.items():
        out[mode] = {key: value / n for key, value in counts.items()}
        out[mode]["counts"] = counts
    secs = out.pop("seconds_per_query")
    out["query_ms_median"] = 1000 * float(np.median(secs)) if secs else None
    out["misses"] = misses
    return out


def run(out: Path, quick: bool = False, seed: int = 0) -> dict[str, Any]:
    """Measure and write the JSON to ``out``; return it."""
    out = Path(out)
    result: dict[str, Any] = provenance("within", out, quick, seed)
    result["headlines"] = HEADLINES
    result["tolerance"] = {"relative": RELATIVE_TOLERANCE, "seconds": SECONDS_TOLERANCE}
    n_takes = 3 if quick else 12
    result["data"] = {}
    for name in ("hdm05", "bandai1"):
        rng = np.random.default_rng(np.random.SeedSequence([seed, len(name)]))
        result["data"][name] = _score(_real_cases(name, n_takes, rng))
    result["data"]["generated"] = _score(_generated_cases())
    atomic_write_json(out, result)
    return result
