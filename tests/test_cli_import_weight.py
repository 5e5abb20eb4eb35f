"""Commands load only what they run (issue 29): the modules a command imports, asserted as a
set (a time would depend on the machine's load). Numba's import and its first kernel cost
most of a second of CPU, scikit-learn and the codec's kernels more."""

from __future__ import annotations

import json
import socket
import subprocess
import sys

import pytest

from quatmotion.io import write_motion
from quatmotion.parallel import Runner
from quatmotion.retrieval.index import ClipIndex
from quatmotion.synthetic import generate_clip

# Run a command in a fresh interpreter, then print the modules it imported.
_RUN = (
    "import json, sys\n"
    "from quatmotion.cli import main\n"
    "sys.argv = ['quatmotion'] + sys.argv[1:]\n"
    "try:\n"
    "    main()\n"
    "except SystemExit as done:\n"
    "    code = done.code\n"
    "else:\n"
    "    code = 0\n"
    "sys.stderr.write('\\nMODULES ' + json.dumps([code, sorted(sys.modules)]))\n"
)
HEAVY = ("numba", "sklearn", "scipy", "quatmotion.sparse", "quatmotion.codec", "fastapi")
"""Never loaded by a command that runs none of them."""


def _modules(*args: str) -> tuple[int, set[str], str, str]:
    """The command's exit code, the modules it loaded, its output (stdout then stderr) and
    its stdout alone (where JSON is read: a first run's compile notice goes to stderr)."""
    done = subprocess.run(
        [sys.executable, "-c", _RUN, *args], capture_output=True, text=True, timeout=600
    )
    head, _, tail = done.stderr.rpartition("\nMODULES ")
    code, modules = json.loads(tail)
    return code, set(modules), done.stdout + head, done.stdout


def _loaded(modules: set[str], names: tuple[str, ...]) -> list[str]:
    return [n for n in names if n in modules or any(m.startswith(n + ".") for m in modules)]


def test_help_loads_no_kernel_numpy_or_package_metadata():
    code, modules, output, _ = _modules("--help")
    assert code == 0 and "search" in output
    # importlib.metadata (the version, the benchmarks' provenance) and the datasets' HTTP
    # client are read when asked for, not by every command
    light = ("numpy", "importlib.metadata", "quatmotion.bench", "quatmotion.datasets")
    assert _loaded(modules, HEAVY + light) == []


def test_serve_says_a_busy_port_before_it_loads_the_web_app(tmp_path):
    clips = [generate_clip(kind, 0, n_frames=60) for kind in ("walk", "squat")]
    index = tmp_path / "a.qidx"
    ClipIndex.build(clips, index, runner=Runner.inline())
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        code, modules, output, _ = _modules("serve", "--index", str(index), "--port", str(port))
    assert code == 2 and f"port {port} on 127.0.0.1 is in use" in output
    assert _loaded(modules, (*HEAVY, "quatmotion.server.app", "uvicorn", "numpy")) == []


@pytest.mark.parametrize("as_file", [False, True])
def test_search_loads_no_scikit_learn_or_codec(tmp_path, as_file):
    """By name: NumPy and SQLite only (retrieval.quick); by file: the reader and the retrieval
    kernels (Numba), never the sparse codec or scikit-learn."""
    folder = tmp_path / "clips"
    folder.mkdir()
    for kind in ("walk", "squat", "punch"):
        write_motion(generate_clip(kind, 1, n_frames=90), folder / f"{kind}.bvh")
    index = tmp_path / "a.qidx"
    ClipIndex.build([folder], index, runner=Runner.inline())
    query = str(folder / "walk.bvh") if as_file else "walk"
    code, modules, output, stdout = _modules("search", query, "--index", str(index), "--json")
    assert code == 0, output
    assert json.loads(stdout)["left_out"] == "walk"
    heavy = ("sklearn", "quatmotion.sparse", "quatmotion.codec", "fastapi", "scipy.stats")
    assert _loaded(modules, heavy if as_file else (*heavy, "numba", "quatmotion.io")) == []
