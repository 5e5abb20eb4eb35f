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

from __future__ import annotations

import importlib
from typing import Any

# Loaded on first use: ``quatmotion serve`` binds its port (``server.listen``) before the
# application and the codec it decodes with are imported, so a busy port is said at once.
_HOMES = {
    "CSRF_HEADER": "app",
    "DEFAULT_MAX_UPLOAD": "app",
    "allowed_hosts_for": "app",
    "create_app": "app",
    "is_loopback": "app",
    "parse_size": "app",
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
