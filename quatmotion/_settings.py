"""Settings objects: frozen, validated once by declarative constraints, stored in the files
they produce.

Conventions
-----------
* A settings class is a frozen dataclass deriving from :class:`Settings`, with every field
  given a documented default and a ``_parameter_constraints`` entry in scikit-learn's
  vocabulary (``Interval``, ``StrOptions``, ``"boolean"``, ``"random_state"``, ``None``, a
  type), the one vocabulary :mod:`quatmotion.sparse` validates with too
  (:func:`validate_parameters`). Construction validates every field
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

import numpy as np

from quatmotion.errors import FormatError

__all__ = ["Interval", "Settings", "StrOptions", "validate_parameters"]


# Parameter constraints in scikit-learn's vocabulary (what its estimators and
# quatmotion.sparse declare), checked here: scikit-learn's own checker lives in a private module
# that any of its releases may move, and importing it costs about a second. The messages follow
# scikit-learn's ("The 'x' parameter of C must be ... Got v instead.").
@dataclasses.dataclass(frozen=True)
class Interval:
    """A number of ``type`` (``Integral`` or ``Real``) between ``left`` and ``right``.

    ``None`` ends are infinite; ``closed`` is ``"left"``, ``"right"``, ``"both"`` or
    ``"neither"``, and an infinite end is compared as the closedness says (so ``inf`` is outside
    ``[0, inf)``). Booleans and NaN are never inside.
    """

    type: type
    left: float | None
    right: float | None
    closed: str

    def __init__(self, type_: type, left: float | None, right: float | None, *, closed: str):
        if type_ not in (Integral, Real):
            raise TypeError(f"Interval type must be Integral or Real, got {type_!r}")
        if closed not in ("left", "right", "both", "neither"):
            raise ValueError(f"closed must be left, right, both or neither, got {closed!r}")
        for name, value in (("type", type_), ("left", left), ("right", right), ("closed", closed)):
            object.__setattr__(self, name, value)

    def satisfied(self, value: Any) -> bool:
        """Whether ``value`` is a number of this type inside the interval."""
        if isinstance(value, bool) or not isinstance(value, self.type):
            return False
        if value != value:  # NaN
            return False
        left = -math.inf if self.left is None else self.left
        right = math.inf if self.right is None else self.right
        low_ok = value >= left if self.closed in ("left", "both") else value > left
        high_ok = value <= right if self.closed in ("right", "both") else value < right
        return bool(low_ok and high_ok)

    def __str__(self) -> str:
        kind = "an int" if self.type is Integral else "a float"
        low = "[" if self.closed in ("left", "both") else "("
        high = "]" if self.closed in ("right", "both") else ")"
        left = "-inf" if self.left is None else self.left
        right = "inf" if self.right is None else self.right
        return f"{kind} in the range {low}{left}, {right}{high}"


@dataclasses.dataclass(frozen=True)
class StrOptions:
    """One of the strings ``options``."""

    options: frozenset[str]

    def __init__(self, options: Any):
        object.__setattr__(self, "options", frozenset(options))

    def satisfied(self, value: Any) -> bool:
        return isinstance(value, str) and value in self.options

    def __str__(self) -> str:
        return "a str among {" + ", ".join(repr(o) for o in sorted(self.options)) + "}"


def _satisfied(constraint: Any, value: Any) -> bool:
    """Whether ``value`` meets one constraint of the vocabulary."""
    if constraint is None:
        return value is None
    if constraint == "boolean":
        return isinstance(value, bool | np.bool_)
    if constraint == "random_state":
        return (
            value is None
            or isinstance(value, np.random.RandomState)
            or (
                isinstance(value, Integral)
                and not isinstance(value, bool)
                and 0 <= value <= 2**32 - 1
            )
        )
    if isinstance(constraint, Interval | StrOptions):
        return constraint.satisfied(value)
    if isinstance(constraint, type):
        return isinstance(value, constraint)
    raise TypeError(f"unknown parameter constraint {constraint!r}")


def _describe(constraint: Any) -> str:
    if constraint is None:
        return "None"
    if constraint == "boolean":
        return "an instance of 'bool'"
    if constraint == "random_state":
        return "an int in the range [0, 4294967295], an instance of 'RandomState' or None"
    if isinstance(constraint, type):
        return f"an instance of {constraint.__qualname__!r}"
    return str(constraint)


def validate_parameters(
    constraints: Mapping[str, list[Any]], params: Mapping[str, Any], caller: str
) -> None:
    """Check every parameter named in ``constraints`` against its list (any one may hold).

    Raises
    ------
    ValueError
        Naming the parameter, ``caller``, what it must be and the value given (a ValueError and
        never a TypeError, for the command line's bad-input contract).
    """
    for name, allowed in constraints.items():
        if name not in params:
            continue
        value = params[name]
        if any(_satisfied(c, value) for c in allowed):
            continue
        described = [_describe(c) for c in allowed]
        must = ", ".join(described[:-1]) + " or " if len(described) > 1 else ""
        must += described[-1]
        raise ValueError(
            f"The {name!r} parameter of {caller} must be {must}. Got {value!r} instead."
        )


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
        validate_parameters(constraints, params, type(self).__name__)
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
