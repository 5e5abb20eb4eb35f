"""quatmotion: compress and search human motion-capture libraries."""

from importlib.metadata import PackageNotFoundError, version

from quatmotion import _jit
from quatmotion.errors import FormatError

# Before any kernel module is imported: where Numba keeps the compiled kernels (a read-only
# install gets a per-user folder instead of none).
_jit.configure_cache()

try:
    __version__ = version("quatmotion")
except PackageNotFoundError:  # a source tree on sys.path without an install
    __version__ = "0+unknown"

__all__ = ["FormatError", "__version__"]
