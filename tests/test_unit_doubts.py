"""Doubtful units and frame rates (issue 17, item 2; issue 21, items 7 and 9):
:func:`quatmotion.io.implausible_values` warns about a figure no unit makes human (a 300 cm
giant) and about frame rates motion capture does not run at; the unit guess weighs the stature
chain, so a studio layout's misleading rest pose (a 135 cm figure in inches once read as 53 cm)
no longer fools it; and the library's batch functions take ``units=`` and report doubts through
``on_doubt`` (from their workers too)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from quatmotion import codec, io
from quatmotion.collection import ReadSettings
from quatmotion.datasets import data_root
from quatmotion.motion import forward_kinematics
from quatmotion.retrieval import ClipIndex, IndexSettings
from quatmotion.synthetic import cmu_skeleton, generate_clip

DATA = data_root(must_exist=False)
INCH_CM = 2.54


def test_a_doubtful_unit_is_a_figure_no_unit_makes_human_not_every_guess(studio_walk):
    _, studio = studio_walk(135.0, INCH_CM)
    back = io.parse_bvh(io.bvh_text(studio), "studio.bvh")
    assert back.skeleton.extras["bvh_unit"] == "in"  # the stature chain, not the rest pose
    assert io.implausible_values(back) == []
    _, giant = studio_walk(300.0, 1.0)
    back = io.parse_bvh(io.bvh_text(giant), "giant.bvh")
    (doubt,) = io.implausible_values(back)
    assert doubt.kind == "unit" and "50 to 220 cm" in doubt.message
    for height in (150.0, 170.0, 190.0):  # adults in centimetres, their rest pose standing
        adult = generate_clip("walk", 1, n_frames=60, skeleton=cmu_skeleton(height))
        back = io.parse_bvh(io.bvh_text(adult), "adult.bvh")
        assert back.skeleton.extras["bvh_unit_guessed"] and io.implausible_values(back) == []
    given = io.parse_bvh(io.bvh_text(studio), "studio.bvh", scale="in")
    assert io.implausible_values(given) == []


@pytest.mark.needs_data
@pytest.mark.parametrize("collection", ["bandai1", "cmu_bvh"])
def test_no_doubt_about_the_units_of_the_shared_libraries(collection):
    files = sorted((DATA / collection).rglob("*.bvh"))[::8]
    assert files
    for path in files:
        assert io.implausible_values(io.read_motion(path)) == [], path


@pytest.mark.parametrize(("fps", "doubtful"), [(0.001, True), (1e5, True), (120.0, False)])
def test_a_frame_rate_outside_motion_capture_is_a_doubt(fps, doubtful):
    clip = dataclasses.replace(generate_clip("walk", 1, n_frames=10), fps=fps)
    kinds = [d.kind for d in io.implausible_values(clip)]
    assert ("rate" in kinds) == doubtful


def test_compress_reads_in_the_unit_given_and_hears_the_doubts(tmp_path, studio_walk):
    truth, studio = studio_walk(300.0, 1.0)  # a giant in cm: no unit makes it a human
    path = tmp_path / "studio.bvh"
    io.write_bvh(studio, path)
    heard = []
    codec.compress([path], max_error=1.0, workers=1, on_doubt=lambda *doubt: heard.append(doubt))
    assert [(source, doubt.kind) for source, doubt in heard] == [(str(path), "unit")]
    heard.clear()
    result = codec.compress(
        [path], max_error=1.0, units="cm", workers=1, on_doubt=lambda *doubt: heard.append(doubt)
    )
    assert heard == []
    with codec.Archive.open(result.data) as archive:
        decoded = archive.read(0)
    assert decoded.skeleton.extras["bvh_scale"] == 1.0
    true = forward_kinematics(truth).all_positions()
    back = forward_kinematics(decoded).all_positions()
    assert np.linalg.norm(true - back, axis=-1).max() <= 1.0 + 1e-6  # the bound, in true cm


def test_build_index_hears_the_doubts_its_workers_find(tmp_path, studio_walk):
    _, studio = studio_walk(300.0, 1.0)
    folder = tmp_path / "clips"
    folder.mkdir()
    io.write_bvh(studio, folder / "studio.bvh")
    io.write_bvh(generate_clip("walk", 1, n_frames=60), folder / "walk.bvh")
    heard = []
    report = ClipIndex.build(
        [folder], tmp_path / "x.qidx", IndexSettings(kinds=("motion",)), workers=2,
        on_doubt=lambda source, doubt: heard.append((source, doubt.kind)),
    )  # fmt: skip
    assert len(report.added) == 2 and heard == [(str(folder / "studio.bvh"), "unit")]
    heard.clear()
    settings = IndexSettings(kinds=("motion",), read=ReadSettings(units="cm"))
    ClipIndex.build(
        [folder / "studio.bvh"], tmp_path / "y.qidx", settings, workers=1,
        on_doubt=lambda source, doubt: heard.append(source),
    )  # fmt: skip
    assert heard == []
