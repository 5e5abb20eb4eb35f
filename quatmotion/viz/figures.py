"""Matplotlib figures: the backend choice and atomic PNG output, in one place.

Conventions
-----------
* Figures are drawn off-screen (the Agg backend): quatmotion runs on machines without a
  display, and benchmarks must not open windows.
* :func:`save_figure` writes through :func:`quatmotion._atomic.atomic_output` (a temporary PNG,
  then a rename), so a half-written figure never replaces a good one, and closes the figure so
  long benchmark runs do not accumulate open figures.
"""

from __future__ import annotations

from pathlib import Path
from types import ModuleType
from typing import Any

from quatmotion._atomic import atomic_output

__all__ = ["pyplot", "save_figure"]


def pyplot() -> ModuleType:
    """``matplotlib.pyplot`` on the Agg backend (imported on first use: it takes a second)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(figure: Any, path: str | Path, *, dpi: int = 110, tight: bool = True) -> Path:
    """Write ``figure`` to ``path`` as PNG atomically, then close it.

    Parameters
    ----------
    figure : matplotlib.figure.Figure
    path : str or Path
        Destination ``.png``; missing folders are created.
    dpi : int
        Resolution.
    tight : bool
        Apply ``tight_layout`` first, so titles and labels are not clipped.

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    path = Path(path)
    try:
        if tight:
            figure.tight_layout()
        with atomic_output(path, suffix=".png") as temp:
            figure.savefig(temp, dpi=dpi)
    finally:
        pyplot().close(figure)
    return path
