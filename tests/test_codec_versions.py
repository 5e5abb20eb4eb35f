"""Files written by earlier releases keep opening: the ``.qmz`` fixtures of 0.3.0 (format
version 1, ``tests/data/make_v030_fixtures.py``) decode to the values 0.3.0 decoded."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from quatmotion import codec

FIXTURES = Path(__file__).parent / "data" / "v0.3.0"
# A unit quaternion component within a few float64 ulp of 1.
ROTATION_ULPS = 1e-15


@pytest.mark.parametrize("name", ["amc.qmz", "bvh.qmz"])
def test_v030_library_reads_the_same_rotations(name):
    expected = np.load(FIXTURES / "expected.npz")
    with codec.Archive.open(FIXTURES / name) as archive:
        assert len(archive) == 2
        for i, clip in enumerate(archive.names()):
            translation, rotations = archive.read_rotations(i)
            np.testing.assert_array_equal(translation, expected[f"{name}/{clip}/translation"])
            # The decoded integers and control points are exact; the final quaternion
            # normalisation may round the last bit differently with numpy's SIMD path
            # (version and CPU), so rotations match to a few ulp, not bit for bit.
            np.testing.assert_allclose(
                rotations, expected[f"{name}/{clip}/rotations"], rtol=0, atol=ROTATION_ULPS
            )
            motion = archive.read(i)
            assert motion.name == clip and motion.n_frames == rotations.shape[0]


FIXTURES_040 = Path(__file__).parent / "data" / "v0.4.0"
"""Format version 2 files written by 0.4.0 (``tests/data/make_v040_qmz_fixtures.py``): ``best`` at
1 cm (inserted knots, a break) and 0.1 cm (rows kept frame by frame), ``spline`` at 2 cm."""


@pytest.mark.parametrize("name", ["best.qmz", "tight.qmz", "spline.qmz"])
def test_v040_library_reads_the_same_rotations(name):
    expected = np.load(FIXTURES_040 / "expected.npz")
    with codec.Archive.open(FIXTURES_040 / name) as archive:
        assert archive.version == 2
        for i, clip in enumerate(archive.names()):
            translation, rotations = archive.read_rotations(i)
            np.testing.assert_array_equal(translation, expected[f"{name}/{clip}/translation"])
            np.testing.assert_allclose(
                rotations, expected[f"{name}/{clip}/rotations"], rtol=0, atol=ROTATION_ULPS
            )
            fps = archive.entries[i].fps
            root, sampled = archive.sample(i, np.arange(len(rotations)) / fps)
            np.testing.assert_allclose(sampled, rotations, rtol=0, atol=1e-12)


@pytest.mark.parametrize("name", ["best.qmz", "tight.qmz"])
def test_adding_to_a_v040_file_rewrites_it_in_format_3_without_loss(tmp_path, name):
    """The old clips are re-coded (the same quantised rows in format 3's segments), so they
    decode to what 0.4.0 decoded; the new clip is coded in format 3."""
    import shutil

    from quatmotion.codec.container import FORMAT_VERSION
    from quatmotion.io import write_bvh
    from quatmotion.synthetic import generate_clip

    path = tmp_path / name
    shutil.copy(FIXTURES_040 / name, path)
    write_bvh(generate_clip("walk", 12, n_frames=30), tmp_path / "new_walk.bvh")
    expected = np.load(FIXTURES_040 / "expected.npz")
    report = codec.Archive.add(path, [tmp_path / "new_walk.bvh"])
    assert len(report.added) == 1
    with codec.Archive.open(path) as archive:
        assert archive.version == FORMAT_VERSION == 3
        names = archive.names()
        assert names[-1] == "new_walk"
        for i, clip in enumerate(names[:-1]):
            translation, rotations = archive.read_rotations(i)
            np.testing.assert_array_equal(translation, expected[f"{name}/{clip}/translation"])
            np.testing.assert_allclose(
                rotations, expected[f"{name}/{clip}/rotations"], rtol=0, atol=ROTATION_ULPS
            )
        assert archive.read(len(names) - 1).n_frames == 30
