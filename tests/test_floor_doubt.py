"""Issue 29 item 5: a markerless capture's BVH (the root's rest height in its OFFSET, its
position channels near zero) read as absolute stands half under the floor. ``info`` (every
reader, through :func:`quatmotion.io.implausible_values`) says so and names the reading that
puts the feet on the floor, ``--bvh-translations relative``, which reads the root's channels
relative to its OFFSET. The rig is made here from a generated clip: no mocap file is kept."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from quatmotion import io
from quatmotion.cli import app
from quatmotion.motion import forward_kinematics
from quatmotion.synthetic import generate_clip


def markerless_rig(folder: Path) -> tuple[Path, np.ndarray]:
    """A squat in place written as a markerless exporter writes it: the root's OFFSET at its
    median height, its position channels the small motion about it. Returns the file and the
    true positions (cm)."""
    clip = generate_clip("squat", 1, n_frames=120)
    truth = forward_kinematics(clip).all_positions()
    plain = folder / "plain.bvh"
    io.write_bvh(clip, plain)
    motion = io.read_motion(plain)
    sk = motion.skeleton
    rest = np.median(motion.root_translation, axis=0)
    offsets = sk.offsets.copy()
    offsets[0] = rest
    markerless = dataclasses.replace(
        motion,
        skeleton=dataclasses.replace(sk, offsets=offsets),
        root_translation=motion.root_translation - rest,
    )
    path = folder / "markerless.bvh"
    io.write_bvh(markerless, path)
    return path, truth


def test_feet_under_the_floor_all_clip_long_are_a_doubt_naming_the_relative_reading(tmp_path):
    path, truth = markerless_rig(tmp_path)
    absolute = io.read_motion(path)
    floor = [d for d in io.implausible_values(absolute) if d.kind == "floor"]
    assert len(floor) == 1 and "--bvh-translations relative" in floor[0].message, floor
    relative = io.read_motion(path, translations="relative")
    assert [d for d in io.implausible_values(relative) if d.kind == "floor"] == []
    back = forward_kinematics(relative).all_positions()
    assert np.abs(back - truth).max() < 1e-3  # the reading named is the true figure


def test_info_warns_once_and_the_clips_that_stand_on_the_floor_are_no_doubt(tmp_path):
    path, _ = markerless_rig(tmp_path)
    result = CliRunner().invoke(app, ["info", str(path)])
    assert result.exit_code == 0, result.output
    warnings = [w for w in result.stderr.splitlines() if "below the floor" in w]
    assert len(warnings) == 1 and "--bvh-translations relative" in warnings[0], result.stderr
    result = CliRunner().invoke(app, ["info", str(path), "--bvh-translations", "relative"])
    assert result.exit_code == 0 and "below the floor" not in result.stderr, result.output
    for kind in ("walk", "jump", "squat"):  # standing, jumping, crouching: on the floor
        clip = generate_clip(kind, 2, n_frames=120)
        assert [d for d in io.implausible_values(clip) if d.kind == "floor"] == [], kind


@pytest.mark.needs_data
@pytest.mark.parametrize("collection", ["cmu", "cmu_bvh", "hdm05", "bandai1"])
def test_no_floor_doubt_about_the_shared_libraries(collection):
    from quatmotion.datasets import data_root

    root = data_root() / collection
    files = sorted(f for f in root.rglob("*") if f.suffix.lower() in (".amc", ".bvh"))[::25]
    assert files
    for path in files[:12]:
        motion = io.read_motion(path)
        assert [d for d in io.implausible_values(motion) if d.kind == "floor"] == [], path


def test_the_viewer_floor_follows_feet_that_stay_under_it(browser, tmp_path):
    """The viewer's grid is the floor at Y = 0, unless the figure stays under it all clip
    long: then it is at the clip's lowest point (the page says where: ``data-floor``)."""
    from quatmotion.viz import write_view

    path, _ = markerless_rig(tmp_path)
    under = io.read_motion(path)
    lowest = float(forward_kinematics(under).all_positions()[..., 1].min())
    for motion, floor in ((under, lowest), (io.read_motion(path, translations="relative"), 0.0)):
        page_path = tmp_path / f"{floor:.0f}.html"
        write_view(page_path, [motion])
        page = browser.new_page(viewport={"width": 800, "height": 600})
        page.goto(page_path.as_uri())
        page.wait_for_selector("html[data-first-play-ms], html[data-error]", state="attached")
        assert page.evaluate("document.documentElement.dataset.error || null") is None
        shown = float(page.evaluate("document.documentElement.dataset.floor"))
        assert shown == pytest.approx(floor, abs=1.0), (shown, floor)
        page.close()
