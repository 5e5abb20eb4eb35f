"""``compress`` at library size with one skeleton per clip (issue 17, item 7).

``run(out, quick, seed)`` generates libraries of 300, 1,000 and 3,000 short clips (quick: 100,
300 and 1,000), each clip on a skeleton of its own (the procedural CMU-like figure at a stature
drawn per clip, so every bone length differs), writes them as BVH files to a temporary folder
and runs ``quatmotion.codec.Archive.build`` on the folder at the default 1 cm bound, each size in a
fresh subprocess. Per size it reports:

* ``seconds`` and ``seconds_per_clip``: the whole call (reading, the skeleton and layout pass,
  encoding, the file written); ``prepare_seconds_per_clip``: reading and the skeleton and
  layout pass alone (until the first encoding step reports). Time per clip flat in the number
  of clips is what this measures: a skeleton table that compares each clip with every earlier
  skeleton makes it grow linearly.
* ``first_progress_seconds``: from the call to its first progress report.
* ``peak_rss_mb``: the subprocess's peak resident memory (``ru_maxrss``), its pool workers not
  included; ``file_bytes`` and ``skeletons`` of the file written.

The machine may be shared: the figures are one run each (the growth with size, not the
absolute time, is the result).
"""

from __future__ import annotations

import json
import pathlib
import subprocess
import sys
import tempfile
from typing import Any

from quatmotion._atomic import atomic_write_json
from quatmotion.bench import provenance

SIZES = (300, 1_000, 3_000)
QUICK_SIZES = (100, 300, 1_000)
CLIP_FRAMES = 30  # one second at 30 fps: short clips put the weight on the per-clip passes
FPS = 30.0
KINDS_USED = ("walk", "run", "jump", "wave")


def write_library(folder: pathlib.Path, n_clips: int, seed: int) -> None:
    """``n_clips`` BVH files in ``folder``, each on a skeleton of its own stature."""
    import numpy as np

    from quatmotion.io import write_bvh
    from quatmotion.synthetic import cmu_skeleton, generate_clip

    rng = np.random.default_rng(seed)
    heights = rng.uniform(140.0, 200.0, n_clips)
    for k in range(n_clips):
        skeleton = cmu_skeleton(float(heights[k]))
        kind = KINDS_USED[k % len(KINDS_USED)]
        motion = generate_clip(kind, seed + k, n_frames=CLIP_FRAMES, fps=FPS, skeleton=skeleton)
        write_bvh(motion.renamed(f"clip_{k:05d}"), folder / f"clip_{k:05d}.bvh")


def measure(folder: str, out: str) -> dict[str, Any]:
    """Compress ``folder`` to ``out`` (in this process) and time it; the subprocess's part."""
    import resource
    import time

    from quatmotion.codec import Archive, CompressSettings

    marks: dict[str, float] = {}
    t0 = time.perf_counter()

    def progress(step: str, done: int, total: int) -> None:
        now = time.perf_counter() - t0
        marks.setdefault("first", now)
        if step not in ("read", "prepare"):
            marks.setdefault("encode", now)

    Archive.build([folder], out, CompressSettings(max_error=1.0), progress=progress)
    seconds = time.perf_counter() - t0
    with Archive.open(out) as archive:
        n_skeletons = len(archive.header.skeletons)
        n_clips = len(archive)
    return {
        "clips": n_clips,
        "skeletons": n_skeletons,
        "seconds": seconds,
        "prepare_seconds": marks.get("encode", seconds),
        "first_progress_seconds": marks.get("first", seconds),
        "file_bytes": pathlib.Path(out).stat().st_size,
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
    }


def _one_size(n_clips: int, seed: int) -> dict[str, Any]:
    with tempfile.TemporaryDirectory(prefix="qm-compression-scale-") as tmp:
        folder = pathlib.Path(tmp) / "clips"
        folder.mkdir()
        write_library(folder, n_clips, seed)
        code = (
            "import json, sys\n"
            "from quatmotion.bench.compression_scale import measure\n"
            "print(json.dumps(measure(sys.argv[1], sys.argv[2])))\n"
        )
        done = subprocess.run(
            [sys.executable, "-c", code, str(folder), str(pathlib.Path(tmp) / "x.qmz")],
            check=True,
            capture_output=True,
            text=True,
        )
    row = json.loads(done.stdout.strip().splitlines()[-1])
    row["seconds_per_clip"] = row["seconds"] / n_clips
    row["prepare_seconds_per_clip"] = row["prepare_seconds"] / n_clips
    return row


def run(out: pathlib.Path, quick: bool = False, seed: int = 0) -> dict[str, Any]:
    """Measure ``compress`` at each size (see the module docstring) and write the JSON."""
    out = pathlib.Path(out)
    result: dict[str, Any] = provenance("compression_scale", out, quick, seed)
    result["clip_frames"] = CLIP_FRAMES
    result["sizes"] = []
    for n_clips in QUICK_SIZES if quick else SIZES:
        row = _one_size(n_clips, seed)
        print(
            f"{n_clips} clips: {row['seconds']:.1f} s, {row['seconds_per_clip'] * 1000:.1f} ms "
            f"per clip ({row['prepare_seconds_per_clip'] * 1000:.1f} ms before encoding), "
            f"first progress {row['first_progress_seconds']:.2f} s, "
            f"peak RSS {row['peak_rss_mb']:.0f} MB",
            flush=True,
        )
        result["sizes"].append({"n_clips": n_clips, **row})
    per_clip = [r["seconds_per_clip"] for r in result["sizes"]]
    result["per_clip_growth"] = per_clip[-1] / per_clip[0]
    atomic_write_json(out, result)
    return result
