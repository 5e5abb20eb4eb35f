"""The web app: ``quatmotion serve``, a local site to browse, play, compare and search a library.

* :mod:`quatmotion.server.clips`: :class:`ClipCatalogue`, the clips of a ``.qmz`` library, a
  ``.qidx`` index and a pose index joined by name and addressed by id; decoding, originals,
  search and pose search.
* :mod:`quatmotion.server.app`: :func:`create_app`, the FastAPI application (pages, the JSON
  API under ``/api/``, its limits and safety rules); ``quatmotion serve`` runs it with uvicorn.
* :mod:`quatmotion.server.building`: :class:`LibraryBuild`, a library built in the background
  while the app already answers (``quatmotion serve DIR``), served file by file.
* :mod:`quatmotion.server.uploads`: :class:`UploadGate`, how many uploads are taken at once
  and the memory budget their parsing runs under.
* ``static/``: the pages and their script; they show clips with the viewer of
  :mod:`quatmotion.viz`, served by the app.
"""

from quatmotion.server.app import (
    CSRF_HEADER,
    DEFAULT_MAX_UPLOAD,
    allowed_hosts_for,
    create_app,
    is_loopback,
    parse_size,
)
from quatmotion.server.building import LibraryBuild
from quatmotion.server.clips import ClipCatalogue
from quatmotion.server.uploads import UploadGate

__all__ = [
    "CSRF_HEADER",
    "DEFAULT_MAX_UPLOAD",
    "ClipCatalogue",
    "LibraryBuild",
    "UploadGate",
    "allowed_hosts_for",
    "create_app",
    "is_loopback",
    "parse_size",
]
