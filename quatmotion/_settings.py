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
import math
import typing
from collections.abc import Mapping
from numbers import Integral, Real
from pathlib import Path
from typing import Any, ClassVar, Self

from quatmotion.errors import FormatError

__all__ = ["Interval", "Settings", "StrOptions"]


# scikit-learn's parameter validation (what its estimators and quatmotion.sparse use): the
# constraints are declarative and the messages name the parameter, the range and the value.
# Importing it costs about a second (scikit-learn imports SciPy's statistics), so settings
# declare their ranges with the two light descriptions below, which become scikit-learn's
# objects only when a value fails the quick check: a valid settings object (an index opened
# for one query) is checked without importing scikit-learn.
@dataclasses.dataclass(frozen=True)
class Interval:
    """scikit-learn's ``Interval(type, left, right, closed=...)``, built when needed."""

    type: type
    left: float | None
    right: float | None
    closed: str

    def __init__(self, type_: type, left: float | None, right: float | None, *, closed: str):
        for name, value in (("type", type_), ("left", left), ("right", right), ("closed", closed)):
            object.__setattr__(self, name, value)

    def satisfied(self, value: Any) -> bool | None:
        """True when scikit-learn's would accept ``value``; None: let it decide."""
        if isinstance(value, bool) or not isinstance(value, self.type):
            return None
        if value != value:  # NaN
            return None
        # an open end is an infinite bound, compared as the interval's closedness says (so
        # inf is outside [0, inf), as scikit-learn has it)
        left = -math.inf if self.left is None else self.left
        right = math.inf if self.right is None else self.right
        low_ok = value >= left if self.closed in ("left", "both") else value > left
        high_ok = value <= right if self.closed in ("right", "both") else value < right
        return True if low_ok and high_ok else None

    def sklearn(self) -> Any:
        from sklearn.utils._param_validation import Interval as SkInterval

        return SkInterval(self.type, self.left, self.right, closed=self.closed)


@dataclasses.dataclass(frozen=True)
class StrOptions:
    """scikit-learn's ``StrOptions(options)``, built when needed."""

    options: frozenset[str]

    def __init__(self, options: Any):
        object.__setattr__(self, "options", frozenset(options))

    def satisfied(self, value: Any) -> bool | None:
        return True if isinstance(value, str) and value in self.options else None

    def sklearn(self) -> Any:
        from sklearn.utils._param_validation import StrOptions as SkStrOptions

        return SkStrOptions(set(self.options))


def _quick_check(constraint: Any, value: Any) -> bool | None:
    """Whether ``value`` meets one constraint, when that is plain (None: ask scikit-learn)."""
    if constraint is None:
        return True if value is None else None
    if constraint == "boolean":
        return True if isinstance(value, bool) else None
    if isinstance(constraint, Interval | StrOptions):
        return constraint.satisfied(value)
    if isinstance(constraint, type) and constraint not in (Integral, Real):
        return True if isinstance(value, constraint) else None
    return None


def _validate(constraints: Mapping[str, list[Any]], params: Mapping[str, Any], caller: str) -> None:
    """scikit-learn's ``validate_parameter_constraints``, imported only when some value is not
    plainly valid (its message then names the parameter, the range and the value)."""
    if all(any(_quick_check(c, params[k]) for c in cs) for k, cs in constraints.items()):
        return
    from sklearn.utils._param_validation import (
        InvalidParameterError,
        validate_parameter_constraints,
    )

    full = {
        k: [c.sklearn() if isinstance(c, Interval | StrOptions) else c for c in cs]
        for k, cs in constraints.items()
    }
    try:
        validate_parameter_constraints(full, dict(params), caller_name=caller)
    except InvalidParameterError as error:
        # A ValueError (and no TypeError) for the command line's bad-input contract.
        raise ValueError(str(error)) from None


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
        _validate(constraints, params, type(self).__name__)
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
