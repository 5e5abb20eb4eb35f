"""The codecs, one interface (:class:`~quatmotion.codec.methods._base.Method`), by name.

``best`` is the default; ``spline`` the strong simple baseline of issue 10; ``naive`` the floor
every codec is measured against; ``qssd`` and ``ksvd`` the paper's Fig. 2 pipeline with its
sparse model and with the Euclidean K-SVD.

A codec's module is imported when the codec is first asked for (:data:`METHODS` knows the
names without importing any): a reader of a ``best`` file loads neither the dictionary codecs'
kernels nor scikit-learn (issue 32's runtime apart).
"""

from __future__ import annotations

import importlib
from collections.abc import Iterator, MutableMapping
from typing import Any

from quatmotion.codec.methods._base import ClipContext, CodingOptions, EncodedLibrary, Method

__all__ = [
    "METHODS",
    "ClipContext",
    "CodingOptions",
    "EncodedLibrary",
    "Method",
    "NaiveMethod",
    "SparseMethod",
    "SplineMethod",
    "get_method",
]

_MODULE = "quatmotion.codec.methods."
_CODECS: dict[str, tuple[str, str, tuple]] = {
    # name: (module, class, arguments); the spline settings by the module's attribute name
    "best": ("spline", "SplineMethod", ("best", "BEST")),
    "spline": ("spline", "SplineMethod", ("spline", "BASELINE")),
    "naive": ("naive", "NaiveMethod", ()),
    "qssd": ("sparse", "SparseMethod", ("qssd",)),
    "ksvd": ("sparse", "SparseMethod", ("ksvd",)),
}
_CLASSES = {"SplineMethod": "spline", "NaiveMethod": "naive", "SparseMethod": "sparse"}


class _Registry(MutableMapping[str, Method]):
    """Every codec by name, each made (its module imported) on first use; a name set is
    kept as given (a test's codec with other settings) and deleting it restores the
    default."""

    def __init__(self) -> None:
        self._made: dict[str, Method] = {}
        self._names = list(_CODECS)

    def __getitem__(self, name: str) -> Method:
        method = self._made.get(name)
        if method is None:
            module, cls, args = _CODECS[name]  # KeyError for an unknown name, as a dict
            m = importlib.import_module(_MODULE + module)
            settings = [getattr(m, a) if a.isupper() else a for a in args]
            method = self._made[name] = getattr(m, cls)(*settings)
        return method

    def __setitem__(self, name: str, method: Method) -> None:
        if name not in self._names:
            self._names.append(name)
        self._made[name] = method

    def __delitem__(self, name: str) -> None:
        if name not in self._names:
            raise KeyError(name)
        self._made.pop(name, None)
        if name not in _CODECS:
            self._names.remove(name)

    def __iter__(self) -> Iterator[str]:
        return iter(list(self._names))

    def __len__(self) -> int:
        return len(self._names)

    def __contains__(self, name: object) -> bool:
        return name in self._names


METHODS: MutableMapping[str, Method] = _Registry()
"""Every codec by name."""


def get_method(name: str) -> Method:
    """The codec called ``name`` (``ValueError`` listing the names otherwise)."""
    try:
        return METHODS[name]
    except KeyError:
        raise ValueError(f"unknown method {name!r}; choose one of {', '.join(METHODS)}") from None


def __getattr__(name: str) -> Any:  # the classes, from their modules when first named
    if name in _CLASSES:
        return getattr(importlib.import_module(_MODULE + _CLASSES[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
