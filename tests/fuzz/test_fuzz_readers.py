"""Fuzzing every motion-file reader (issue 30), briefly: Hypothesis drives the corpus's
mutations of real, generated and hostile seeds (``st.randoms()``, so a finding shrinks to
few mutations); every reader either reads the bytes or refuses them with a FormatError naming
the file. The issue's proofs of concept are refused, every file in ``regressions/`` too (a
finding of a long run, ``make fuzz``, kept). The long runs: ``tests/fuzz/run.py``."""

from __future__ import annotations

import random
from datetime import timedelta
from pathlib import Path

import pytest
from fuzz_corpus import READERS, hostile, mutate, seeds
from fuzz_targets import run
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

REGRESSIONS = Path(__file__).parent / "regressions"
QUICK = settings(
    max_examples=40,
    deadline=timedelta(seconds=10),
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
    database=None,
    derandomize=True,  # the suite is the same run each time; make fuzz explores
)


@pytest.mark.parametrize("reader", READERS)
def test_every_seed_is_read_and_every_proof_of_concept_refused(reader):
    bad = hostile(reader)
    for data in seeds(reader):
        assert run(reader, data) == ("refused" if data in bad else "read")


@pytest.mark.parametrize("reader", READERS)
@QUICK
@given(rng=st.randoms(use_true_random=False), which=st.integers(0, 1000))
def test_mutated_files_are_read_or_refused(reader, rng: random.Random, which: int):
    corpus = seeds(reader)
    run(reader, mutate(reader, corpus[which % len(corpus)], rng))


@pytest.mark.parametrize(
    "path",
    sorted(p for reader in READERS for p in (REGRESSIONS / reader).glob("*") if p.is_file()),
    ids=lambda p: f"{p.parent.name}-{p.name}",
)
def test_regressions(path: Path):
    """A file a long run found (``regressions/READER/NAME``): read or refused now."""
    run(path.parent.name, path.read_bytes())
