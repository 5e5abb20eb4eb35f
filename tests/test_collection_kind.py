"""The collection surface in fact (issue 33): the file kinds implement
:class:`quatmotion.collection.kind.Kind`'s build/open/add with its parameters (names, order,
kinds) before any option of their own, and a build or an add through the surface reports the
doubts of its clips to ``on_doubt``."""

from __future__ import annotations

import inspect

import pytest

from quatmotion import io
from quatmotion.codec import Archive, CompressSettings
from quatmotion.collection.kind import Kind
from quatmotion.pose.library import PoseLibrary, PoseSettings
from quatmotion.retrieval import ClipIndex, IndexSettings
from quatmotion.synthetic import generate_clip

KINDS = [Archive, ClipIndex, PoseLibrary]


def _conforms(method: object, wanted: object) -> bool:
    """``method`` takes ``wanted``'s parameters (names, order, kinds) first, then only options
    with defaults."""
    have = list(inspect.signature(method).parameters.values())
    need = list(inspect.signature(wanted).parameters.values())
    same = [(p.name, p.kind) for p in have[: len(need)]] == [(p.name, p.kind) for p in need]
    return same and all(p.default is not inspect.Parameter.empty for p in have[len(need) :])


@pytest.mark.parametrize("kind", KINDS, ids=lambda k: k.__name__)
@pytest.mark.parametrize("name", ["build", "open", "add"])
def test_each_kind_has_the_protocols_signature(kind, name):
    assert _conforms(getattr(kind, name), getattr(Kind, name))
    assert isinstance(kind, Kind)


def test_the_check_refuses_what_the_surface_was_before():
    def build_04(cls, sources, out, settings=None, *, runner=None, progress=None):
        """Archive.build before issue 33: no on_doubt."""

    def build_options(cls, sources, out, settings=None, **options):
        """ClipIndex.build before issue 33."""

    def add_keyword_settings(cls, path, sources, *, settings=None, runner=None, progress=None,
                             on_doubt=None):  # fmt: skip
        """settings keyword-only."""

    assert not _conforms(build_04, Kind.build)
    assert not _conforms(build_options, Kind.build)
    assert not _conforms(add_keyword_settings, Kind.add)


@pytest.mark.parametrize(
    ("kind", "settings", "suffix"),
    [
        (Archive, CompressSettings(max_error=1.0), ".qmz"),
        (ClipIndex, IndexSettings(), ".qidx"),
        (PoseLibrary, PoseSettings(metric="GPD+RDSR", rank=2, n_pairs=20, n_unlabeled=100), ".npz"),
    ],
    ids=["Archive", "ClipIndex", "PoseLibrary"],
)
def test_build_and_add_through_the_surface_report_doubts(
    tmp_path, studio_walk, kind, settings, suffix
):
    _, giant = studio_walk(300.0, 1.0)  # no unit makes this figure a human: a doubt
    doubtful = tmp_path / "giant.bvh"
    io.write_bvh(giant, doubtful)
    plain = tmp_path / "walk.bvh"
    io.write_bvh(generate_clip("walk", 1, n_frames=60), plain)
    out = tmp_path / f"lib{suffix}"
    heard: list[tuple[str, str]] = []
    report = kind.build(
        [plain], out, settings, on_doubt=lambda path, doubt: heard.append((path, doubt.kind))
    )
    assert len(report.added) == 1 and heard == []
    report = kind.add(
        out, [doubtful], None, on_doubt=lambda path, doubt: heard.append((path, doubt.kind))
    )
    assert len(report.added) == 1 and heard == [(str(doubtful), "unit")]
    heard.clear()
    kind.build(
        [doubtful], tmp_path / f"other{suffix}", settings,
        on_doubt=lambda path, doubt: heard.append((path, doubt.kind)),
    )  # fmt: skip
    assert heard == [(str(doubtful), "unit")]
    with kind.open(out) as opened:
        assert len(opened.clips()) == 2
