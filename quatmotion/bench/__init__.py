"""Benchmarks: each module ``quatmotion.bench.<name>`` measures one part of the package.

Contract: ``run(out: pathlib.Path, quick: bool = False, seed: int = 0) -> dict`` measures,
writes the result as JSON to ``out`` (figures as PNG beside it) and returns the same dict.
``quatmotion bench <name> --out F [--quick] [--seed N]`` imports the module lazily and calls
``run``. Benchmarks are not tests: they report numbers (see METRICS.md for their names), they
do not assert them.
"""
