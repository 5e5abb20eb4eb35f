"""The summary tables a benchmark publishes in its JSON (``tables``), which ``quatmotion
report`` renders without knowing the benchmark's keys
(:func:`quatmotion.viz.report.published_tables`).

Each benchmark that publishes tables turns its own result into them (``summary_tables``), so
the layout of a result and the tables read from it live in one module.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any

from quatmotion.viz.report import format_value as fmt
from quatmotion.viz.report import value_at as get

__all__ = ["fmt", "get", "table"]


def table(
    title: str, columns: Sequence[str], rows: Iterable[Sequence[Any]], note: str = ""
) -> dict[str, Any]:
    """One published table; every row must have a cell per column."""
    cells = [list(r) for r in rows]
    for number, row in enumerate(cells):
        if len(row) != len(columns):
            raise ValueError(f"{title}: row {number} has {len(row)} cells, not {len(columns)}")
    return {"title": title, "columns": list(columns), "rows": cells, "note": note}
