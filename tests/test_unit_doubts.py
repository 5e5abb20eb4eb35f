"""Doubtful units and frame rates (issue 17, item 2; issue 21, items 7 and 9):
:func:`quatmotion.io.implausible_values` warns about a figure no unit makes human (a 300 cm
giant) and about frame rates motion capture does not run at; the unit guess weighs the stature
chain, so a studio layout's misleading rest pose (a 135 cm figure in inches once read as 53 cm)
no longer fools it; and the library's batch functions take ``units=`` and report doubts through
``on_doubt`` (from their workers too)."""

from __future__ import annotations

import dataclasses
import re

import numpy as np
import pytest

from quatmotion import codec, io
from quatmotion.collection import ReadSettings
from quatmotion.datasets import data_root
from quatmotion.motion import forward_kinematics
from quatmotion.parallel import Runner
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
    codec.Archive.build(
        [path],
        None,
        codec.CompressSettings(max_error=1.0),
        runner=Runner.inline(),
        on_doubt=lambda *doubt: heard.append(doubt),
    )
    assert [(source, doubt.kind) for source, doubt in heard] == [(str(path), "unit")]
    heard.clear()
    result = codec.Archive.build(
        [path],
        None,
        codec.CompressSettings(max_error=1.0, read=ReadSettings(units="cm")),
        runner=Runner.inline(),
        on_doubt=lambda *doubt: heard.append(doubt),
    )  # a unit given is checked too (issue 29): still no human, and no unit likelier
    assert [(doubt.kind, doubt.likely_unit) for _, doubt in heard] == [("unit", None)]
    with codec.Archive.open(result.details["data"]) as archive:
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
        [folder], tmp_path / "x.qidx", IndexSettings(kinds=("motion",)), runner=Runner.local(2),
        on_doubt=lambda source, doubt: heard.append((source, doubt.kind)),
    )  # fmt: skip
    assert len(report.added) == 2 and heard == [(str(folder / "studio.bvh"), "unit")]
    heard.clear()
    settings = IndexSettings(kinds=("motion",), read=ReadSettings(units="cm"))
    ClipIndex.build(
        [folder / "studio.bvh", folder / "walk.bvh"], tmp_path / "y.qidx", settings,
        runner=Runner.inline(),
        on_doubt=lambda source, doubt: heard.append(source),
    )  # fmt: skip
    assert heard == [str(folder / "studio.bvh")]  # a unit given is checked too (issue 29)


def _metre_walk(tmp_path, studio_walk):
    """A 170 cm walk written in metres (the studio layout), and its file."""
    truth, metres = studio_walk(170.0, 100.0)
    path = tmp_path / "metres.bvh"
    io.write_bvh(metres, path)
    return truth, path


def test_a_unit_given_or_stated_is_checked_as_hard_as_one_guessed(tmp_path, studio_walk):
    """Issue 29 item 3: a metre file read with a given cm is a 1.7 cm figure; an ASF stating
    a unit 100 times too small likewise. Both are doubts naming the likely unit; the unit that
    makes the figure human is no doubt, given or stated."""
    _, path = _metre_walk(tmp_path, studio_walk)
    assert io.implausible_values(io.read_motion(path, units="m")) == []
    (doubt,) = io.implausible_values(io.read_motion(path, units="cm"))
    assert doubt.kind == "unit" and doubt.likely_unit == "m", doubt
    assert "the unit given" in doubt.message and "read in m" in doubt.message
    clip = generate_clip("walk", 1, n_frames=30)  # on CMU's skeleton, ASF units 0.45
    io.write_asf(clip.skeleton, tmp_path / "walk.asf")
    io.write_amc(clip, tmp_path / "walk.amc")
    assert io.implausible_values(io.read_motion(tmp_path / "walk.amc")) == []
    text = (tmp_path / "walk.asf").read_text()
    length = re.search(r"^  length (\S+)$", text, re.MULTILINE)
    shrunk = f"  length {float(length.group(1)) * 100:.10g}"
    (tmp_path / "walk.asf").write_text(text.replace(length.group(0), shrunk))
    (doubt,) = io.implausible_values(io.read_motion(tmp_path / "walk.amc"))
    assert doubt.kind == "unit" and doubt.likely_unit == "asf", doubt


@pytest.mark.parametrize(
    "command",
    [
        ["info", "{clip}"],
        ["convert", "{clip}", "{tmp}/out.bvh"],
        ["view", "{clip}", "-o", "{tmp}/v.html"],
        ["index", "build", "{clip}", "-o", "{tmp}/x.qidx", "--workers", "1"],
        ["search", "{clip}", "--index", "{idx}"],
        ["compress", "{clip}", "-o", "{tmp}/x.qmz", "--max-error", "1", "--force-units"],
    ],
    ids=lambda c: " ".join(c[:2]) if c[0] == "index" else c[0],
)
def test_every_command_warns_of_a_unit_given_naming_the_likely_one(tmp_path, studio_walk, command):
    """One home (:func:`quatmotion.io.implausible_values`), one warning line naming the likely
    unit, whichever command reads the file."""
    from typer.testing import CliRunner

    from quatmotion.cli import app

    _, path = _metre_walk(tmp_path, studio_walk)
    index = tmp_path / "i.qidx"
    if command[0] == "search":
        other = tmp_path / "other.bvh"
        io.write_bvh(generate_clip("walk", 2, n_frames=60), other)
        ClipIndex.build([other], index, IndexSettings(kinds=("motion",)), runner=Runner.inline())
    args = [a.format(clip=path, tmp=tmp_path, idx=index) for a in command]
    result = CliRunner().invoke(app, [*args, "--units", "cm"])
    assert result.exit_code == 0, result.output
    warnings = [line for line in result.stderr.splitlines() if line.startswith("warning:")]
    assert len(warnings) == 1 and "--units m" in warnings[0], result.stderr


def test_compress_and_append_refuse_a_unit_that_makes_no_human_unless_forced(tmp_path, studio_walk):
    """``compress --units cm`` of a metre file declared 0.0x cm errors that were metres: it
    is one error line naming the likely unit, exit 2, nothing written; ``--force-units`` goes
    on (the bound then holds in the unit read); ``append`` the same."""
    from typer.testing import CliRunner

    from quatmotion.cli import app

    truth, path = _metre_walk(tmp_path, studio_walk)
    out = tmp_path / "x.qmz"
    run = CliRunner().invoke
    for args in (["compress", str(path), "-o", str(out)], ["compress", str(path), "-o", str(out)]):
        result = run(app, [*args, "--units", "cm", "--max-error", "1"])
        assert result.exit_code == 2, result.output
        errors = [line for line in result.stderr.splitlines() if line.startswith("error:")]
        assert len(errors) == 1 and "likely --units m" in errors[0], result.stderr
        assert "Traceback" not in result.output and not out.exists()
        args[-1] = str(tmp_path / "y.qmz")
    result = run(app, ["compress", str(path), "-o", str(out), "--units", "m", "--max-error", "1"])
    assert result.exit_code == 0 and "warning" not in result.stderr, result.output
    before = out.read_bytes()
    other = tmp_path / "again.bvh"
    other.write_bytes(path.read_bytes().replace(b"Frame Time", b"Frame Time", 1) + b"\n")
    result = run(app, ["append", str(out), str(other), "--units", "cm"])
    assert result.exit_code == 2 and "likely --units m" in result.stderr, result.output
    assert out.read_bytes() == before
    result = run(app, ["append", str(out), str(other), "--units", "cm", "--force-units"])
    assert result.exit_code == 0, result.output
    with codec.Archive.open(out) as archive:
        assert archive.read(0).skeleton.extras["bvh_scale"] == 100.0
        decoded = archive.read(0)
    error = forward_kinematics(decoded).all_positions() - forward_kinematics(truth).all_positions()
    assert np.linalg.norm(error, axis=-1).max() <= 1.0 + 1e-6
