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
