"""A search's number of results: one default (retrieval.ranges), checked once at the public
entries (search, search_within, quick_search, ``search --top``), trusted by the kernels."""

from __future__ import annotations

import inspect
from pathlib import Path

import pytest
from typer.testing import CliRunner

from quatmotion.cli import app
from quatmotion.cli.retrieval import search_command
from quatmotion.parallel import Runner
from quatmotion.retrieval import quick
from quatmotion.retrieval.index import ClipIndex
from quatmotion.retrieval.methods import METHODS
from quatmotion.retrieval.ranges import DEFAULT_TOP, check_top
from quatmotion.retrieval.search import DEFAULT_K, search, search_within
from quatmotion.synthetic import KINDS, generate_clip


def _default(func, name: str) -> object:
    return inspect.signature(func).parameters[name].default


def test_every_entry_defaults_to_the_one_default():
    assert DEFAULT_K == DEFAULT_TOP
    assert _default(search_command, "top") == DEFAULT_TOP
    for func in (ClipIndex.search, search, search_within, quick.quick_search, quick.quick_query):
        assert _default(func, "k") == DEFAULT_TOP, func.__qualname__


@pytest.mark.parametrize("bad", [0, -3, 2.0, True, "5"])
def test_check_top_refuses_what_is_not_a_count(bad):
    with pytest.raises(ValueError, match="k must be an integer of at least 1"):
        check_top(bad)


@pytest.fixture(scope="module")
def index(tmp_path_factory) -> Path:
    clips = [generate_clip(k, s, n_frames=60) for k in KINDS[:3] for s in range(2)]
    out = tmp_path_factory.mktemp("top") / "a.qidx"
    ClipIndex.build(clips, out, runner=Runner.inline())
    return out


@pytest.mark.parametrize("top", ["0", "-3"])
def test_cli_top_below_one_is_one_error_line(index, top):
    result = CliRunner().invoke(app, ["search", "walk_0", "--index", str(index), "--top", top])
    assert result.exit_code == 2
    lines = result.stderr.strip().splitlines()
    assert lines == [f"error: --top must be at least 1, got {top}"]


def test_the_library_refuses_k_below_one_at_its_entries(index):
    with ClipIndex.open(index) as idx:
        name = idx.rows()[0].name
        for k in (0, -1):
            with pytest.raises(ValueError, match="at least 1"):
                idx.search(name, k=k)
            with pytest.raises(ValueError, match="at least 1"):
                search_within(idx, name, k=k)
        with pytest.raises(ValueError, match="at least 1"):
            quick.quick_search(index, name, 0)
        # every method's ranking, with k at the library's size and at 1, agrees
        for method in METHODS:
            if method == "within":
                continue
            try:
                every = search(idx, name, method=method, k=len(idx))
            except ValueError:  # a method this index has no features for
                continue
            first = search(idx, name, method=method, k=1)
            assert [r.as_dict() for r in first] == [r.as_dict() for r in every[:1]], method
