"""Benchmarks: each module ``quatmotion.bench.<name>`` measures one part of the package.

Contract: ``run(out: pathlib.Path, quick: bool = False, seed: int = 0) -> dict`` measures,
writes the result as JSON to ``out`` (figures as PNG beside it) and returns the same dict.
``quatmotion bench <name> --out F [--quick] [--seed N]`` imports the module lazily and calls
``run``. Benchmarks are not tests: they report numbers (see docs/metrics.md for their names), they
do not assert them. Every result starts with :func:`provenance` (benchmark name, the command
that reproduces it, the machine), which ``quatmotion report`` shows beside the numbers.
"""

from __future__ import annotations

import pkgutil

from quatmotion.bench._provenance import provenance

__all__ = ["names", "provenance"]


def names() -> list[str]:
    """The benchmarks of this package: its public modules, sorted (each has a ``run``)."""
    return sorted(m.name for m in pkgutil.iter_modules(__path__) if not m.name.startswith("_"))
