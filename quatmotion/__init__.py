"""quatmotion: compress and search human motion-capture libraries."""

from quatmotion.errors import FormatError

__version__ = "0.2.0"

__all__ = ["FormatError", "__version__"]
