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
from quatmotion.parallel import Runner
from quatmotion.retrieval.index import ClipIndex
from quatmotion.retrieval.search import query_row, search
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
    return json.loads(done.stdout)


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


def test_a_file_of_an_indexed_clip_is_its_name_and_is_left_out(library):
    """One self-match rule: the file of an indexed clip (matched on its content hash, wherever
    the file lies) is that clip, left out of its results as a search by its name leaves it
    out, alone or in --queries, with the same results; the output names it."""
    folder, index = library
    elsewhere = folder / "elsewhere"
    elsewhere.mkdir(exist_ok=True)
    copy = elsewhere / "renamed take.bvh"
    copy.write_bytes((folder / "squat_2.bvh").read_bytes())
    cases = [(str(folder / "walk_1.bvh"), "walk_1"), (str(copy), "squat_2")]
    listing = folder / "both.txt"
    listing.write_text("\n".join(t for pair in cases for t in pair) + "\n", encoding="utf-8")
    batch = _cli("--queries", str(listing), "--index", str(index))["queries"]
    for i, (file, name) in enumerate(cases):
        by_file = _cli(file, "--index", str(index))
        by_name = _cli(name, "--index", str(index))
        assert by_file["left_out"] == by_name["left_out"] == name
        assert name not in [r["clip"] for r in by_file["results"]]
        assert by_file["results"] == by_name["results"]
        assert batch[2 * i]["left_out"] == batch[2 * i + 1]["left_out"] == name
        assert batch[2 * i]["results"] == batch[2 * i + 1]["results"] == by_name["results"]
        # --within: the same rule
        within = _cli(file, "--index", str(index), "--within")
        assert within["left_out"] == name
        assert name not in [r["clip"] for r in within["results"]]
        # the table says so in one line
        table = runner.invoke(app, ["search", file, "--index", str(index), "--top", "2"])
        assert f"left out {name}: the query itself" in table.output
    other = generate_clip("walk", 11, n_frames=150)  # a take the index does not hold
    write_motion(other, elsewhere / "new.bvh")
    fresh = _cli(str(elsewhere / "new.bvh"), "--index", str(index))
    assert fresh["left_out"] is None and len(fresh["results"]) == TOP
    table = runner.invoke(app, ["search", str(elsewhere / "new.bvh"), "--index", str(index)])
    assert "left out" not in table.output


def test_the_library_leaves_out_a_clip_made_in_memory_it_indexed(tmp_path):
    clips = [generate_clip(kind, 0, n_frames=120) for kind in ("walk", "squat", "punch")]
    out = tmp_path / "memory.qidx"
    ClipIndex.build(clips, out, runner=Runner.inline())
    with ClipIndex.open(out) as idx:
        results = search(idx, clips[1], k=5)
        assert query_row(idx, clips[1]).name == clips[1].name
        assert clips[1].name not in [r.clip for r in results] and len(results) == 2
        assert [r.as_dict() for r in results] == [
            r.as_dict() for r in search(idx, clips[1].name, k=5)
        ]


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
