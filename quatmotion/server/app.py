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
  before reading when the request declares its length).
* Errors are JSON ``{"detail": "<one line>"}``: 400 for a bad request (malformed or invalid
  parameters, an upload the parsers reject, with their message), 404 for an unknown clip or
  something the server was not started with, 413 for a body over the limit.
* Work that takes time (decoding, searching, parsing an upload) runs in the thread pool, off
  the event loop, so the server answers other requests meanwhile.
"""

from __future__ import annotations

import functools
import hashlib
import ipaddress
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
from starlette.middleware.trustedhost import TrustedHostMiddleware
from starlette.types import ASGIApp, Message, Receive, Scope, Send

import quatmotion
from quatmotion.errors import FormatError
from quatmotion.io import MOTION_SUFFIXES, parse_motion
from quatmotion.server.clips import (
    SORT_KEYS,
    ClipCatalogue,
    ClipNotFoundError,
    UnavailableError,
)
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
                            "description": "The query clip: an .amc or .bvh file.",
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
    }
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

    Returns
    -------
    fastapi.FastAPI
        Its files are open until the app shuts down (the ``lifespan``), or until
        ``app.state.catalogue.close()``.

    Raises
    ------
    ValueError
        Neither a library nor an index, or a limit below one byte.
    FileNotFoundError, FormatError
        A file missing or not of its format (naming it).
    """
    if max_upload < 1:
        raise ValueError(f"max_upload must be at least 1 byte, got {max_upload}")
    catalogue = ClipCatalogue.open(library, index, poses)

    @asynccontextmanager
    async def lifespan(_app: FastAPI) -> AsyncIterator[None]:
        yield
        catalogue.close()

    try:
        app = FastAPIOffline(
            title="quatmotion",
            version=quatmotion.__version__,
            summary="Browse, play, compare and search a motion-capture library.",
            static_url="/assets/docs",
            lifespan=lifespan,
        )
        app.state.catalogue = catalogue
        # Added last is outermost: the Host check, then the body limit, then the headers.
        app.add_middleware(SecurityHeaders)
        app.add_middleware(BodySizeLimit, max_bytes=max_upload)
        app.add_middleware(TrustedHostMiddleware, allowed_hosts=list(allowed_hosts))
        _add_error_handlers(app)
        app.state.max_upload = max_upload
        _mount_assets(app)
        for router in (pages_router, clips_router, search_router, poses_router):
            app.include_router(router)
    except BaseException:
        catalogue.close()
        raise
    return app


def _error(status: int, message: object) -> JSONResponse:
    text = str(message).strip()
    return JSONResponse({"detail": text.splitlines()[0] if text else "error"}, status_code=status)


def _add_error_handlers(app: FastAPI) -> None:
    @app.exception_handler(RequestValidationError)
    async def invalid(_request: Request, error: RequestValidationError) -> JSONResponse:
        first = error.errors()[0] if error.errors() else {}
        where = ".".join(str(p) for p in first.get("loc", ()) if p not in ("path", "query"))
        return _error(400, f"{where}: {first.get('msg', 'invalid request')}")

    @app.exception_handler(ClipNotFoundError)
    async def not_found(_request: Request, error: ClipNotFoundError) -> JSONResponse:
        return _error(404, error)

    @app.exception_handler(UnavailableError)
    async def unavailable(_request: Request, error: UnavailableError) -> JSONResponse:
        return _error(404, error)

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
    return request.app.state.catalogue  # type: ignore[no-any-return]


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
def info(catalogue: Catalogue, max_upload: MaxUpload) -> InfoModel:
    """What the server serves: its files (names only), clip count, search methods, limits."""
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
    )


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
    an .amc or .bvh; ``asf``, the skeleton an .amc needs; ``method``; ``top``). The
    upload is parsed in memory and not kept; a file the parser rejects gets 400 with its
    message."""
    form = await _read_form(request)
    upload = form.get("file")
    if not isinstance(upload, UploadFile):
        raise HTTPException(400, "the form needs a 'file' field holding an .amc or .bvh file")
    asf = form.get("asf")
    if asf is not None and not isinstance(asf, UploadFile):
        raise HTTPException(400, "the 'asf' field must be a file (the ASF skeleton)")
    method = form.get("method") or None
    top = _form_int(form.get("top"), "top", 20, 1, MAX_TOP)
    name = _upload_name(upload.filename, MOTION_SUFFIXES)
    asf_name = _upload_name(asf.filename, (".asf",)) if asf is not None else "skeleton.asf"
    data = await upload.read()
    asf_data = await asf.read() if asf is not None else None
    if name.lower().endswith(".amc") and asf_data is None:
        raise HTTPException(
            400,
            f"{name}: an AMC holds no skeleton; upload its ASF file too (form field 'asf')",
        )
    return await run_in_threadpool(
        _search_upload, catalogue, data, name, asf_data, asf_name, method, top
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
    data: bytes,
    name: str,
    asf_data: bytes | None,
    asf_name: str,
    method: str | None,
    top: int,
) -> SearchResponse:
    """Parse an upload and search with it (in a worker thread)."""
    started = time.perf_counter()
    try:
        motion = parse_motion(data, name, asf_data, asf_name)
    except FormatError as error:
        raise HTTPException(400, str(error).splitlines()[0]) from None
    # the file's content_hash (an AMC's with its ASF's bytes), its identity in the index
    digest = hashlib.sha256(data)
    if name.lower().endswith(".amc") and asf_data is not None:
        digest.update(asf_data)
    sha256 = digest.hexdigest()
    used, hits, own = catalogue.search(motion, method=method, top=top, sha256=sha256)
    return SearchResponse(
        query=motion.name,
        query_id=None,
        method=used,
        seconds=time.perf_counter() - started,
        left_out=own,
        results=[SearchHitModel(**h.__dict__) for h in hits],
        query_clip=frame_data.encode_clip(motion),
    )
