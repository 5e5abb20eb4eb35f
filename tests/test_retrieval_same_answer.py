"""One search, one answer: the same results (order and distances, bit for bit) whichever path
computes them (a name answered without Numba, a number, a file, ``--queries``, the library)
and whichever x86-64 processor runs them (issue 29). ``make test`` runs this module twice:
on the host, then as on a baseline processor (its ``BASELINE_CPU``)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from quatmotion.cli import app
from quatmotion.io import write_motion
from quatmotion.retrieval.index import ClipIndex
from quatmotion.retrieval.search import search
from quatmotion.synthetic import generate_clip

pytestmark = pytest.mark.same_answer

runner = CliRunner()

# What make test's BASELINE_CPU sets (the Makefile), for a child process.
BASELINE_CPU = {
    "NUMBA_CPU_NAME": "generic",
    "NUMBA_CACHE_DIR": str(Path(sys.prefix, "numba-generic")),
    "NPY_DISABLE_CPU_FEATURES": "X86_V3 X86_V4 AVX512_ICL AVX512_SPR AVX512_SKX AVX512F AVX2 FMA3",
    "OPENBLAS_CORETYPE": "Prescott",
}
TOP = 6


@pytest.fixture(scope="module")
def library(tmp_path_factory) -> tuple[Path, Path]:
    """A folder of clips (several lengths, so that bands and slopes differ) and its index."""
    folder = tmp_path_factory.mktemp("same")
    for kind, frames in (("walk", 180), ("squat", 120), ("punch", 240), ("jump", 150)):
        for seed in range(3):
            clip = generate_clip(kind, seed, n_frames=frames + 37 * seed)
            write_motion(clip, folder / f"{kind}_{seed}.bvh")
    index = folder / "lib.qidx"
    build = ["index", "build", str(folder), "-o", str(index), "--workers", "1"]
    done = runner.invoke(app, build)
    assert done.exit_code == 0, done.output
    return folder, index


def _cli(*args: str) -> dict:
    done = runner.invoke(app, ["search", *args, "--top", str(TOP), "--json"])
    assert done.exit_code == 0, done.output
    return json.loads(done.output)


def test_a_name_its_number_and_a_batch_give_the_same_bits(library):
    folder, index = library
    with ClipIndex.open(index) as idx:
        names = [r.name for r in idx.rows()]
        by_library = {n: [r.as_dict() for r in search(idx, n, k=TOP)] for n in names}
    listing = folder / "names.txt"
    listing.write_text("\n".join(names) + "\n", encoding="utf-8")
    batch = _cli("--queries", str(listing), "--index", str(index))["queries"]
    for number, (name, doc) in enumerate(zip(names, batch, strict=True)):
        quick = _cli(name, "--index", str(index))["results"]  # NumPy, without Numba
        numbered = _cli(str(number), "--index", str(index))["results"]  # Numba
        assert quick == doc["results"] == numbered == by_library[name], name


def test_a_file_alone_and_in_a_batch_give_the_same_bits(library):
    folder, index = library
    files = sorted(str(p) for p in folder.glob("*.bvh"))
    listing = folder / "files.txt"
    listing.write_text("\n".join(files) + "\n", encoding="utf-8")
    batch = _cli("--queries", str(listing), "--index", str(index))["queries"]
    for doc in batch:
        assert _cli(doc["query"], "--index", str(index))["results"] == doc["results"]


_CHILD = (
    "import sys\n"
    "from quatmotion.cli import main\n"
    "sys.argv = ['quatmotion'] + sys.argv[1:]\n"
    "main()\n"
)


@pytest.mark.skipif(
    os.environ.get("NUMBA_CPU_NAME") == "generic", reason="this run is the baseline already"
)
def test_a_baseline_processor_gives_the_same_bits(library):
    """Numba's generic target, NumPy's baseline loops and OpenBLAS's oldest kernels: the same
    distances as this processor's, for names and files."""
    folder, index = library
    queries = sorted(str(p) for p in folder.glob("*.bvh"))[::2] + ["walk_1", "punch_2"]
    listing = folder / "mixed.txt"
    listing.write_text("\n".join(queries) + "\n", encoding="utf-8")
    args = ["search", "--queries", str(listing), "--index", str(index), "--top", str(TOP)]
    here = _cli(*args[1:])
    done = subprocess.run(
        [sys.executable, "-c", _CHILD, *args, "--json"],
        capture_output=True,
        text=True,
        timeout=900,
        env={**os.environ, **BASELINE_CPU},
    )
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout) == here
