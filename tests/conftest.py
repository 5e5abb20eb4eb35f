"""Fixtures shared by the test modules."""

from __future__ import annotations

import functools
import http.server
import io
import os
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from quatmotion.datasets import data_root
from quatmotion.parallel import Runner


def _quiet(handler: type) -> type:
    """``handler`` without its log line per request on stderr."""

    class Quiet(handler):
        def log_message(self, format, *args):  # noqa: A002 (the base class's signature)
            pass

    return Quiet


@pytest.fixture()
def serve_directory() -> Iterator[Callable[..., str]]:
    """Start static HTTP servers on 127.0.0.1 (free port, a thread each) for one test.

    Call it with a folder (and optionally a ``SimpleHTTPRequestHandler`` subclass); it returns
    the base URL. Requests are not logged. Every server it started is shut down when the test
    ends. Nothing but the loopback is reached.
    """
    started: list[tuple[http.server.ThreadingHTTPServer, threading.Thread]] = []

    def start(directory: Path, handler: type = http.server.SimpleHTTPRequestHandler) -> str:
        server = http.server.ThreadingHTTPServer(
            ("127.0.0.1", 0), functools.partial(_quiet(handler), directory=str(directory))
        )
        thread = threading.Thread(target=server.serve_forever, daemon=True)
        thread.start()
        started.append((server, thread))
        return f"http://127.0.0.1:{server.server_address[1]}"

    yield start
    for server, thread in started:
        server.shutdown()
        server.server_close()
        thread.join(timeout=5)


@pytest.fixture()
def serve_app() -> Iterator[Callable[[Any], str]]:
    """Serve web apps with uvicorn, as ``quatmotion serve`` does (its socket bound by
    ``server.listen``: 127.0.0.1, a free port, a thread each) for one test.

    Call it with an ASGI app; it returns the base URL once the server answers. Every server
    it started is stopped when the test ends.
    """
    import time

    import uvicorn

    from quatmotion.server import listen

    started: list[tuple[Any, threading.Thread]] = []

    def start(app: Any) -> str:
        sock = listen.bind("127.0.0.1", 0)
        server = uvicorn.Server(uvicorn.Config(app, log_level="warning"))
        thread = threading.Thread(target=server.run, kwargs={"sockets": [sock]}, daemon=True)
        thread.start()
        started.append((server, thread))
        deadline = time.monotonic() + 60
        while not server.started and time.monotonic() < deadline:
            time.sleep(0.05)
        assert server.started, "uvicorn did not start within 60 s"
        return listen.url_of(sock).rstrip("/")

    yield start
    for server, thread in started:
        server.should_exit = True
        thread.join(timeout=30)


# The real mocap folder ($QUATMOTION_DATA, else ../shared/data): tests that read it carry the
# ``needs_data`` marker and skip, naming the folder, only where it is absent (CI always has it).
_DATA = data_root(must_exist=False)


def pytest_runtest_setup(item: pytest.Item) -> None:
    if item.get_closest_marker("needs_data") and not _DATA.is_dir():
        pytest.skip(f"mocap data folder {_DATA} absent (set QUATMOTION_DATA)")


# A real headless browser for the viewer (and web app) tests: quatmotion.viz.browser launches
# Debian's chromium through Playwright. `make browser` installs both; .ci/run does it and sets
# QUATMOTION_REQUIRE_BROWSER=1, so on CI a missing browser fails the tests instead of skipping.
ARTIFACTS = Path(__file__).resolve().parents[1] / "test-artifacts"
"""Screenshots the browser tests leave for people to look at (ignored by git)."""


@pytest.fixture(scope="session")
def browser() -> Iterator[Any]:
    """A headless Chromium (a Playwright ``Browser``), one per test process."""
    from quatmotion.viz.browser import headless_chromium, missing_browser

    reason = missing_browser()
    if reason:
        if os.environ.get("QUATMOTION_REQUIRE_BROWSER"):
            pytest.fail(f"browser tests required but {reason}")
        pytest.skip(reason)
    with headless_chromium() as launched:
        yield launched


@pytest.fixture()
def artifact_dir() -> Path:
    """``test-artifacts/`` at the project root, created."""
    ARTIFACTS.mkdir(exist_ok=True)
    return ARTIFACTS


# The viewer's framing, read back from a page showing a viewer (window.quatmotionViewer): at its
# first, middle and last frames every drawn point of every figure lands inside its own viewport
# and in front of the camera (QuatmotionViewer's projectedPoints), and what the canvas shows in
# colour (the figures; background, grid and label text are grey) lies where those points are,
# around them within a joint's size: nothing drawn elsewhere (no bone from a root the viewer
# does not show) and each figure really drawn (its pixels span its points).
FIGURE_SATURATION = 60  # max - min of R, G, B: the figures' colours, never the greys


def _saturated_box(image: Any, left: int, right: int) -> tuple[int, int, int, int] | None:
    import numpy as np

    part = image[:, left:right].astype(np.int16)
    mask = (part.max(axis=-1) - part.min(axis=-1)) > FIGURE_SATURATION
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    if not rows.size:
        return None
    return left + int(cols[0]), left + int(cols[-1]), int(rows[0]), int(rows[-1])


def _check_figures_in_view(page: Any, canvas: str = ".qmv-canvas canvas") -> list[str]:
    """Seek the page's viewer to its first, middle and last frames and check the framing there;
    the problems found (an empty list when the framing holds)."""
    import numpy as np
    from PIL import Image

    problems = []
    page.evaluate("quatmotionViewer.pause()")
    n = int(page.evaluate("quatmotionViewer.nFrames"))
    for frame in sorted({0, n // 2, n - 1}):
        page.evaluate(f"quatmotionViewer.seek({frame})")
        page.evaluate(
            "new Promise((done) => requestAnimationFrame(() => requestAnimationFrame(done)))"
        )
        shown = page.evaluate("quatmotionViewer.projectedPoints()")
        png = page.locator(canvas).screenshot()
        image = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))
        height = shown["height"]
        for port in shown["viewports"]:
            left, right = port["x"], port["x"] + port["width"]
            where = f"frame {frame}, viewport of clips {port['clips']}"
            xy = np.array([p[2:4] for p in port["points"]], dtype=float)
            if not xy.size:
                problems.append(f"{where}: no points drawn")
                continue
            outside = (xy[:, 0] < left) | (xy[:, 0] > right) | (xy[:, 1] < 0) | (xy[:, 1] > height)
            behind = sum(not p[4] for p in port["points"])
            (px0, py0), (px1, py1) = xy.min(axis=0), xy.max(axis=0)
            extent = f"x {px0:.0f}..{px1:.0f}, y {py0:.0f}..{py1:.0f}"
            if outside.any() or behind:
                problems.append(
                    f"{where}: {int(outside.sum())} points outside [{left}, {right}] x "
                    f"[0, {height}], {behind} behind the camera; points at {extent}"
                )
            box = _saturated_box(image, left, right)
            span = py1 - py0
            margin = 14 + 0.06 * max(span, px1 - px0)
            if box is None:
                problems.append(f"{where}: no figure drawn")
                continue
            x0, x1, y0, y1 = box
            if x0 < px0 - margin or x1 > px1 + margin or y0 < py0 - margin or y1 > py1 + margin:
                problems.append(
                    f"{where}: coloured pixels at x {x0}..{x1}, y {y0}..{y1} reach beyond the "
                    f"figure's points at {extent}"
                )
            if y1 - y0 < 0.7 * span:
                problems.append(f"{where}: the figure's pixels span {y1 - y0} px of its {span:.0f}")
    return problems


@pytest.fixture()
def figures_in_view() -> Callable[..., list[str]]:
    """``check(page, canvas=".qmv-canvas canvas")``: the framing problems of the viewer on
    ``page`` at its first, middle and last frames (an empty list when it holds)."""
    return _check_figures_in_view


REAL_CLIPS = {
    "bandai1_walk": "bandai1/clips/dataset-1_walk_active_001.bvh",  # a static joint_Root
    "cmu_walk": "cmu/02/02_01.amc",
    "hdm05_jog": "hdm05/clips/jogLeftCircle4StepsRstart/"
    "HDM_bd_jogLeftCircle4StepsRstart_001_120.amc",
    "cmu_bvh_walk": "cmu_bvh/07/07_01.bvh",
}


@pytest.fixture(scope="session")
def real_clips() -> dict[str, Path]:
    """A clip of each skeleton family in the mocap data folder, by a short name (tests that use
    it carry ``needs_data``)."""
    return {name: _DATA / path for name, path in REAL_CLIPS.items()}


# A small motion library for the web app tests: generated clips as BVH files, a .qmz library of
# six of them, a .qidx index of all seven (kick_0 is indexed but not compressed) and a pose index.
SERVED_KINDS = ("walk", "squat", "jumping_jack")


@pytest.fixture(scope="session")
def motion_library(tmp_path_factory) -> dict[str, Path]:
    """Paths ``clips`` (folder), ``library`` (.qmz), ``index`` (.qidx), ``poses`` (pose index)."""
    from quatmotion import codec
    from quatmotion.io import read_motion, write_motion
    from quatmotion.pose.data import PoseClip
    from quatmotion.pose.library import PoseLibrary, PoseSettings
    from quatmotion.retrieval import ClipIndex, IndexSettings
    from quatmotion.synthetic import generate_clip

    root = tmp_path_factory.mktemp("served")
    clips = root / "clips"
    clips.mkdir()
    names = [f"{kind}_{seed}" for kind in SERVED_KINDS for seed in range(2)]
    for name in [*names, "kick_0"]:
        kind, seed = name.rsplit("_", 1)
        write_motion(generate_clip(kind, int(seed), n_frames=120), clips / f"{name}.bvh")
    labels = {name: name.rsplit("_", 1)[0] for name in [*names, "kick_0"]}
    settings = IndexSettings(kinds=("motion",))
    report = ClipIndex.build(
        [clips], root / "lib.qidx", settings, labels=labels, runner=Runner.inline()
    )
    assert len(report.added) == 7 and not report.failures, report
    codec.Archive.build(
        [clips / f"{n}.bvh" for n in names], root / "lib.qmz", codec.CompressSettings(max_error=1.0)
    )
    prepared = [
        PoseClip.from_motion(read_motion(f), fps=30, height=170, name=str(f))
        for f in sorted(clips.glob("*.bvh"))
    ]
    settings = PoseSettings(n_pairs=100, n_unlabeled=500)
    PoseLibrary.build_in_memory(prepared, settings).save(root / "poses.idx")
    return {
        "clips": clips,
        "library": root / "lib.qmz",
        "index": root / "lib.qidx",
        "poses": root / "poses.idx",
    }


@pytest.fixture()
def studio_walk() -> Callable[[float, float], tuple[Any, Any]]:
    """``make(height_cm, cm_per_unit) -> (truth, studio)``: a generated walk of a figure
    ``height_cm`` tall (the truth, in centimetres), and the same walk laid out as issue 17's
    studio library writes it, in a length unit of ``cm_per_unit``: position channels on every
    joint (they carry the body; the OFFSETs do not), a rest pose lying along X at four times
    the body's bone lengths. The rest pose's size misleads the unit guess, as it did there (a
    135 cm figure in inches read as 53 cm)."""
    import dataclasses

    import numpy as np

    from quatmotion import io
    from quatmotion.motion import Motion
    from quatmotion.synthetic import cmu_skeleton, generate_clip

    def make(height_cm: float, cm_per_unit: float) -> tuple[Motion, Motion]:
        truth = generate_clip("walk", 3, n_frames=120, skeleton=cmu_skeleton(height_cm))
        twin = io.to_bvh_skeleton(truth.skeleton, [True] * truth.skeleton.n_joints)
        lying = np.zeros_like(twin.offsets)
        lying[:, 0] = 4.0 * np.linalg.norm(twin.offsets, axis=1)
        skeleton = dataclasses.replace(
            twin,
            offsets=lying,
            channels=tuple(("tx", "ty", "tz", "rz", "ry", "rx") for _ in twin.joint_names),
            extras={**twin.extras, "bvh_scale": cm_per_unit},
            name="studio",
        )
        carried = np.broadcast_to(twin.offsets, (truth.n_frames, twin.n_joints, 3)).copy()
        studio = Motion(
            skeleton, truth.fps, truth.root_translation, truth.rotations, carried, name="studio"
        )
        return truth, studio

    return make


@pytest.fixture(scope="session")
def v030(tmp_path_factory) -> Path:
    """A copy of ``tests/data/v0.3.0`` with the generated clips its 0.3.0 index and pose library
    were built from written back beside them (the same calls as
    ``tests/data/make_v030_index_fixtures.py``: generated clips are bit-identical by contract,
    so they are made here instead of committed as motion files)."""
    import shutil

    from quatmotion.io import write_motion
    from quatmotion.synthetic import generate_clip

    source = Path(__file__).parent / "data" / "v0.3.0"
    folder = tmp_path_factory.mktemp("v030") / "v0.3.0"
    shutil.copytree(source, folder)
    clips = folder / "index_clips"
    for sub, name, kind, seed in (
        ("s1", "take_001", "walk", 0),
        ("s2", "take_001", "squat", 1),
        ("s1", "punch", "punch", 2),
    ):
        (clips / sub).mkdir(parents=True, exist_ok=True)
        motion = generate_clip(kind, seed, n_frames=40, fps=30.0)
        write_motion(motion, clips / sub / f"{name}.bvh")
    return folder


@pytest.fixture(scope="module")
def dask_cluster() -> Iterator[str]:
    """A 2-process Dask cluster on 127.0.0.1 (free ports, no dashboard), closed afterwards."""
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(
        n_workers=2,
        threads_per_worker=1,
        processes=True,
        host="127.0.0.1",
        scheduler_port=0,
        dashboard_address=None,
    ) as cluster:
        yield cluster.scheduler_address
