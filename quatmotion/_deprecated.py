"""The names before 0.4.0: thin aliases that warn (docs/migration-0.4.md maps them)."""

from __future__ import annotations

import warnings

__all__ = ["warn_renamed"]


def warn_renamed(old: str, new: str) -> None:
    """A :class:`DeprecationWarning` naming the new name, at the caller's caller."""
    warnings.warn(
        f"{old} is the name before quatmotion 0.4.0: use {new} (docs/migration-0.4.md)",
        DeprecationWarning,
        stacklevel=3,
    )
