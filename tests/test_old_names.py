"""The names before 0.4.0 (docs/migration-0.4.md): each still works, warns with a
DeprecationWarning naming the new name, and gives what the new name gives; no module of the
package calls one of them."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest

import quatmotion
from quatmotion.io import write_motion
from quatmotion.pose.library import PoseLibrary
from quatmotion.retrieval import ClipIndex, IndexSettings
from quatmotion.retrieval.build import build_index
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
    new = ClipIndex.build(files, tmp_path / "new.qidx", IndexSettings(), workers=1)
    assert old.added == new.added and not old.failures and not new.failures
    with ClipIndex.open(tmp_path / "old.qidx") as a, ClipIndex.open(tmp_path / "new.qidx") as b:
        assert [r.as_dict() for r in a.rows()] == [r.as_dict() for r in b.rows()]


# -- no module of the package uses an old name ---------------------------------------------
_OLD_METHODS = {("PoseLibrary", "load"), ("ClipIndex", "create")}
_OLD_FUNCTIONS = {"build_index"}
_DEFINED_IN = {"retrieval/build.py", "retrieval/__init__.py"}  # the aliases themselves


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
                if a.name in _OLD_FUNCTIONS
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
