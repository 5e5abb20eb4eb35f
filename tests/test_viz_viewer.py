"""The viewer page and its frame data, without a browser (tests/test_viz_browser.py plays it)."""

from __future__ import annotations

import dataclasses
import json
import re

import numpy as np
import pytest
from typer.testing import CliRunner

from quatmotion.cli import app
from quatmotion.io import write_motion
from quatmotion.motion import Motion, forward_kinematics
from quatmotion.synthetic import generate_clip
from quatmotion.viz import frame_data, viewer


def _lossy(motion: Motion) -> Motion:
    """A stand-in for a decoded clip: every quaternion component rounded to 2 decimals."""
    rotations = np.round(motion.rotations, 2)
    rotations /= np.linalg.norm(rotations, axis=-1, keepdims=True)
    return Motion(motion.skeleton, motion.fps, motion.root_translation, rotations, name="lossy")


def _embedded(page: str) -> dict:
    match = re.search(r'<script id="quatmotion-data" type="application/json">(.*?)</script>', page)
    assert match, "no embedded data"
    return json.loads(match.group(1))


@pytest.fixture(scope="module")
def walk() -> Motion:
    # 2,000 frames of walking: the root travels metres while the body spans one.
    return generate_clip("walk", 4, n_frames=2000)


def test_clip_payload_decodes_to_every_frame_within_its_stated_bound(walk):
    payload = frame_data.encode_clip(walk)
    expected = forward_kinematics(walk).all_positions()
    decoded = frame_data.decode_clip(json.loads(json.dumps(payload)))
    assert decoded.shape == expected.shape == (2000, walk.n_joints + walk.skeleton.n_sites, 3)
    assert np.abs(decoded - expected).max() <= payload["max_quantisation_cm"] + 1e-9
    # Root-relative quantisation keeps the bound at a body's scale, not the walk's.
    assert payload["max_quantisation_cm"] < 0.01
    assert payload["n_frames"] == 2000 and payload["fps"] == walk.fps
    names = payload["point_names"]
    assert names == [*walk.skeleton.joint_names, *walk.skeleton.site_names]
    # One bone per non-root joint and per end site, each from a parent to a child.
    assert len(payload["bones"]) == walk.n_joints - 1 + walk.skeleton.n_sites
    assert all(a < b for a, b in payload["bones"])


def test_uint16_block_bound_wraparound_and_constant_columns():
    rng = np.random.default_rng(0)
    values = rng.normal(0, 50, size=(300, 6))
    values[::2, 0] = 1e3  # jumps across the whole range between frames: deltas wrap mod 2**16
    values[:, [2, 5]] = 7.25  # group 2 (columns 2 and 5) is constant
    block = frame_data.encode_uint16(values, groups=3)
    decoded = frame_data.decode_block(block)
    step = np.tile(block["step"], 2)
    assert np.all(np.abs(decoded - values) <= step / 2 + 1e-9)
    assert np.all(decoded[:, [2, 5]] == 7.25)


def test_float32_block_is_exact_to_float32():
    values = np.random.default_rng(1).normal(0, 1e4, size=(50, 3))
    decoded = frame_data.decode_block(frame_data.encode_float32(values))
    assert np.array_equal(decoded, values.astype(np.float32).astype(np.float64))


def test_a_block_of_the_wrong_size_is_refused():
    block = frame_data.encode_uint16(np.zeros((10, 3)))
    with pytest.raises(ValueError, match=r"shape \(11, 3\)"):
        frame_data.decode_block({**block, "shape": [11, 3]})


def test_comparison_errors_are_point_distances_and_arms():
    clip = generate_clip("squat", 2, n_frames=120)
    shifted = Motion(
        clip.skeleton, clip.fps, clip.root_translation + [3.0, 0.0, 4.0], clip.rotations
    )
    _, _, errors = frame_data.encode_comparison(clip, shifted)
    # Every point moved by the same (3, 0, 4) cm: 5 cm everywhere.
    assert errors["arms_cm"] == pytest.approx(5.0) and errors["max_cm"] == pytest.approx(5.0)
    np.testing.assert_allclose(frame_data.decode_block(errors["block"]), 5.0, atol=1e-9)

    lossy = _lossy(clip)
    _, _, errors = frame_data.encode_comparison(clip, lossy)
    distance = np.linalg.norm(
        forward_kinematics(clip).all_positions() - forward_kinematics(lossy).all_positions(),
        axis=-1,
    )
    assert errors["arms_cm"] == pytest.approx(np.sqrt((distance**2).mean(axis=1)).mean())
    decoded = frame_data.decode_block(errors["block"])
    assert np.abs(decoded - distance).max() <= errors["max_quantisation_cm"] + 1e-12


def test_comparison_needs_the_same_skeleton_frames_and_rate():
    clip = generate_clip("kick", 1, n_frames=100)
    with pytest.raises(ValueError, match="same skeleton and frame count"):
        frame_data.encode_comparison(clip, clip.slice(0, 90))
    with pytest.raises(ValueError, match="fps"):
        half_rate = generate_clip("kick", 1, n_frames=200).slice(0, None, 2)  # 100 frames, 60 fps
        frame_data.encode_comparison(clip, half_rate)


def test_view_data_pairs_any_two_clips_and_says_when_it_shows_no_error():
    long = generate_clip("walk", 1, n_frames=120)
    short = generate_clip("walk", 2, n_frames=90)
    data = viewer.view_data([long, long], [short, long])
    different, same = data["pairs"]
    assert [c["n_frames"] for c in data["clips"]] == [120, 90, 120, 120]  # each at its length
    assert different["errors"] is None and different["arms_cm"] is None
    assert "lengths differ (120 and 90 frames)" in different["no_error"]
    assert same["errors"] is not None and "no_error" not in same and same["max_cm"] < 1e-6

    sk = long.skeleton
    anonymous = dataclasses.replace(
        long,
        skeleton=dataclasses.replace(sk, joint_names=tuple(f"j{k}" for k in range(sk.n_joints))),
    )
    (pair,) = viewer.view_data([long], [anonymous])["pairs"]
    assert pair["errors"] is None and "skeletons differ" in pair["no_error"]
    half_rate = generate_clip("walk", 1, n_frames=240).slice(0, None, 2)
    (pair,) = viewer.view_data([long], [half_rate])["pairs"]
    assert "frame rates differ (120 and 60 fps)" in pair["no_error"]


def test_page_holds_every_frame_and_fetches_nothing(tmp_path):
    clips = [generate_clip("wave", 1, n_frames=150), generate_clip("jump", 2, n_frames=90)]
    path = viewer.write_view(tmp_path / "view.html", clips, ghost=10)
    page = path.read_text(encoding="utf-8")
    data = _embedded(page)
    assert [c["n_frames"] for c in data["clips"]] == [150, 90]
    assert data["ghost"] == 10 and data["layout"] == "side" and data["pairs"] == []
    for clip, payload in zip(clips, data["clips"], strict=True):
        expected = forward_kinematics(clip).all_positions()
        decoded = frame_data.decode_clip(payload)
        assert np.abs(decoded - expected).max() <= payload["max_quantisation_cm"] + 1e-9
    # Everything inline: no element loads a source, no URL to fetch, and the page forbids it.
    assert not re.search(r"<(script|link|img|iframe|source)\b[^>]*\b(src|href)\s*=", page, re.I)
    assert "<link" not in page.lower()
    assert "default-src 'none'" in page
    assert "three.js 0.187.0" in page and "MIT licence" in page


def test_data_cannot_break_out_of_its_script_element(tmp_path):
    clip = generate_clip("punch", 1, n_frames=20)
    name = "</script><script>alert(1)</script><!--"
    clip = Motion(clip.skeleton, clip.fps, clip.root_translation, clip.rotations, name=name)
    page = viewer.write_view(tmp_path / "v.html", [clip]).read_text(encoding="utf-8")
    assert "<script>alert(1)" not in page
    assert _embedded(page)["clips"][0]["name"] == name
    assert "<title>quatmotion view: &lt;/script&gt;" in page


def test_compare_pairs_each_clip_with_its_second_motion(tmp_path):
    clip = generate_clip("run", 3, n_frames=100)
    data = viewer.view_data([clip], [_lossy(clip)], layout="overlay")
    assert data["layout"] == "overlay"
    assert [c["name"] for c in data["clips"]] == [clip.name, "lossy"]
    (pair,) = data["pairs"]
    assert (pair["reference"], pair["compared"]) == (0, 1)
    assert 0 < pair["arms_cm"] <= pair["max_cm"]


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"motions": []}, "at least one"),
        ({"ghost": -1}, "ghost"),
        ({"layout": "grid"}, "layout"),
        ({"compare": []}, "give one for each"),
    ],
)
def test_view_data_refuses_bad_arguments(kwargs, message):
    arguments = {"motions": [generate_clip("walk", 1, n_frames=10)], **kwargs}
    motions = arguments.pop("motions")
    with pytest.raises(ValueError, match=message):
        viewer.view_data(motions, **arguments)


def test_view_command_writes_the_page_and_reports_bad_input(tmp_path):
    clip = generate_clip("jumping_jack", 1, n_frames=60)
    bvh = tmp_path / "jack.bvh"
    write_motion(clip, bvh)
    runner = CliRunner()
    out = tmp_path / "out" / "jack.html"
    result = runner.invoke(app, ["view", str(bvh), "--compare", str(bvh), "-o", str(out)])
    assert result.exit_code == 0, result.output
    data = _embedded(out.read_text(encoding="utf-8"))
    assert data["pairs"][0]["max_cm"] < 1e-3  # a clip against itself (BVH round trip)

    for args, needle in (
        (["view", str(bvh), "--compare", str(bvh), "--compare", str(bvh)], "give one per file"),
        (["view", "lib.qmz::clip_7"], "lib.qmz: no such file"),
        (["view", str(tmp_path / "missing.bvh")], "no such file"),
        (["view", str(bvh), "--layout", "grid"], "--layout"),
    ):
        result = runner.invoke(app, [*args, "-o", str(tmp_path / "bad.html")])
        assert result.exit_code == 2, result.output
        assert needle in result.stderr and "Traceback" not in result.output
    assert not (tmp_path / "bad.html").exists()


def test_view_plays_two_clips_of_different_lengths_and_says_why_it_shows_no_error(tmp_path):
    # Refused before ("the clips need the same skeleton and frame count").
    long, short = tmp_path / "long.bvh", tmp_path / "short.bvh"
    write_motion(generate_clip("walk", 1, n_frames=120), long)
    write_motion(generate_clip("run", 2, n_frames=80), short)
    out = tmp_path / "pair.html"
    result = CliRunner().invoke(app, ["view", str(long), "--compare", str(short), "-o", str(out)])
    assert result.exit_code == 0, result.output
    assert "no per-frame error for long vs short: their lengths differ (120 and 80" in " ".join(
        result.output.split()
    )
    data = _embedded(out.read_text(encoding="utf-8"))
    assert [c["n_frames"] for c in data["clips"]] == [120, 80]
    assert data["pairs"][0]["errors"] is None and "lengths differ" in data["pairs"][0]["no_error"]


def test_view_reads_qmz_clips_and_decoded_copies(tmp_path):
    """``LIB.qmz::CLIP`` reads a clip through the codec and ``--compare-decoded`` shows a clip
    beside its compressed-then-decoded copy: both pairs differ from the original, within the
    bound the library was written with."""
    from quatmotion import codec

    clip = generate_clip("kick", 2, n_frames=80)
    library = tmp_path / "lib.qmz"
    codec.Archive.build([clip], library, codec.CompressSettings(max_error=1.0))
    bvh = tmp_path / "kick.bvh"
    write_motion(clip, bvh)
    runner = CliRunner()
    for args, compared in (
        (["--compare", f"{library}::{clip.name}"], f"lib.qmz::{clip.name}"),
        (["--compare-decoded"], "kick (decoded)"),  # the file stem
    ):
        out = tmp_path / f"page{len(args)}.html"
        result = runner.invoke(app, ["view", str(bvh), *args, "-o", str(out)])
        assert result.exit_code == 0, result.output
        data = _embedded(out.read_text(encoding="utf-8"))
        assert data["clips"][1]["name"] == compared
        assert 0 < data["pairs"][0]["max_cm"] <= 1.0 + 1e-3
    result = runner.invoke(app, ["view", f"{library}::other", "-o", str(tmp_path / "x.html")])
    assert result.exit_code == 2 and "other" in result.stderr


def test_view_and_report_keep_an_existing_page_unless_forced(tmp_path):
    clip = generate_clip("squat", 1, n_frames=30)
    bvh = tmp_path / "squat.bvh"
    write_motion(clip, bvh)
    page = tmp_path / "page.html"
    page.write_text("mine")
    runner = CliRunner()
    for args in (["view", str(bvh)], ["report", str(bvh)]):
        result = runner.invoke(app, [*args, "-o", str(page)])
        assert result.exit_code == 2 and "--force" in result.stderr
        assert page.read_text() == "mine"
    result = runner.invoke(app, ["view", str(bvh), "-o", str(page), "--force"])
    assert result.exit_code == 0, result.output
    assert page.read_text() != "mine"
    result = runner.invoke(app, ["view", str(bvh), "-o", str(bvh)])
    assert result.exit_code == 2 and "is also an input" in result.stderr
