"""Write the v0.3.0 clip-index and pose-library fixtures (tests/data/v0.3.0/).

Run once, at main commit 09b7cd3 (quatmotion 0.3.0: .qidx format version 1, pose library
format version 2), from the checkout's root:

    .venv/bin/python tests/data/make_v030_index_fixtures.py

It writes three small generated BVH clips (two of them with one stem, in two folders), a
labels CSV, a clip index of them (``index_v030.qidx``: motion features only, to stay small)
and a pose library (``pose_v030.npz``, RDSR of rank 2 to stay small) with the commands of
that release, then the values the tests compare against (``index_pose_v030.json``). The
files are committed except the three clips, which the tests' ``v030`` fixture
(conftest.py) writes again with the same calls (no motion files in the repository;
generated clips are bit-identical, and the tests check their hashes against the stored
ones); the tests check that the current code opens them and reads the same
values. Do not run it again with a newer quatmotion: the point of the files is that an older
release wrote them.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent / "v0.3.0"
COMMIT = "09b7cd3"


def main() -> None:
    from quatmotion.io import write_motion
    from quatmotion.synthetic import generate_clip

    clips = HERE / "index_clips"
    (clips / "s1").mkdir(parents=True, exist_ok=True)
    (clips / "s2").mkdir(parents=True, exist_ok=True)
    write_motion(generate_clip("walk", 0, n_frames=40, fps=30.0), clips / "s1" / "take_001.bvh")
    write_motion(generate_clip("squat", 1, n_frames=40, fps=30.0), clips / "s2" / "take_001.bvh")
    write_motion(generate_clip("punch", 2, n_frames=40, fps=30.0), clips / "s1" / "punch.bvh")
    (HERE / "index_labels.csv").write_text("clip,label\npunch,hit\n")
    qm = [str(Path(sys.executable).with_name("quatmotion"))]
    index = HERE / "index_v030.qidx"
    pose = HERE / "pose_v030.npz"
    index.unlink(missing_ok=True)
    pose.unlink(missing_ok=True)
    # relative sources, as a user types them: 0.3.0 stores the paths as given
    subprocess.run(
        [
            *qm,
            "index",
            "build",
            "index_clips",
            "-o",
            index.name,
            "--kinds",
            "motion",
            "--labels",
            "index_labels.csv",
            "--workers",
            "1",
        ],
        cwd=HERE,
        check=True,
    )
    subprocess.run(
        [
            *qm,
            "pose",
            "index",
            "index_clips",
            "-o",
            pose.name,
            "--workers",
            "1",
            "--pairs",
            "20",
            "--fit-poses",
            "200",
            "--metric",
            "GPD+RDSR",
            "--rank",
            "2",
            "--unlabeled",
            "100",
        ],
        cwd=HERE,
        check=True,
    )
    from quatmotion.pose.library import PoseLibrary
    from quatmotion.retrieval.index import ClipIndex

    with ClipIndex.open(index) as idx:
        rows = [r.__dict__ for r in idx.clips()]
        _, library = idx.load(("frames", "embedding"))
        embeddings = [lib["embedding"].tolist() for lib in library.features]
    poses = PoseLibrary.load(pose)
    values = {
        "commit": COMMIT,
        "index": {"clips": rows, "embeddings": embeddings},
        "pose": {
            "clip_names": poses.clip_names,
            "n_poses": int(len(poses.clip_of)),
            "frame_of": poses.frame_of.tolist(),
            "meta": poses.meta,
            "first_match": [
                [int(m.clip), int(m.frame), round(float(m.distance), 6)]
                for m in poses.nearest(poses.pose_query(0, 10)[0], k=3)
            ],
        },
    }
    (HERE / "index_pose_v030.json").write_text(json.dumps(values, indent=1, sort_keys=True))


if __name__ == "__main__":
    main()
