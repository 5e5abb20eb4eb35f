"""The benchmark report: one standalone HTML page gathering benchmark results.

Conventions
-----------
* Input: the JSON files ``quatmotion bench NAME --out F`` writes (one per benchmark run), each
  with its PNG figures beside it. The benchmark's name is the JSON's ``"benchmark"`` field (else
  the file stem); figures are the ``"figures"`` list (paths relative to the JSON's folder, or
  absolute), else the ``<stem>_*.png`` files beside it.
* Every benchmark renders without code here: :func:`generic_tables` turns any JSON into tables
  (scalars as key/value rows, a mapping of records or a list of records as a table, long
  numeric lists as a summary). A benchmark describes its own results: its ``headlines``
  (:func:`headline_table`) and its summary ``tables`` (:func:`published_tables`) come first,
  the generic tables follow, so no number is lost and no key of a benchmark is named here.
* Figures are embedded as base64 PNG: the page stands alone and opens offline.
"""

from __future__ import annotations

import base64
import html
import json
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from quatmotion._atomic import atomic_write_text
from quatmotion.errors import FormatError

__all__ = [
    "BenchmarkResult",
    "Table",
    "generic_tables",
    "load_result",
    "render_report",
    "write_report",
]

_PROVENANCE_KEYS = ("benchmark", "machine", "command", "figures", "started")
_LONG_TABLE_ROWS = 25  # longer tables start folded
_MAX_COLUMNS = 14  # wider groups of records stay as nested key/value tables


@dataclass(frozen=True)
class Table:
    """A titled table: ``header`` names the columns, each row has as many cells."""

    title: str
    header: tuple[str, ...]
    rows: tuple[tuple[Any, ...], ...]
    note: str = ""


@dataclass(frozen=True)
class BenchmarkResult:
    """One benchmark's JSON and its figures.

    Attributes
    ----------
    path : Path
        The JSON file.
    name : str
        The benchmark (``"benchmark"`` field, else the file stem).
    data : dict
        The parsed JSON.
    figures : list of Path
        PNG files of the run, existing or not (missing ones are reported on the page).
    """

    path: Path
    name: str
    data: dict[str, Any]
    figures: list[Path] = field(default_factory=list)


def load_result(path: str | Path) -> BenchmarkResult:
    """Read one benchmark JSON; ``FormatError`` naming the file, line and column if malformed."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as error:
        raise FormatError(f"cannot read benchmark result: {error.strerror}", path) from None
    except UnicodeDecodeError as error:
        raise FormatError(f"not UTF-8 text (byte {error.start})", path) from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as error:
        raise FormatError(
            f"not JSON: {error.msg} (column {error.colno})", path, error.lineno
        ) from None
    if not isinstance(data, dict):
        raise FormatError(f"expected a JSON object, found {type(data).__name__}", path)
    name = str(data.get("benchmark") or path.stem)
    listed = data.get("figures")
    if isinstance(listed, list) and all(isinstance(f, str) for f in listed):
        figures = [p if p.is_absolute() else path.parent / p for p in map(Path, listed)]
    else:
        figures = sorted(path.parent.glob(f"{path.stem}_*.png"))
    return BenchmarkResult(path=path, name=name, data=data, figures=figures)


# ---------------------------------------------------------------------------- generic tables


def _is_scalar(value: Any) -> bool:
    return value is None or isinstance(value, str | int | float | bool)


def _records_table(title: str, records: Mapping[str, Any] | Sequence[Any]) -> Table | None:
    """A table of records (dicts) keyed by name or position, on their scalar fields."""
    items = list(records.items()) if isinstance(records, Mapping) else list(enumerate(records))
    if len(items) < 2 or not all(isinstance(v, Mapping) for _, v in items):
        return None
    columns: list[str] = []
    for _, record in items:
        for key, value in record.items():
            if _is_scalar(value) and key not in columns:
                columns.append(key)
    if not columns or len(columns) > _MAX_COLUMNS:
        return None
    rows = tuple((str(k), *(record.get(c, "") for c in columns)) for k, record in items)
    return Table(title, ("", *columns), rows)


def _list_summary(values: Sequence[Any]) -> str | None:
    if values and all(isinstance(v, int | float) and not isinstance(v, bool) for v in values):
        finite = sorted(v for v in values if math.isfinite(v))
        if not finite:
            return f"{len(values)} values, none finite"
        median = finite[len(finite) // 2]
        return (
            f"{len(values)} values: min {format_value(finite[0])}, median {format_value(median)}, "
            f"max {format_value(finite[-1])}"
        )
    return None


def generic_tables(
    data: Mapping[str, Any], title: str = "", skip: Iterable[str] = ()
) -> list[Table]:
    """Tables of any JSON object, recursively.

    Scalars of an object become ``key | value`` rows of one table; a mapping or list of
    records (objects) with at most 14 scalar fields becomes a table with a row per record
    (their nested values follow as their own tables); a list of up to 12 scalars is shown
    inline, a longer numeric list as count, min, median and max.
    """
    skip = set(skip)
    tables: list[Table] = []
    scalars: list[tuple[str, Any]] = []
    nested: list[tuple[str, Any]] = []
    for key, value in data.items():
        if key in skip:
            continue
        if _is_scalar(value):
            scalars.append((key, value))
        elif isinstance(value, list) and all(_is_scalar(v) for v in value):
            if len(value) <= 12:
                scalars.append((key, ", ".join(format_value(v) for v in value) or "(empty)"))
            else:
                scalars.append((key, _list_summary(value) or f"{len(value)} values"))
        else:
            nested.append((key, value))
    if scalars:
        tables.append(Table(title or "values", ("field", "value"), tuple(scalars)))
    for key, value in nested:
        path = f"{title}.{key}" if title else key
        records = _records_table(path, value)
        if records is not None:
            tables.append(records)
            # What a record holds beyond its scalar fields still shows, one table per record.
            items = value.items() if isinstance(value, Mapping) else enumerate(value)
            for name, record in items:
                rest = {k: v for k, v in record.items() if not _is_scalar(v)}
                if rest:
                    tables += generic_tables(rest, f"{path}.{name}")
        elif isinstance(value, Mapping):
            tables += generic_tables(value, path)
        elif isinstance(value, list):
            as_mapping = {str(i): v for i, v in enumerate(value)}
            tables += generic_tables(as_mapping, path)
    return tables


# ---------------------------------------------------------------- what a benchmark publishes


def value_at(data: Any, *keys: str, default: Any = None) -> Any:
    """``data[k0][k1]...``, or ``default`` where a key is missing or a level is no mapping."""
    node = data
    for key in keys:
        if not isinstance(node, Mapping) or key not in node:
            return default
        node = node[key]
    return node


_BETTER = ("higher", "lower", "")


def headline_table(data: Mapping[str, Any]) -> Table | None:
    """The headline figures a benchmark publishes about itself, or None if it publishes none.

    A benchmark's JSON may carry ``headlines``: a list of ``{"name", "path", "unit", "better",
    "format"}`` (``path`` the list of keys down to the value; ``better`` ``"higher"``,
    ``"lower"`` or ``""``; ``format`` ``"percent"`` or ``""``). The report reads figures through
    it, so a benchmark describes its own schema and the report names no key of it. A headline
    whose value is missing shows as missing; a malformed entry raises ``ValueError`` naming it.
    """
    listed = data.get("headlines")
    if listed is None:
        return None
    if not isinstance(listed, list):
        raise ValueError(f"headlines: expected a list, found {type(listed).__name__}")
    rows = []
    for number, entry in enumerate(listed):
        if not isinstance(entry, Mapping) or not isinstance(entry.get("name"), str):
            raise ValueError(f"headlines[{number}]: expected an object with a name")
        path = entry.get("path")
        if not isinstance(path, list) or not all(isinstance(k, str) for k in path):
            raise ValueError(f"headlines[{number}] ({entry['name']}): path must be a list of keys")
        better = entry.get("better", "")
        if better not in _BETTER:
            raise ValueError(
                f"headlines[{number}] ({entry['name']}): better must be one of {_BETTER}"
            )
        value = value_at(data, *path)
        if isinstance(value, int | float) and not isinstance(value, bool):
            shown = f"{value:.1%}" if entry.get("format") == "percent" else format_value(value)
        else:
            shown = "missing" if value is None else str(value)
        rows.append((entry["name"], shown, str(entry.get("unit", "")), better))
    return Table("Headline figures", ("figure", "value", "unit", "better"), tuple(rows))


def published_tables(data: Mapping[str, Any]) -> list[Table]:
    """The summary tables a benchmark publishes about itself (its JSON's ``tables``: a list of
    ``{"title", "columns", "rows", "note"}``, each row as many cells as columns), so the
    report shows a benchmark's summary without naming any key of its results.

    Raises
    ------
    ValueError
        A malformed entry, named by its position and title.
    """
    listed = data.get("tables")
    if listed is None:
        return []
    if not isinstance(listed, list):
        raise ValueError(f"tables: expected a list, found {type(listed).__name__}")
    tables = []
    for number, entry in enumerate(listed):
        if not isinstance(entry, Mapping) or not isinstance(entry.get("title"), str):
            raise ValueError(f"tables[{number}]: expected an object with a title")
        columns, rows = entry.get("columns"), entry.get("rows")
        where = f"tables[{number}] ({entry['title']})"
        if not isinstance(columns, list) or not all(isinstance(c, str) for c in columns):
            raise ValueError(f"{where}: columns must be a list of names")
        if not isinstance(rows, list) or not all(
            isinstance(r, list) and len(r) == len(columns) for r in rows
        ):
            raise ValueError(f"{where}: rows must be lists of {len(columns)} cells")
        note = entry.get("note", "")
        tables.append(
            Table(entry["title"], tuple(columns), tuple(tuple(r) for r in rows), str(note))
        )
    return tables


# ---------------------------------------------------------------------------- HTML


def format_value(value: Any) -> str:
    """A value as the report prints it (numbers to four significant digits, thousands
    separated, missing as a dash)."""
    if isinstance(value, bool) or value is None:
        return str(value).lower() if value is not None else "\u2014"
    if isinstance(value, int):
        return f"{value:,}" if abs(value) >= 10_000 else str(value)
    if isinstance(value, float):
        if not math.isfinite(value):
            return str(value)
        if value == 0 or 1e-3 <= abs(value) < 1e6:
            return f"{value:.4g}" if abs(value) < 1e4 else f"{value:,.0f}"
        return f"{value:.3e}"
    return str(value)


def _table_html(table: Table) -> str:
    head = "".join(f"<th>{html.escape(h)}</th>" for h in table.header)
    body = "".join(
        "<tr>" + "".join(_cell(v, i) for i, v in enumerate(row)) + "</tr>" for row in table.rows
    )
    note = f'<p class="note">{html.escape(table.note)}</p>' if table.note else ""
    grid = f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>{note}"
    title = html.escape(table.title)
    if len(table.rows) > _LONG_TABLE_ROWS:
        return f"<details><summary>{title} ({len(table.rows)} rows)</summary>{grid}</details>"
    return f"<h4>{title}</h4>{grid}"


def _cell(value: Any, column: int) -> str:
    numeric = isinstance(value, int | float) and not isinstance(value, bool)
    cls = ' class="num"' if numeric else ""
    return f"<td{cls}>{html.escape(format_value(value))}</td>"


def _figure_html(path: Path) -> str:
    name = html.escape(path.name)
    try:
        data = path.read_bytes()
    except OSError:
        return f'<p class="missing">figure {name} not found beside the JSON</p>'
    encoded = base64.b64encode(data).decode("ascii")
    return (
        f'<figure><img alt="{name}" src="data:image/png;base64,{encoded}">'
        f"<figcaption>{name}</figcaption></figure>"
    )


def _provenance_html(data: Mapping[str, Any]) -> str:
    """Where the numbers come from: the command, the machine, when, and the run's options."""
    missing = '<span class="missing">not recorded</span>'
    command = data.get("command")
    machine = data.get("machine")
    rows = [
        ("command", f"<code>{html.escape(str(command))}</code>" if command else missing),
        (
            "machine",
            html.escape(
                " \u00b7 ".join(
                    f"{k}: {format_value(v)}" for k, v in machine.items() if _is_scalar(v)
                )
            )
            if isinstance(machine, Mapping)
            else missing,
        ),
    ]
    for key in ("started", "quick", "seed", "data", "data_root"):
        if key in data and _is_scalar(data[key]):
            rows.append((key, html.escape(format_value(data[key]))))
    body = "".join(f"<tr><th>{k}</th><td>{v}</td></tr>" for k, v in rows)
    return f'<table class="provenance">{body}</table>'


_STYLE = """
body { font: 14px/1.45 system-ui, sans-serif; color: #1d2330; margin: 0 auto; max-width: 1100px;
       padding: 16px 24px 48px; }
h1 { font-size: 22px; } h2 { font-size: 19px; border-bottom: 2px solid #dfe3ea; padding-top: 12px; }
h3 { font-size: 16px; } h4 { font-size: 14px; margin: 14px 0 4px; }
table { border-collapse: collapse; margin: 4px 0 8px; font-size: 13px; }
th, td { border: 1px solid #d5d9e0; padding: 2px 8px; text-align: left; vertical-align: top; }
thead th { background: #eef1f5; } td.num { text-align: right; font-variant-numeric: tabular-nums; }
table.provenance th { background: #f6f7f9; width: 8em; }
.figures { display: flex; flex-wrap: wrap; gap: 8px 16px; align-items: flex-start; }
figure { margin: 0 0 8px; max-width: 100%; }
figure img { max-width: 100%; border: 1px solid #e3e6eb; }
figcaption { font-size: 12px; color: #5a6273; }
details { margin: 8px 0; } summary { cursor: pointer; font-weight: 600; }
.note { font-size: 12px; color: #5a6273; margin: 0 0 8px; }
.missing { color: #a33; }
nav a { margin-right: 12px; }
"""


def render_report(results: Sequence[BenchmarkResult], title: str = "quatmotion benchmarks") -> str:
    """The report page for ``results``: per benchmark, provenance, tables and figures."""
    sections = []
    links = []
    for index, result in enumerate(results):
        anchor = html.escape(f"b{index}-{result.name}")
        links.append(f'<a href="#{anchor}">{html.escape(result.name)}</a>')
        parts = [
            f'<h2 id="{anchor}">{html.escape(result.name)}</h2>',
            f'<p class="note">{html.escape(str(result.path))}</p>',
            _provenance_html(result.data),
        ]
        try:
            headlines = headline_table(result.data)
        except ValueError as error:
            headlines = None
            parts.append(f'<p class="missing">{html.escape(str(error))}</p>')
        if headlines is not None and headlines.rows:
            parts.append(_table_html(headlines))
        try:
            tables = published_tables(result.data)
        except ValueError as error:
            # A malformed summary: named, and the numbers still show below.
            tables = []
            parts.append(f'<p class="missing">{html.escape(str(error))}</p>')
        parts += [_table_html(t) for t in tables if t.rows]
        if result.figures:
            figures = "".join(_figure_html(p) for p in result.figures)
            parts.append(f'<h3>Figures</h3><div class="figures">{figures}</div>')
        everything = "".join(
            _table_html(t) for t in generic_tables(result.data, skip=_PROVENANCE_KEYS)
        )
        if tables:
            parts.append(f"<details><summary>All results</summary>{everything}</details>")
        else:
            parts.append(f"<h3>Results</h3>{everything}")
        sections.append("<section>" + "\n".join(parts) + "</section>")
    return (
        '<!doctype html><html lang="en"><head><meta charset="utf-8">'
        '<meta http-equiv="Content-Security-Policy" content="default-src \'none\'; '
        "style-src 'unsafe-inline'; img-src data:\">"
        f"<title>{html.escape(title)}</title><style>{_STYLE}</style></head><body>"
        f"<h1>{html.escape(title)}</h1><nav>{''.join(links)}</nav>"
        + "\n".join(sections)
        + "</body></html>\n"
    )


def write_report(
    out: str | Path, json_paths: Sequence[str | Path], title: str = "quatmotion benchmarks"
) -> Path:
    """Read benchmark JSON files and write their report page to ``out`` atomically."""
    if not json_paths:
        raise ValueError("no benchmark results given")
    results = [load_result(p) for p in json_paths]
    atomic_write_text(out, render_report(results, title))
    return Path(out)
