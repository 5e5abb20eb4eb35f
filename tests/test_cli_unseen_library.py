"""Issue 17: what broke when an unseen studio's library went through every command.

The overwrite policy against every file a command reads (item 1), ``--units`` and
``--skeleton`` on every command that reads motion with a warning for a doubtful unit (item 2),
an unwritable destination refused up front with one line (item 5), and the small things a user
notices (``--within`` frames, one clip-name matcher, frame rates, ``--json``, read-only files;
``--version`` and help text are in test_cli_usability.py, the matcher's own rules in
test_clip_names.py). Organised by item; each test fails on the code before the fix.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from test_cli_usability import _assert_bad_input, _invoke  # the same command-line contract

from quatmotion import codec, io
from quatmotion.motion import Motion, forward_kinematics
from quatmotion.synthetic import generate_clip

INCH_CM = 2.54


def _warnings(result) -> list[str]:
    return [line for line in result.stderr.splitlines() if line.startswith("warning: ")]


def _max_error(a: Motion, b: Motion, scale: float = 1.0) -> float:
    pa = forward_kinematics(a).all_positions()
    pb = forward_kinematics(b).all_positions() * scale
    return float(np.linalg.norm(pa - pb, axis=-1).max())


@pytest.fixture()
def clips(tmp_path: Path) -> Path:
    """A folder as a user has one: a BVH walk, a CMU-named AMC (01_01.amc) with its subject's
    ASF (01.asf, found by name), and a benchmark result with its figure."""
    folder = tmp_path / "clips"
    assert _invoke("generate", "walk", folder / "walk.bvh", "--frames", "40").exit_code == 0
    assert _invoke("generate", "run", folder / "01_01.amc", "--frames", "40").exit_code == 0
    (folder / "01_01.asf").rename(folder / "01.asf")
    (tmp_path / "result.json").write_text('{"benchmark": "x", "seconds": 1.0}\n')
    (tmp_path / "result_bars.png").write_bytes(b"\x89PNG\r\n\x1a\n not really a figure")
    return folder


# --- 1. no command writes over a file it reads, folders expanded, --force or not -------------


_OVER_INPUTS = {
    "compress over a clip of its folder": (
        ["compress", "{clips}", "-o", "{clips}/walk.bvh", "--force"], "walk.bvh"),
    "compress over an ASF its AMC reads": (
        ["compress", "{clips}", "-o", "{clips}/01.asf", "--force"], "01.asf"),
    "index build over a clip of its folder": (
        ["index", "build", "{clips}", "-o", "{clips}/walk.bvh", "--kinds", "motion"], "walk.bvh"),
    "pose index over an ASF its AMC reads": (
        ["pose", "index", "{clips}", "-o", "{clips}/01.asf", "--force"], "01.asf"),
    "convert an AMC over its own ASF": (
        ["convert", "{clips}/01_01.amc", "{clips}/01.amc", "--force"], "01.asf"),
    "convert over the --skeleton it reads": (
        ["convert", "{clips}/01_01.amc", "{clips}/body.amc", "--skeleton", "{clips}/body.asf",
         "--force"], "body.asf"),
    "view over an ASF it reads": (
        ["view", "{clips}/01_01.amc", "-o", "{clips}/01.asf", "--force"], "01.asf"),
    "report over a figure it embeds": (
        ["report", "{clips}/../result.json", "-o", "{clips}/../result_bars.png", "--force"],
        "../result_bars.png"),
}  # fmt: skip


@pytest.mark.parametrize("case", list(_OVER_INPUTS))
def test_no_command_writes_over_a_file_it_reads(clips, case):
    args, victim = _OVER_INPUTS[case]
    shutil.copy(clips / "01.asf", clips / "body.asf")
    before = (clips / victim).read_bytes()
    result = _invoke(*(a.format(clips=clips) for a in args))
    _assert_bad_input(result, Path(victim).name, "is also an input")
    assert (clips / victim).read_bytes() == before


# --- 5. a destination that cannot be written: one line naming it, before any work ------------


_WRITERS = {
    "compress": ["compress", "{clips}", "-o", "{out}.qmz"],
    "decompress": ["decompress", "{lib}", "-o", "{out}"],
    "convert": ["convert", "{clips}/walk.bvh", "{out}.bvh"],
    "convert into a folder": ["convert", "{clips}/walk.bvh", "{clips}/01_01.amc", "{out}"],
    "view": ["view", "{clips}/walk.bvh", "-o", "{out}.html"],
    "report": ["report", "{clips}/../result.json", "-o", "{out}.html"],
    "pose index": ["pose", "index", "{clips}", "-o", "{out}.idx"],
    "index build": ["index", "build", "{clips}", "-o", "{out}.qidx"],
    "generate": ["generate", "walk", "{out}.bvh"],
    "bench": ["bench", "io", "--out", "{out}.json"],
}


@pytest.fixture()
def library(clips: Path) -> Path:
    lib = clips.parent / "lib.qmz"
    assert _invoke("compress", clips / "walk.bvh", "-o", lib).exit_code == 0
    return lib


@pytest.mark.parametrize("command", list(_WRITERS))
def test_a_destination_under_a_file_is_one_error_naming_it(clips, library, command):
    blocker = clips.parent / "notes.txt"
    blocker.write_text("a file, not a folder\n")
    out = f"{blocker}/x"
    args = [a.format(clips=clips, lib=library, out=out) for a in _WRITERS[command]]
    message = _assert_bad_input(_invoke(*args), out, "cannot be written", "notes.txt")
    assert ".tmp" not in message and "Errno" not in message


def _unprivileged(code: str, args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    """``python -c CODE ARGS`` as a user who cannot write where root could: this user when not
    root, else uid 65534 (nobody) through setpriv; skipped where that user cannot run this
    checkout. Numba's cache goes to a folder that user can write (a package cache another user
    cannot write is issue 17's item 8)."""
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cwd / "numba-cache")}
    prefix = []
    if os.geteuid() == 0:
        if shutil.which("setpriv") is None:
            pytest.skip("root, and no setpriv to run as another user")
        prefix = ["setpriv", "--reuid=65534", "--regid=65534", "--clear-groups"]
    probe = subprocess.run(
        [*prefix, sys.executable, "-c", "import quatmotion.cli"], cwd=cwd, env=env,
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    if probe.returncode != 0:
        pytest.skip(f"uid 65534 cannot run this checkout: {probe.stderr.strip()[-200:]}")
    command = [*prefix, sys.executable, "-c", code, *args]
    return subprocess.run(command, cwd=cwd, env=env, capture_output=True, text=True, timeout=300)


_MAIN = "from quatmotion.cli import main; main()"


@pytest.fixture()
def shared_folder() -> Iterator[Path]:
    """A folder another user can enter (pytest's tmp_path is its owner's only)."""
    folder = Path(tempfile.mkdtemp(prefix="quatmotion-test-"))
    folder.chmod(0o755)
    (folder / "numba-cache").mkdir(mode=0o777)
    (folder / "numba-cache").chmod(0o777)
    try:
        yield folder
    finally:
        for path in folder.rglob("*"):
            if path.is_dir():
                path.chmod(0o755)
        shutil.rmtree(folder, ignore_errors=True)


def test_an_unwritable_folder_is_one_error_naming_the_path_given(shared_folder):
    folder = shared_folder
    walk = folder / "clips" / "walk.bvh"
    assert _invoke("generate", "walk", walk, "--frames", "30").exit_code == 0
    for path in folder.rglob("*"):
        path.chmod(0o777 if path.is_dir() else 0o644)
    (folder / "ro").mkdir(mode=0o555)
    (folder / "ro").chmod(0o555)
    for args in (
        ["index", "build", "clips", "-o", "ro/x.qidx", "--kinds", "motion", "--workers", "1"],
        ["compress", "clips", "-o", "ro/x.qmz", "--workers", "1"],
        ["pose", "index", "clips", "-o", "ro/p.idx", "--workers", "1"],
    ):
        result = _unprivileged(_MAIN, args, folder)
        assert result.returncode == 2, (args, result.stdout, result.stderr)
        lines = [line for line in result.stderr.splitlines() if line.strip()]
        assert lines == [f"error: {args[args.index('-o') + 1]}: cannot be written: no permission "
                         "to write in ro"], result.stderr  # fmt: skip
    assert list((folder / "ro").iterdir()) == []
    # the library's own atomic writes name the file asked for, never their temporary file
    code = (
        "from quatmotion._atomic import atomic_write_bytes\n"
        "try:\n    atomic_write_bytes('ro/x.qmz', b'x')\n"
        "except PermissionError as e:\n    print(e.filename)\n"
    )
    done = _unprivileged(code, [], folder)
    assert done.stdout.strip() == "ro/x.qmz", done.stderr


# --- small things: read-only files are not rewritten --------------------------------------------


def test_append_to_a_read_only_library_refuses_and_keeps_it(clips, library):
    library.chmod(0o444)
    before = library.read_bytes()
    _assert_bad_input(_invoke("append", library, clips / "01_01.amc"), "lib.qmz", "read-only")
    assert library.read_bytes() == before
    forced = _invoke("compress", clips / "01_01.amc", "-o", library, "--force")
    _assert_bad_input(forced, "lib.qmz", "read-only")
    assert library.read_bytes() == before


def test_index_add_and_remove_refuse_a_read_only_index(clips, tmp_path):
    index = tmp_path / "x.qidx"
    built = _invoke("index", "build", clips / "walk.bvh", "-o", index, "--kinds", "motion")
    assert built.exit_code == 0, built.output
    index.chmod(0o444)
    before = index.read_bytes()
    _assert_bad_input(
        _invoke("index", "add", index, clips / "01_01.amc", "--kinds", "motion"), "read-only"
    )
    _assert_bad_input(_invoke("index", "remove", index, "walk"), "read-only")
    assert index.read_bytes() == before


# --- 2. units: the same --units and --skeleton everywhere, a warning where a guess is doubtful --


_READERS = {
    "compress": ["compress", "{clip}", "-o", "{tmp}/x.qmz"],
    "append": ["append", "{lib}", "{clip}"],
    "index build": ["index", "build", "{clip}", "-o", "{tmp}/x.qidx"],
    "index add": ["index", "add", "{idx}", "{clip}"],
    "search": ["search", "{clip}", "--index", "{idx}"],
    "pose index": ["pose", "index", "{clip}", "-o", "{tmp}/p.idx"],
    "pose search": ["pose", "search", "{poses}", "--file", "{clip}", "--frame", "0"],
    "info": ["info", "{clip}"],
    "convert": ["convert", "{clip}", "{tmp}/y.bvh"],
    "view": ["view", "{clip}", "-o", "{tmp}/v.html"],
    "demo": ["demo", "{clip}", "--out", "{tmp}/demo", "--quick"],
}


@pytest.mark.parametrize("command", list(_READERS))
def test_every_command_that_reads_motion_takes_units_and_skeleton(clips, tmp_path, command):
    """Both options exist and reach the command's checks (a bad value is the command's own
    one-line error, not a usage error): --units furlong, --skeleton of a missing file."""
    fields = {
        "clip": clips / "walk.bvh", "tmp": tmp_path, "lib": tmp_path / "lib.qmz",
        "idx": tmp_path / "i.qidx", "poses": tmp_path / "p0.idx",
    }  # fmt: skip
    (tmp_path / "lib.qmz").write_bytes(b"")
    (tmp_path / "i.qidx").write_bytes(b"")
    (tmp_path / "p0.idx").write_bytes(b"")
    args = [a.format(**fields) for a in _READERS[command]]
    _assert_bad_input(_invoke(*args, "--units", "furlong"), "furlong")
    missing = tmp_path / "missing.asf"
    _assert_bad_input(_invoke(*args, "--skeleton", missing), "missing.asf")


def test_compress_reads_a_studio_layout_in_its_unit_and_warns_about_a_giant(tmp_path, studio_walk):
    """Issue 17's case: a 135 cm figure written in inches, its rest pose laid out along X, read
    as 53 cm (guessed cm) when the guess looked at the rest pose. The stature chain reads it in
    inches (issue 21, item 7); a figure no unit makes human (300 cm in cm) is warned about,
    guessed or given (issue 29: a unit given is checked as hard), and ``--units`` keeps the
    bound in the unit given (no unit is likelier: it is no refusal)."""
    truth, studio = studio_walk(135.0, INCH_CM)
    bvh = tmp_path / "studio.bvh"
    io.write_bvh(studio, bvh)
    lib = tmp_path / "guessed.qmz"
    result = _invoke("compress", bvh, "-o", lib, "--max-error", "1", "--workers", "1")
    assert result.exit_code == 0, result.output
    assert _warnings(result) == [] and "length unit: in (guessed)" in result.stdout
    with codec.Archive.open(lib) as archive:
        assert _max_error(truth, archive.read(0)) <= 1.0 + 1e-6  # the bound, in true cm

    truth, giant = studio_walk(300.0, 1.0)
    io.write_bvh(giant, bvh)
    result = _invoke("compress", bvh, "-o", tmp_path / "giant.qmz", "--max-error", "1")
    assert result.exit_code == 0, result.output
    (warning,) = _warnings(result)
    assert "studio.bvh" in warning and "--units" in warning and "50 to 220 cm" in warning
    lib = tmp_path / "given.qmz"
    result = _invoke("compress", bvh, "-o", lib, "--max-error", "1", "--units", "cm")
    assert result.exit_code == 0, result.output
    (warning,) = _warnings(result)
    assert "the unit given" in warning and "50 to 220 cm" in warning
    assert "length unit: cm (given)" in result.stdout
    with codec.Archive.open(lib) as archive:
        decoded = archive.read(0)
    assert _max_error(truth, decoded) <= 1.0 + 1e-6  # the bound holds on the true figure
    listing = _invoke("ls", lib)
    assert re.search(r"studio .* cm \(given\)", listing.stdout), listing.stdout


def test_append_takes_the_unit_and_reports_it(tmp_path, clips, studio_walk):
    _, studio = studio_walk(135.0, INCH_CM)
    io.write_bvh(studio, tmp_path / "studio.bvh")
    lib = tmp_path / "lib.qmz"
    assert _invoke("compress", clips / "walk.bvh", "-o", lib).exit_code == 0
    guessed = _invoke("append", lib, tmp_path / "studio.bvh", "--workers", "1")
    assert guessed.exit_code == 0, guessed.output
    assert _warnings(guessed) == [] and "in (guessed)" in guessed.stdout
    with codec.Archive.open(lib) as archive:
        assert archive.read("studio").skeleton.extras["bvh_scale"] == INCH_CM


def test_batch_commands_warn_about_a_doubtful_unit_from_their_workers(tmp_path, clips, studio_walk):
    _, studio = studio_walk(300.0, 1.0)  # a giant: no unit makes it human
    io.write_bvh(studio, clips / "studio.bvh")
    built = _invoke(
        "index", "build", clips, "-o", tmp_path / "x.qidx", "--kinds", "motion", "--workers", "2"
    )
    assert built.exit_code == 0, built.output
    (warning,) = _warnings(built)
    assert "studio.bvh" in warning and "--units" in warning
    poses = _invoke(
        "pose", "index", clips, "-o", tmp_path / "p.idx", "--rank", "4", "--unlabeled", "50",
        "--pairs", "10", "--workers", "2",
    )  # fmt: skip
    assert poses.exit_code == 0, poses.output
    (warning,) = _warnings(poses)
    assert "studio.bvh" in warning and "--units" in warning
    given = _invoke(
        "index", "build", clips / "studio.bvh", "-o", tmp_path / "y.qidx", "--kinds", "motion",
        "--units", "cm",
    )  # fmt: skip
    assert given.exit_code == 0, given.output
    (warning,) = _warnings(given)  # a unit given is checked as hard as one guessed (issue 29)
    assert "the unit given" in warning and "50 to 220 cm" in warning


# --- small things: a frame time of 1,000 s -------------------------------------------------------


@pytest.mark.parametrize(
    ("frame_time", "doubtful"), [(1000.0, True), (1e-4, True), (1 / 120, False)]
)
def test_an_absurd_frame_rate_is_warned_about(tmp_path, frame_time, doubtful):
    clip = generate_clip("walk", 1, n_frames=10)
    text = io.bvh_text(clip)
    text = re.sub(r"Frame Time: \S+", f"Frame Time: {frame_time!r}", text)
    path = tmp_path / "slow.bvh"
    path.write_text(text)
    result = _invoke("info", path)
    assert result.exit_code == 0, result.output
    warnings = [w for w in _warnings(result) if "frame time" in w]
    assert bool(warnings) == doubtful, result.stderr
    if doubtful:
        assert "slow.bvh" in warnings[0] and "frames per second" in warnings[0]


def test_a_frame_rate_over_the_readers_limit_is_refused_naming_the_line_and_the_limit(tmp_path):
    # 100,000 frames/s: past quatmotion.limits' frame rate, refused before the frames are read
    text = re.sub(r"Frame Time: \S+", "Frame Time: 1e-05", io.bvh_text(generate_clip("walk", 1)))
    path = tmp_path / "fast.bvh"
    path.write_text(text)
    _assert_bad_input(_invoke("info", path), "over the limit of 10,000")


# --- small things: one clip-name matcher ---------------------------------------------------------


def test_decompress_and_view_take_a_clip_by_file_name_stem_or_number(tmp_path, clips, library):
    out = tmp_path / "out"
    result = _invoke("decompress", library, "-o", out, "--clip", "walk.bvh", "--clip", "0")
    assert result.exit_code == 0, result.output
    assert [p.name for p in out.iterdir()] == ["walk.bvh"]  # one clip, named twice
    page = tmp_path / "v.html"
    assert _invoke("view", f"{library}::walk.bvh", "-o", page).exit_code == 0
    _assert_bad_input(_invoke("decompress", library, "-o", out, "--clip", "wlak"), "close names")


def test_search_takes_an_indexed_clip_by_name_and_refuses_an_ambiguous_one(tmp_path):
    for seed, (folder, kind) in enumerate([("a", "walk"), ("b", "walk"), ("a", "squat")]):
        path = tmp_path / folder / f"{kind}.bvh"
        assert _invoke("generate", kind, path, "--frames", "90", "--seed", seed).exit_code == 0
    index = tmp_path / "x.qidx"
    folders = (tmp_path / "a", tmp_path / "b")
    built = _invoke("index", "build", *folders, "-o", index, "--kinds", "motion")
    assert built.exit_code == 0, built.output
    message = _assert_bad_input(_invoke("search", "walk", "--index", index), "ambiguous")
    assert "(a/walk, b/walk)" in message  # the two clips by their names (issue 18)
    result = _invoke("search", "b/walk.bvh", "--index", index, "--json")  # not a file here
    assert result.exit_code == 0, result.output
    paths = [r["path"] for r in json.loads(result.stdout)["results"]]
    assert str(tmp_path / "b" / "walk.bvh") not in paths  # the query, left out of its results
    assert str(tmp_path / "a" / "walk.bvh") in paths
    by_stem = _invoke("search", "squat", "--index", index, "--json")
    assert by_stem.exit_code == 0 and json.loads(by_stem.stdout)["results"]
    _assert_bad_input(_invoke("index", "remove", index, "walk"), "ambiguous")


# --- small things: --within shows the frames it found, as the JSON does --------------------------


def test_search_within_shows_first_and_last_frames_like_its_json(tmp_path):
    folder = tmp_path / "clips"
    for kind in ("walk", "squat", "jumping_jack"):
        assert _invoke("generate", kind, folder / f"{kind}.bvh", "--frames", "240").exit_code == 0
    index = tmp_path / "x.qidx"
    assert _invoke("index", "build", folder, "-o", index, "--kinds", "motion").exit_code == 0
    query = tmp_path / "q.bvh"
    assert _invoke("generate", "squat", query, "--frames", "90", "--seed", "4").exit_code == 0
    as_json = _invoke("search", query, "--index", index, "--within", "--json")
    table = _invoke("search", query, "--index", index, "--within")
    assert as_json.exit_code == 0 and table.exit_code == 0, table.output
    results = json.loads(as_json.stdout)["results"]
    assert "first-last" in table.stdout
    for r in results:
        shown = f"{r['start_frame']}-{r['stop_frame'] - 1}"
        assert re.search(rf"│ {r['clip']}\s.*│ {shown}\s", table.stdout), (shown, table.stdout)
        assert r["stop_frame"] <= 240  # exclusive: never past the clip's 240 frames


# --- small things: --json on ls, info and compress -----------------------------------------------


def test_ls_info_and_compress_print_one_json_document(tmp_path, clips):
    lib = tmp_path / "x.qmz"
    compressed = _invoke("compress", clips, "-o", lib, "--json", "--workers", "1")
    assert compressed.exit_code == 0, compressed.output
    doc = json.loads(compressed.stdout)  # the whole of stdout: no bar, no summary line
    assert {"library", "bytes", "method", "ratio", "clips", "failed", "max_error_cm"} <= set(doc)
    assert sorted(c["name"] for c in doc["clips"]) == ["01_01", "walk"]
    listed = json.loads(_invoke("ls", lib, "--json").stdout)
    assert listed["clips"] == doc["clips"] and listed["bytes"] == lib.stat().st_size
    walk = next(c for c in listed["clips"] if c["name"] == "walk")
    assert walk["unit"] == "cm" and walk["unit_guessed"] is True and walk["frames"] == 40
    assert {"fps", "bytes", "ratio", "max_error_cm", "arms_cm", "cm_per_unit"} <= set(walk)
    amc = next(c for c in listed["clips"] if c["name"] == "01_01")
    assert amc["unit_source"] == "asf" and amc["unit_guessed"] is False
    info = json.loads(_invoke("info", clips / "walk.bvh", "--json").stdout)
    assert info["frames"] == 40 and info["unit"] == "cm" and info["unit_guessed"] is True
    assert {"fps", "duration_s", "joints", "vertical_extent_cm", "pelvis"} <= set(info)
    asf = json.loads(_invoke("info", clips / "01.asf", "--json").stdout)
    assert asf["unit_source"] == "asf" and "frames" not in asf
