"""Rules 1-3 of the clip-name rule (:func:`quatmotion.io.names.match_clip`), importing
nothing: the quick search path (:mod:`quatmotion.retrieval.quick`, which loads no Numba and so
no :mod:`quatmotion.io`) finds a clip by its name with the same code."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import PurePath

__all__ = ["CLIP_SUFFIXES", "bare_parts", "rule_matches"]

CLIP_SUFFIXES = (".amc", ".bvh", ".glb", ".gltf", ".fbx")
"""``quatmotion.io.MOTION_SUFFIXES``, which this module cannot import (a test keeps them one)."""


def bare_parts(text: str) -> tuple[str, ...]:
    """Path components of ``text`` with a motion-file suffix removed from the last."""
    parts = PurePath(text).parts
    last = parts[-1].lower() if parts else ""
    suffix = next((s for s in CLIP_SUFFIXES if last.endswith(s)), None)
    if suffix is not None:
        parts = (*parts[:-1], parts[-1][: -len(suffix)])
    return parts


def _ends(name: tuple[str, ...], query: tuple[str, ...]) -> bool:
    return 0 < len(query) <= len(name) and name[-len(query) :] == query


def rule_matches(query: str, names: Sequence[str]) -> list[int]:
    """The clips of ``names`` the first of rules 1-3 with any match finds for ``query``: 1. the
    name itself, 2. an end of its path, 3. that end without a motion-file suffix (empty: no
    rule matches)."""
    paths = [PurePath(name).parts for name in names]
    asked, asked_bare = PurePath(query).parts, bare_parts(query)
    rules = (
        lambda i: names[i] == query,
        lambda i: _ends(paths[i], asked),
        lambda i: _ends(bare_parts(names[i]), asked_bare),
    )
    for rule in rules:
        matches = [i for i in range(len(names)) if rule(i)]
        if matches:
            return matches
    return []
