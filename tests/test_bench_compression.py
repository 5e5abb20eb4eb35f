"""The compression bench's speed-ups measure what the slow way measured (issue 17, item 12):
learned dictionaries reused across a library's re-encodes give the same bytes and errors, and
the quality search finds the fixed steps' answer in fewer encodes."""

from __future__ import annotations

import dataclasses

import pytest

from quatmotion.bench import compression as bench
from quatmotion.codec.methods import sparse
from quatmotion.codec.metrics import collection_errors
from quatmotion.synthetic import cmu_skeleton, generate_clip


@pytest.fixture(scope="module")
def clips():
    """Four short clips on two skeleton structures (two layouts, two dictionaries)."""
    base = cmu_skeleton()
    names = list(base.joint_names)
    names[-1] += "_other"
    other = dataclasses.replace(base, joint_names=tuple(names))
    out = []
    for k in range(4):
        clip = generate_clip(("walk", "run")[k % 2], 30 + k, n_frames=96).renamed(f"c{k}")
        out.append(dataclasses.replace(clip, skeleton=other) if k >= 2 else clip)
    return out


class _Counting:
    """Counts ``fit`` calls of a learner class."""

    def __init__(self, cls):
        self.cls, self.fits = cls, 0

    def __call__(self, *args, **kwargs):
        est = self.cls(*args, **kwargs)
        fit = est.fit

        def counted(samples):
            self.fits += 1
            return fit(samples)

        est.fit = counted
        return est


def test_cached_dictionaries_give_the_uncached_bytes_and_learn_once_per_layout(clips, monkeypatch):
    counting = _Counting(sparse.QSSD)
    monkeypatch.setattr(sparse, "QSSD", counting)
    monkeypatch.setattr(sparse, "_FIT_CACHE", {})  # this test's cache only (restored after)
    monkeypatch.setitem(bench.METHODS, "qssd", sparse.SparseMethod("qssd", max_iter=2))

    def run(quality):
        settings = dict(max_error=5.0, method="qssd", quality=quality)
        details = bench.compress_in_memory(clips, None, "inline", **settings).details
        return details["data"], collection_errors(details["clip_errors"])

    uncached = []
    for quality in (1.0, 0.7, 1.0):
        sparse.clear_fit_cache()
        uncached.append(run(quality))
    assert counting.fits == 6  # two layouts, learned again each time
    sparse.clear_fit_cache()
    cached = [run(quality) for quality in (1.0, 0.7, 1.0)]
    assert counting.fits == 8  # both layouts learned once, then reused
    assert sparse.cached_fit_seconds() > 0
    for (data_u, err_u), (data_c, err_c) in zip(uncached, cached, strict=True):
        assert data_c == data_u
        assert err_c.arms == err_u.arms and err_c.max_joint == err_u.max_joint
    assert cached[0][0] != cached[1][0]  # the knob did change the bytes


def _fixed_steps(arms_of, target, steps=bench.QUALITY_STEPS):
    """The slow way: k = 0, 1, 2... until the target holds."""
    for k in range(steps):
        if arms_of(k) <= target:
            return k, k + 1
    return steps - 1, steps


def test_quality_search_finds_the_fixed_steps_answer_in_fewer_encodes(clips):
    sources = [(100_000, "bvh")] * len(clips)
    encodes = []

    def arms_of(k):
        encodes.append(k)
        # naive without a bound: the knob is the quantiser step, so the ARMS follows it
        r = bench.compress_in_memory(
            clips,
            sources,
            "inline",
            method="naive",
            quality=8.0 * bench.METHODS["naive"].default_quality * bench.QUALITY_STEP**k,
        )
        return collection_errors(r.details["clip_errors"]).arms

    measured = {k: arms_of(k) for k in range(bench.QUALITY_STEPS)}
    encodes.clear()
    # targets whose first holding step is far along the grid (where fixed steps cost most)
    for target_step in (4, 5, 6):
        target = measured[target_step] * 1.001
        want, fixed_tries = _fixed_steps(measured.__getitem__, target)
        encodes.clear()
        k, tries = bench.search_quality_step(arms_of, target)
        assert k == want
        assert measured[k] <= target  # the target holds at the step found...
        assert k == 0 or measured[k - 1] > target  # ...and not at the step before it
        assert tries == len(encodes) < fixed_tries


@pytest.mark.parametrize("first", [0, 1, 3, 6, 7, 8])
def test_quality_search_on_a_known_curve(first):
    """ARMS = c * knob**1.6 with its first holding step at ``first`` (8: none holds)."""
    arms = {k: 2.0 * bench.QUALITY_STEP ** (1.6 * k) for k in range(bench.QUALITY_STEPS)}
    target = arms[first] * 1.0001 if first < bench.QUALITY_STEPS else arms[7] * 0.5
    k, tries = bench.search_quality_step(arms.__getitem__, target)
    want, fixed = _fixed_steps(arms.__getitem__, target)
    assert k == want
    # at most one try more where the fixed steps stop early, fewer where they go far
    assert tries <= fixed + 1 and (fixed < 5 or tries < fixed)
