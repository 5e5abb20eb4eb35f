"""Long fuzz runs (``make fuzz``): mutate each reader's seeds for a time budget and keep every
finding under ``regressions/READER/`` (named by its hash), where the suite re-reads it.

    python tests/fuzz/run.py --seconds 600 --seed 1 bvh asf amc gltf glb

Each reader runs in its own process, one after another unless ``--jobs`` says otherwise;
a run prints how many files were read, refused and found. Exit status 1 when anything was found.

Two engines (``--engine``): ``atheris`` (coverage-guided: libFuzzer's mutations and the
corpus's, inputs that reach new code kept and mutated further; a crash, a hang over 20 s or
2 GB of memory is a finding too; the ``fuzz`` extra installs it, ``atheris_run.py`` is its
target), and ``random`` (the corpus's mutations of the seeds, seeded, as the suite's
Hypothesis tests do). ``auto``: atheris when it is installed.
"""

from __future__ import annotations

import argparse
import hashlib
import importlib.util
import random
import re
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

from fuzz_corpus import ISOLATED, READERS, mutate, seeds  # noqa: E402
from fuzz_targets import FindingError, run  # noqa: E402

REGRESSIONS = Path(__file__).parent / "regressions"


def fuzz(reader: str, seconds: float, seed: int, examples: int | None = None) -> dict[str, int]:
    rng = random.Random(f"{reader}:{seed}")
    corpus = list(seeds(reader))
    counts = {"read": 0, "refused": 0, "found": 0}
    found: set[str] = set()
    started = time.monotonic()
    deadline = started + seconds
    done = 0
    while time.monotonic() < deadline and (examples is None or done < examples):
        done += 1
        data = mutate(reader, rng.choice(corpus), rng)
        try:
            counts[run(reader, data)] += 1
        except FindingError as finding:
            counts["found"] += 1
            keep(reader, data, finding, found)
    elapsed = time.monotonic() - started
    print(f"{reader}: {counts} in {elapsed:.0f} s (seed {seed})", flush=True)
    return counts


def keep(reader: str, data: bytes, finding: FindingError | str, found: set[str]) -> None:
    """Write ``data`` to ``regressions/READER/`` unless a finding of its kind was kept."""
    key = finding if isinstance(finding, str) else _where(finding)
    if key in found:
        return  # one file per kind of finding
    found.add(key)
    name = hashlib.sha256(data).hexdigest()[:16]
    (REGRESSIONS / reader).mkdir(parents=True, exist_ok=True)
    (REGRESSIONS / reader / name).write_bytes(data)
    print(f"{reader}: found {finding} -> regressions/{reader}/{name}", flush=True)


def fuzz_atheris(reader: str, seconds: float, seed: int) -> dict[str, int]:
    """``reader`` under atheris for ``seconds`` (libFuzzer in a child process, started again
    after a crash it stopped at, with the time left)."""
    counts = {"runs": 0, "found": 0}
    found: set[str] = set()
    deadline = time.monotonic() + seconds
    with tempfile.TemporaryDirectory(prefix="quatmotion-fuzz-") as folder:
        corpus, artifacts = Path(folder, "corpus"), Path(folder, "artifacts")
        corpus.mkdir()
        artifacts.mkdir()
        for k, data in enumerate(seeds(reader)):
            (corpus / f"seed{k}").write_bytes(data)
        longest = max(len(data) for data in seeds(reader))
        for attempt in range(8):
            left = int(deadline - time.monotonic())
            if left < 5:
                break
            done = subprocess.run(
                [sys.executable, str(Path(__file__).parent / "atheris_run.py"), reader,
                 f"-max_total_time={left}", f"-seed={seed * 100 + attempt + 1}",
                 "-timeout=20", "-rss_limit_mb=2048", f"-max_len={min(2 * longest, 4 << 20)}",
                 f"-artifact_prefix={artifacts}/", "-print_final_stats=1", str(corpus)],
                capture_output=True, text=True, timeout=left + 120,
            )  # fmt: skip
            print(
                "".join(line + "\n" for line in done.stdout.splitlines() if "found" in line),
                end="",
                flush=True,
            )
            counts["found"] += done.stdout.count(f"{reader}: found")
            runs = re.findall(r"stat::number_of_executed_units: (\d+)", done.stderr)
            counts["runs"] += int(runs[-1]) if runs else 0
            for slow in artifacts.glob("slow-unit-*"):  # a note; a hang is -timeout's finding
                slow.unlink()
            crashed = sorted(artifacts.iterdir())
            for artifact in crashed:  # a signal, a hang, memory: libFuzzer's own findings
                counts["found"] += 1
                kind = artifact.name.split("-", 1)[0]
                keep(reader, artifact.read_bytes(), f"{kind} in the native or Python code", found)
                artifact.unlink()
            if not crashed and done.returncode != 0:
                print(f"{reader}: atheris ended with {done.returncode}: {done.stderr[-1500:]}")
                break
            if not crashed:
                break
    print(f"{reader}: {counts} in {seconds:.0f} s (atheris, seed {seed})", flush=True)
    return counts


def _where(finding: FindingError) -> str:
    """A finding's kind: its exception's type and the innermost line of quatmotion raising it."""
    cause = finding.__cause__
    if cause is None:
        return str(finding).split(":", 2)[1]
    place = ""
    trace = cause.__traceback__
    while trace is not None:
        code = trace.tb_frame.f_code
        if "quatmotion" in code.co_filename:
            place = f"{Path(code.co_filename).name}:{trace.tb_lineno}"
        trace = trace.tb_next
    return f"{type(cause).__name__} at {place}"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("readers", nargs="*", help=f"of {', '.join(READERS)} (all by default)")
    parser.add_argument("--seconds", type=float, default=600.0, help="per reader")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--jobs", type=int, default=1)
    parser.add_argument("--examples", type=int, help="stop after so many files per reader")
    parser.add_argument("--engine", choices=("auto", "atheris", "random"), default="auto")
    args = parser.parse_args(argv)
    known = READERS + ISOLATED
    readers = args.readers or list(known)
    unknown = sorted(set(readers) - set(known))
    if unknown:
        parser.error(f"no reader {', '.join(unknown)}; the readers: {', '.join(known)}")
    engine = args.engine
    if engine == "auto":  # so many files: the random engine's count
        atheris = importlib.util.find_spec("atheris") and args.examples is None
        engine = "atheris" if atheris else "random"
    if engine == "atheris" and args.examples is not None:
        parser.error("--examples counts the random engine's files: use --engine random")
    with ProcessPoolExecutor(args.jobs) as pool:
        if engine == "atheris":
            jobs = pool.map(fuzz_atheris, readers, [args.seconds] * len(readers),
                            [args.seed] * len(readers))  # fmt: skip
        else:
            jobs = pool.map(fuzz, readers, [args.seconds] * len(readers),
                            [args.seed] * len(readers), [args.examples] * len(readers))  # fmt: skip
        results = list(jobs)
    return 1 if any(r["found"] for r in results) else 0


if __name__ == "__main__":
    sys.exit(main())
