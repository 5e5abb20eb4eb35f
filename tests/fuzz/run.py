"""Long fuzz runs (``make fuzz``): mutate each reader's seeds for a time budget and keep every
finding under ``regressions/READER/`` (named by its hash), where the suite re-reads it.

    python tests/fuzz/run.py --minutes 10 --seed 1 bvh asf amc gltf glb

Each reader runs in its own process, one after another unless ``--jobs`` says otherwise;
a run prints how many files were read, refused and found. Exit status 1 when anything was found.
"""

from __future__ import annotations

import argparse
import hashlib
import random
import sys
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
            key = _where(finding)
            if key in found:
                continue  # one file per kind of finding
            found.add(key)
            name = hashlib.sha256(data).hexdigest()[:16]
            (REGRESSIONS / reader).mkdir(parents=True, exist_ok=True)
            (REGRESSIONS / reader / name).write_bytes(data)
            print(f"{reader}: found {finding} -> regressions/{reader}/{name}", flush=True)
    elapsed = time.monotonic() - started
    print(f"{reader}: {counts} in {elapsed:.0f} s (seed {seed})", flush=True)
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
    parser.add_argument("--minutes", type=float, default=10.0, help="per reader")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--jobs", type=int, default=1)
    parser.add_argument("--examples", type=int, help="stop after so many files per reader")
    args = parser.parse_args(argv)
    known = READERS + ISOLATED
    readers = args.readers or list(known)
    unknown = sorted(set(readers) - set(known))
    if unknown:
        parser.error(f"no reader {', '.join(unknown)}; the readers: {', '.join(known)}")
    with ProcessPoolExecutor(args.jobs) as pool:
        results = list(
            pool.map(
                fuzz,
                readers,
                [args.minutes * 60] * len(readers),
                [args.seed] * len(readers),
                [args.examples] * len(readers),
            )
        )
    return 1 if any(r["found"] for r in results) else 0


if __name__ == "__main__":
    sys.exit(main())
