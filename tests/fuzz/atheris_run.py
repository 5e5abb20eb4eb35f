"""One reader under atheris, coverage-guided (started by ``run.py --engine atheris``):

    python tests/fuzz/atheris_run.py READER [libFuzzer options] CORPUS_FOLDER

quatmotion's modules are instrumented (which branches an input reaches); inputs come from
libFuzzer's byte mutations and the corpus's own (``fuzz_corpus.mutate``), half each. A reader's
finding (anything but a read or a FormatError naming the file) is kept under
``regressions/READER/`` and the run goes on; a crash, a hang or memory beyond the limit stops
libFuzzer, which writes the input to its ``-artifact_prefix`` (``run.py`` keeps it).
"""

from __future__ import annotations

import importlib.util
import random
import sys
from pathlib import Path

import atheris

sys.path.insert(0, str(Path(__file__).parent))
READER = sys.argv.pop(1)


def _compiled() -> list[str]:
    """quatmotion's modules that Numba compiles from (instrumented bytecode is no function
    Numba can type): left as they are."""
    spec = importlib.util.find_spec("quatmotion")
    assert spec is not None and spec.origin is not None
    root = Path(spec.origin).parent
    return [
        ".".join(("quatmotion", *path.relative_to(root).with_suffix("").parts))
        for path in root.rglob("*.py")
        if "numba" in path.read_text(encoding="utf-8")
    ]


with atheris.instrument_imports(include=["quatmotion"], exclude=_compiled()):
    from fuzz_corpus import mutate
    from fuzz_targets import FindingError, run
    from run import keep

_FOUND: set[str] = set()


def test_one_input(data: bytes) -> None:
    try:
        run(READER, data)
    except FindingError as finding:
        keep(READER, data, finding, _FOUND)


def custom_mutator(data: bytes, max_size: int, seed: int) -> bytes:
    rng = random.Random(seed)
    if rng.random() < 0.5:
        try:
            return mutate(READER, data, rng)[:max_size]
        except Exception:  # noqa: BLE001 (a mutation of a mutant that no longer parses)
            pass
    return atheris.Mutate(data, max_size)


if __name__ == "__main__":
    atheris.Setup(sys.argv, test_one_input, custom_mutator=custom_mutator)
    atheris.Fuzz()
