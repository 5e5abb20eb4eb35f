"""The web app: ``quatmotion serve``, a local site to browse, play, compare and search a library.

* :mod:`quatmotion.server.clips`: :class:`ClipCatalogue`, the clips of a ``.qmz`` library, a
  ``.qidx`` index and a pose index joined by name and addressed by id; decoding, originals,
  search and pose search.
* :mod:`quatmotion.server.app`: :func:`create_app`, the FastAPI application (pages, the JSON
  API under ``/api/``, its limits and safety rules); ``quatmotion serve`` runs it with uvicorn.
* ``static/``: the pages and their script; they show clips with the viewer of
  :mod:`quatmotion.viz`, served by the app.
"""

from quatmotion.server.app import (
    DEFAULT_MAX_UPLOAD,
    allowed_hosts_for,
    create_app,
    is_loopback,
    parse_size,
)
from quatmotion.server.clips import ClipCatalogue

__all__ = [
    "DEFAULT_MAX_UPLOAD",
    "ClipCatalogue",
    "allowed_hosts_for",
    "create_app",
    "is_loopback",
    "parse_size",
]
