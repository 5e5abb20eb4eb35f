"""The ``quatmotion`` command line, through Typer's CliRunner."""

from __future__ import annotations

import json
import re
import sys
import types
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from quatmotion import bench as bench_package
from quatmotion import io
from quatmotion.cli import app
from quatmotion.datasets import data_root
from quatmotion.motion import forward_kinematics

DATA = data_root(must_exist=False)

PROJECT = Path(__file__).resolve().parents[1]
CLIPS = {
    "cmu_amc": DATA / "cmu" / "02" / "02_01.amc",
    "hdm05_amc": DATA
    / "hdm05"
    / "clips"
    / "kickLFront1Reps"
    / "HDM_bd_kickLFront1Reps_001_120.amc",
    "bandai_bvh": DATA / "bandai1" / "clips" / "dataset-1_walk_normal_001.bvh",
    "cmu_bvh": DATA / "cmu_bvh" / "07" / "07_01.bvh",
}

runner = CliRunner()


def _invoke(*args: str):
    return runner.invoke(app, [str(a) for a in args])


def _field(output: str, name: str) -> str:
    match = re.search(rf"{re.escape(name)}\W+([-\w.]+)", output)
    assert match, f"no {name!r} in:\n{output}"
    return match.group(1)


def _assert_bad_input(result, *needles: str) -> None:
    assert result.exit_code == 2, result.output
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), result.stderr
    assert "Traceback" not in result.output
    for needle in needles:
        assert needle in lines[0]


def _positions(motion) -> np.ndarray:
    return forward_kinematics(motion).positions


# --- info ---------------------------------------------------------------------------------------


@pytest.mark.needs_data
@pytest.mark.parametrize("key", list(CLIPS))
def test_info_reports_the_clip(key):
    path = CLIPS[key]
    result = _invoke("info", path)
    assert result.exit_code == 0, result.output
    motion = io.read_motion(path)
    assert int(_field(result.stdout, "frames")) == motion.n_frames
    assert int(_field(result.stdout, "joints")) == motion.n_joints
    assert float(_field(result.stdout, "fps")) == pytest.approx(motion.fps)
    assert float(_field(result.stdout, "duration (s)")) == pytest.approx(
        motion.n_frames / motion.fps, abs=1e-3
    )
    rest = re.search(r"rest pose height \(cm\)\W+(.+?)\s*│", result.stdout).group(1)
    if key == "bandai_bvh":  # its rest pose lies along X
        assert "not upright" in rest
    else:
        assert float(rest) == pytest.approx(motion.skeleton.height(), abs=0.05)


@pytest.mark.needs_data
def test_info_takes_an_explicit_skeleton_and_reads_asf_alone():
    amc, asf = CLIPS["cmu_amc"], CLIPS["cmu_amc"].with_name("02.asf")
    result = _invoke("info", amc, "--skeleton", asf)
    assert result.exit_code == 0 and int(_field(result.stdout, "joints")) == 31
    result = _invoke("info", asf)
    assert result.exit_code == 0 and int(_field(result.stdout, "joints")) == 31


# --- convert ------------------------------------------------------------------------------------


@pytest.mark.needs_data
def test_convert_amc_to_bvh_keeps_the_motion(tmp_path):
    out = tmp_path / "walk.bvh"
    result = _invoke("convert", CLIPS["cmu_amc"], out)
    assert result.exit_code == 0, result.output
    original = io.read_motion(CLIPS["cmu_amc"])
    converted = io.read_motion(out)
    assert converted.n_frames == original.n_frames
    np.testing.assert_allclose(_positions(converted), _positions(original), atol=1e-3)


@pytest.mark.needs_data
def test_convert_amc_to_amc_writes_a_findable_asf(tmp_path):
    out = tmp_path / "HDM_bd_kick_001_120.amc"
    result = _invoke("convert", CLIPS["hdm05_amc"], out)
    assert result.exit_code == 0, result.output
    assert (tmp_path / "HDM_bd_kick_001_120.asf").is_file()  # same name: found first
    assert not (tmp_path / "HDM_bd.asf").exists()
    converted = io.read_motion(out)
    original = io.read_motion(CLIPS["hdm05_amc"])
    np.testing.assert_allclose(_positions(converted), _positions(original), atol=1e-3)


@pytest.mark.needs_data
def test_convert_many_into_a_folder(tmp_path):
    inputs = [CLIPS["bandai_bvh"], CLIPS["cmu_bvh"]]
    out = tmp_path / "converted"
    result = _invoke("convert", *inputs, out)
    assert result.exit_code == 0, result.output
    for source in inputs:
        written = out / source.name
        assert written.is_file()
        a, b = io.read_motion(source), io.read_motion(written)
        assert a.n_frames == b.n_frames
        np.testing.assert_allclose(_positions(b), _positions(a), atol=1e-3)


@pytest.mark.needs_data
def test_bvh_to_amc_is_refused_cleanly(tmp_path):
    result = _invoke("convert", CLIPS["bandai_bvh"], tmp_path / "x.amc")
    _assert_bad_input(result, "ASF")
    assert not (tmp_path / "x.amc").exists()


def test_generated_clip_through_generate_info_and_convert(tmp_path):
    amc = tmp_path / "walk_01.amc"
    result = _invoke("generate", "walk", amc, "--seed", "4", "--frames", "48")
    assert result.exit_code == 0, result.output
    assert (tmp_path / "walk_01.asf").is_file()
    info = _invoke("info", amc)
    assert info.exit_code == 0, info.output
    assert int(_field(info.stdout, "frames")) == 48
    assert int(_field(info.stdout, "joints")) == 31
    bvh = tmp_path / "walk_01.bvh"
    assert _invoke("convert", amc, bvh).exit_code == 0
    from quatmotion.synthetic import generate_clip

    expected = _positions(generate_clip("walk", 4, n_frames=48))
    np.testing.assert_allclose(_positions(io.read_motion(bvh)), expected, atol=1e-3)
    np.testing.assert_allclose(_positions(io.read_motion(amc)), expected, atol=1e-3)


# --- bad input ------------------------------------------------------------------------------------


def test_bad_input_exits_2_with_one_line(tmp_path):
    _assert_bad_input(_invoke("info", tmp_path / "missing.bvh"), "missing.bvh")
    (tmp_path / "notes.txt").write_text("hello")
    _assert_bad_input(_invoke("info", tmp_path / "notes.txt"), ".txt")
    broken = tmp_path / "broken.bvh"
    broken.write_text("HIERARCHY\nROOT Hips\n{\n  OFFSET 0 0\n")
    _assert_bad_input(_invoke("info", broken), "broken.bvh")
    _assert_bad_input(_invoke("convert", broken, tmp_path / "out.bvh"), "broken.bvh")
    assert not (tmp_path / "out.bvh").exists()
    _assert_bad_input(_invoke("generate", "moonwalk", tmp_path / "m.bvh"), "moonwalk")
    _assert_bad_input(_invoke("convert", broken, tmp_path / "out.xyz"))


def test_broken_amc_exits_2(tmp_path):
    from quatmotion.synthetic import generate_clip

    m = generate_clip("squat", 0, n_frames=5)
    io.write_asf(m.skeleton, tmp_path / "s.asf")
    io.write_amc(m, tmp_path / "s_01.amc")
    text = (tmp_path / "s_01.amc").read_text().splitlines()
    text[6] = "lfemur 1.0 banana 3.0"  # inside frame 1
    (tmp_path / "s_01.amc").write_text("\n".join(text))
    _assert_bad_input(_invoke("info", tmp_path / "s_01.amc"), "s_01.amc")


# --- bench, datasets, demo -----------------------------------------------------------------------


def test_bench_calls_run_with_the_options(tmp_path, monkeypatch):
    calls = []

    def run(out: Path, quick: bool = False, seed: int = 0) -> dict:
        calls.append((out, quick, seed))
        out.write_text(json.dumps({"ok": True}))
        return {"ok": True, "score": 0.5}

    fake = types.ModuleType("quatmotion.bench.fakebench")
    fake.run = run
    monkeypatch.setitem(sys.modules, "quatmotion.bench.fakebench", fake)
    monkeypatch.setattr(bench_package, "names", lambda: ["fakebench"])
    out = tmp_path / "sub" / "bench.json"
    result = _invoke("bench", "fakebench", "--out", out, "--quick", "--seed", "7")
    assert result.exit_code == 0, result.output
    assert calls == [(out, True, 7)]
    assert json.loads(out.read_text()) == {"ok": True}
    _assert_bad_input(_invoke("bench", "nosuch", "--out", out), "nosuch", "fakebench")


def test_bench_lists_the_real_benchmarks():
    names = bench_package.names()
    assert all((PROJECT / "quatmotion" / "bench" / f"{n}.py").is_file() for n in names)
    result = _invoke("bench", "definitely_not_a_bench", "--out", "x.json")
    _assert_bad_input(result, *names)


@pytest.mark.needs_data
def test_datasets_list_counts_the_collection():
    from quatmotion.datasets import catalogue

    result = _invoke("datasets", "list", "--collection", "hdm05", "--limit", "3")
    assert result.exit_code == 0, result.output
    assert int(re.search(r"(\d+) clips", result.stdout).group(1)) == len(
        catalogue(collection="hdm05")
    )
    _assert_bad_input(_invoke("datasets", "list", "--collection", "nope"), "nope")


@pytest.mark.needs_data
def test_datasets_fetch_against_a_local_server(tmp_path, serve_directory):
    site = tmp_path / "site" / "subjects"
    site.mkdir(parents=True)
    (site / "03").symlink_to(DATA / "cmu" / "03", target_is_directory=True)
    dest = tmp_path / "dest"
    url = serve_directory(tmp_path / "site")
    result = _invoke(
        "datasets",
        "fetch",
        "cmu",
        "--subjects",
        "3",
        "--trials",
        "1,2",
        "--dest",
        dest,
        "--base-url",
        url,
    )
    assert result.exit_code == 0, result.output
    bad = _invoke("datasets", "fetch", "cmu", "--subjects", "4", "--dest", dest, "--base-url", url)
    for name in ("03.asf", "03_01.amc", "03_02.amc"):
        assert (dest / "03" / name).read_bytes() == (DATA / "cmu" / "03" / name).read_bytes()
    _assert_bad_input(bad, "404")
    _assert_bad_input(_invoke("datasets", "fetch", "hdm05", "--subjects", "1"), "cmu")


def test_demo_quick_writes_figure_and_beats_the_identity(tmp_path):
    out = tmp_path / "demo"
    result = _invoke("demo", "--quick", "--out", out, "--seed", "1")
    assert result.exit_code == 0, result.output
    summary = json.loads((out / "summary.json").read_text())
    figure = Path(summary["figure"])
    assert figure.parent == out and figure.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    methods = {row["method"]: row for row in summary["methods"]}
    assert set(methods) == {"QSSD", "K-SVD"}
    # Reference: reconstructing every displacement as the identity (no motion at all).
    from quatmotion.demo import sample_step
    from quatmotion.motion import angular_displacements
    from quatmotion.synthetic import generate_library

    clips = [m for m, _ in generate_library(1, seed=1)]
    samples = np.concatenate([angular_displacements(m, step=sample_step(m)) for m in clips])
    identity_error = np.degrees(2 * np.arccos(np.clip(np.abs(samples[..., 0]), 0, 1))).mean()
    for row in methods.values():
        assert 0 <= row["test_error_deg"] < identity_error
    assert summary["n_train"] + summary["n_test"] == len(samples)


def test_pose_commands_are_mounted():
    result = _invoke("pose", "--help")
    assert result.exit_code == 0, result.output
    assert "quatmotion pose" in result.stdout and "search" in result.stdout
