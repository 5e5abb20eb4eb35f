"""The web app: pages to browse, play, compare and search a motion library, over a JSON API.

Conventions
-----------
* :func:`create_app` builds the application from the files it serves and its limits, so tests
  build it in-process (FastAPI's ``TestClient``) and ``quatmotion serve`` runs it with uvicorn.
  It only assembles the parts, laid out as FastAPI's bigger applications are:
  :mod:`~quatmotion.server.middleware` (host check, CSRF guard, body limit, security headers),
  :mod:`~quatmotion.server.dependencies` (the app's state, limits and upload reading as the
  routes receive them), :mod:`~quatmotion.server.schemas` (the API's models),
  :mod:`~quatmotion.server.handlers` (errors as JSON) and :mod:`~quatmotion.server.routers`
  (one module per area).
* The API lives under ``/api/`` and is documented at ``/docs`` (Swagger UI) and ``/redoc``,
  whose scripts are served by the app itself (``fastapi-offline``); the pages (``/``,
  ``/play``, ``/compare``, ``/search``, ``/poses``) are static files of this package that call
  the API and show clips with the viewer of :mod:`quatmotion.viz` (its scripts, three.js
  included, served from ``/assets/viewer/``). Nothing is fetched from another site, and each
  page's Content-Security-Policy says so.
* Clips are addressed by id (:mod:`quatmotion.server.clips`); no request value becomes a path.
  Responses name clips, never the server's files.
* Uploads (``POST /api/search/upload``, multipart) are read and parsed in memory, never
  written anywhere; every request body is limited to ``max_upload`` bytes (413 beyond it,
  before reading when the request declares its length); they are admitted and parsed under
  the rules of :mod:`quatmotion.server.uploads` (one per client, a few at once, a memory
  budget).
* Every POST carries the header ``X-Quatmotion-Request`` and no ``Origin``/``Sec-Fetch-Site``
  of another site (:class:`~quatmotion.server.middleware.CsrfGuard`); a bound loopback
  answers its host names only (:class:`~quatmotion.server.middleware.HostCheck`, ``[::1]``
  included).
* Errors are JSON ``{"detail": "<one line>"}``: 400 for a bad request (malformed or invalid
  parameters, an upload the parsers reject, with their message: whatever an uploaded file
  holds, never a 500), 403 for a POST the CSRF guard refuses, 404 for an unknown clip or
  something the server was not started with, 413 for a body over the limit or an upload over
  the parsing budget, 415 for a kind of file whose optional reader is not installed, 429 for
  a second upload of one client, 503 (with ``Retry-After``) when the uploads' slots are taken
  or, while a library is being built (:mod:`quatmotion.server.building`), for what may still
  come.
* Work that takes time (decoding, searching, parsing an upload) runs in the thread pool, off
  the event loop, so the server answers other requests meanwhile.
"""

from __future__ import annotations

import importlib
import warnings
from collections.abc import AsyncIterator, Callable, Sequence
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

from fastapi import FastAPI
from fastapi_offline import FastAPIOffline

import quatmotion
from quatmotion.server.building import LibraryBuild
from quatmotion.server.clips import ClipCatalogue
from quatmotion.server.dependencies import DEFAULT_MAX_UPLOAD
from quatmotion.server.handlers import add_error_handlers
from quatmotion.server.middleware import (
    LOOPBACK_HOSTS,
    BodySizeLimit,
    CsrfGuard,
    HostCheck,
    SecurityHeaders,
)
from quatmotion.server.routers import build as build_routes
from quatmotion.server.routers import clips, pages, poses, search
from quatmotion.server.uploads import UploadGate

__all__ = ["create_app"]

ROUTERS = (pages.router, clips.router, build_routes.router, search.router, poses.router)
"""Every route of the app, by area."""


def create_app(
    library: str | Path | None = None,
    index: str | Path | None = None,
    poses: str | Path | None = None,
    *,
    max_upload: int = DEFAULT_MAX_UPLOAD,
    allowed_hosts: Sequence[str] = LOOPBACK_HOSTS,
    build: LibraryBuild | None = None,
    uploads: UploadGate | None = None,
) -> FastAPI:
    """The web app serving a motion library (module conventions).

    Parameters
    ----------
    library, index, poses : path, optional
        A ``.qmz`` library (browse, play, compare with the originals), a ``.qidx`` index
        (labels, originals, search by example) and a pose index (pose search); at least one
        of the first two, or a ``build``.
    max_upload : int, keyword-only
        Largest request body, bytes (an upload with its form fields); 413 beyond it.
    allowed_hosts : sequence of str, keyword-only
        Host names (the ``Host`` header) the app answers; others get 400. ``("*",)`` for any.
        The default suits a server bound to the loopback (``allowed_hosts_for``).
    build : LibraryBuild, keyword-only, optional
        A library to build instead of files: started with the app, each file served as it is
        complete, stopped when the app shuts down.
    uploads : UploadGate, keyword-only, optional
        Uploads taken at once and the memory their parsing may use (its defaults when None).

    Returns
    -------
    fastapi.FastAPI
        Its files are open until the app shuts down (the ``lifespan``), or until
        ``app.state.catalogue.close()``.

    Raises
    ------
    ValueError
        Neither a library nor an index nor a build, files beside a build, or a limit below
        one byte.
    FileNotFoundError, FormatError
        A file missing or not of its format (naming it).
    """
    if max_upload < 1:
        raise ValueError(f"max_upload must be at least 1 byte, got {max_upload}")
    if build is not None and (library, index, poses) != (None, None, None):
        raise ValueError("give the files to serve or a build, not both")
    catalogue = ClipCatalogue.open(library, index, poses) if build is None else None
    try:
        app = FastAPIOffline(
            title="quatmotion",
            version=quatmotion.__version__,
            summary="Browse, play, compare and search a motion-capture library.",
            static_url="/assets/docs",
            lifespan=_lifespan(catalogue, build),
        )
        app.state.catalogue, app.state.build = catalogue, build
        app.state.max_upload, app.state.uploads = max_upload, uploads or UploadGate()
        # Added last is outermost: the Host check, the CSRF guard, the body limit, then
        # the headers.
        app.add_middleware(SecurityHeaders)
        app.add_middleware(BodySizeLimit, max_bytes=max_upload)
        app.add_middleware(CsrfGuard)
        app.add_middleware(HostCheck, allowed=list(allowed_hosts))
        add_error_handlers(app)
        pages.mount_assets(app)
        for router in ROUTERS:
            app.include_router(router)
    except BaseException:
        _close(catalogue, build)
        raise
    return app


def _close(catalogue: ClipCatalogue | None, build: LibraryBuild | None) -> None:
    if catalogue is not None:
        catalogue.close()
    if build is not None:
        build.stop()


def _lifespan(
    catalogue: ClipCatalogue | None, build: LibraryBuild | None
) -> Callable[[FastAPI], AsyncIterator[None]]:
    """The app's life: a build starts once the server answers (its first pages come before
    the work); the files close and the build stops at shutdown."""

    @asynccontextmanager
    async def lifespan(_app: FastAPI) -> AsyncIterator[None]:
        if build is not None:
            build.start()
        yield
        _close(catalogue, build)

    return lifespan  # type: ignore[return-value]


# The names this module held before the server's split (0.4.0): found where they live now,
# with a warning; removed in 0.6.0 (docs/migration-0.4.md).
_MOVED = {
    "CSRF_HEADER": "middleware",
    "LOOPBACK_HOSTS": "middleware",
    "allowed_hosts_for": "middleware",
    "is_loopback": "middleware",
    "DEFAULT_MAX_UPLOAD": "dependencies",
    "MAX_TOP": "dependencies",
    "parse_size": "dependencies",
    "served_catalogue": "dependencies",
    "PAGES": "routers.pages",
    "parse_upload": "uploads",
}


def __getattr__(name: str) -> Any:
    if name not in _MOVED:
        raise AttributeError(f"module 'quatmotion.server.app' has no attribute {name!r}")
    home = f"quatmotion.server.{_MOVED[name]}"
    warnings.warn(
        f"quatmotion.server.app.{name} moved to {home}.{name} in 0.4.0 and goes in 0.6.0 "
        "(docs/migration-0.4.md)",
        DeprecationWarning,
        stacklevel=2,
    )
    return getattr(importlib.import_module(home), name)
