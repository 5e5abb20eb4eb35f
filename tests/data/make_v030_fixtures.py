"""Write the ``.qmz`` fixtures of format version 1 (quatmotion 0.3.0) and what they decode to.

Run at commit 09b7cd3 of main (quatmotion 0.3.0, ``.qmz`` format version 1), before issue 18
changed the format::

    .venv/bin/python tests/data/make_v030_fixtures.py

It writes, into ``tests/data/v0.3.0/``:

* ``amc.qmz``: two generated clips written as ASF + AMC, compressed with ``best`` at 1 cm;
* ``bvh.qmz``: two generated clips written as BVH, compressed with ``naive`` at 2 cm;
* ``expected.npz``: for every clip of each file, the root translation and local rotations
  this code decodes (``<file>/<clip>/translation``, ``<file>/<clip>/rotations``), which
  ``tests/test_codec_versions.py`` compares with what today's reader decodes.

The sources are written to a temporary folder and not kept (the fixtures must stay a few kB).
"""

from __future__ import annotations

import subprocess
import tempfile
from pathlib import Path

import numpy as np

from quatmotion import codec
from quatmotion.io import read_motion, write_amc, write_asf, write_bvh
from quatmotion.synthetic import generate_clip

HERE = Path(__file__).parent / "v0.3.0"


def main() -> None:
    HERE.mkdir(parents=True, exist_ok=True)
    expected: dict[str, np.ndarray] = {}
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        amc = []
        for kind, seed in (("walk", 1), ("squat", 2)):
            clip = generate_clip(kind, seed, n_frames=24)
            write_asf(clip.skeleton, folder / f"{kind}_{seed}.asf")
            write_amc(clip, folder / f"{kind}_{seed}.amc")
            amc.append(folder / f"{kind}_{seed}.amc")
        bvh = []
        for kind, seed in (("kick", 3), ("wave", 4)):
            path = folder / f"{kind}_{seed}.bvh"
            write_bvh(generate_clip(kind, seed, n_frames=20), path)
            bvh.append(path)
        codec.compress(amc, HERE / "amc.qmz", max_error=1.0, method="best", workers=1,
                       scheduler="inline")  # fmt: skip
        codec.compress(bvh, HERE / "bvh.qmz", max_error=2.0, method="naive", workers=1,
                       scheduler="inline")  # fmt: skip
        assert read_motion(bvh[0]).n_frames == 20
    for name in ("amc.qmz", "bvh.qmz"):
        with codec.open(HERE / name) as archive:
            for i, clip in enumerate(archive.names()):
                translation, rotations = archive.read_rotations(i)
                expected[f"{name}/{clip}/translation"] = translation
                expected[f"{name}/{clip}/rotations"] = rotations
    np.savez_compressed(HERE / "expected.npz", **expected)
    commit = subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, check=False
    ).stdout.strip()
    print(f"wrote {HERE} at commit {commit}")


if __name__ == "__main__":
    main()
