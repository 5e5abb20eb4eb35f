"""A collection's labels: where they come from, and how a label given for a clip finds it.

Conventions
-----------
* A label is one string per clip (its class: HDM05's motion class, Bandai's content); "" for
  none. Every file kind stores it beside the clip's reference and can change it later
  (``set_labels``) without rebuilding.
* Sources, in order of precedence: a mapping given by the user (a CSV,
  :func:`quatmotion.io.labels.read_labels_csv`), the clip's sidecar
  (:func:`quatmotion.io.labels.sidecar_labels`), its class folder (``clips/CLASS/file.amc``:
  the folder's name, when asked for), the data folder's catalogue
  (:func:`quatmotion.datasets.catalogue`). The first that has a label for a clip gives it.
* A key of a user's mapping matches a clip by its name, its file name, its stem (when that
  stem is one clip's only) or its path; keys that match no clip are reported, never dropped
  in silence.
"""

from __future__ import annotations

import os
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from quatmotion.collection.reading import ClipSource
from quatmotion.io.labels import main_label, sidecar_labels

__all__ = ["LabelAssignment", "catalogue_labels", "label_sources"]


@dataclass
class LabelAssignment:
    """Labels for the clips of a collection, and the keys of a given mapping matching none."""

    labels: dict[str, str] = field(default_factory=dict)
    """Clip name -> label, for the clips that got one."""
    unmatched: list[str] = field(default_factory=list)
    """Keys of the user's mapping that name no clip."""


def catalogue_labels() -> dict[str, str]:
    """Resolved path -> label of every clip of the data folder's catalogue (empty without one)."""
    from quatmotion.datasets import DataNotFoundError, catalogue

    try:
        return {str(e.path.resolve()): e.label for e in catalogue()}
    except DataNotFoundError:
        return {}


def match_keys(given: Mapping[str, str], sources: Sequence[ClipSource]) -> LabelAssignment:
    """The clips each key of ``given`` names (module conventions)."""
    stems = Counter(Path(s.name).name for s in sources)
    lookup: dict[str, str] = {}
    for s in sources:
        keys = [s.name]
        if s.path is not None:
            keys += [s.path.name, str(s.path), os.path.normpath(str(s.path))]
            if stems[Path(s.name).name] == 1:
                keys.append(s.path.stem)
        for key in keys:
            lookup.setdefault(key, s.name)
    out = LabelAssignment()
    for key, label in given.items():
        name = lookup.get(key) or lookup.get(os.path.abspath(key))
        if name is None:
            out.unmatched.append(key)
        else:
            out.labels[name] = label
    return out


def label_sources(
    sources: Sequence[ClipSource],
    given: Mapping[str, str] | None = None,
    *,
    sidecars: bool = True,
    folders: bool = False,
    catalogue: bool = True,
) -> LabelAssignment:
    """Every clip's label by the precedence of the module's conventions.

    Raises
    ------
    FormatError
        A malformed sidecar (naming it).
    """
    out = match_keys(given or {}, sources) if given else LabelAssignment()
    known = catalogue_labels() if catalogue else {}
    for s in sources:
        if s.name in out.labels or s.path is None:
            continue
        label = main_label(sidecar_labels(s.path)) if sidecars else ""
        if not label and folders:
            label = s.path.parent.name
        if not label:
            label = known.get(str(s.path.resolve()), "")
        if label:
            out.labels[s.name] = label
    return out
