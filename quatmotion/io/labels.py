"""Labels that travel with motion files: JSON sidecars, label lists, CSV tables.

Conventions
-----------
* A *sidecar* is a JSON object beside a clip with the clip's stem (``walk_001.bvh`` and
  ``walk_001.json``). Its string values are labels as they are; an integer value of key ``K``
  is an index into a *label list* ``K_label.txt`` (one name per line), looked up in the
  sidecar's folder and up to three folders above it (the Bandai-Namco layout:
  ``{"content": 6, "style": 11}`` with ``content_label.txt`` beside ``clips/``). A prefix that
  every name of a list shares and that ends in ``_`` or ``-`` (``dataset-1_``) is dropped.
* A labels CSV has the columns ``clip`` (a clip's name, file name, stem or path) and ``label``.
* Nothing here guesses: a sidecar that is not a JSON object, or an index outside its list, is a
  :class:`~quatmotion.errors.FormatError` naming the file.
"""

from __future__ import annotations

import csv
import functools
import json
import os
from pathlib import Path

from quatmotion.errors import FormatError

__all__ = ["LABEL_KEYS", "read_labels_csv", "sidecar_labels"]

LABEL_KEYS = ("label", "class", "content", "action", "category")
"""Sidecar keys that name a clip's main label, in order of preference."""


def sidecar_labels(path: str | Path) -> dict[str, str]:
    """The labels of the sidecar beside the motion file ``path`` (empty without one).

    Raises
    ------
    FormatError
        For a sidecar that is not a JSON object of strings and integers, or an index outside
        its label list (naming the sidecar).
    """
    meta = Path(path).with_suffix(".json")
    if not meta.is_file():
        return {}
    try:
        info = json.loads(meta.read_text(encoding="utf-8-sig"))
    except (UnicodeDecodeError, json.JSONDecodeError) as error:
        raise FormatError(f"not a JSON label sidecar ({error})", meta) from None
    if not isinstance(info, dict):
        raise FormatError("a label sidecar must be a JSON object", meta)
    labels: dict[str, str] = {}
    for key, value in info.items():
        if isinstance(value, str):
            labels[str(key)] = value
        elif isinstance(value, int) and not isinstance(value, bool):
            names = _label_list(meta.parent, str(key))
            if names is None:
                labels[str(key)] = str(value)
            elif 0 <= value < len(names):
                labels[str(key)] = names[value]
            else:
                raise FormatError(
                    f"{key} {value} is outside its label list ({len(names)} names)", meta
                )
    return labels


def main_label(labels: dict[str, str]) -> str:
    """The label a classifier would use: the first of :data:`LABEL_KEYS` present, else ""."""
    return next((labels[k] for k in LABEL_KEYS if labels.get(k)), "")


def _label_list(folder: Path, key: str) -> list[str] | None:
    for parent in [folder, *list(folder.parents)[:3]]:
        candidate = parent / f"{key}_label.txt"
        if candidate.is_file():
            return list(_read_label_list(str(candidate), os.stat(candidate).st_mtime_ns))
    return None


@functools.lru_cache(maxsize=64)
def _read_label_list(path: str, _mtime: int) -> tuple[str, ...]:
    names = [line.strip() for line in Path(path).read_text(encoding="utf-8-sig").splitlines()]
    names = [n for n in names if n]
    return tuple(_without_common_prefix(names))


def _without_common_prefix(names: list[str]) -> list[str]:
    if len(names) < 2:
        return names
    prefix = os.path.commonprefix(names)
    cut = max(prefix.rfind("_"), prefix.rfind("-"))
    if cut < 0:
        return names
    return [n[cut + 1 :] for n in names]


def read_labels_csv(path: str | Path) -> dict[str, str]:
    """Labels from a CSV with columns ``clip`` (name, file name, stem or path) and ``label``.

    Raises
    ------
    FormatError
        When the header lacks those columns (naming the file, line 1).
    """
    path = Path(path)
    with open(path, newline="", encoding="utf-8-sig") as f:
        reader = csv.DictReader(f)
        if not reader.fieldnames or not {"clip", "label"} <= set(reader.fieldnames):
            raise FormatError("a labels CSV needs the columns 'clip' and 'label'", path, 1)
        return {row["clip"].strip(): (row["label"] or "").strip() for row in reader}
