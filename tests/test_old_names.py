"""The names before 0.4.0 (docs/migration-0.4.md): each still works, warns with a
DeprecationWarning naming the new name, and gives what the new name gives; no module of the
package calls one of them."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import quatmotion
from quatmotion import codec
from quatmotion.io import write_motion
from quatmotion.parallel import Runner
from quatmotion.pose.library import PoseLibrary
from quatmotion.retrieval import ClipIndex, IndexSettings
from quatmotion.retrieval.build import build_index
from quatmotion.server import app as server_app
from quatmotion.synthetic import generate_clip

PACKAGE = Path(quatmotion.__file__).parent


def test_pose_library_load_warns_and_opens_as_open(v030):
    path = v030 / "pose_v030.npz"
    with pytest.warns(DeprecationWarning, match="PoseLibrary.open"):
        old = PoseLibrary.load(path)
    new = PoseLibrary.open(path)
    assert old.clip_names == new.clip_names and old.version == new.version
    np.testing.assert_array_equal(old.frame_of, new.frame_of)
    assert old.index.to_bytes() == new.index.to_bytes()


def test_clip_index_create_warns_and_makes_the_same_empty_index(tmp_path):
    with pytest.warns(DeprecationWarning, match="ClipIndex.build"):
        old = ClipIndex.create(tmp_path / "old.qidx")
    new = ClipIndex._create(tmp_path / "new.qidx")
    with old, new:
        assert old.rows() == new.rows() == [] and old.settings == new.settings
        assert old.version == new.version


def test_build_index_warns_and_indexes_as_clip_index_build(tmp_path):
    for seed, kind in enumerate(["walk", "squat"]):
        write_motion(generate_clip(kind, seed, n_frames=40, fps=30.0), tmp_path / f"{kind}.bvh")
    files = sorted(tmp_path.glob("*.bvh"))
    with pytest.warns(DeprecationWarning, match="ClipIndex.build"):
        old = build_index(files, tmp_path / "old.qidx", workers=1)
    new = ClipIndex.build(files, tmp_path / "new.qidx", IndexSettings(), runner=Runner.inline())
    assert old.added == new.added and not old.failures and not new.failures
    with ClipIndex.open(tmp_path / "old.qidx") as a, ClipIndex.open(tmp_path / "new.qidx") as b:
        assert [r.as_dict() for r in a.rows()] == [r.as_dict() for r in b.rows()]


def test_clip_index_workers_keyword_warns_and_builds_as_its_runner(tmp_path):
    files = _clips(tmp_path)
    with pytest.warns(DeprecationWarning, match=r"runner=Runner\.local\(workers\)"):
        old = ClipIndex.build(files[:2], tmp_path / "old.qidx", workers=1)
    with pytest.warns(DeprecationWarning, match="ClipIndex.add"):
        ClipIndex.add(tmp_path / "old.qidx", files[2:], workers=1)
    new = ClipIndex.build(files[:2], tmp_path / "new.qidx", runner=Runner.inline())
    ClipIndex.add(tmp_path / "new.qidx", files[2:], runner=Runner.inline())
    assert old.added == new.added
    with ClipIndex.open(tmp_path / "old.qidx") as a, ClipIndex.open(tmp_path / "new.qidx") as b:
        assert [r.as_dict() for r in a.rows()] == [r.as_dict() for r in b.rows()]
    with pytest.warns(DeprecationWarning), pytest.raises(ValueError, match="once"):
        ClipIndex.build(files, tmp_path / "twice.qidx", runner=Runner.inline(), workers=2)
    assert not (tmp_path / "twice.qidx").exists()


def test_runner_of_is_runner_of_the_command_line(tmp_path):
    from quatmotion.codec.writer import runner_of
    from quatmotion.parallel import Scheduler

    assert Runner.of() is None and Runner.of(None, None) is None
    assert Runner.of(1).scheduler.kind == "inline"
    assert Runner.of(2) == Runner.resolve("processes", workers=2)
    assert Runner.of(scheduler=Scheduler("inline")) == Runner.inline()
    with pytest.warns(DeprecationWarning, match="Runner.of"):
        assert runner_of(2, "processes") == Runner.of(2, "processes")


def _clips(folder: Path) -> list[Path]:
    for seed, kind in enumerate(["walk", "squat", "run"]):
        write_motion(generate_clip(kind, seed, n_frames=40, fps=30.0), folder / f"{kind}.bvh")
    return sorted(folder.glob("*.bvh"))


def test_codec_compress_warns_and_writes_what_archive_build_writes(tmp_path):
    files = _clips(tmp_path)
    with pytest.warns(DeprecationWarning, match="codec.Archive.build"):
        old = codec.compress(files, tmp_path / "old.qmz", max_error=2.0, seed=3, workers=1)
    settings = codec.CompressSettings(max_error=2.0, seed=3)
    new = codec.Archive.build(files, tmp_path / "new.qmz", settings, runner=Runner.inline())
    assert (tmp_path / "old.qmz").read_bytes() == (tmp_path / "new.qmz").read_bytes()
    assert old.size == (tmp_path / "new.qmz").stat().st_size
    assert old.clip_errors == new.details["clip_errors"]


def test_codec_append_warns_adds_as_archive_add_and_refuses_nothing_new(tmp_path):
    first, *rest = _clips(tmp_path)
    for name in ("old.qmz", "new.qmz"):
        codec.Archive.build([first], tmp_path / name, runner=Runner.inline())
    with pytest.warns(DeprecationWarning, match="codec.Archive.add"):
        old = codec.append(tmp_path / "old.qmz", rest, max_error=1.0, workers=1)
    report = codec.Archive.add(tmp_path / "new.qmz", rest, runner=Runner.inline())
    assert (tmp_path / "old.qmz").read_bytes() == (tmp_path / "new.qmz").read_bytes()
    assert len(old.clip_errors) == len(report.added) == 2
    with pytest.warns(DeprecationWarning), pytest.raises(ValueError, match="already holds"):
        codec.append(tmp_path / "old.qmz", rest, workers=1)


@pytest.mark.parametrize("name", ["open", "open_archive"])
def test_codec_open_warns_and_opens_as_archive_open(tmp_path, name):
    data = codec.Archive.build(_clips(tmp_path)[:1], None, runner=Runner.inline()).details["data"]
    with pytest.warns(DeprecationWarning, match="codec.Archive.open"):
        old = getattr(codec, name)(data)
    with old, codec.Archive.open(data) as new:
        assert old.names() == new.names()
        np.testing.assert_array_equal(old.read(0).rotations, new.read(0).rotations)


def test_importing_the_codec_loads_no_writer():
    script = (
        "import sys, quatmotion.codec\n"
        "print(sorted(m for m in sys.modules if m.startswith('quatmotion.codec.')))"
    )
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    loaded = out.stdout.strip()
    assert "quatmotion.codec.writer" not in loaded and "_old_names" not in loaded, loaded


# -- no module of the package uses an old name ---------------------------------------------
_OLD_METHODS = {
    ("PoseLibrary", "load"),
    ("ClipIndex", "create"),
    *(("codec", name) for name in ("compress", "append", "open", "open_archive")),
}
_OLD_FUNCTIONS = {"build_index"}
_OLD_IMPORTS = {("quatmotion.codec", n) for n in ("compress", "append", "open", "open_archive")}
_OLD_IMPORTS |= {("quatmotion.server.app", n) for n in server_app._MOVED}
_DEFINED_IN = {  # the aliases themselves
    "retrieval/build.py",
    "retrieval/__init__.py",
    "codec/__init__.py",
    "codec/_old_names.py",
}


def _old_names_used(path: Path) -> list[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    found = []
    for node in ast.walk(tree):
        attribute = isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name)
        if attribute and (node.value.id, node.attr) in _OLD_METHODS:
            found.append(f"{node.value.id}.{node.attr} (line {node.lineno})")
        call = isinstance(node, ast.Call) and isinstance(node.func, ast.Name)
        if call and node.func.id in _OLD_FUNCTIONS:
            found.append(f"{node.func.id}() (line {node.lineno})")
        if isinstance(node, ast.ImportFrom):
            found += [
                f"import of {a.name} (line {node.lineno})"
                for a in node.names
                if a.name in _OLD_FUNCTIONS or (node.module, a.name) in _OLD_IMPORTS
            ]
    return found


def test_no_module_of_the_package_uses_an_old_name():
    used = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(PACKAGE).as_posix()
        if rel in _DEFINED_IN:
            continue
        if found := _old_names_used(path):
            used[rel] = found
    assert used == {}
