"""quatmotion: compress and search human motion-capture libraries."""

from importlib.metadata import PackageNotFoundError, version

from quatmotion.errors import FormatError

try:
    __version__ = version("quatmotion")
except PackageNotFoundError:  # a source tree on sys.path without an install
    __version__ = "0+unknown"

__all__ = ["FormatError", "__version__"]
