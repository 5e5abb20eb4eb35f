"""Compression larger than memory (issue 18): the clips are read in the workers, not in the
caller; the layouts and models are learned on a bounded sample; every runner gives the same
bytes."""

from __future__ import annotations

from pathlib import Path

import pytest

from quatmotion.codec import Archive, CompressSettings
from quatmotion.codec.writer import code, plan, scan
from quatmotion.collection import ReadSettings
from quatmotion.io import write_bvh
from quatmotion.parallel import Runner
from quatmotion.synthetic import KINDS, generate_clip

N_CLIPS = 8
SETTINGS = CompressSettings(read=ReadSettings(units="cm"), fit_sample=3)


@pytest.fixture(scope="module")
def clips(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("scale")
    for i in range(N_CLIPS):
        clip = generate_clip(KINDS[i % len(KINDS)], i, n_frames=24, fps=30.0)
        write_bvh(clip, folder / f"c{i:02d}.bvh")
    return folder


@pytest.fixture(scope="module")
def inline_bytes(clips: Path) -> bytes:
    return Archive.build([clips], None, SETTINGS, runner=Runner.inline()).details["data"]


def _layouts(data: bytes) -> int:
    with Archive.open(data) as archive:
        return len(archive.header.layouts)


def test_the_caller_reads_only_the_sample(clips, inline_bytes, monkeypatch, tmp_path) -> None:
    """With a local pool, every clip is scanned and coded in a worker: the caller reads the
    fitting sample only (at most ``fit_sample`` clips of each layout)."""
    read_here: list[str] = []
    read_clip = plan.read_clip

    def counting(source, read=None):
        read_here.append(source.name)
        return read_clip(source, read)

    for step in (scan, plan, code):  # every step that reads a clip
        monkeypatch.setattr(step, "read_clip", counting)
    out = tmp_path / "pool.qmz"
    report = Archive.build([clips], out, SETTINGS, runner=Runner.local(workers=2))
    assert len(report.added) == N_CLIPS
    assert len(read_here) <= SETTINGS.fit_sample * _layouts(inline_bytes) < N_CLIPS
    assert out.read_bytes() == inline_bytes  # the pool gives the inline bytes
    assert "data" not in report.details  # the bytes are in the file, not in memory


def test_layouts_and_models_learned_on_a_bounded_sample(clips, monkeypatch) -> None:
    fitted: list[int] = []
    prepare_library = plan.prepare_library

    def spy(motions, *args, **kwargs):
        fitted.append(len(motions))
        return prepare_library(motions, *args, **kwargs)

    monkeypatch.setattr(plan, "prepare_library", spy)
    report = Archive.build([clips], None, SETTINGS, runner=Runner.inline())
    n_layouts = _layouts(report.details["data"])
    assert fitted and all(n <= SETTINGS.fit_sample * n_layouts for n in fitted)
    assert len(report.added) == N_CLIPS
    # a sample as large as the library learns on every clip: another file, same clips
    whole = Archive.build(
        [clips], None, SETTINGS.replace(fit_sample=N_CLIPS), runner=Runner.inline()
    )
    with Archive.open(whole.details["data"]) as archive:
        assert len(archive) == N_CLIPS


def test_inline_pool_and_dask_give_the_same_bytes(clips, inline_bytes, dask_cluster, tmp_path):
    for name, runner in (
        ("pool_chunked", Runner.local(workers=2, chunk_size=3)),
        ("dask", Runner.dask(dask_cluster)),
        ("dask_chunked", Runner.dask(dask_cluster, chunk_size=4)),
    ):
        out = tmp_path / f"{name}.qmz"
        Archive.build([clips], out, SETTINGS, runner=runner)
        assert out.read_bytes() == inline_bytes, name


def test_add_streams_the_old_chunks(clips, tmp_path) -> None:
    files = sorted(clips.glob("*.bvh"))
    out = tmp_path / "added.qmz"
    Archive.build(files[:3], out, SETTINGS, runner=Runner.inline())
    with Archive.open(out) as before:
        old = list(before.clip_payloads())
    report = Archive.add(out, files[3:], runner=Runner.inline())
    assert len(report.added) == N_CLIPS - 3 and "data" not in report.details
    with Archive.open(out) as after:
        assert len(after) == N_CLIPS
        assert list(after.clip_payloads())[:3] == old  # copied byte for byte
