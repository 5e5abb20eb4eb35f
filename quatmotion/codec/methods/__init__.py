"""The codecs, one interface (:class:`~quatmotion.codec.methods._base.Method`), by name.

``best`` is the default; ``spline`` the strong simple baseline of issue 10; ``naive`` the floor
every codec is measured against; ``qssd`` and ``ksvd`` the paper's Fig. 2 pipeline with its
sparse model and with the Euclidean K-SVD.
"""

from __future__ import annotations

from quatmotion.codec.methods._base import ClipContext, EncodedLibrary, Method
from quatmotion.codec.methods.naive import NaiveMethod
from quatmotion.codec.methods.sparse import SparseMethod
from quatmotion.codec.methods.spline import BASELINE, BEST, SplineMethod

__all__ = ["METHODS", "ClipContext", "EncodedLibrary", "Method", "get_method"]


def _registry() -> dict[str, Method]:
    return {
        "best": SplineMethod("best", BEST),
        "spline": SplineMethod("spline", BASELINE),
        "naive": NaiveMethod(),
        "qssd": SparseMethod("qssd"),
        "ksvd": SparseMethod("ksvd"),
    }


METHODS: dict[str, Method] = _registry()
"""Every codec by name."""


def get_method(name: str) -> Method:
    """The codec called ``name`` (``ValueError`` listing the names otherwise)."""
    try:
        return METHODS[name]
    except KeyError:
        raise ValueError(f"unknown method {name!r}; choose one of {', '.join(METHODS)}") from None
