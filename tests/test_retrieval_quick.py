"""A single query of the default by clip name without Numba (retrieval.quick, issue 19)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from quatmotion.parallel import Runner
from quatmotion.retrieval import _kernels, quick
from quatmotion.retrieval.distances import pack_sequences
from quatmotion.retrieval.index import FORMAT, ClipIndex
from quatmotion.retrieval.methods import DEFAULT_METHOD, FUSED_RADIUS
from quatmotion.retrieval.search import search
from quatmotion.synthetic import KINDS, generate_clip

pytestmark = pytest.mark.same_answer


def test_its_constants_are_the_index_and_the_defaults():
    assert quick.METHOD == DEFAULT_METHOD
    assert quick.RADIUS == FUSED_RADIUS
    assert (FORMAT.name, FORMAT.version) == (quick.FORMAT_NAME, quick.INDEX_VERSION)


def test_fused_distances_are_the_kernels_dtw_bit_for_bit():
    # the compiled kernel and its definition run as Python, without abandoning
    rng = np.random.default_rng(0)
    streams = [rng.normal(size=(m, 7)).astype(np.float32) for m in (3, 9, 17, 30, 61, 120)]
    frames, offsets = pack_sequences(streams)
    frames_t = np.ascontiguousarray(frames.T)
    for q in (streams[1], streams[3], streams[5], rng.normal(size=(1, 7)).astype(np.float32)):
        d = quick.fused_distances(q, streams, 4)
        n = len(q)
        for kernel in (_kernels.dtw_band32, _kernels.dtw_band32.py_func):
            want = [
                kernel(q, frames_t, a, b - a, _kernels.band_radius.py_func(n, b - a, 4), 1e30)
                for a, b in zip(offsets[:-1], offsets[1:], strict=True)
            ]
            np.testing.assert_array_equal(d, want)


@pytest.fixture(scope="module")
def index(tmp_path_factory) -> Path:
    clips = [generate_clip(k, s) for k in KINDS for s in range(3)]
    out = tmp_path_factory.mktemp("quick") / "a.qidx"
    ClipIndex.build(clips, out, runner=Runner.inline())
    return out


def _full(index: Path, name: str, k: int) -> list[dict]:
    with ClipIndex.open(index) as idx:
        return [r.as_dict() for r in search(idx, name, k=k)]


def _same(got: list[dict], want: list[dict]) -> None:
    assert [r["clip"] for r in got] == [r["clip"] for r in want]
    assert [(r["rank"], r["path"], r["label"]) for r in got] == [
        (r["rank"], r["path"], r["label"]) for r in want
    ]
    assert [r["distance"] for r in got] == [r["distance"] for r in want]


def test_it_ranks_as_the_numba_path(index):
    with ClipIndex.open(index) as idx:
        names = [r.name for r in idx.rows()]
    for name in names[::2]:
        for k in (1, 5, len(names)):
            got = quick.quick_search(index, name, k)
            assert got is not None
            _same(got, _full(index, name, k))


def test_what_it_does_not_answer_is_left_to_the_full_path(index, tmp_path):
    assert quick.quick_search(index, "3", 5) is None  # a number
    assert quick.quick_search(index, "no-such-clip", 5) is None
    assert quick.quick_search(tmp_path / "none.qidx", "x", 5) is None
    bad = tmp_path / "bad.qidx"
    bad.write_bytes(b"not sqlite at all" * 10)
    assert quick.quick_search(bad, "x", 5) is None


_WRAPPER = (
    "import sys\n"
    "from quatmotion.cli import main\n"
    "sys.argv = ['quatmotion'] + sys.argv[1:]\n"
    "try:\n"
    "    main()\n"
    "finally:\n"
    "    sys.stderr.write('NUMBA=%s' % ('numba' in sys.modules))\n"
)


def _cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", _WRAPPER, *args], capture_output=True, text=True, timeout=600
    )


def test_a_shell_query_by_name_imports_no_numba_and_answers_as_the_numba_path(index):
    with ClipIndex.open(index) as idx:
        name = idx.rows()[4].name
    done = _cli("search", name, "--index", str(index), "--top", "5", "--json")
    assert done.returncode == 0, done.stderr
    assert done.stderr.endswith("NUMBA=False"), done.stderr
    doc = json.loads(done.stdout)
    assert doc["query"] == name and doc["method"] == DEFAULT_METHOD
    _same(doc["results"], _full(index, name, 5))
    # a table too
    done = _cli("search", name, "--index", str(index), "--top", "3")
    assert done.returncode == 0 and done.stderr.endswith("NUMBA=False"), done.stderr
    # by number: the full path (Numba), the same answer
    with ClipIndex.open(index) as idx:
        number = str([r.name for r in idx.rows()].index(name))
    done = _cli("search", number, "--index", str(index), "--top", "5", "--json")
    assert done.returncode == 0 and done.stderr.endswith("NUMBA=True"), done.stderr
    _same(json.loads(done.stdout)["results"], doc["results"])


def test_stored_arrays_read_as_np_load_reads_them():
    from quatmotion.retrieval.index_file import _to_blob
    from quatmotion.retrieval.stored import read_array as _from_blob

    rng = np.random.default_rng(1)
    for a in (
        rng.normal(size=(7, 52)).astype(np.float32),
        rng.normal(size=156),
        np.arange(5, dtype=np.int64),
        np.float32(2.5),
        np.zeros((0, 3), np.float32),
        np.asfortranarray(rng.normal(size=(3, 4))),
    ):
        blob = _to_blob(a)
        got, want = quick._array(blob), _from_blob(blob)
        assert got.dtype == want.dtype and got.shape == want.shape
        np.testing.assert_array_equal(got, want)
