"""The standalone viewer page in a real headless Chromium (the ``browser`` fixture, conftest).

The page's Content-Security-Policy forbids ``eval``, so the tests wait on selectors
(``html[data-first-play-ms]``) and read state with ``page.evaluate`` (which the policy does
not cover), never with ``wait_for_function``.
"""

from __future__ import annotations

import io

import numpy as np
import pytest
from PIL import Image

from quatmotion import codec
from quatmotion.io import read_motion
from quatmotion.motion import Motion, forward_kinematics
from quatmotion.synthetic import generate_clip
from quatmotion.viz import write_view


def _lossy(motion: Motion) -> Motion:
    """A stand-in for a decoded clip: every quaternion component rounded to 2 decimals."""
    rotations = np.round(motion.rotations, 2)
    rotations /= np.linalg.norm(rotations, axis=-1, keepdims=True)
    return Motion(motion.skeleton, motion.fps, motion.root_translation, rotations, name="rounded")


def _frame(page) -> int:
    return int(page.evaluate("document.documentElement.dataset.frame"))


def _canvas(page) -> np.ndarray:
    page.evaluate("new Promise((done) => requestAnimationFrame(() => requestAnimationFrame(done)))")
    png = page.locator(".qmv-canvas canvas").screenshot()
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=np.int16)


@pytest.fixture(scope="module")
def compare_page(tmp_path_factory):
    clip = generate_clip("jumping_jack", 5, n_frames=360)
    decoded = _lossy(clip)
    path = tmp_path_factory.mktemp("view") / "compare.html"
    write_view(path, [clip], [decoded], ghost=30)
    return path, clip, decoded


def test_view_page_plays_offline_and_shows_the_comparison(browser, compare_page, artifact_dir):
    path, clip, decoded = compare_page
    page = browser.new_page(viewport={"width": 1200, "height": 760})
    requests: list[str] = []
    page.on("request", lambda request: requests.append(request.url))
    errors: list[str] = []
    page.on("pageerror", lambda error: errors.append(str(error)))
    page.goto(path.as_uri())
    page.wait_for_selector("html[data-first-play-ms]", state="attached", timeout=20_000)
    assert not errors and page.evaluate("document.documentElement.dataset.error") is None
    assert requests == [path.as_uri()]  # the page itself, nothing else

    # It plays: the frame counter advances on its own.
    first = _frame(page)
    page.wait_for_timeout(400)
    assert page.evaluate("document.documentElement.dataset.playing") == "true"
    assert _frame(page) != first
    counter = page.locator(".qmv-counter").inner_text()
    assert counter.startswith("frame ") and counter.endswith(" / 359")
    page.screenshot(path=str(artifact_dir / "viewer-compare-playing.png"))

    # Space pauses; the arrow key steps exactly one frame.
    page.keyboard.press("Space")
    assert page.evaluate("document.documentElement.dataset.playing") == "false"
    paused = _frame(page)
    page.keyboard.press("ArrowRight")
    assert _frame(page) == min(paused + 1, 359)

    # The canvas changes between two frames.
    page.evaluate("quatmotionViewer.seek(0)")
    before = _canvas(page)
    page.evaluate("quatmotionViewer.seek(180)")
    after = _canvas(page)
    changed = np.any(np.abs(after - before) > 24, axis=-1).mean()
    assert changed > 0.002, f"only {changed:.4%} of the canvas changed between frames 0 and 180"
    page.screenshot(path=str(artifact_dir / "viewer-compare-frame180.png"))

    # What the page decoded is the clip, and the error it shows is the frame's RMS.
    expected = forward_kinematics(clip).all_positions()
    P = expected.shape[1]
    frame_180 = f"quatmotionViewer.clips[0].positions.subarray({180 * P * 3}, {181 * P * 3})"
    shown = np.array(page.evaluate(f"Array.from({frame_180})")).reshape(P, 3)
    np.testing.assert_allclose(shown, expected[180], atol=0.01)
    distance = np.linalg.norm(expected - forward_kinematics(decoded).all_positions(), axis=-1)
    rms_text = page.locator(".qmv-frame-rms").inner_text()
    assert float(rms_text.split()[0]) == pytest.approx(
        np.sqrt(np.mean(distance[180] ** 2)), abs=0.006
    )
    page.close()


def _decoded(motion: Motion) -> Motion:
    """``motion`` through the codec at 1 cm, as ``view --compare-decoded`` shows it."""
    with codec.Archive.open(
        codec.Archive.build([motion], None, codec.CompressSettings(max_error=1.0)).details["data"]
    ) as archive:
        return archive.read(0)


def _open(browser, path):
    page = browser.new_page(viewport={"width": 1200, "height": 760})
    errors: list[str] = []
    page.on("pageerror", lambda error: errors.append(str(error)))
    requests: list[str] = []
    page.on("request", lambda request: requests.append(request.url))
    page.goto(path.as_uri())
    page.wait_for_selector("html[data-first-play-ms], html[data-error]", state="attached")
    assert page.evaluate("document.documentElement.dataset.error || null") is None
    assert requests == [path.as_uri()]  # nothing fetched
    return page, errors


@pytest.mark.needs_data
def test_every_skeleton_family_stays_whole_in_view(
    browser, real_clips, figures_in_view, tmp_path, artifact_dir
):
    """The whole figure inside the canvas at the first, middle and last frames, on one clip of
    each family, beside its decoded copy and beside a clip of another skeleton and length."""
    clips = {name: read_motion(path) for name, path in real_clips.items()}
    bandai, cmu = clips["bandai1_walk"], clips["cmu_walk"]
    pages = {name: ([motion], None, None) for name, motion in clips.items()}
    pages["bandai1_walk_decoded"] = ([bandai], [_decoded(bandai)], None)
    pages["hdm05_jog_decoded"] = ([clips["hdm05_jog"]], [_decoded(clips["hdm05_jog"])], None)
    pages["bandai1_vs_cmu"] = ([bandai], [cmu], None)
    pages["bandai1_vs_cmu_overlay"] = ([bandai], [cmu], "overlay")
    problems: list[str] = []
    for name, (motions, compare, layout) in pages.items():
        path = write_view(tmp_path / f"{name}.html", motions, compare, layout=layout)
        page, errors = _open(browser, path)
        problems += [f"{name}: {p}" for p in figures_in_view(page)]
        page.screenshot(path=str(artifact_dir / f"viewer-{name}.png"))
        if name == "bandai1_walk":
            # joint_Root is neither drawn nor followed: one sphere per other point, one bone
            # per joint below the hips and per end site, the camera on the hips.
            sk = bandai.skeleton
            figure = "quatmotionViewer.figures[0]"
            drawn = page.evaluate(
                f"[{figure}.joints.count, {figure}.bones.count,"
                " quatmotionViewer.clips[0].follow, quatmotionViewer.follow]"
            )
            expected = [sk.n_joints + sk.n_sites - 1, sk.n_joints - 2 + sk.n_sites, 1, True]
            if drawn != expected:
                problems.append(f"{name}: spheres, bones, followed point, following {drawn}")
        if name.startswith("bandai1_vs_cmu"):
            # Two skeletons, two lengths: both play, no per-frame error, and the page says why.
            panel = page.locator(".qmv-error").inner_text()
            assert "no per-frame error: their skeletons differ" in panel, panel
            assert page.locator(".qmv-strip").count() == 0
            assert page.evaluate("quatmotionViewer.nFrames") == bandai.n_frames  # the longer
            page.evaluate(f"quatmotionViewer.seek({bandai.n_frames - 1})")
            assert "ended, holds frame 342" in page.locator(".qmv-labels").inner_text()
        assert not errors, errors
        page.close()
    assert not problems, "\n".join(problems)
