"""The ``quatmotion`` command line (Typer + Rich): thin modules, one per command group.

Each module registers its commands on the root application (:mod:`quatmotion.cli._app`) and
calls the library; none computes anything itself. Heavy imports (NumPy, scikit-learn, Numba
kernels) happen inside the commands, so ``quatmotion --help`` stays quick. Every command keeps
the bad-input contract of :mod:`quatmotion.cli._common`: exit code 2 and a one-line ``error:``
message, never a traceback.

Modules: :mod:`~quatmotion.cli.motion` (``info``, ``convert``, ``generate``),
:mod:`~quatmotion.cli.codec` (``compress``, ``decompress``, ``ls``, ``append``),
:mod:`~quatmotion.cli.datasets` (``datasets list|fetch``), :mod:`~quatmotion.cli.pose`
(``pose index|search``), :mod:`~quatmotion.cli.retrieval` (``index build|add|remove|ls``,
``search``), :mod:`~quatmotion.cli.viz` (``view``, ``report``), :mod:`~quatmotion.cli.server`
(``serve``), :mod:`~quatmotion.cli.bench` (``bench``), :mod:`~quatmotion.cli.demo` (``demo``),
:mod:`~quatmotion.cli.warmup` (``warm-up``).
"""

from __future__ import annotations

import importlib

from quatmotion.cli._app import app, reflow_all_help

# Importing a command module registers its commands; this order is the order of --help.
for _module in (
    "motion",
    "codec",
    "datasets",
    "pose",
    "retrieval",
    "viz",
    "server",
    "bench",
    "demo",
    "warmup",
):
    importlib.import_module(f"quatmotion.cli.{_module}")
reflow_all_help(app)

__all__ = ["app", "main"]


def main() -> None:
    """Console-script entry point."""
    app()
