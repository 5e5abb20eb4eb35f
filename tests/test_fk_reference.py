"""Forward kinematics against joint positions from an independent implementation.

The reference files (``reference/*.npz`` in the data folder) hold the first frames of AMC and
BVH clips; README.md there states the conventions. Agreement is required within 1e-3 cm.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from quatmotion.datasets import data_root
from quatmotion.io import asf_bone_end_positions, read_amc, read_bvh
from quatmotion.motion import forward_kinematics

DATA = data_root(must_exist=False)

REFERENCES = sorted((DATA / "reference").glob("*.npz")) if DATA.is_dir() else []
AMC_REFERENCES = [r for r in REFERENCES if "positions_cm" in np.load(r).files]
TOLERANCE_CM = 1e-3


@pytest.mark.needs_data
def test_reference_folder_has_both_formats():
    kinds = {"positions_cm" in np.load(r).files for r in REFERENCES}
    assert kinds == {True, False}, "expected AMC and BVH references"


@pytest.mark.needs_data
@pytest.mark.parametrize("reference", REFERENCES, ids=lambda p: p.stem)
def test_forward_kinematics_matches_reference(reference: Path):
    ref = np.load(reference)
    source = DATA / str(ref["source"])
    if "positions_cm" in ref.files:
        expected = ref["positions_cm"]
        motion = read_amc(source, DATA / str(ref["skeleton"])).slice(0, len(expected))
        actual = asf_bone_end_positions(motion)
        bones = [b["name"] for b in motion.skeleton.extras["asf_bones"]]
        assert list(ref["joint_names"]) == ["root", *bones]
    else:
        expected = ref["positions_file_units"]
        motion = read_bvh(source).slice(0, len(expected))
        actual = forward_kinematics(motion).positions / motion.skeleton.extras["bvh_scale"]
        assert list(ref["joint_names"]) == list(motion.skeleton.joint_names)
        assert np.array_equal(ref["parents"], motion.skeleton.parents)
    assert actual.shape == expected.shape
    error = np.abs(actual - expected).max()
    assert error < TOLERANCE_CM, f"{reference.stem}: max error {error} > {TOLERANCE_CM}"


@pytest.mark.needs_data
@pytest.mark.parametrize("reference", AMC_REFERENCES, ids=lambda p: p.stem)
def test_reference_parents_match_asf_hierarchy(reference: Path):
    ref = np.load(reference)
    motion = read_amc(DATA / str(ref["source"]), DATA / str(ref["skeleton"])).slice(0, 1)
    sk = motion.skeleton
    names = list(ref["joint_names"])
    # Reference parent of bone b is its parent bone (root: 0), in reference (file) order.
    ours = [-1] + [names.index(sk.joint_names[sk.parents[sk.index(n)]]) for n in names[1:]]
    assert np.array_equal(ref["parents"], ours)


@pytest.mark.needs_data
def test_forward_kinematics_keeps_bone_lengths_on_real_motion():
    clip = next(iter(sorted((DATA / "cmu").glob("*/*.amc"))))
    motion = read_amc(clip).slice(0, None, 7)
    sk = motion.skeleton
    pose = forward_kinematics(motion)
    lengths = np.linalg.norm(pose.positions[:, 1:] - pose.positions[:, sk.parents[1:]], axis=-1)
    assert np.allclose(lengths, np.linalg.norm(sk.offsets[1:], axis=-1), atol=1e-9)
    site_lengths = np.linalg.norm(pose.site_positions - pose.positions[:, sk.site_parents], axis=-1)
    assert np.allclose(site_lengths, np.linalg.norm(sk.site_offsets, axis=-1), atol=1e-9)
