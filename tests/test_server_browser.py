"""The web app end to end: ``quatmotion serve`` in a subprocess on a free loopback port, its
pages in a real headless Chromium (the ``browser`` fixture, conftest).

The pages' Content-Security-Policy forbids ``eval``, so the test waits on selectors (the pages
set ``data-state`` on ``<html>``) and reads state with ``page.evaluate``, never with
``wait_for_function``.
"""

from __future__ import annotations

import contextlib
import io
import json
import socket
import subprocess
import sys
import time
import urllib.request
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from quatmotion.parallel import Runner


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


@contextlib.contextmanager
def _serve(log_path, *files: str) -> Iterator[str]:
    """``quatmotion serve FILES...`` in a subprocess on a free loopback port; its base URL once
    it answers. Stopped on exit."""
    port = _free_port()
    log = log_path.open("w")
    command = [sys.executable, "-c", "from quatmotion.cli import main; main()", "serve", *files]
    server = subprocess.Popen([*command, "--port", str(port)], stdout=log, stderr=subprocess.STDOUT)
    base = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 90
        while True:
            if server.poll() is not None:
                pytest.fail(f"quatmotion serve exited: {log_path.read_text()}")
            try:
                with urllib.request.urlopen(f"{base}/api/info", timeout=2) as response:
                    json.load(response)
                break
            except OSError:
                if time.monotonic() > deadline:
                    pytest.fail("quatmotion serve did not answer within 90 s")
                time.sleep(0.25)
        yield base
    finally:
        server.terminate()
        try:
            server.wait(timeout=20)
        except subprocess.TimeoutExpired:
            server.kill()
            server.wait()
        log.close()


@pytest.fixture()
def served(motion_library, tmp_path) -> Iterator[str]:
    """``quatmotion serve`` over the test library; its base URL. Stopped after the test."""
    files = []
    for kind in ("library", "index", "poses"):
        files += [f"--{kind}", str(motion_library[kind])]
    with _serve(tmp_path / "serve.log", *files) as base:
        with urllib.request.urlopen(f"{base}/api/info", timeout=10) as response:
            assert json.load(response)["clips"] == 7
        yield base


@pytest.fixture(scope="module")
def real_library(real_clips, tmp_path_factory) -> dict[str, Path]:
    """A ``.qmz`` library and a ``.qidx`` index of one clip of each skeleton family."""
    from quatmotion import codec
    from quatmotion.retrieval import ClipIndex, IndexSettings

    root = tmp_path_factory.mktemp("real")
    paths = list(real_clips.values())
    codec.Archive.build(paths, root / "real.qmz", codec.CompressSettings(max_error=1.0))
    settings = IndexSettings(kinds=("motion",))
    report = ClipIndex.build(paths, root / "real.qidx", settings, runner=Runner.inline())
    assert len(report.added) == len(paths) and not report.failures, report
    return {"library": root / "real.qmz", "index": root / "real.qidx"}


_CANVAS = "#viewer .qmv-canvas canvas"


def _canvas(page) -> np.ndarray:
    page.evaluate("new Promise((done) => requestAnimationFrame(() => requestAnimationFrame(done)))")
    png = page.locator(_CANVAS).screenshot()
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=np.int16)


def _state(page, state: str, timeout: float = 30_000) -> None:
    page.wait_for_selector(
        f"html[data-state={state}], html[data-error]", state="attached", timeout=timeout
    )
    error = page.evaluate("document.documentElement.dataset.error || null")
    assert error is None, error


def test_search_page_finds_and_plays_results_in_a_real_browser(
    browser, served, motion_library, artifact_dir
):
    page = browser.new_page(viewport={"width": 1280, "height": 800})
    requests: list[str] = []
    page.on("request", lambda request: requests.append(request.url))
    errors: list[str] = []
    page.on("pageerror", lambda error: errors.append(str(error)))

    # The library page lists every clip.
    page.goto(f"{served}/")
    _state(page, "ready")
    assert page.locator("#clips tbody tr").count() == 7
    page.screenshot(path=str(artifact_dir / "server-browse.png"))

    # Search by an indexed clip: the results list, its own kind first.
    page.goto(f"{served}/search?clip=walk_0")
    _state(page, "ready")
    results = page.locator("#results li")
    assert results.count() == 6  # every other indexed clip
    assert results.nth(0).get_attribute("data-id") == "walk_1"
    assert "walk" in results.nth(0).inner_text()
    assert "walk_0, the query itself, left out" in page.locator("#summary").inner_text()

    # Play the first result beside the query; the 3D canvas changes between two frames.
    results.nth(0).locator("button.play-result").click()
    page.wait_for_selector("html[data-playing-result=walk_1]", state="attached", timeout=30_000)
    _state(page, "ready")
    names = page.evaluate("quatmotionViewer.clips.map((c) => c.name)")
    assert names == ["walk_0", "walk_1"]
    first = int(page.evaluate("quatmotionViewer.frame"))
    page.wait_for_timeout(400)
    assert page.evaluate("quatmotionViewer.playing") is True
    assert int(page.evaluate("quatmotionViewer.frame")) != first
    page.screenshot(path=str(artifact_dir / "server-search-playing.png"))
    page.evaluate("quatmotionViewer.pause(); quatmotionViewer.seek(0)")
    before = _canvas(page)
    page.evaluate("quatmotionViewer.seek(60)")
    after = _canvas(page)
    changed = np.any(np.abs(after - before) > 24, axis=-1).mean()
    assert changed > 0.002, f"only {changed:.4%} of the canvas changed between frames 0 and 60"

    # Search by an uploaded file of an indexed clip: that clip is left out, as by its id.
    page.check("input[name=source][value=upload]")
    page.set_input_files("input[name=file]", str(motion_library["clips"] / "squat_1.bvh"))
    page.evaluate("document.documentElement.dataset.state = 'asked'")
    page.click("#run")
    _state(page, "ready")
    assert results.nth(0).get_attribute("data-id") == "squat_0"
    assert "squat_1, the query itself, left out" in page.locator("#summary").inner_text()
    assert page.evaluate("quatmotionViewer.clips[0].name") == "squat_1"  # the query plays
    page.screenshot(path=str(artifact_dir / "server-upload-results.png"))

    # The comparison page: original beside decoded, the measured error shown.
    page.goto(f"{served}/compare?clip=walk_0")
    _state(page, "ready")
    page.wait_for_selector("html[data-first-play-ms]", state="attached", timeout=30_000)
    assert "measured: ARMS" in page.locator("#status").inner_text()
    page.screenshot(path=str(artifact_dir / "server-compare.png"))

    assert not errors, errors
    assert all(url.startswith(served) for url in requests), [
        u for u in requests if not u.startswith(served)
    ]
    page.close()


@pytest.mark.needs_data
def test_play_compare_and_search_pages_keep_every_family_in_view(
    browser, real_clips, real_library, figures_in_view, tmp_path, artifact_dir
):
    """The web app's play, compare (original beside decoded) and search ("play beside" the
    first result) pages: each figure inside its viewport at the first, middle and last frames,
    on a bandai1 walk (a static joint_Root), a CMU AMC walk, an HDM05 jog and a CMU BVH walk."""
    library, index = (str(real_library[k]) for k in ("library", "index"))
    with _serve(tmp_path / "serve.log", "--library", library, "--index", index) as served:
        page = browser.new_page(viewport={"width": 1280, "height": 800})
        errors: list[str] = []
        page.on("pageerror", lambda error: errors.append(str(error)))
        requests: list[str] = []
        page.on("request", lambda request: requests.append(request.url))
        problems: list[str] = []
        for name, path in real_clips.items():
            clip = path.stem
            for kind in ("play", "compare", "search"):
                page.goto(f"{served}/{kind}?clip={clip}")
                _state(page, "ready")
                if kind == "search":
                    page.evaluate("document.documentElement.dataset.state = 'asked'")
                    page.locator("#results li button.play-result").nth(0).click()
                    _state(page, "ready")
                    assert page.evaluate("quatmotionViewer.clips.length") == 2
                problems += [f"{kind} {name}: {p}" for p in figures_in_view(page, _CANVAS)]
                page.screenshot(path=str(artifact_dir / f"server-{kind}-{name}.png"))
        assert not errors, errors
        assert all(url.startswith(served) for url in requests), requests
        page.close()
    assert not problems, "\n".join(problems)


def test_clip_names_and_labels_are_shown_as_text_never_as_html(browser, tmp_path):
    """A clip whose file name and label are HTML (a label comes from any CSV or sidecar): the
    pages show them as text; no element of theirs is made, no script of theirs runs."""
    from quatmotion.io import write_motion
    from quatmotion.retrieval import ClipIndex, IndexSettings
    from quatmotion.synthetic import generate_clip

    hostile = '<img src=x onerror="document.documentElement.dataset.pwned=1">'
    clips = tmp_path / "clips"
    clips.mkdir()
    name = "<b>bold<i>"
    write_motion(generate_clip("walk", 1, n_frames=60), clips / f"{name}.bvh")
    write_motion(generate_clip("walk", 2, n_frames=60), clips / "plain.bvh")
    index = tmp_path / "x.qidx"
    settings = IndexSettings(kinds=("motion",))
    ClipIndex.build(
        [clips], index, settings, labels={name: hostile, "plain": hostile}, runner=Runner.inline()
    )
    with _serve(tmp_path / "serve.log", "--index", str(index)) as base:
        page = browser.new_page(viewport={"width": 1280, "height": 800})
        page.goto(f"{base}/")
        _state(page, "ready")
        assert page.locator("#clips img, #clips b, #clips i").count() == 0
        text = page.locator("#clips").inner_text()
        assert name in text and hostile in text
        page.goto(f"{base}/search?clip=plain")
        _state(page, "ready")
        assert page.locator("#results img, #results b").count() == 0
        assert name in page.locator("#results").inner_text()
        assert page.evaluate("document.documentElement.dataset.pwned || null") is None
        page.close()


def test_serve_dir_shows_the_build_in_the_page_and_fills_the_list_as_it_lands(
    browser, tmp_path, artifact_dir
):
    """``serve DIR`` answers before its library is built: the page shows the build's step and
    progress, then the clips once indexed, then the build's end."""
    from quatmotion.io import write_motion
    from quatmotion.synthetic import generate_clip

    folder = tmp_path / "studio"
    folder.mkdir()
    for k, kind in enumerate(("walk", "walk", "squat")):
        write_motion(generate_clip(kind, k, n_frames=90), folder / f"{kind}_{k}.bvh")
    with _serve(tmp_path / "serve.log", str(folder)) as base:
        page = browser.new_page(viewport={"width": 1280, "height": 800})
        page.goto(f"{base}/")
        # the banner's text comes with the page's first poll of /api/build (data-build)
        page.wait_for_selector("html[data-build]", state="attached", timeout=60_000)
        state = page.evaluate("document.documentElement.dataset.build")
        shown = page.locator("#build").inner_text()
        assert shown.startswith("Building " if state == "building" else "Built "), (state, shown)
        page.wait_for_selector("html[data-build=ready]", state="attached", timeout=600_000)
        page.wait_for_selector("#clips tbody tr:nth-child(3)", state="attached", timeout=60_000)
        assert "Built " in page.locator("#build").inner_text()
        page.screenshot(path=str(artifact_dir / "server-built.png"))
        page.goto(f"{base}/compare?clip=walk_0")
        _state(page, "ready", timeout=120_000)
        assert "measured: ARMS" in page.locator("#status").inner_text()
        page.close()
