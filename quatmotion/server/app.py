"""The web app: pages to browse, play, compare and search a motion library, over a JSON API.

Conventions
-----------
* :func:`create_app` builds the application from the files it serves and its limits, so tests
  build it in-process (FastAPI's ``TestClient``) and ``quatmotion serve`` runs it with uvicorn.
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
* Every POST carries the header :data:`CSRF_HEADER` and no ``Origin``/``Sec-Fetch-Site`` of
  another site (:class:`CsrfGuard`); a bound loopback answers its host names only
  (:class:`HostCheck`, ``[::1]`` included).
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

import functools
import hashlib
import ipaddress
import logging
import sys
import time
from collections.abc import AsyncIterator, Sequence
from contextlib import asynccontextmanager
from importlib import resources
from pathlib import Path, PurePosixPath
from typing import Annotated, Any, Literal

from fastapi import APIRouter, Depends, FastAPI, HTTPException, Query, Request
from fastapi import Path as PathParam
from fastapi.exceptions import RequestValidationError
from fastapi.responses import HTMLResponse, JSONResponse
from fastapi.staticfiles import StaticFiles
from fastapi_offline import FastAPIOffline
from pydantic import BaseModel, Field
from starlette.concurrency import run_in_threadpool
from starlette.datastructures import UploadFile
from starlette.formparsers import MultiPartException, MultiPartParser
from starlette.types import ASGIApp, Message, Receive, Scope, Send

import quatmotion
from quatmotion.errors import FormatError
from quatmotion.io import MOTION_SUFFIXES, parse_motion
from quatmotion.motion import Motion
from quatmotion.server.building import LibraryBuild
from quatmotion.server.clips import (
    SORT_KEYS,
    ClipCatalogue,
    ClipNotFoundError,
    UnavailableError,
)
from quatmotion.server.uploads import UploadGate
from quatmotion.viz import frame_data
from quatmotion.viz.viewer import static_folder

__all__ = [
    "DEFAULT_MAX_UPLOAD",
    "LOOPBACK_HOSTS",
    "PAGES",
    "allowed_hosts_for",
    "create_app",
    "is_loopback",
    "parse_size",
]

DEFAULT_MAX_UPLOAD = 50_000_000
"""Largest request body, bytes (50 MB): an upload and its form fields."""

LOOPBACK_HOSTS = ("127.0.0.1", "localhost", "::1")
"""Host names a server bound to the loopback answers to (the defence against DNS rebinding:
a page of another site that resolves its own name to 127.0.0.1 is refused)."""

PAGES = ("browse", "play", "compare", "search", "poses")
"""The pages: ``/`` (browse) and ``/play``, ``/compare``, ``/search``, ``/poses``."""

# Each page is its <main> fragment (static/NAME.html) in the one layout (static/_layout.html):
# its title, and whether it shows the 3D viewer (which brings three.js and the viewer's files).
_PAGE_TITLES = {"browse": "library", "play": "play", "compare": "compare", "search": "search",
                "poses": "poses"}  # fmt: skip
_VIEWER_STYLE = '<link rel="stylesheet" href="/assets/viewer/viewer.css">\n'
_VIEWER_SCRIPTS = (
    '<script src="/assets/viewer/three.min.js"></script>\n'
    '<script src="/assets/viewer/viewer.js"></script>\n'
)

CSRF_HEADER = "X-Quatmotion-Request"
"""The header every POST must carry (any value; the pages send ``1``): the guard against
cross-site request forgery (:class:`CsrfGuard`)."""

_SAFE_METHODS = ("GET", "HEAD", "OPTIONS")
_log = logging.getLogger("quatmotion.server")
MAX_TOP = 200
_CLIP_ID = r"^[A-Za-z0-9_.~-]{1,120}$"
_PAGE_POLICY = (
    "default-src 'none'; script-src 'self'; style-src 'self' 'unsafe-inline'; "
    "img-src 'self' data: blob:; connect-src 'self'; base-uri 'none'; form-action 'self'; "
    "frame-ancestors 'none'"
)
_SIZE_UNITS = {
    "": 1,
    "b": 1,
    "k": 10**3,
    "kb": 10**3,
    "m": 10**6,
    "mb": 10**6,
    "g": 10**9,
    "gb": 10**9,
    "kib": 2**10,
    "mib": 2**20,
    "gib": 2**30,
}


# ---------------------------------------------------------------------------- small helpers
def parse_size(text: str) -> int:
    """Bytes of a size such as ``50MB``, ``500k``, ``2MiB`` or ``1000`` (MB = 10**6 bytes,
    MiB = 2**20); ``ValueError`` naming the text otherwise, or for less than one byte."""
    cleaned = text.strip().lower().replace(" ", "")
    number = cleaned.rstrip("bgikm")
    unit = cleaned[len(number) :]
    try:
        value = float(number) * _SIZE_UNITS[unit]
    except (KeyError, ValueError):
        raise ValueError(f"{text!r} is not a size (examples: 50MB, 500kB, 2MiB, 1000000)") from None
    if not value >= 1 or value != value or value == float("inf"):
        raise ValueError(f"a size must be at least one byte, got {text!r}")
    return int(value)


def is_loopback(host: str) -> bool:
    """Whether binding ``host`` serves this machine only (``localhost`` or a loopback
    address)."""
    if host.strip().lower() == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def allowed_hosts_for(host: str) -> tuple[str, ...]:
    """Host names the server answers to when bound to ``host``: the loopback names for a
    loopback address, anything otherwise (the user chose to be reachable)."""
    return LOOPBACK_HOSTS if is_loopback(host) else ("*",)


# ---------------------------------------------------------------------------- API models
class ClipModel(BaseModel):
    """A clip of the catalogue."""

    id: str = Field(description="The clip's address in the API.")
    name: str = Field(description="Its name (file stem).")
    label: str = Field(description="Its label from the index ('' if none).")
    frames: int
    fps: float
    duration_s: float
    compressed_bytes: int | None = Field(description="Its chunk in the .qmz library.")
    declared_max_error_cm: float | None = Field(
        description="Largest joint-position error the library declares for it, cm."
    )
    declared_arms_cm: float | None = Field(description="Its declared ARMS, cm.")
    in_library: bool
    in_index: bool
    in_poses: bool
    has_original: bool = Field(description="Its original file is available (for /compare).")


class ClipList(BaseModel):
    clips: list[ClipModel]
    labels: list[str] = Field(description="Every label in use, sorted.")
    sort: str
    order: Literal["asc", "desc"]


class InfoModel(BaseModel):
    """What the server serves."""

    version: str
    library: str | None = Field(description="File name of the .qmz library.")
    index: str | None = Field(description="File name of the .qidx index.")
    poses: str | None = Field(description="File name of the pose index.")
    clips: int
    methods: list[str] = Field(description="Search methods the index has features for.")
    default_method: str | None
    max_upload_bytes: int
    motion_suffixes: list[str]
    building: bool = Field(description="A library is being built: see /api/build.")


class BuildModel(BaseModel):
    """A library being built while the server answers (``quatmotion serve DIR``)."""

    state: Literal["none", "building", "ready", "failed", "stopped"]
    source: str = ""
    step: str = Field("", description="What it is doing (index, compress: encode, poses...).")
    done: int = 0
    total: int = 0
    served: list[str] = Field([], description="Stages served so far: index, library, poses.")
    clips: int = Field(0, description="Clips served now.")
    failed: list[str] = Field([], description="'file: reason' of each clip left out.")
    message: str = Field("", description="Why it failed.")
    seconds: float = 0.0


class SearchHitModel(BaseModel):
    rank: int
    id: str | None = Field(description="The clip's id (None if the catalogue lacks it).")
    clip: str
    label: str
    distance: float | None = Field(description="Smaller is closer; None where not computed.")


class SearchResponse(BaseModel):
    query: str = Field(description="The query clip's name.")
    query_id: str | None = Field(description="Its id when it is a clip of the catalogue.")
    method: str
    seconds: float = Field(description="Time the search took, s.")
    left_out: str | None = Field(
        None, description="The indexed clip the query is, left out of its results (None: none)."
    )
    results: list[SearchHitModel]
    query_clip: dict[str, Any] | None = Field(
        None, description="An uploaded query's frame data (quatmotion-frames/1), to play it."
    )


class PoseHitModel(BaseModel):
    rank: int
    id: str | None
    clip: str
    frame: int = Field(description="Frame in the clip, from 0.")
    seconds: float | None
    distance: float


class PoseResponse(BaseModel):
    clip: str = Field(description="The query clip's id.")
    frame: int = Field(description="The frame of the indexed pose used as the query.")
    results: list[PoseHitModel]


_UPLOAD_BODY = {
    "parameters": [
        {
            "name": CSRF_HEADER,
            "in": "header",
            "required": True,
            "schema": {"type": "string", "default": "1"},
            "description": "Any value: the guard against cross-site request forgery.",
        }
    ],
    "requestBody": {
        "required": True,
        "content": {
            "multipart/form-data": {
                "schema": {
                    "type": "object",
                    "required": ["file"],
                    "properties": {
                        "file": {
                            "type": "string",
                            "format": "binary",
                            "description": "The query clip: .amc, .bvh, .glb or .gltf.",
                        },
                        "asf": {
                            "type": "string",
                            "format": "binary",
                            "description": "The ASF skeleton of an .amc query (required then).",
                        },
                        "method": {"type": "string", "description": "Search method."},
                        "top": {"type": "integer", "minimum": 1, "maximum": MAX_TOP},
                    },
                }
            }
        },
    },
}


# ---------------------------------------------------------------------------- middleware
class BodySizeLimit:
    """ASGI middleware: a request body over ``max_bytes`` gets 413.

    A declared ``Content-Length`` over the limit is refused before anything is read; a body
    sent without one (chunked) is counted as it arrives and refused when it passes the limit.
    """

    def __init__(self, app: ASGIApp, max_bytes: int) -> None:
        self.app = app
        self.max_bytes = max_bytes
        self.message = f"request body larger than the server's limit of {max_bytes} bytes"

    def _too_large(self) -> JSONResponse:
        return JSONResponse({"detail": self.message}, status_code=413)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        declared = dict(scope["headers"]).get(b"content-length")
        if declared is not None:
            try:
                length = int(declared)
            except ValueError:
                length = -1
            if length < 0:
                response = JSONResponse({"detail": "malformed Content-Length"}, status_code=400)
                await response(scope, receive, send)
                return
            if length > self.max_bytes:
                await self._too_large()(scope, receive, send)
                return
        received = 0
        started = False

        async def counted() -> Message:
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > self.max_bytes:
                    raise HTTPException(413, self.message)
            return message

        async def watched(message: Message) -> None:
            nonlocal started
            started = started or message["type"] == "http.response.start"
            await send(message)

        try:
            await self.app(scope, counted, watched)
        except HTTPException as error:
            if error.status_code != 413 or started:
                raise
            await self._too_large()(scope, receive, send)


class SecurityHeaders:
    """ASGI middleware: ``nosniff`` and no referrer on every response."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        async def with_headers(message: Message) -> None:
            if message["type"] == "http.response.start":
                headers = list(message.get("headers", []))
                headers += [
                    (b"x-content-type-options", b"nosniff"),
                    (b"referrer-policy", b"no-referrer"),
                ]
                message = {**message, "headers": headers}
            await send(message)

        await self.app(scope, receive, with_headers if scope["type"] == "http" else send)


def host_name(header: str) -> str:
    """The host name of a ``Host`` header, lower-case, without its port: ``[::1]:8000`` ->
    ``::1``, ``localhost:8000`` -> ``localhost``."""
    text = header.strip().lower()
    if text.startswith("["):
        return text[1 : text.find("]")] if "]" in text else ""
    return text.rsplit(":", 1)[0] if text.count(":") == 1 else text


class HostCheck:
    """ASGI middleware: a request whose ``Host`` is not one of ``allowed`` gets 400 (the
    defence against DNS rebinding); ``("*",)`` allows any. IPv6 hosts come bracketed
    (``[::1]:8000``)."""

    def __init__(self, app: ASGIApp, allowed: Sequence[str]) -> None:
        self.app = app
        self.any = "*" in allowed
        self.allowed = {host_name(h) if h.startswith("[") else h.lower() for h in allowed}

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] in ("http", "websocket") and not self.any:
            header = dict(scope["headers"]).get(b"host", b"").decode("latin-1")
            if host_name(header) not in self.allowed:
                response = JSONResponse({"detail": "invalid host header"}, status_code=400)
                await response(scope, receive, send)
                return
        await self.app(scope, receive, send)


class CsrfGuard:
    """ASGI middleware: a request that may change something (any method but GET, HEAD and
    OPTIONS) gets 403 unless it carries the header :data:`CSRF_HEADER` and nothing says it
    comes from another site (``Sec-Fetch-Site`` other than ``same-origin``/``none``, or an
    ``Origin`` other than the server's own).

    A form of another site, posted to the server by the browser of a person who visits it,
    can set neither that header nor its own origin; the app's pages send the header.
    """

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "http" and scope["method"] not in _SAFE_METHODS:
            reason = self._refused(dict(scope["headers"]))
            if reason:
                await JSONResponse({"detail": reason}, status_code=403)(scope, receive, send)
                return
        await self.app(scope, receive, send)

    @staticmethod
    def _refused(headers: dict[bytes, bytes]) -> str:
        site = headers.get(b"sec-fetch-site", b"").decode("latin-1").lower()
        if site and site not in ("same-origin", "none"):
            return f"cross-site request refused (Sec-Fetch-Site: {site})"
        origin = headers.get(b"origin")
        if origin is not None:
            own = headers.get(b"host", b"").decode("latin-1").lower()
            given = origin.decode("latin-1").lower()
            if given.partition("://")[2] != own:
                return f"cross-origin request refused (Origin: {given[:100]})"
        if not headers.get(CSRF_HEADER.lower().encode()):
            return (
                f"a {CSRF_HEADER} header is required on this request (the app's pages send it; "
                "another site's form cannot)"
            )
        return ""


class _InMemoryMultiPartParser(MultiPartParser):
    # Starlette spools file parts over 1 MB to a temporary file; an upload here stays in
    # memory (the body limit bounds it), so nothing of it is ever written to disk.
    spool_max_size = sys.maxsize


# ---------------------------------------------------------------------------- the app
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
    """The web app serving a motion library.

    Parameters
    ----------
    library : path, optional
        A ``.qmz`` library: browse, play, compare with the originals.
    index : path, optional
        A ``.qidx`` index: labels, originals, search by example. At least one of ``library``
        and ``index``.
    poses : path, optional
        A pose index (``quatmotion pose index``): pose search.
    max_upload : int, keyword-only
        Largest request body, bytes (an upload with its form fields); 413 beyond it.
    allowed_hosts : sequence of str, keyword-only
        Host names (the ``Host`` header) the app answers; others get 400. ``("*",)`` for any.
        The default suits a server bound to the loopback (:func:`allowed_hosts_for`).
    build : LibraryBuild, keyword-only, optional
        A library to build (:mod:`quatmotion.server.building`), instead of files: the app
        starts it when it starts, serves each of its files as it is complete, and stops it
        when it shuts down.
    uploads : UploadGate, keyword-only, optional
        How many uploads are taken at once and the memory their parsing may use
        (:class:`~quatmotion.server.uploads.UploadGate`; its defaults when None).

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

    def close() -> None:
        if catalogue is not None:
            catalogue.close()
        if build is not None:
            build.stop()

    @asynccontextmanager
    async def lifespan(_app: FastAPI) -> AsyncIterator[None]:
        if build is not None:
            build.start()  # once the server answers: its first pages come before the work
        yield
        close()

    try:
        app = FastAPIOffline(
            title="quatmotion",
            version=quatmotion.__version__,
            summary="Browse, play, compare and search a motion-capture library.",
            static_url="/assets/docs",
            lifespan=lifespan,
        )
        app.state.catalogue = catalogue
        app.state.build = build
        app.state.uploads = uploads or UploadGate()
        # Added last is outermost: the Host check, the CSRF guard, the body limit, then
        # the headers.
        app.add_middleware(SecurityHeaders)
        app.add_middleware(BodySizeLimit, max_bytes=max_upload)
        app.add_middleware(CsrfGuard)
        app.add_middleware(HostCheck, allowed=list(allowed_hosts))
        _add_error_handlers(app)
        app.state.max_upload = max_upload
        _mount_assets(app)
        for router in (pages_router, clips_router, search_router, poses_router):
            app.include_router(router)
    except BaseException:
        close()
        raise
    return app


def served_catalogue(app: FastAPI) -> ClipCatalogue:
    """The catalogue ``app`` serves now: its files', or its build's so far."""
    build: LibraryBuild | None = app.state.build
    return build.catalogue if build is not None else app.state.catalogue  # type: ignore[no-any-return]


def _error(status: int, message: object) -> JSONResponse:
    text = str(message).strip()
    return JSONResponse({"detail": text.splitlines()[0] if text else "error"}, status_code=status)


def _add_error_handlers(app: FastAPI) -> None:
    @app.exception_handler(RequestValidationError)
    async def invalid(_request: Request, error: RequestValidationError) -> JSONResponse:
        first = error.errors()[0] if error.errors() else {}
        where = ".".join(str(p) for p in first.get("loc", ()) if p not in ("path", "query"))
        return _error(400, f"{where}: {first.get('msg', 'invalid request')}")

    def missing(request: Request, error: Exception) -> JSONResponse:
        # While a build runs, what is missing may come: 503, try again (not 404, not there).
        build: LibraryBuild | None = request.app.state.build
        if build is not None and build.running:
            response = _error(503, f"{error} (the library is still being built: {build.where()})")
            response.headers["retry-after"] = "2"
            return response
        return _error(404, error)

    app.add_exception_handler(ClipNotFoundError, missing)  # type: ignore[arg-type]
    app.add_exception_handler(UnavailableError, missing)  # type: ignore[arg-type]

    @app.exception_handler(ValueError)  # FormatError included: bad input, the parser's line
    async def bad_input(_request: Request, error: ValueError) -> JSONResponse:
        return _error(400, error)


def _page(layout: str, name: str, fragment: Any) -> str:
    """Page ``name``: its ``<main>`` fragment in the layout, with the viewer's files if it uses
    the viewer (any page that has a ``#viewer`` element)."""
    main = fragment.read_text(encoding="utf-8")
    viewer = 'id="viewer"' in main
    return layout.format(
        title=_PAGE_TITLES[name],
        page=name,
        main=main,
        viewer_style=_VIEWER_STYLE if viewer else "",
        viewer_scripts=_VIEWER_SCRIPTS if viewer else "",
    )


def _mount_assets(app: FastAPI) -> None:
    pages = resources.files("quatmotion.server").joinpath("static")
    app.mount("/assets/app", StaticFiles(directory=str(pages)), name="app-assets")
    app.mount("/assets/viewer", StaticFiles(directory=str(static_folder())), name="viewer-assets")


@functools.cache
def _page_texts() -> dict[str, str]:
    """Every page's HTML, made once per process from the packaged fragments and layout."""
    pages = resources.files("quatmotion.server").joinpath("static")
    layout = pages.joinpath("_layout.html").read_text(encoding="utf-8")
    return {name: _page(layout, name, pages.joinpath(f"{name}.html")) for name in PAGES}


pages_router = APIRouter(include_in_schema=False)


def _page_endpoint(name: str) -> Any:
    def endpoint() -> HTMLResponse:
        return HTMLResponse(_page_texts()[name], headers={"content-security-policy": _PAGE_POLICY})

    endpoint.__doc__ = f"The {name} page."
    return endpoint


for _name in PAGES:
    pages_router.add_api_route(
        "/" if _name == "browse" else f"/{_name}",
        _page_endpoint(_name),
        methods=["GET"],
        name=f"page-{_name}",
    )


ClipId = Annotated[str, PathParam(pattern=_CLIP_ID, description="A clip id.")]
QueryClipId = Annotated[str, Query(pattern=_CLIP_ID, description="A clip id.")]


def get_catalogue(request: Request) -> ClipCatalogue:
    """The catalogue the app serves (a dependency of every API route)."""
    return served_catalogue(request.app)


def get_max_upload(request: Request) -> int:
    """The app's largest request body, bytes."""
    return int(request.app.state.max_upload)


Catalogue = Annotated[ClipCatalogue, Depends(get_catalogue)]
MaxUpload = Annotated[int, Depends(get_max_upload)]

# The API by area; create_app includes them.
clips_router = APIRouter()
search_router = APIRouter()
poses_router = APIRouter()


def clip_model(info: Any) -> ClipModel:
    """The API model of a :class:`ClipInfo`."""
    return ClipModel(**info.as_dict())


@clips_router.get("/api/info", response_model=InfoModel, tags=["library"])
def info(request: Request, catalogue: Catalogue, max_upload: MaxUpload) -> InfoModel:
    """What the server serves: its files (names only), clip count, search methods, limits."""
    build: LibraryBuild | None = request.app.state.build
    return InfoModel(
        version=quatmotion.__version__,
        library=catalogue.library_path.name if catalogue.library_path else None,
        index=catalogue.index_path.name if catalogue.index_path else None,
        poses=catalogue.poses_path.name if catalogue.poses_path else None,
        clips=len(catalogue),
        methods=list(catalogue.methods),
        default_method=catalogue.methods[0] if catalogue.methods else None,
        max_upload_bytes=max_upload,
        motion_suffixes=list(MOTION_SUFFIXES),
        building=build is not None and build.running,
    )


@clips_router.get("/api/build", response_model=BuildModel, tags=["library"])
def build_status(request: Request) -> BuildModel:
    """Where the library the server was started to build is (``quatmotion serve DIR``):
    its step, the stages served so far, the clips left out. ``state`` is ``none`` for a
    server started with its files."""
    build: LibraryBuild | None = request.app.state.build
    if build is None:
        return BuildModel(state="none")
    return BuildModel(**build.status())


@clips_router.get("/api/clips", response_model=ClipList, tags=["library"])
def clips(
    catalogue: Catalogue,
    label: Annotated[str | None, Query(max_length=200, description="Only this label.")] = None,
    sort: Annotated[
        Literal[SORT_KEYS],  # type: ignore[valid-type]
        Query(description="Column to sort by."),
    ] = "name",
    order: Annotated[Literal["asc", "desc"], Query()] = "asc",
) -> ClipList:
    """The clips, filtered by label and sorted by any column (missing values last)."""
    rows = catalogue.clips(label=label, sort=sort, descending=order == "desc")
    return ClipList(
        clips=[clip_model(r) for r in rows], labels=catalogue.labels(), sort=sort, order=order
    )


@clips_router.get("/api/clips/{clip_id}", response_model=ClipModel, tags=["library"])
def clip(clip_id: ClipId, catalogue: Catalogue) -> ClipModel:
    """One clip."""
    return clip_model(catalogue.info(clip_id))


@clips_router.get("/api/clips/{clip_id}/frames", tags=["viewer"])
def frames(
    clip_id: ClipId,
    catalogue: Catalogue,
    start: Annotated[int | None, Query(ge=0, description="First frame (from 0).")] = None,
    stop: Annotated[int | None, Query(ge=1, description="Frame after the last.")] = None,
) -> dict[str, Any]:
    """A clip's frame data for the viewer (``quatmotion-frames/1``: joint and end-site
    positions, cm, compact), decoded from the library or read from its original file;
    ``start``/``stop`` select frames. Show it with ``QuatmotionViewer.show(element,
    {clips: [payload]})``."""
    return catalogue.frames(clip_id, start, stop)


@clips_router.get("/api/clips/{clip_id}/compare", tags=["viewer"])
def compare(clip_id: ClipId, catalogue: Catalogue) -> dict[str, Any]:
    """The viewer document of a clip's original file (blue) beside its decoded version
    (green) with the per-joint error (``quatmotion.viz.view_data``); 404 when the clip is
    not in the library or its original is not available."""
    return catalogue.comparison(clip_id)


@search_router.get("/api/search", response_model=SearchResponse, tags=["search"])
def search_clip(
    clip: QueryClipId,
    catalogue: Catalogue,
    method: Annotated[str | None, Query(max_length=64)] = None,
    top: Annotated[int, Query(ge=1, le=MAX_TOP)] = 20,
) -> SearchResponse:
    """Rank the indexed clips by likeness to an indexed clip (left out of its results)."""
    started = time.perf_counter()
    used, hits, own = catalogue.search(clip, method=method, top=top)
    return SearchResponse(
        query=catalogue.info(clip).name,
        query_id=clip,
        method=used,
        seconds=time.perf_counter() - started,
        left_out=own,
        results=[SearchHitModel(**h.__dict__) for h in hits],
    )


@search_router.post(
    "/api/search/upload",
    response_model=SearchResponse,
    tags=["search"],
    openapi_extra=_UPLOAD_BODY,
)
async def search_upload(request: Request, catalogue: Catalogue) -> SearchResponse:
    """Rank the indexed clips by likeness to an uploaded clip (multipart form: ``file``,
    an .amc, .bvh, .glb or .gltf; ``asf``, the skeleton an .amc needs; ``method``; ``top``).
    The upload is parsed in memory and not kept; a file the parser rejects gets 400 with its
    message. Requests need the header ``X-Quatmotion-Request`` (403 without). One upload at a
    time per client (429), a few at once overall (503), parsed under a memory budget (413 for
    a file that alone needs more)."""
    gate: UploadGate = request.app.state.uploads
    with gate.admitted(request.client.host if request.client else ""):
        declared = request.headers.get("content-length", "")
        if declared.isdigit():  # a body no reading of which fits the budget: refused unread
            gate.check(gate.least_cost(int(declared)), "an upload of this size")
        form = await _read_form(request)
        upload = form.get("file")
        if not isinstance(upload, UploadFile):
            raise HTTPException(400, "the form needs a 'file' field holding a motion file")
        asf = form.get("asf")
        if asf is not None and not isinstance(asf, UploadFile):
            raise HTTPException(400, "the 'asf' field must be a file (the ASF skeleton)")
        method = form.get("method") or None
        top = _form_int(form.get("top"), "top", 20, 1, MAX_TOP)
        name = _upload_name(upload.filename, MOTION_SUFFIXES)
        asf_name = _upload_name(asf.filename, (".asf",)) if asf is not None else "skeleton.asf"
        data = await upload.read()
        asf_data = await asf.read() if asf is not None else None
        await form.close()
        if name.lower().endswith(".amc") and asf_data is None:
            raise HTTPException(
                400,
                f"{name}: an AMC holds no skeleton; upload its ASF file too (form field 'asf')",
            )
        cost = gate.cost(name, len(data)) + gate.cost(asf_name, len(asf_data or b""))
        gate.check(cost, name)
        return await run_in_threadpool(
            _search_upload, catalogue, gate, cost, data, name, asf_data, asf_name, method, top
        )


@poses_router.get("/api/poses", response_model=PoseResponse, tags=["search"])
def pose_search(
    clip: QueryClipId,
    catalogue: Catalogue,
    frame: Annotated[int, Query(ge=0, description="Frame of the clip, from 0.")],
    k: Annotated[int, Query(ge=1, le=MAX_TOP, description="Poses wanted.")] = 10,
    other_clips: Annotated[bool, Query(description="Leave out the clip's own poses.")] = False,
) -> PoseResponse:
    """The poses nearest to a frame of a clip, under the pose index's learned distance."""
    found, hits = catalogue.pose_search(clip, frame, k=k, other_clips=other_clips)
    return PoseResponse(clip=clip, frame=found, results=[PoseHitModel(**h.__dict__) for h in hits])


async def _read_form(request: Request) -> Any:
    """The multipart form of ``request``, every part in memory (400 when malformed)."""
    content_type = request.headers.get("content-type", "")
    if not content_type.lower().startswith("multipart/form-data"):
        raise HTTPException(
            400, "expected a multipart/form-data upload with a 'file' field (.amc or .bvh)"
        )
    parser = _InMemoryMultiPartParser(
        request.headers, request.stream(), max_files=2, max_fields=8, max_part_size=4096
    )
    try:
        return await parser.parse()
    except MultiPartException as error:
        raise HTTPException(400, f"malformed upload: {error.message}") from None


def _form_int(value: object, name: str, default: int, low: int, high: int) -> int:
    if value is None or value == "":
        return default
    try:
        number = int(str(value))
    except ValueError:
        raise HTTPException(400, f"{name} must be an integer, got {str(value)[:40]!r}") from None
    if not low <= number <= high:
        raise HTTPException(400, f"{name} must lie in {low}..{high}, got {number}")
    return number


def _upload_name(filename: str | None, suffixes: Sequence[str]) -> str:
    """The base name of an uploaded file (for messages and the clip's name; never opened),
    checked against ``suffixes``."""
    base = PurePosixPath((filename or "").replace("\\", "/")).name.strip()[:120]
    if not base:
        raise HTTPException(400, f"an uploaded file needs a name ending in {', '.join(suffixes)}")
    if not base.lower().endswith(tuple(suffixes)):
        raise HTTPException(400, f"{base}: unknown file type (expected {' or '.join(suffixes)})")
    return base


def _search_upload(
    catalogue: ClipCatalogue,
    gate: UploadGate,
    cost: int,
    data: bytes,
    name: str,
    asf_data: bytes | None,
    asf_name: str,
    method: str | None,
    top: int,
) -> SearchResponse:
    """Parse an upload under the memory budget and search with it (in a worker thread)."""
    started = time.perf_counter()
    with gate.parsing(cost):
        motion = parse_upload(data, name, asf_data, asf_name)
        # the file's content_hash (an AMC's with its ASF's bytes), its identity in the index
        digest = hashlib.sha256(data)
        if name.lower().endswith(".amc") and asf_data is not None:
            digest.update(asf_data)
        del data, asf_data
        used, hits, own = catalogue.search(
            motion, method=method, top=top, sha256=digest.hexdigest()
        )
        query_clip = frame_data.encode_clip(motion)
    return SearchResponse(
        query=motion.name,
        query_id=None,
        method=used,
        seconds=time.perf_counter() - started,
        left_out=own,
        results=[SearchHitModel(**h.__dict__) for h in hits],
        query_clip=query_clip,
    )


def parse_upload(
    data: bytes, name: str, asf_data: bytes | None = None, asf_name: str = "skeleton.asf"
) -> Motion:
    """An uploaded motion file parsed (:func:`quatmotion.io.parse_motion`), every error of
    the file an ``HTTPException`` with a 4xx and one line: the reader's message (400), a
    file too deep or too large for the parser (413), a kind of file whose optional reader is
    not installed (415), any other failure of the reader on these bytes (400, naming the
    error's kind). Nothing the file holds makes a 500."""
    try:
        return parse_motion(data, name, asf_data, asf_name)
    except FormatError as error:  # a limit of quatmotion.limits included; names its file
        raise HTTPException(400, _one_line(error, "" if error.path else name)) from None
    except ValueError as error:
        raise HTTPException(400, _one_line(error, name)) from None
    except (MemoryError, RecursionError) as error:
        raise HTTPException(
            413, f"{name}: too large or too deeply nested to parse ({type(error).__name__})"
        ) from None
    except ImportError as error:  # an optional reader not installed here: the server's lack
        raise HTTPException(415, f"{name}: this server cannot read it ({error})") from None
    except Exception as error:  # a reader's fault on odd bytes is still the file's answer
        _log.warning("upload %s: the reader failed", name, exc_info=True)
        raise HTTPException(
            400, f"{name}: cannot be read ({type(error).__name__}: {_one_line(error, '')})"
        ) from None


def _one_line(error: BaseException, name: str) -> str:
    lines = str(error).strip().splitlines()
    text = lines[0] if lines else type(error).__name__
    return text if not name or text.startswith(name) else f"{name}: {text}"
