"""Retrieval's search defaults and their check, in a module of their own that imports
nothing, so that the command line states them in its options without importing the search
(NumPy, Numba kernels): :func:`~quatmotion.retrieval.search.search`,
:meth:`~quatmotion.retrieval.index.ClipIndex.search`, :mod:`~quatmotion.retrieval.quick`,
``quatmotion search --top`` and the web app's search read them from here."""

__all__ = ["DEFAULT_TOP", "check_top"]

DEFAULT_TOP = 20
"""Clips a search answers with when the caller names no number."""


def check_top(k: int, name: str = "k") -> int:
    """``k``, the number of results a search is asked for, once it is an integer of at least
    1 (the public entries check it; the kernels under them trust it).

    Raises
    ------
    ValueError
        ``k`` below 1, or not an integer; the message names ``name``.
    """
    if isinstance(k, bool) or not isinstance(k, int) or k < 1:
        raise ValueError(f"{name} must be an integer of at least 1, got {k!r}")
    return k
