"""The web app: ``quatmotion serve``, a local site to browse, play, compare and search a library.

* :mod:`quatmotion.server.clips`: :class:`ClipCatalogue`, the clips of a ``.qmz`` library, a
  ``.qidx`` index and a pose index joined by name and addressed by id; decoding, originals,
  search and pose search.
* :mod:`quatmotion.server.app`: :func:`create_app`, the FastAPI application assembled from
  :mod:`~quatmotion.server.routers` (pages and the JSON API under ``/api/``, one module per
  area), :mod:`~quatmotion.server.middleware` (host check, CSRF guard, body limit, headers),
  :mod:`~quatmotion.server.dependencies` (state, limits, upload reading),
  :mod:`~quatmotion.server.schemas` (the API's models) and :mod:`~quatmotion.server.handlers`
  (errors); ``quatmotion serve`` runs it with uvicorn.
* :mod:`quatmotion.server.building`: :class:`LibraryBuild`, a library built in the background
  while the app already answers (``quatmotion serve DIR``), served file by file.
* :mod:`quatmotion.server.uploads`: :class:`UploadGate`, how many uploads are taken at once
  and the memory budget their parsing runs under.
* ``static/``: the pages and their script; they show clips with the viewer of
  :mod:`quatmotion.viz`, served by the app.
"""

from __future__ import annotations

import importlib
from typing import Any

# Loaded on first use: ``quatmotion serve`` binds its port (``server.listen``) before the
# application and the codec it decodes with are imported, so a busy port is said at once.
_HOMES = {
    "CSRF_HEADER": "middleware",
    "DEFAULT_MAX_UPLOAD": "dependencies",
    "allowed_hosts_for": "middleware",
    "create_app": "app",
    "is_loopback": "middleware",
    "parse_size": "dependencies",
    "LibraryBuild": "building",
    "ClipCatalogue": "clips",
    "UploadGate": "uploads",
}

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


def __getattr__(name: str) -> Any:
    if name not in _HOMES:
        raise AttributeError(f"module 'quatmotion.server' has no attribute {name!r}")
    value = getattr(importlib.import_module(f"quatmotion.server.{_HOMES[name]}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted([*globals(), *_HOMES])
