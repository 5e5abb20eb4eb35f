"""quatmotion: compress and search human motion-capture libraries."""

from quatmotion import _jit
from quatmotion.errors import FormatError

# Before any kernel module is imported: where Numba keeps the compiled kernels (a read-only
# install gets a per-user folder instead of none).
_jit.configure_cache()


def __getattr__(name: str) -> str:
    """``__version__``, read from the installed metadata when first asked for (importing
    ``importlib.metadata`` costs more than the rest of ``import quatmotion``)."""
    if name != "__version__":
        raise AttributeError(f"module 'quatmotion' has no attribute {name!r}")
    from importlib.metadata import PackageNotFoundError, version

    try:
        found = version("quatmotion")
    except PackageNotFoundError:  # a source tree on sys.path without an install
        found = "0+unknown"
    globals()["__version__"] = found
    return found


__all__ = ["FormatError", "__version__"]
