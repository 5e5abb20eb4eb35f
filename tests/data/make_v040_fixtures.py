"""Write the v0.4.0 collection fixtures (tests/data/v0.4.0/): files of the formats before
takes (``.qmz`` version 2, ``.qidx`` version 2, pose library version 3).

Run once, with quatmotion 0.4.0's code first on the path (``git archive ac2a3df quatmotion``
unpacked in OLD_CHECKOUT: main before clip references carried a take), from any folder:

    PYTHONPATH=OLD_CHECKOUT .venv/bin/python tests/data/make_v040_fixtures.py

It writes two small generated BVH clips to a temporary folder, then a library
(``lib_v040.qmz``), a clip index (``index_v040.qidx``, motion features) and a pose library
(``pose_v040.npz``, RDSR of rank 2 and no transition judge, to stay small) of them, and what
the tests compare against (``expected_v040.json``: every clip's reference as that release
wrote it). The clips are not kept: the tests read the references, not the files. Do not run
it again with a newer quatmotion: the point of the files is that an older release wrote them.
"""

from __future__ import annotations

import json
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent / "v0.4.0"


def main() -> None:
    from quatmotion.codec import Archive, CompressSettings
    from quatmotion.io import write_motion
    from quatmotion.parallel import Runner
    from quatmotion.pose.library import PoseLibrary, PoseSettings
    from quatmotion.retrieval.index import ClipIndex, IndexSettings
    from quatmotion.synthetic import generate_clip

    HERE.mkdir(exist_ok=True)
    outputs = {
        "qmz": HERE / "lib_v040.qmz",
        "qidx": HERE / "index_v040.qidx",
        "pose": HERE / "pose_v040.npz",
    }
    for path in outputs.values():
        path.unlink(missing_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        clips = [Path(tmp) / "walk.bvh", Path(tmp) / "squat.bvh"]
        write_motion(generate_clip("walk", 0, n_frames=40, fps=30.0), clips[0])
        write_motion(generate_clip("squat", 1, n_frames=40, fps=30.0), clips[1])
        Archive.build(clips, outputs["qmz"], CompressSettings())
        ClipIndex.build(
            clips, outputs["qidx"], IndexSettings(kinds=("motion",)), runner=Runner.inline()
        )
        PoseLibrary.build(
            clips,
            outputs["pose"],
            PoseSettings(metric="GPD+RDSR", rank=2, n_unlabeled=50, n_pairs=20, fit_poses=100),
            workers=1,
        )
    # without the transition judge (400 kB of principal components), as a library whose clips
    # gave too few transitions is written: saved again by the same release
    library = PoseLibrary.open(outputs["pose"])
    library.model = {k: v for k, v in library.model.items() if not k.startswith("transition_")}
    library.pose_rows = None
    library.meta["transitions"] = "left out of this fixture (size)"
    library.save(outputs["pose"])
    expected = {}
    with Archive.open(outputs["qmz"]) as archive:
        expected["qmz"] = {
            "version": archive.version,
            "clips": [r.to_dict() for r in archive.clips()],
        }
    with ClipIndex.open(outputs["qidx"]) as index:
        expected["qidx"] = {"version": index.version, "clips": _refs(index.clips())}
    pose = PoseLibrary.open(outputs["pose"])
    expected["pose"] = {"version": pose.version, "clips": _refs(pose.clips())}
    (HERE / "expected_v040.json").write_text(json.dumps(expected, indent=1, sort_keys=True) + "\n")
    print({k: v.stat().st_size for k, v in outputs.items()})


def _refs(refs) -> list[dict]:
    return [r.to_dict() for r in refs]


main()
