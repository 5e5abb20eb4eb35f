"""Issue 9: what a new user can type gets an answer that means what it says, one ``error:`` line
(exit code 2) for bad input, a ``warning:`` line for doubtful input, and no stray or clobbered
file. Organised by command; each test names the issue item it covers."""

from __future__ import annotations

import json
import re
import tomllib
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from quatmotion import io
from quatmotion.cli import app
from quatmotion.datasets import data_root

DATA = data_root(must_exist=False)
ROOT = Path(__file__).resolve().parents[1]
BANDAI_WALK = DATA / "bandai1" / "clips" / "dataset-1_walk_normal_001.bvh"

runner = CliRunner()


def _invoke(*args: object):
    return runner.invoke(app, [str(a) for a in args])


def _assert_bad_input(result, *needles: str) -> str:
    assert result.exit_code == 2, result.output
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    errors = [line for line in lines if line.startswith("error: ")]
    assert len(errors) == 1 and errors[0] == lines[-1], result.stderr
    assert "Traceback" not in result.output
    for needle in needles:
        assert needle in errors[0], errors[0]
    return errors[0]


def _field(output: str, name: str) -> str:
    match = re.search(rf"{re.escape(name)}\s*│\s*([^│]+?)\s*│", output)
    assert match, f"no {name!r} in:\n{output}"
    return match.group(1)


def _stick_bvh(path: Path, height_units: float, root_x: float = 0.0) -> Path:
    """A two-bone stick figure ``height_units`` tall in its own (unstated) unit: a body (it
    has a head), measured by its extent."""
    half = height_units / 2
    path.write_text(
        "HIERARCHY\nROOT Hips\n{\n  OFFSET 0 0 0\n  CHANNELS 3 Xposition Yposition Zposition\n"
        f"  JOINT Head\n  {{\n    OFFSET 0 {half!r} 0\n    CHANNELS 1 Zrotation\n"
        f"    End Site\n    {{\n      OFFSET 0 {half!r} 0\n    }}\n  }}\n}}\n"
        f"MOTION\nFrames: 2\nFrame Time: 0.01\n{root_x!r} 0 0 0\n{root_x!r} 0 0 5\n"
    )
    return path


# --- small things: --version, help pages, piped output ------------------------------------------


def test_version_option_prints_the_package_version():
    from quatmotion import __version__

    result = _invoke("--version")
    assert result.exit_code == 0, result.output
    assert result.stdout.strip() == f"quatmotion {__version__}"


def test_version_is_the_one_in_pyproject_and_the_release_being_documented():
    from importlib.metadata import version

    declared = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]
    result = _invoke("--version")
    assert result.stdout.strip() == f"quatmotion {declared}"
    assert version("quatmotion") == declared
    performance = (ROOT / "docs" / "performance.md").read_text()
    newest = re.search(r"^## (\d+\.\d+\.\d+)", performance, re.MULTILINE)
    assert newest and newest.group(1) == declared  # the release the docs are collecting numbers for


def test_the_licence_is_an_spdx_expression_and_the_build_backend_reads_it():
    """PEP 639: ``project.license`` a string holding an SPDX expression (a table is deprecated
    and fails builds from 2027), which setuptools reads from 77 on."""
    from packaging.licenses import canonicalize_license_expression
    from packaging.requirements import Requirement
    from packaging.version import Version

    pyproject = tomllib.loads((ROOT / "pyproject.toml").read_text())
    licence = pyproject["project"]["license"]
    assert isinstance(licence, str)
    assert canonicalize_license_expression(licence) == licence
    assert not any(c.startswith("License ::") for c in pyproject["project"].get("classifiers", []))
    setuptools = next(
        Requirement(r) for r in pyproject["build-system"]["requires"] if r.startswith("setuptools")
    )
    assert not setuptools.specifier.contains(Version("76.1"))
    assert setuptools.specifier.contains(Version("77.0.0"))


def _commands(group, prefix=()):
    import click

    for name, command in group.commands.items():
        yield (*prefix, name)
        if isinstance(command, click.Group):
            yield from _commands(command, (*prefix, name))


@pytest.mark.parametrize("width", [80, 120])
def test_no_help_page_breaks_a_sentence_where_the_source_did(width, monkeypatch):
    """A line of a command's description ends where the next word would not fit, or where a
    paragraph ends: never early ("same bytes on / any / scheduler")."""
    import typer.main

    monkeypatch.setenv("COLUMNS", str(width))
    for command in _commands(typer.main.get_command(app)):
        result = _invoke(*command, "--help")
        assert result.exit_code == 0, (command, result.output)
        lines = result.stdout.splitlines()
        start = next(i for i, line in enumerate(lines) if line.strip().startswith("Usage:")) + 1
        stop = next((i for i, line in enumerate(lines) if line.startswith("╭")), len(lines))
        described = [line.rstrip() for line in lines[start:stop]]
        for line, following in zip(described, described[1:], strict=False):
            if line.strip() and following.strip():
                room = width - len(line) - 1
                assert len(following.split()[0]) > room - 2, (command, line, following)


def test_generate_help_lists_the_motion_kinds():
    from quatmotion.synthetic import KINDS

    result = _invoke("generate", "--help")
    text = " ".join(result.stdout.split())
    assert all(kind in text for kind in KINDS), text


@pytest.mark.parametrize(
    "args",
    [(), ("pose",), ("datasets",), ("pose", "index", "--help"), ("pose", "search", "--help"),
     ("info", "--help"), ("convert", "--help"), ("generate", "--help"), ("bench", "--help"),
     ("demo", "--help"), ("datasets", "list", "--help"), ("datasets", "fetch", "--help")],
)  # fmt: skip
def test_no_help_page_offers_shell_completion(args):
    result = _invoke(*args, "--help") if args[-1:] != ("--help",) else _invoke(*args)
    assert "completion" not in result.output.lower()


def test_piped_output_keeps_file_paths_whole(tmp_path):
    deep = tmp_path / ("a_rather_long_folder_name_" * 4) / "walk_with_a_long_name_too.bvh"
    deep.parent.mkdir()
    assert _invoke("generate", "walk", deep, "--frames", "10").exit_code == 0
    result = _invoke("info", deep)
    assert result.exit_code == 0, result.output
    assert str(deep) in result.stdout  # on one line, not folded at 80 columns


# --- info: units (3), heights (4), absurd values (15) -------------------------------------------


def test_info_reports_the_guessed_unit_and_warns_when_the_figure_is_implausible(tmp_path):
    # A 90 cm child in centimetres: 229 cm read in inches is no human (issue 21, item 7).
    child = _stick_bvh(tmp_path / "child.bvh", 90.0)
    result = _invoke("info", child)
    assert result.exit_code == 0, result.output
    assert _field(result.stdout, "unit") == "cm (guessed)" and "warning" not in result.stderr
    giant = _invoke("info", _stick_bvh(tmp_path / "giant.bvh", 300.0))  # no unit makes it human
    warning = [line for line in giant.stderr.splitlines() if line.startswith("warning:")]
    assert warning and "--units" in warning[0] and "50 to 220 cm" in warning[0], giant.stderr
    given = _invoke("info", child, "--units", "cm")
    assert given.exit_code == 0, given.output
    assert "warning" not in given.stderr
    assert float(_field(given.stdout, "rest pose height (cm)")) == pytest.approx(90.0)
    adult = _invoke("info", _stick_bvh(tmp_path / "adult.bvh", 175.0))
    assert "cm" in _field(adult.stdout, "unit") and "warning" not in adult.stderr


def test_units_option_is_validated_and_reaches_every_reader(tmp_path):
    child = _stick_bvh(tmp_path / "child.bvh", 90.0)
    _assert_bad_input(_invoke("info", child, "--units", "furlong"), "furlong", "cm")
    out = tmp_path / "child_cm.bvh"
    assert _invoke("convert", child, out, "--units", "cm").exit_code == 0
    assert io.read_motion(out, units="cm").skeleton.height() == pytest.approx(90.0)
    amc = tmp_path / "w.amc"
    assert _invoke("generate", "walk", amc, "--frames", "5").exit_code == 0
    # An ASF states its unit; --units replaces it (issue 21, item 9).
    given = _invoke("info", amc, "--units", "cm")
    assert given.exit_code == 0 and _field(given.stdout, "unit") == "cm (given)", given.output


def test_a_unit_is_read_from_a_string_or_a_number(tmp_path):
    child = _stick_bvh(tmp_path / "child.bvh", 90.0)
    assert io.read_motion(child, units="mm").skeleton.height() == pytest.approx(9.0)
    assert io.read_motion(child, units="m").skeleton.height() == pytest.approx(9000.0)
    sk = io.read_motion(child, units="in").skeleton
    assert sk.height() == pytest.approx(228.6) and sk.extras["bvh_unit"] == "in"
    with pytest.raises(ValueError, match="furlong"):
        io.read_motion(child, units="furlong")


@pytest.mark.needs_data
def test_info_heights_mean_what_they_say_for_a_lying_rest_pose():
    """Bandai's rest pose lies along X and its root joint stays put while Hips moves."""
    result = _invoke("info", BANDAI_WALK)
    assert result.exit_code == 0, result.output
    out = result.stdout
    assert "not upright" in _field(out, "rest pose height (cm)")
    assert "standing height" not in out and "rest height" not in out
    median_extent = float(_field(out, "vertical extent, median over frames (cm)"))
    assert 120 < median_extent < 200
    hips = _field(out, "Hips at frame 0 (cm)").split()
    assert float(hips[1]) > 50  # the moving pelvis, not the static joint_Root at the origin


@pytest.mark.needs_data
def test_info_of_a_lie_down_clip_labels_its_extent():
    amc = DATA / "hdm05" / "clips" / "lieDownFloor" / "HDM_bd_lieDownFloor_001_120.amc"
    out = _invoke("info", amc).stdout
    stature = float(_field(out, "ankle-to-head bone chain (cm)"))
    extent = float(_field(out, "vertical extent, median over frames (cm)"))
    assert 140 < stature < 200 and extent < stature  # lying most of the clip: labelled so
    assert float(_field(out, "rest pose height (cm)")) > 140


def test_info_warns_about_absurd_values_and_prints_them_briefly(tmp_path):
    far = _stick_bvh(tmp_path / "far.bvh", 175.0, root_x=1e308)
    result = _invoke("info", far)
    assert result.exit_code == 0, result.output
    assert max(len(line) for line in result.stdout.splitlines()) < 200
    assert "e+308" in result.stdout
    warnings = [line for line in result.stderr.splitlines() if line.startswith("warning:")]
    assert any("km" in w for w in warnings), result.stderr


def test_info_of_an_asf_shows_its_unit(tmp_path):
    assert _invoke("generate", "walk", tmp_path / "w.amc", "--frames", "5").exit_code == 0
    result = _invoke("info", tmp_path / "w.asf")
    assert result.exit_code == 0, result.output
    assert "ASF" in _field(result.stdout, "unit")


# --- generate and convert: the skeleton written where it is found (5), no stray or clobbered
# --- files (7, 8, 9), bounded arguments (10) ------------------------------------------------------


@pytest.mark.parametrize("name", ["run.amc", "my_walk.amc", "HDM_xx_kick_001_120.amc"])
def test_a_written_amc_is_read_back_by_every_reader(tmp_path, name):
    (tmp_path / "my.asf").write_text("someone else's skeleton\n")
    (tmp_path / "HDM_xx.asf").write_text("someone else's skeleton\n")
    amc = tmp_path / name
    result = _invoke("generate", "walk", amc, "--frames", "12")
    assert result.exit_code == 0, result.output
    assert amc.with_suffix(".asf").is_file()
    assert (tmp_path / "my.asf").read_text() == "someone else's skeleton\n"
    assert (tmp_path / "HDM_xx.asf").read_text() == "someone else's skeleton\n"
    assert io.read_motion(amc).n_frames == 12
    info = _invoke("info", amc)
    assert info.exit_code == 0, info.output
    bvh = tmp_path / "back.bvh"
    assert _invoke("convert", amc, bvh).exit_code == 0
    assert io.read_motion(bvh).n_frames == 12


def test_an_unknown_output_extension_is_an_error_and_leaves_nothing(tmp_path):
    clip = tmp_path / "a.bvh"
    assert _invoke("generate", "walk", clip, "--frames", "5").exit_code == 0
    _assert_bad_input(_invoke("convert", clip, tmp_path / "out" / "x.txt"), "x.txt", ".txt")
    assert not (tmp_path / "out").exists()


def test_a_failed_batch_convert_leaves_no_folder_or_partial_output(tmp_path):
    good = tmp_path / "a.bvh"
    assert _invoke("generate", "walk", good, "--frames", "5").exit_code == 0
    broken = tmp_path / "broken.bvh"
    broken.write_text("HIERARCHY\nROOT a\n{\n OFFSET 0 0 0\n")
    out = tmp_path / "converted"
    _assert_bad_input(_invoke("convert", good, broken, out), "broken.bvh")
    assert not out.exists()
    existing = tmp_path / "existing"
    existing.mkdir()
    _assert_bad_input(_invoke("convert", good, broken, existing), "broken.bvh")
    assert list(existing.iterdir()) == []


def test_outputs_are_never_replaced_without_force_and_inputs_never(tmp_path):
    clip = tmp_path / "a.bvh"
    assert _invoke("generate", "walk", clip, "--frames", "5").exit_code == 0
    before = clip.read_bytes()
    _assert_bad_input(_invoke("convert", clip, clip), "a.bvh", "input")
    _assert_bad_input(_invoke("convert", clip, clip, "--force"), "a.bvh", "input")
    _assert_bad_input(_invoke("generate", "run", clip, "--frames", "5"), "a.bvh", "--force")
    assert clip.read_bytes() == before
    assert _invoke("generate", "run", clip, "--frames", "5", "--force").exit_code == 0
    assert clip.read_bytes() != before
    other = tmp_path / "b.bvh"
    other.write_text("mine\n")
    _assert_bad_input(_invoke("convert", clip, other), "b.bvh", "--force")
    assert other.read_text() == "mine\n"
    folder = tmp_path / "folder"
    folder.mkdir()
    (folder / "a.bvh").write_text("mine\n")
    assert _invoke("generate", "walk", tmp_path / "c.bvh", "--frames", "5").exit_code == 0
    _assert_bad_input(_invoke("convert", clip, tmp_path / "c.bvh", folder), "a.bvh", "--force")
    assert (folder / "a.bvh").read_text() == "mine\n" and not (folder / "c.bvh").exists()


def test_an_amc_output_refuses_to_replace_an_existing_asf(tmp_path):
    (tmp_path / "w.asf").write_text("mine\n")
    _assert_bad_input(_invoke("generate", "walk", tmp_path / "w.amc", "--frames", "5"), "w.asf")
    assert (tmp_path / "w.asf").read_text() == "mine\n" and not (tmp_path / "w.amc").exists()


def test_a_folder_named_like_a_clip_is_reported_plainly(tmp_path):
    folder = tmp_path / "x.bvh"
    folder.mkdir()
    message = _assert_bad_input(_invoke("generate", "walk", folder, "--frames", "5"), "x.bvh")
    assert ".tmp" not in message and "Errno" not in message
    clip = tmp_path / "a.bvh"
    assert _invoke("generate", "walk", clip, "--frames", "5").exit_code == 0
    assert _invoke("convert", clip, folder).exit_code == 0  # an existing folder: write into it
    assert (folder / "a.bvh").is_file()


@pytest.mark.parametrize(
    ("option", "value", "needle"),
    [("--frames", "2000000000", "--frames"), ("--frames", "0", "--frames"),
     ("--fps", "1e-300", "--fps"), ("--fps", "0", "--fps"), ("--fps", "nan", "--fps"),
     ("--fps", "1e9", "--fps"), ("--seed", "-1", "--seed")],
)  # fmt: skip
def test_generate_bounds_its_arguments(tmp_path, option, value, needle):
    out = tmp_path / "big.bvh"
    _assert_bad_input(_invoke("generate", "walk", out, option, value), needle)
    assert not out.exists()


# --- pose index and pose search: frames (2), --skeleton (6), options (11), bad values (12),
# --- wrong files (13), clip names and -k (14), --json ------------------------------------------


@pytest.fixture(scope="module")
def pose_library(tmp_path_factory):
    """A small library of generated clips (one BVH per kind) and its folder."""
    folder = tmp_path_factory.mktemp("poses")
    clips = folder / "clips"
    for kind in ("walk", "squat", "jumping_jack"):
        assert _invoke("generate", kind, clips / f"{kind}.bvh", "--frames", "120").exit_code == 0
    library = folder / "poses.idx"
    result = _invoke(
        "pose", "index", clips, "-o", library, "--rank", "8", "--unlabeled", "200", "--pairs", "40"
    )
    assert result.exit_code == 0, result.output
    return library, clips


def test_pose_search_frames_count_from_zero_and_out_of_range_is_an_error(pose_library):
    library, clips = pose_library
    for where in (("--clip", "walk"), ("--file", clips / "walk.bvh")):
        for frame in ("5000", "120", "-1"):
            _assert_bad_input(
                _invoke("pose", "search", library, *where, "--frame", frame), "0 to 119"
            )
        result = _invoke("pose", "search", library, *where, "--frame", "0", "-k", "1", "--json")
        assert result.exit_code == 0, result.output
        assert json.loads(result.stdout)["query"]["frame"] == 0
    table = _invoke("pose", "search", library, "--clip", "walk", "--frame", "4")
    assert "count from 0" in table.stdout
    assert "count from 0" in _invoke("pose", "search", "--help").stdout


def test_pose_search_json_has_the_search_document_shape(pose_library):
    library, _ = pose_library
    result = _invoke("pose", "search", library, "--clip", "squat", "--frame", "60", "--json")
    assert result.exit_code == 0, result.output
    doc = json.loads(result.stdout)
    assert {"query", "method", "results"} <= set(doc)
    assert doc["query"]["clip"] == "squat" and doc["query"]["frame"] == 60
    first = doc["results"][0]
    assert {"rank", "clip", "path", "label", "distance", "frame", "seconds"} <= set(first)
    assert first["rank"] == 1 and first["clip"] == "squat" and first["frame"] == 60
    assert first["path"].endswith("squat.bvh") and first["distance"] < 1e-4
    assert [r["rank"] for r in doc["results"]] == list(range(1, 11))


def test_pose_search_other_clips_leaves_out_a_file_of_an_indexed_clip(pose_library):
    """--other-clips leaves out the query's own clip whether it is named or given as its file
    (the content hash): the same poses either way."""
    library, clips = pose_library
    # frame 32: an indexed pose (the library samples the 120 fps clips at 30 fps), so the
    # file's query pose is the one --clip takes
    args = ("--frame", "32", "--other-clips", "-k", "10", "--json")
    by_clip = _invoke("pose", "search", library, "--clip", "squat", *args)
    by_file = _invoke("pose", "search", library, "--file", clips / "squat.bvh", *args)
    assert by_clip.exit_code == 0 and by_file.exit_code == 0, by_file.output
    named, filed = json.loads(by_clip.stdout)["results"], json.loads(by_file.stdout)["results"]
    assert "squat" not in {Path(r["clip"]).stem for r in filed}
    assert [(r["clip"], r["frame"]) for r in filed] == [(r["clip"], r["frame"]) for r in named]


def test_pose_search_clip_names_numbers_and_k(pose_library):
    library, _ = pose_library
    number = _invoke("pose", "search", library, "--clip", "1", "--frame", "0", "-k", "1", "--json")
    assert number.exit_code == 0, number.output
    names = [json.loads(number.stdout)["results"][0]["clip"]]
    by_name = _invoke("pose", "search", library, "--clip", names[0], "--frame", "0", "--json")
    assert json.loads(by_name.stdout)["query"]["clip"] == names[0]
    _assert_bad_input(_invoke("pose", "search", library, "--clip", "7", "--frame", "0"), "0 to 2")
    _assert_bad_input(
        _invoke("pose", "search", library, "--clip", "jumpingjack", "--frame", "0"),
        "jumping_jack",
    )
    n_poses = 3 * 30  # 120 frames at 120 fps indexed at 30 fps
    for k in ("0", str(n_poses + 1)):
        _assert_bad_input(
            _invoke("pose", "search", library, "--clip", "walk", "--frame", "0", "-k", k),
            f"1 to {n_poses}",
        )
    others = _invoke(
        "pose", "search", library, "--clip", "walk", "--frame", "0", "--other-clips", "-k", "61"
    )
    _assert_bad_input(others, "1 to 60")


def test_pose_commands_take_skeleton_and_units(pose_library, tmp_path):
    library, _ = pose_library
    amc = tmp_path / "walk_01.amc"
    assert _invoke("generate", "walk", amc, "--frames", "60").exit_code == 0
    amc.with_suffix(".asf").rename(tmp_path / "body.asf")
    # the folder's only ASF is the AMC's; with two, neither named for it, the user must choose
    only = _invoke("pose", "search", library, "--file", amc, "--frame", "0", "-k", "1")
    assert only.exit_code == 0, only.output
    (tmp_path / "other.asf").write_bytes((tmp_path / "body.asf").read_bytes())
    _assert_bad_input(
        _invoke("pose", "search", library, "--file", amc, "--frame", "0"), "--skeleton"
    )
    found = _invoke(
        "pose", "search", library, "--file", amc, "--skeleton", tmp_path / "body.asf",
        "--frame", "0", "-k", "1",
    )  # fmt: skip
    assert found.exit_code == 0, found.output
    bvh = tmp_path / "w.bvh"
    assert _invoke("generate", "walk", bvh, "--frames", "60").exit_code == 0
    found = _invoke("pose", "search", library, "--file", bvh, "--units", "cm", "--frame", "0")
    assert found.exit_code == 0, found.output
    out = tmp_path / "amc.idx"
    index = _invoke(
        "pose", "index", amc, bvh, "-o", out, "--skeleton", tmp_path / "body.asf",
        "--rank", "4", "--unlabeled", "50", "--pairs", "10",
    )  # fmt: skip
    assert index.exit_code == 0, index.output
    assert "of 2 clips; 0 of 2 clips failed" in index.stdout


@pytest.mark.parametrize(
    ("option", "value"),
    [("--fps", "0"), ("--fps", "nan"), ("--height", "-170"), ("--rank", "0"),
     ("--unlabeled", "0"), ("--pairs", "0"), ("--seed", "-3")],
)  # fmt: skip
def test_pose_index_checks_its_options_before_reading(tmp_path, option, value):
    missing = tmp_path / "no-such-folder"
    result = _invoke("pose", "index", missing, "-o", tmp_path / "x.idx", option, value)
    _assert_bad_input(result, option)


def test_pose_index_skips_absurd_clips_quietly_and_keeps_its_inputs(tmp_path, pose_library):
    _, clips = pose_library
    folder = tmp_path / "clips"
    folder.mkdir()
    for name in ("walk.bvh", "squat.bvh"):
        (folder / name).write_bytes((clips / name).read_bytes())
    _stick_bvh(folder / "far.bvh", 175.0, root_x=1e308)
    (folder / "x.bvh").mkdir()  # a folder named like a clip is not a clip
    out = tmp_path / "lib.idx"
    args = ("pose", "index", folder, "-o", out, "--rank", "4", "--unlabeled", "50", "--pairs", "10")
    result = _invoke(*args)
    assert result.exit_code == 1, result.output  # the library is written; a clip failed
    assert "Warning" not in result.stderr and "RuntimeWarning" not in result.output
    assert re.search(r"skipped .*far\.bvh: .*1 km", result.stderr), result.stderr
    assert "1 of 3 clips failed" in result.stdout
    _assert_bad_input(_invoke(*args), "lib.idx", "--force")
    assert _invoke(*args, "--force").exit_code == 1
    walk = folder / "walk.bvh"
    before = walk.read_bytes()
    _assert_bad_input(_invoke("pose", "index", folder, "-o", walk, "--force"), "input")
    assert walk.read_bytes() == before


def test_pose_search_names_a_file_that_is_not_a_library(tmp_path):
    pickled = tmp_path / "objects.npy"
    np.save(pickled, np.array([{"a": 1}], dtype=object), allow_pickle=True)
    text = tmp_path / "notes.idx"
    text.write_text("not a library\n")
    other = tmp_path / "other.npz"
    np.savez(other, x=np.zeros(3))
    for path in (pickled, text, other):
        message = _assert_bad_input(
            _invoke("pose", "search", path, "--clip", "0", "--frame", "0"),
            path.name, "not a quatmotion pose library", "versions 2 to 4",
        )  # fmt: skip
        assert "pickle" not in message
    _assert_bad_input(_invoke("pose", "search", tmp_path, "--clip", "0", "--frame", "0"))


# --- bench, demo, datasets: the same policies ------------------------------------------------


def test_bench_out_is_a_json_file_never_a_folder_or_an_existing_file(tmp_path):
    _assert_bad_input(_invoke("bench", "io", "--out", tmp_path), "json")
    folder = tmp_path / "results.json"
    folder.mkdir()
    _assert_bad_input(_invoke("bench", "io", "--out", folder), "folder")
    existing = tmp_path / "io.json"
    existing.write_text("{}")
    _assert_bad_input(_invoke("bench", "io", "--out", existing), "--force")
    assert existing.read_text() == "{}"
    _assert_bad_input(
        _invoke("bench", "io", "--out", tmp_path / "x.json", "--seed", "-1"), "--seed"
    )


def test_demo_keeps_an_earlier_summary_unless_forced(tmp_path):
    out = tmp_path / "demo"
    out.mkdir()
    (out / "summary.json").write_text("{}")
    _assert_bad_input(_invoke("demo", "--quick", "--out", out), "summary.json", "--force")
    assert (out / "summary.json").read_text() == "{}"
    a_file = tmp_path / "file"
    a_file.write_text("x")
    _assert_bad_input(_invoke("demo", "--quick", "--out", a_file), "folder")


def test_datasets_options_are_checked():
    _assert_bad_input(_invoke("datasets", "list", "--limit", "-1"), "--limit")
    assert "--force" in _invoke("datasets", "fetch", "--help").stdout


def test_units_and_skeleton_reach_the_demo_and_batch_convert(tmp_path):
    child = _stick_bvh(tmp_path / "child.bvh", 90.0)
    _assert_bad_input(_invoke("demo", child, "--units", "furlong", "--out", tmp_path), "furlong")
    amc = tmp_path / "w.amc"
    assert _invoke("generate", "walk", amc, "--frames", "5").exit_code == 0
    out = tmp_path / "both"
    result = _invoke("convert", child, amc, out, "--units", "cm")  # --units: for the BVH
    assert result.exit_code == 0, result.output
    written = io.read_motion(out / "child.bvh", units="cm")  # the numbers of the input
    assert written.skeleton.height() == pytest.approx(90.0)
