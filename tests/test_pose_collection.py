"""The pose library as a collection: PoseSettings in the file, clip references, the 0.3.0 file
still read under the one version policy (issue 18)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from quatmotion.cli import app
from quatmotion.collection import ClipRef, content_hash
from quatmotion.io import write_motion
from quatmotion.parallel import Runner
from quatmotion.pose.library import FORMAT, PoseLibrary, PoseSettings
from quatmotion.synthetic import generate_clip

runner = CliRunner()
SMALL = {"metric": "GPD+RDSR", "rank": 2, "n_unlabeled": 100, "n_pairs": 20, "fit_poses": 200}


def test_the_0_3_0_pose_library_opens_and_answers_as_it_did(v030):
    expected = json.loads((v030 / "index_pose_v030.json").read_text())["pose"]
    library = PoseLibrary.open(v030 / "pose_v030.npz")
    assert library.version == 2 and library.format.version == 2 and FORMAT.version == 4
    assert library.clip_names == expected["clip_names"]
    assert library.frame_of.tolist() == expected["frame_of"]
    matches = library.nearest(library.pose_query(0, 10)[0], k=3)
    got = [[m.clip, m.frame, round(m.distance, 6)] for m in matches]
    assert got == expected["first_match"]
    refs = library.clips()  # 0.3.0 stored none: from the paths, found beside the file
    assert [r.name for r in refs] == ["punch", "s1/take_001", "s2/take_001"]
    clip_files = v030 / "index_clips"
    assert refs[0].sha256 == content_hash(clip_files / "s1" / "punch.bvh")
    assert library.settings is None


def test_a_library_built_from_files_stores_its_settings_and_references(tmp_path):
    for folder, kind, seed in (("s1", "walk", 0), ("s2", "squat", 1)):
        (tmp_path / "clips" / folder).mkdir(parents=True)
        write_motion(generate_clip(kind, seed, n_frames=40, fps=30.0),
                     tmp_path / "clips" / folder / "take_001.bvh")  # fmt: skip
    settings = PoseSettings(**SMALL)
    out = tmp_path / "p.npz"
    report = PoseLibrary.build([tmp_path / "clips"], out, settings, runner=Runner.inline())
    assert [r.name for r in report.added] == ["s1/take_001", "s2/take_001"]
    assert not report.failures
    back = PoseLibrary.open(out)
    assert back.version == 4 and back.settings == settings
    assert back.clips() == tuple(report.added) and isinstance(back.clips()[0], ClipRef)
    assert all(Path(r.path).is_absolute() for r in back.clips())
    listed = runner.invoke(app, ["pose", "ls", str(out), "--json"])
    assert listed.exit_code == 0, listed.output
    doc = json.loads(listed.stdout)
    assert doc["settings"]["rank"] == 2 and [c["poses"] for c in doc["clips"]] == [40, 40]
    built = report.details["library"]
    np.testing.assert_array_equal(back.frame_of, built.frame_of)


@pytest.mark.parametrize(
    ("field", "value"), [("fps", 0.0), ("height", -1.0), ("rank", 0), ("seed", -1)]
)
def test_pose_settings_refuse_values_out_of_range(field, value):
    with pytest.raises(ValueError, match=field):
        PoseSettings(**{field: value})


def test_adding_clips_keeps_the_distance_skips_held_clips_and_names_apart(tmp_path):
    clips = tmp_path / "clips"
    for folder, kind, seed in (("s1", "walk", 0), ("s2", "squat", 1), ("s3", "walk", 2)):
        (clips / folder).mkdir(parents=True)
        write_motion(generate_clip(kind, seed, n_frames=40, fps=30.0),
                     clips / folder / "take_001.bvh")  # fmt: skip
    out = tmp_path / "p.npz"
    PoseLibrary.build(
        [clips / "s1", clips / "s2"], out, PoseSettings(**SMALL), runner=Runner.inline()
    )
    before = PoseLibrary.open(out)
    # s3/take_001 collides with a stored stem; s1/take_001 is already there (same content)
    result = runner.invoke(app, ["pose", "add", str(out), str(clips / "s3"), str(clips / "s1")])
    assert result.exit_code == 0, result.output
    assert "1 clips added, 1 already there" in result.output
    after = PoseLibrary.open(out)
    assert [r.name for r in after.clips()] == ["s1/take_001", "s2/take_001", "s3/take_001"]
    np.testing.assert_array_equal(after.model["W"], before.model["W"])  # nothing relearned
    assert len(after.clip_of) == len(before.clip_of) + 40
    assert after.clip_of[-40:].tolist() == [2] * 40 and after.frame_of[-40:].tolist() == list(
        range(40)
    )
    # the added clip's poses are found as themselves
    query, _, _ = after.pose_query(2, 10)
    [best] = after.nearest(query, k=1)
    assert (best.clip, best.frame) == (2, 10)
    # the old poses still answer as before
    q0 = before.pose_query(0, 5)[0]
    first = before.nearest(q0, k=1)[0]
    assert (after.nearest(q0, k=1)[0].clip, after.nearest(q0, k=1)[0].frame) == (
        first.clip,
        first.frame,
    )


# -- the keywords before issue 33 (docs/migration-0.4.md) ----------------------------------
FAST = {"n_pairs": 20, "n_unlabeled": 100}
SPECS = [("walk", 0, 40), ("squat", 1, 47), ("kick", 2, 45)]


def _load():
    import functools

    from quatmotion.bench.scale import generated_pose_clip

    return functools.partial(generated_pose_clip, fps=15.0, height=170.0)


def test_the_in_memory_build_under_its_old_name_warns_and_builds_the_same_library():
    clips = [_load()(s) for s in SPECS]
    new = PoseLibrary.build_in_memory(clips, PoseSettings(**FAST, seed=3))
    with pytest.warns(DeprecationWarning, match="build_in_memory"):
        old = PoseLibrary.build(clips, **FAST, seed=3)
    assert isinstance(old, PoseLibrary) and old.index.to_bytes() == new.index.to_bytes()
    with pytest.warns(DeprecationWarning, match="estimator="):
        PoseLibrary.build_in_memory(clips, PoseSettings(**FAST), metric=None)
    with pytest.raises(TypeError, match="'ranks'"):
        PoseLibrary.build_in_memory(clips, ranks=3)


def test_the_streamed_builds_old_keywords_warn_and_build_what_the_settings_build():
    with pytest.warns(DeprecationWarning) as caught:
        old, _ = PoseLibrary.build_streamed(SPECS, _load(), metric_name="GPD+LMS", **FAST,
                                            workers=1)  # fmt: skip
    said = " ".join(str(w.message) for w in caught)
    assert "PoseSettings(...)" in said and "runner=Runner" in said
    settings = PoseSettings(metric="GPD+LMS", **FAST)
    new, _ = PoseLibrary.build_streamed(SPECS, _load(), settings, runner=Runner.inline())
    assert old.metric == new.metric == "GPD+LMS"
    assert old.index.to_bytes() == new.index.to_bytes()
    with pytest.warns(DeprecationWarning), pytest.raises(ValueError, match="rank"):
        PoseLibrary.build_streamed(SPECS, _load(), rank=0)  # checked by PoseSettings


def test_add_takes_the_settings_whole_and_refuses_what_would_change_the_library(tmp_path):
    (tmp_path / "a").mkdir()
    for i, kind in enumerate(["walk", "squat", "kick"]):
        write_motion(generate_clip(kind, i, n_frames=40, fps=30.0), tmp_path / "a" / f"{kind}.bvh")
    settings = PoseSettings(**SMALL)
    out = tmp_path / "p.npz"
    paths = sorted((tmp_path / "a").glob("*.bvh"))
    PoseLibrary.build(paths[:1], out, settings, runner=Runner.inline())
    assert PoseLibrary.stored_settings(out) == settings
    with pytest.raises(ValueError, match="rank=2"):
        PoseLibrary.add(out, paths[1:2], settings.replace(rank=3), runner=Runner.inline())
    read_cm = settings.replace(read=settings.read.replace(units="cm"))
    report = PoseLibrary.add(out, paths[1:2], read_cm, runner=Runner.inline())
    assert len(report.added) == 1 and report.settings == read_cm
    with pytest.warns(DeprecationWarning, match="settings.read"):
        report = PoseLibrary.add(out, paths[2:], units="cm", runner=Runner.inline())
    assert len(report.added) == 1 and report.settings.read.units == "cm"
    assert PoseLibrary.stored_settings(out) == settings  # an add keeps what the file stores


def test_pose_index_options_default_to_the_settings_defaults():
    import inspect

    from quatmotion.cli.pose import index_command

    settings = PoseSettings()
    field_of = {"unlabeled": "n_unlabeled", "pairs": "n_pairs"}
    options = inspect.signature(index_command).parameters
    named = ["fps", "height", "metric", "rank", "unlabeled", "pairs", "seed", "fit_poses",
             "index_threads"]  # fmt: skip
    for name in named:
        assert options[name].default == getattr(settings, field_of.get(name, name)), name
