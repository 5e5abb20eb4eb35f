"""Write the ``.qmz`` fixtures of format version 2 (quatmotion 0.4.0) and what they decode to.

Run with the code of main at commit ac2a3df (``.qmz`` format version 2), before issue 32's
format 3, from any folder, with that tree first on the path::

    PYTHONPATH=/path/to/that/tree .venv/bin/python tests/data/make_v040_qmz_fixtures.py

It writes, into ``tests/data/v0.4.0/`` (beside this script):

* ``best.qmz``: three generated clips written as BVH (one with a jump the spline breaks at),
  compressed with ``best`` at 1 cm;
* ``tight.qmz``: two generated clips, ``best`` at 0.1 cm (short knot spacings, many rows);
* ``spline.qmz``: two generated clips, the baseline ``spline`` at 2 cm;
* ``expected.npz``: for every clip of each file, the root translation and local rotations
  that code decodes (``<file>/<clip>/translation``, ``<file>/<clip>/rotations``), which
  ``tests/test_codec_versions.py`` compares with what today's reader decodes.
"""

from __future__ import annotations

import dataclasses
import subprocess
import sys
from pathlib import Path

import numpy as np

from quatmotion import codec
from quatmotion.parallel import Runner
from quatmotion.synthetic import generate_clip

HERE = Path(__file__).resolve().parent / "v0.4.0"


def _jumped(kind: str, seed: int, n_frames: int):
    """A generated clip whose root jumps 60 cm at its middle frame (a glitch ``best`` breaks
    its spline at)."""
    clip = generate_clip(kind, seed, n_frames=n_frames)
    root = clip.root_translation.copy()
    root[n_frames // 2 :, 0] += 60.0
    return dataclasses.replace(clip, root_translation=root)


def main() -> None:
    HERE.mkdir(parents=True, exist_ok=True)
    expected: dict[str, np.ndarray] = {}
    files = {
        "best.qmz": ([generate_clip("walk", 5, n_frames=48), generate_clip("kick", 6,
                      n_frames=30), _jumped("wave", 7, 60)], "best", 1.0),
        "tight.qmz": ([generate_clip("squat", 8, n_frames=40),
                       generate_clip("punch", 9, n_frames=24)], "best", 0.1),
        "spline.qmz": ([generate_clip("walk", 10, n_frames=30),
                        generate_clip("wave", 11, n_frames=20)], "spline", 2.0),
    }  # fmt: skip
    for name, (clips, method, bound) in files.items():
        settings = codec.CompressSettings(max_error=bound, method=method)
        codec.Archive.build(clips, HERE / name, settings, runner=Runner.inline())
        with codec.Archive.open(HERE / name) as archive:
            assert archive.version == 2, archive.version
            for i, clip in enumerate(archive.names()):
                translation, rotations = archive.read_rotations(i)
                expected[f"{name}/{clip}/translation"] = translation
                expected[f"{name}/{clip}/rotations"] = rotations
    np.savez_compressed(HERE / "expected.npz", **expected)
    print(f"wrote {HERE} with {codec.__file__}", file=sys.stderr)
    commit = subprocess.run(
        ["git", "-C", str(Path(codec.__file__).parent), "rev-parse", "--short", "HEAD"],
        capture_output=True, text=True, check=False,
    ).stdout.strip()  # fmt: skip
    print(f"at commit {commit}")


if __name__ == "__main__":
    main()
