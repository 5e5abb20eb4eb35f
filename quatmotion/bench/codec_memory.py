"""Peak memory of ``compress`` against the number of clips (issue 18's larger-than-memory
measure), one fresh process per size so each peak is its own.

    quatmotion bench codec_memory --out codec_memory.json [--quick]   # 1,000 and 10,000 clips
    .venv/bin/python -m quatmotion.bench.codec_memory 1000 10000      # the same, printed

writes ``N`` generated short clips (BVH, 60 frames at 30 fps, seeded) into a temporary folder,
runs :meth:`quatmotion.codec.Archive.build` on the folder in a child process (jobs inline, so
the peak counts every clip's work) and prints the child's peak resident set size
(``ru_maxrss``) and wall time as one JSON line per size.
"""

from __future__ import annotations

import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

FRAMES = 60
FPS = 30.0


def headlines(sizes: tuple[int, ...]) -> list[dict]:
    """The figures this benchmark publishes (:func:`quatmotion.viz.report.headline_table`):
    the peak at each size and its growth from the smallest size to the largest."""
    rows = [
        {
            "name": f"compress peak RSS, {n:,} clips",
            "path": ["peak_rss_mib", str(n)],
            "unit": "MiB",
            "better": "lower",
            "format": "",
        }
        for n in sizes
    ]
    rows.append({
        "name": f"peak RSS growth, {sizes[0]:,} to {sizes[-1]:,} clips",
        "path": ["peak_growth"],
        "unit": "x",
        "better": "lower",
        "format": "",
    })  # fmt: skip
    return rows


def _write_clips(folder: Path, n: int, seed: int = 0) -> None:
    from quatmotion.io import write_bvh
    from quatmotion.synthetic import KINDS, generate_clip

    for i in range(n):
        kind = KINDS[i % len(KINDS)]
        write_bvh(generate_clip(kind, seed + i, n_frames=FRAMES, fps=FPS), folder / f"c{i:05d}.bvh")


def _child(folder: str) -> None:
    from quatmotion.codec import Archive, CompressSettings
    from quatmotion.collection import ReadSettings
    from quatmotion.parallel import Runner

    t0 = time.perf_counter()
    out = Path(folder) / "out.qmz"
    report = Archive.build(
        [Path(folder)], out, CompressSettings(read=ReadSettings(units="cm")), runner=Runner.inline()
    )
    peak_kib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    print(json.dumps({
        "clips": len(report.added), "peak_rss_mib": round(peak_kib / 1024, 1),
        "seconds": round(time.perf_counter() - t0, 1), "bytes": out.stat().st_size,
    }))  # fmt: skip


def measure(n: int, seed: int = 0) -> dict:
    """One size: ``n`` clips written, compressed in a child process; its figures."""
    with tempfile.TemporaryDirectory() as folder:
        _write_clips(Path(folder), n, seed)
        child = [sys.executable, "-m", "quatmotion.bench.codec_memory", "--child", folder]
        done = subprocess.run(child, check=True, capture_output=True, text=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def run(out: Path, quick: bool = False, seed: int = 0) -> dict:
    """The benchmark contract (:mod:`quatmotion.bench`): 1,000 and 10,000 clips (quick: 100
    and 1,000)."""
    from quatmotion._atomic import atomic_write_json
    from quatmotion.bench import provenance

    sizes = (100, 1000) if quick else (1000, 10000)
    result = {**provenance("codec_memory", out, quick, seed), "frames_per_clip": FRAMES}
    result["sizes"] = [measure(n, seed) for n in sizes]
    peaks = {str(row["clips"]): row["peak_rss_mib"] for row in result["sizes"]}
    result["peak_rss_mib"] = peaks
    result["peak_growth"] = peaks[str(sizes[-1])] / peaks[str(sizes[0])]
    result["headlines"] = headlines(sizes)
    atomic_write_json(out, result)
    return result


def main(argv: list[str]) -> None:
    if argv[:1] == ["--child"]:
        _child(argv[1])
        return
    for n in [int(a) for a in argv] or [1000, 10000]:
        print(json.dumps(measure(n)))


if __name__ == "__main__":
    main(sys.argv[1:])
