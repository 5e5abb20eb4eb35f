"""Fuzzing every motion-file reader (issue 30), briefly: Hypothesis drives the corpus's
mutations of real, generated and hostile seeds (``st.randoms()``, so a finding shrinks to
few mutations); every reader either reads the bytes or refuses them with a FormatError naming
the file. The issue's proofs of concept are refused, every file in ``regressions/`` too (a
finding of a long run, ``make fuzz``, kept). The long runs: ``tests/fuzz/run.py``."""

from __future__ import annotations

import random
import subprocess
import sys
from datetime import timedelta
from pathlib import Path

import pytest
from fuzz_corpus import ISOLATED, READERS, hostile, mutate, seeds
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
    sorted(
        p for reader in READERS + ISOLATED for p in (REGRESSIONS / reader).glob("*") if p.is_file()
    ),
    ids=lambda p: f"{p.parent.name}-{p.name}",
)
def test_regressions(path: Path):
    """A file a long run found (``regressions/READER/NAME``): read or refused now."""
    run(path.parent.name, path.read_bytes())


@pytest.mark.parametrize("reader", ISOLATED)
def test_mutated_files_of_c_readers_in_a_process_of_their_own(reader):
    """ufbx is C, hnswlib C++: a mutated FBX or pose library that crashed one would end the
    test run; in a child process it is one failed test (a negative exit code: the signal), and
    a finding is kept as a file."""
    pytest.importorskip({"fbx": "ufbx", "pose": "hnswlib"}[reader])
    run_py = Path(__file__).parent / "run.py"
    done = subprocess.run(
        [sys.executable, str(run_py), "--examples", "30", "--seed", "1", reader],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stdout + done.stderr[-2000:]
    assert "'found': 0" in done.stdout


def test_the_coverage_guided_engine_runs_a_reader_for_its_seconds():
    """``make fuzz``'s engine where atheris is installed (the ``fuzz`` extra): libFuzzer in a
    child process, quatmotion instrumented, stopped by its time budget."""
    pytest.importorskip("atheris")
    run_py = Path(__file__).parent / "run.py"
    done = subprocess.run(
        [sys.executable, str(run_py), "--seconds", "15", "--engine", "atheris", "asf"],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stdout + done.stderr[-2000:]
    assert "'found': 0" in done.stdout and "atheris" in done.stdout
    runs = int(done.stdout.split("'runs': ")[1].split(",")[0])
    assert runs > 0
