"""``make demo`` ends with a search by example over the demo's library, its results printed,
and a ``view.html`` of the example beside its best match, its path printed (issue 17)."""

from __future__ import annotations

import json
import re
from pathlib import Path

from typer.testing import CliRunner

from quatmotion.cli import app
from quatmotion.io import write_asf, write_motion
from quatmotion.synthetic import generate_clip


def _demo(*args: object):
    return CliRunner().invoke(app, ["demo", *map(str, args)])


def _check_ending(result, out: Path) -> dict:
    assert result.exit_code == 0, result.output
    summary = json.loads((out / "summary.json").read_text())["search"]
    query, rows = summary["query"], summary["results"]
    assert rows and query not in [r["clip"] for r in rows]  # the example is left out
    assert [r["rank"] for r in rows] == list(range(1, len(rows) + 1))
    distances = [r["distance"] for r in rows]
    assert distances == sorted(distances)
    text = result.stdout
    assert f"the clips most like {query}" in text
    table = text[text.index(f"clips like {query}") :]
    for row in rows:  # every result printed, in rank order
        assert re.search(rf"│\s+{row['rank']} │ {re.escape(row['clip'])}\s", table), table
    printed = re.search(r"^view: (\S+) ", text, flags=re.M)
    assert printed and Path(printed.group(1)) == out / "view.html" == Path(summary["view"])
    page = (out / "view.html").read_text()
    assert page.startswith("<!DOCTYPE html>") or page.lstrip().lower().startswith("<!doctype")
    assert query in page and rows[0]["clip"] in page
    assert text.rstrip().splitlines()[-1].startswith(f"next: open {out / 'view.html'}")
    return summary


def test_the_demo_ends_with_a_search_by_example_and_a_page_to_open(tmp_path: Path) -> None:
    out = tmp_path / "demo"
    summary = _check_ending(_demo("--quick", "--out", out, "--seed", "1"), out)
    assert len(summary["results"]) == 5
    assert Path(summary["index"]) == out / "library.qidx"
    # again, over its own outputs (make demo runs with --force): the same search
    again = _check_ending(_demo("--quick", "--out", out, "--seed", "1", "--force"), out)
    assert again["results"] == summary["results"]


def test_the_demo_ends_so_on_the_users_clips_too(tmp_path: Path) -> None:
    clips = tmp_path / "mine"
    clips.mkdir()
    for k in range(2):
        write_motion(generate_clip("walk", seed=k, n_frames=60), clips / f"walk{k}.bvh")
    squat = generate_clip("squat", seed=5, n_frames=60)
    write_motion(squat, clips / "squat.amc")
    write_asf(squat.skeleton, clips / "squat.asf")
    out = tmp_path / "out"
    summary = _check_ending(_demo(clips, "--out", out), out)
    assert summary["query"] == "squat"  # the first file found
    assert sorted(r["clip"] for r in summary["results"]) == ["walk0", "walk1"]
    assert not (out / "clips").exists()  # the user's files are indexed where they are
