"""Retrieval methods on generated motions: known answers and invariances."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from quatmotion import quat
from quatmotion.retrieval import distances
from quatmotion.retrieval.features import clip_features, skeleton_fingerprint
from quatmotion.retrieval.methods import DEFAULT_METHOD, METHODS, Library, QueryFeatures
from quatmotion.synthetic import generate_clip

KINDS = ("walk", "squat", "kick", "jumping_jack")
POSITION_METHODS = (
    "dtw-positions",
    "dtw-motion",
    "dtw-heading",
    "pooled",
    "pooled+dtw",
    DEFAULT_METHOD,
)


@pytest.fixture(scope="module")
def library() -> tuple[list[str], Library, list]:
    clips = [generate_clip(k, seed, n_frames=240) for k in KINDS for seed in range(4)]
    labels = [
        c.name.split("_")[0] if not c.name.startswith("jumping") else "jumping_jack" for c in clips
    ]
    feats = [clip_features(c, ("motion",)) for c in clips]
    prints = [skeleton_fingerprint(c.skeleton) for c in clips]
    return labels, Library(feats, prints), clips


def _query(lib: Library, i: int) -> QueryFeatures:
    return QueryFeatures(lib.features[i], lib.fingerprints[i])


@pytest.mark.parametrize("method", POSITION_METHODS)
def test_walk_query_ranks_walks_first(library, method):
    labels, lib, _ = library
    walk = labels.index("walk")
    ranking = METHODS[method].rank(lib, _query(lib, walk), exclude=walk)
    top = [labels[c] for c in ranking.clips[:3]]
    assert top == ["walk"] * 3
    assert walk not in ranking.clips


@pytest.mark.parametrize("method", POSITION_METHODS)
def test_same_clip_twice_is_at_distance_zero(library, method):
    _, lib, _ = library
    doubled = Library(lib.features + [lib.features[5]], lib.fingerprints + [lib.fingerprints[5]])
    ranking = METHODS[method].rank(doubled, _query(lib, 5), exclude=5)
    assert ranking.clips[0] == len(lib)
    assert ranking.distances[0] == pytest.approx(0.0, abs=1e-9)


def test_rotated_and_moved_clip_finds_itself_first(library):
    labels, lib, clips = library
    clip = clips[9]
    yaw = quat.about_axis(np.radians(137.0), "y")
    rotations = clips[9].rotations.copy()
    rotations[:, 0] = quat.multiply(yaw, rotations[:, 0])
    moved = quat.rotate(yaw, clip.root_translation) + np.array([250.0, 0.0, -80.0])
    turned = replace(clip, rotations=rotations, root_translation=moved)
    query = QueryFeatures(clip_features(turned, ("motion",)), skeleton_fingerprint(clip.skeleton))
    for method in POSITION_METHODS:
        ranking = METHODS[method].rank(lib, query)
        assert ranking.clips[0] == 9, method
        assert ranking.distances[0] < 1e-3 * max(1.0, float(np.nanmedian(ranking.distances)))


def test_atom_matching_is_zero_for_permuted_atoms_and_needs_same_shape():
    rng = np.random.default_rng(0)
    atoms = quat.normalize(rng.normal(size=(5, 7, 4))) / np.sqrt(7)
    shuffled = atoms[[3, 1, 4, 0, 2]]
    inverse = quat.conjugate(atoms)
    other = quat.normalize(rng.normal(size=(5, 7, 4))) / np.sqrt(7)
    d = distances.atom_matching_distances(
        atoms, np.stack([shuffled, inverse, other]), quaternion=True
    )
    assert d[0] == pytest.approx(0.0, abs=1e-12)
    assert d[1] == pytest.approx(0.0, abs=1e-12)  # an atom and its inverse are one model
    assert d[2] > 0.1
    with pytest.raises(ValueError, match="do not compare"):
        distances.atom_matching_distances(atoms, other[None, :, :5], quaternion=True)


def test_dictionary_method_ranks_only_the_query_skeleton():
    rng = np.random.default_rng(1)
    feats = [{"qssd": quat.normalize(rng.normal(size=(5, 3, 4))) / np.sqrt(3)} for _ in range(4)]
    lib = Library(feats, ["a", "a", "b", "b"])
    ranking = METHODS["paper-qssd"].rank(lib, QueryFeatures(feats[0], "a"), exclude=0)
    assert list(ranking.clips) == [1]
    assert METHODS["paper-qssd"].rank(lib, QueryFeatures(feats[0], "c")).clips.size == 0


def test_dtw_is_zero_on_itself_and_symmetric():
    rng = np.random.default_rng(2)
    a, b = rng.normal(size=(30, 4)), rng.normal(size=(41, 4))
    assert distances.dtw(a, a) == 0.0
    assert distances.dtw(a, b, band=0.3) == pytest.approx(distances.dtw(b, a, band=0.3), rel=1e-5)
    with pytest.raises(ValueError, match="columns"):
        distances.dtw(a, b[:, :3])
