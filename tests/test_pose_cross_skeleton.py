"""Poses of different skeletons compare: a motion kind is nearest the same kind on another body.

Issue 9 (1): a pose library built from one skeleton answered queries of another with the same
few poses whatever the query: each skeleton's proportions (bone lengths, the GPD's most constant
features) lay far outside the library's feature range and swamped the pose. Poses now go onto
one canonical body (:func:`quatmotion.pose.skeleton16.canonical_positions16`) and features are
clipped to the library's range.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.distance import cdist

from quatmotion import io
from quatmotion.datasets import data_root
from quatmotion.motion import Motion
from quatmotion.pose.data import PoseClip
from quatmotion.pose.library import PoseLibrary, PoseSettings
from quatmotion.synthetic import generate_clip

DATA = data_root(must_exist=False)
HDM = DATA / "hdm05" / "clips"
BANDAI = DATA / "bandai1" / "clips"


def _library(files: list[tuple[Path, str]]) -> tuple[PoseLibrary, np.ndarray, np.ndarray]:
    clips = [PoseClip.from_motion(io.read_motion(f), fps=30, height=170) for f, _ in files]
    lib = PoseLibrary.build_in_memory(clips, PoseSettings(n_unlabeled=2000, n_pairs=300, seed=0))
    kinds = np.array([k for _, k in files])[lib.clip_of]
    return lib, kinds, lib.index.vectors(np.arange(len(kinds)))


@pytest.fixture(scope="module")
def asf_library() -> tuple[PoseLibrary, np.ndarray, np.ndarray]:
    """One skeleton family, as in the issue (the CMU and HDM05 ASF skeletons): two CMU walks and
    the first clip of each HDM05 class, under the library's default metric."""
    files = [(DATA / "cmu" / "02" / f"02_0{t}.amc", "walk") for t in (1, 2)]
    for folder in sorted(HDM.iterdir()):
        first = sorted(folder.glob("*.amc"))[0]
        files.append((first, "kick" if folder.name.startswith("kick") else folder.name))
    return _library(files)


@pytest.fixture(scope="module")
def bandai_library() -> tuple[PoseLibrary, np.ndarray, np.ndarray]:
    """The other way round: the Bandai skeleton only, walks and the kick among other kinds (not
    its dances, whose steps and leg raises are walk and kick poses too)."""
    kinds = ("walk", "kick", "run", "punch", "bow", "bye", "guide", "slash")
    files = [(f, k) for k in kinds for f in sorted(BANDAI.glob(f"dataset-1_{k}_*_001.bvh"))[:2]]
    return _library(files)


def _mean_nearest(library, query: PoseClip, rows: np.ndarray) -> dict[str, float]:
    """For each kind of the library: the distance from each query pose to its nearest pose of
    that kind, averaged over the query poses."""
    lib, kinds, vectors = library
    d = cdist(lib.project_poses(query.poses[rows]), vectors)
    return {k: float(d[:, kinds == k].min(axis=1).mean()) for k in np.unique(kinds)}


def _nearest_kind(library, motion: Motion, mirror: bool = False, peak: bool = False) -> str:
    query = library[0].prepare_query(motion)
    # The Bandai performer kicks with the right leg, HDM05's kickLFront with the left, and a
    # pose distance is not mirror-invariant: the kicks are compared mirrored.
    query = query.mirrored() if mirror else query
    rows = np.arange(len(query))
    if peak:  # the kick itself: the frames where a foot is highest
        rows = np.argsort(-np.maximum(query.local[:, 12, 1], query.local[:, 15, 1]))[:10]
    distances = _mean_nearest(library, query, rows)
    return min(distances, key=distances.get)


@pytest.mark.needs_data
@pytest.mark.parametrize("seed", [1, 3])
def test_a_generated_walk_is_nearest_the_walks(asf_library, bandai_library, seed):
    assert _nearest_kind(asf_library, generate_clip("walk", seed)) == "walk"
    assert _nearest_kind(bandai_library, generate_clip("walk", seed)) == "walk"


@pytest.mark.needs_data
def test_a_bandai_walk_is_nearest_the_cmu_walks(asf_library):
    motion = io.read_motion(BANDAI / "dataset-1_walk_normal_001.bvh")
    assert _nearest_kind(asf_library, motion) == "walk"


@pytest.mark.needs_data
@pytest.mark.parametrize("clip", ["cmu/02/02_01.amc", "cmu/02/02_02.amc", "cmu_bvh/07/07_01.bvh"])
def test_a_cmu_walk_is_nearest_the_bandai_walks(bandai_library, clip):
    assert _nearest_kind(bandai_library, io.read_motion(DATA / clip)) == "walk"


@pytest.mark.needs_data
def test_a_bandai_kick_is_nearest_the_hdm05_kick(asf_library):
    motion = io.read_motion(BANDAI / "dataset-1_kick_normal_001.bvh")
    assert _nearest_kind(asf_library, motion, mirror=True, peak=True) == "kick"


@pytest.mark.needs_data
@pytest.mark.parametrize("actor", ["bd", "dg"])
def test_an_hdm05_kick_is_nearest_the_bandai_kick(bandai_library, actor):
    path = sorted((HDM / "kickLFront1Reps").glob(f"HDM_{actor}_*.amc"))[1]
    assert _nearest_kind(bandai_library, io.read_motion(path), mirror=True, peak=True) == "kick"
