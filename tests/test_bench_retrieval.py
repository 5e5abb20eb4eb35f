"""bench retrieval's label-learning split and headlines (issue 19)."""

from __future__ import annotations

import numpy as np

from quatmotion.bench.retrieval import LEARNED, _Dataset, _headlines, label_learning
from quatmotion.retrieval.features import clip_features, skeleton_fingerprint
from quatmotion.retrieval.methods import DEFAULT_METHOD, METHODS
from quatmotion.synthetic import generate_clip


def test_label_learning_scores_held_out_groups():
    kinds = ("walk", "squat", "wave")
    clips = [(k, s) for k in kinds for s in range(4)]
    motions = [generate_clip(k, s) for k, s in clips]
    data = _Dataset(
        "toy",
        [k for k, _ in clips],
        [],
        [clip_features(m, ("motion",)) for m in motions],
        [skeleton_fingerprint(m.skeleton) for m in motions],
        {},
        [f"actor{s % 2}" for _, s in clips],
    )
    out = label_learning(data)
    assert [s["train"] for s in out["splits"]] == [["actor0"], ["actor1"]]
    for method in (DEFAULT_METHOD, LEARNED):
        assert 0.0 <= out[method]["map"] <= 1.0
    assert np.isfinite(out["map_gain"])
    assert label_learning(_Dataset("x", [], [], [], [], {}, None)) is None


def test_headlines_name_the_default_and_both_scales():
    heads = _headlines(list(METHODS))
    paths = [h["path"] for h in heads]
    assert ["datasets", "bandai1", "methods", DEFAULT_METHOD, "map"] in paths
    assert ["scaling", "10000", DEFAULT_METHOD, "cpu_p95_ms"] in paths
    assert all(h["better"] in ("higher", "lower") for h in heads)
    assert _headlines(["pooled"]) == []
