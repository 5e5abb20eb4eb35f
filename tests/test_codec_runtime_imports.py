"""The decoder apart: reading and sampling a ``best`` file loads no compressor, no other
codec's kernels, no scikit-learn, SQLite or PyWavelets (issue 32; the static half of this is
an import-linter contract in pyproject.toml, this is the dynamic half)."""

from __future__ import annotations

import json
import subprocess
import sys

from quatmotion import codec
from quatmotion.synthetic import generate_clip

HEAVY = (
    "quatmotion.codec.writer",
    "quatmotion.codec.methods.naive",
    "quatmotion.codec.methods.sparse",
    "quatmotion.sparse",
    "quatmotion.retrieval",
    "quatmotion.pose",
    "sklearn",
    "sqlite3",
    "pywt",
    "scipy.interpolate",
    "scipy.stats",
)


def test_reading_a_best_file_loads_no_compressor_parts(tmp_path):
    clip = generate_clip("walk", 5, n_frames=60)
    path = tmp_path / "one.qmz"
    path.write_bytes(
        codec.Archive.build(
            [clip], None, codec.CompressSettings(max_error=1.0, method="best")
        ).details["data"]
    )
    script = f"""
import json, sys
from quatmotion.codec import Archive
with Archive.open({str(path)!r}) as a:
    a.read_rotations(0)
    a.read(0)
    a.sample(a.names()[0], 0.1)
    a.sampler(0).pose(0.2)
print(json.dumps(sorted(sys.modules)))
"""
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True)
    loaded = set(json.loads(out.stdout.strip().splitlines()[-1]))
    assert "quatmotion.codec.methods.spline" in loaded  # the file's codec, and only it
    assert sorted(m for m in HEAVY if m in loaded) == []


def test_every_codec_is_still_registered():
    assert list(codec.METHODS) == ["best", "spline", "naive", "qssd", "ksvd"]
    assert "ksvd" in codec.METHODS and "nope" not in codec.METHODS
    assert codec.METHODS["ksvd"] is codec.METHODS["ksvd"]
    from quatmotion.codec.methods import SparseMethod

    assert isinstance(codec.METHODS["qssd"], SparseMethod)


RUNTIME_MUST_NOT_LOAD = (
    "numba",
    "scipy",
    "sklearn",
    "sqlite3",
    "constriction",
    "quatmotion.codec",
    "quatmotion.motion",
    "quatmotion.io",
    "quatmotion.collection",
    "quatmotion.runtime._kernels",
)


def test_importing_the_runtime_loads_numpy_and_itself_only():
    """``import quatmotion.runtime`` (its rows, rig and sampler) loads no Numba, no codec, no
    motion or reader of the package: its kernels load on the first decode."""
    script = """
import json, sys
import quatmotion.runtime, quatmotion.runtime.clip, quatmotion.runtime.sampler
before = sorted(sys.modules)
quatmotion.runtime.kernels()  # the first decode
print(json.dumps([before, sorted(sys.modules)]))
"""
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True)
    before, after = json.loads(out.stdout.strip().splitlines()[-1])
    loaded = {m for m in before if m.startswith("quatmotion")}
    assert loaded <= {"quatmotion", "quatmotion.errors", "quatmotion._jit", "quatmotion.runtime",
                      "quatmotion.runtime.clip", "quatmotion.runtime.sampler"}  # fmt: skip
    assert [m for m in RUNTIME_MUST_NOT_LOAD if m in before] == []
    assert "numba" in after and "quatmotion.runtime._kernels" in after  # loaded when asked
