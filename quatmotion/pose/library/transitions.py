"""The transition judge a pose library learns and stores: :func:`learn_transitions` (step 1b of
the build, on the sample's blended-transition labels) and :func:`transition_judge` (the judge
read back from a library's ``model``, its ``transition_*`` arrays)."""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from quatmotion.pose import labels
from quatmotion.pose.data import PoseClip, PoseData
from quatmotion.pose.transition import TransitionClassifier

__all__ = ["MIN_PAIRS", "TRANSITION_PREFIX", "learn_transitions", "transition_judge"]

# Fewer transition pairs than this teach a metric (or a judge) too little.
MIN_PAIRS = 10
TRANSITION_PREFIX = "transition_"  # of the transition judge's arrays in a library's model


def transition_judge(model: dict[str, Any]) -> TransitionClassifier | None:
    """The transition judge stored in a library's ``model`` (``transition_*`` arrays), or None."""
    n = len(TRANSITION_PREFIX)
    arrays = {k[n:]: v for k, v in model.items() if k.startswith(TRANSITION_PREFIX)}
    return TransitionClassifier.from_arrays(arrays) if arrays else None


def learn_transitions(
    clips: Sequence[PoseClip],
    *,
    n_pairs: int,
    n_unlabeled: int,
    seed: int,
    say: Callable[[str], None],
    poses: PoseData | None = None,
) -> tuple[dict[str, Any], dict[str, Any]]:
    """Step 1b of the build: the transition judge learned on the sample's blended-transition
    labels (:mod:`quatmotion.pose.blend_labels`), as ``transition_*`` model arrays, and what
    ``meta`` records of it; nothing when the clips give too few good or bad transitions.
    ``poses``: the clips' poses joined, if step 1 has them (their GPD is not computed again)."""
    from quatmotion.pose.blend_labels import blended_transition_labels

    if len(clips) < 2:
        return {}, {"transitions": "not learned: one clip"}
    rng = np.random.default_rng([seed, 20])
    try:
        found, _ = blended_transition_labels(
            [c.local for c in clips], [c.world for c in clips], clips[0].fps,
            n_positive=n_pairs, n_negative=n_pairs, n_queries=max(2000, 4 * n_pairs),
            random_state=rng,
        )  # fmt: skip
    except ValueError as exc:
        say(f"no transition judge ({exc})")
        return {}, {"transitions": f"not learned: {exc}"}
    good = np.asarray(found.labels, dtype=bool)
    if good.sum() < MIN_PAIRS or (~good).sum() < MIN_PAIRS:
        reason = f"{int(good.sum())} good and {int((~good).sum())} bad transitions"
        say(f"no transition judge ({reason})")
        return {}, {"transitions": f"not learned: {reason}"}
    t0 = time.perf_counter()
    offsets = labels.ClipOffsets(np.array([len(c) for c in clips]))
    if poses is None:
        poses = PoseData.concat([c.poses for c in clips])
    p = found.pairs
    a, b = offsets(p[:, 0], p[:, 1]), offsets(p[:, 2], p[:, 3])
    unlabeled = rng.permutation(len(poses))[:n_unlabeled]
    judge = TransitionClassifier(random_state=seed).fit(poses[unlabeled], poses[a], poses[b], good)
    say(f"transition judge on {len(good)} blended transitions: {time.perf_counter() - t0:.1f} s")
    arrays = {f"{TRANSITION_PREFIX}{k}": v for k, v in judge.to_arrays().items()}
    return arrays, {"transitions": {"good": int(good.sum()), "bad": int((~good).sum())}}
