"""Settings objects: frozen, validated once by declarative constraints, stored in the files
they produce.

Conventions
-----------
* A settings class is a frozen dataclass deriving from :class:`Settings`, with every field
  given a documented default and a ``_parameter_constraints`` entry in scikit-learn's
  vocabulary (``Interval``, ``StrOptions``, ``"boolean"``, ``None``, a type...), the one
  vocabulary :mod:`quatmotion.sparse` validates with. Construction validates every field
  once; code that receives a settings object trusts it.
* Cross-field rules (``max_error`` or ``ratio``, not both) go in :meth:`Settings._check`.
* Nested settings are fields whose type is itself a :class:`Settings` (``read`` of the file
  kinds): stored and restored as nested mappings.
* :meth:`Settings.to_dict` gives JSON-ready values (tuples as lists); :meth:`Settings.from_dict`
  restores them, missing keys taking their defaults (a file written before a field existed
  still opens) and unknown keys refused with :class:`~quatmotion.errors.FormatError` (a file
  written by a newer quatmotion, read by an older one, says so instead of losing a setting).
"""

from __future__ import annotations

import dataclasses
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Any, ClassVar, Self

# scikit-learn's parameter validation (what its estimators and quatmotion.sparse use): the
# constraints are declarative and the messages name the parameter, the range and the value.
from sklearn.utils._param_validation import (
    InvalidParameterError,
    validate_parameter_constraints,
)

from quatmotion.errors import FormatError

__all__ = ["Settings"]


@dataclasses.dataclass(frozen=True)
class Settings:
    """Base of every settings object (see the module's conventions)."""

    _parameter_constraints: ClassVar[dict[str, list[Any]]] = {}

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if isinstance(value, list):  # sequences are stored as tuples: frozen, hashable
                object.__setattr__(self, f.name, tuple(value))
        params = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        constraints = {k: v for k, v in self._parameter_constraints.items() if k in params}
        try:
            validate_parameter_constraints(constraints, params, caller_name=type(self).__name__)
        except InvalidParameterError as error:
            # A ValueError (and no TypeError) for the command line's bad-input contract.
            raise ValueError(str(error)) from None
        self._check()

    def _check(self) -> None:
        """Rules across fields; raise ValueError naming them. Nothing by default."""

    # ------------------------------------------------------------------ storing
    def to_dict(self) -> dict[str, Any]:
        """The settings as JSON-ready values (nested settings as mappings)."""
        out: dict[str, Any] = {}
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if isinstance(value, Settings):
                value = value.to_dict()
            elif isinstance(value, tuple):
                value = list(value)
            elif isinstance(value, Path):
                value = str(value)
            out[f.name] = value
        return out

    @classmethod
    def from_dict(cls, values: Mapping[str, Any], source: str | Path | None = None) -> Self:
        """Settings from :meth:`to_dict`'s mapping; missing keys take their defaults.

        Raises
        ------
        FormatError
            Naming ``source`` for unknown keys or values the constraints refuse.
        """
        if not isinstance(values, Mapping):
            raise FormatError(f"{cls.__name__}: expected a mapping, got {values!r}", source)
        hints = typing.get_type_hints(cls)
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(values) - names)
        if unknown:
            raise FormatError(
                f"{cls.__name__}: unknown settings {', '.join(unknown)} "
                "(written by a newer quatmotion?)",
                source,
            )
        kwargs: dict[str, Any] = {}
        for name, value in values.items():
            nested = _settings_type(hints.get(name))
            if nested is not None and isinstance(value, Mapping):
                value = nested.from_dict(value, source)
            kwargs[name] = value
        try:
            return cls(**kwargs)
        except (TypeError, ValueError) as error:
            raise FormatError(f"{cls.__name__}: {error}", source) from None

    def replace(self, **changes: Any) -> Self:
        """A copy with ``changes`` (validated again)."""
        return dataclasses.replace(self, **changes)


def _settings_type(hint: Any) -> type[Settings] | None:
    """The Settings class a field's type hint names (also inside ``X | None``), else None."""
    candidates = typing.get_args(hint) or (hint,)
    for candidate in candidates:
        if isinstance(candidate, type) and issubclass(candidate, Settings):
            return candidate
    return None
