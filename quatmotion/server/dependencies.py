"""What the web app's routes are given (FastAPI dependencies): the app's state, its limits,
the clip ids a request may name and the reading of an upload's form.

Conventions
-----------
* The state lives on ``app.state`` (set by :func:`quatmotion.server.app.create_app`):
  ``catalogue`` (files served) or ``build`` (a library being built), ``max_upload`` (bytes)
  and ``uploads`` (:class:`~quatmotion.server.uploads.UploadGate`). Routes take it through
  :data:`Catalogue`, :data:`Build`, :data:`MaxUpload` and :data:`Uploads`, never from a
  module global, so tests build apps side by side.
* A clip id is checked against :data:`CLIP_ID` before a route sees it (:data:`ClipId` in a
  path, :data:`QueryClipId` in a query); no request value ever becomes a path.
* A route taking an upload is an :class:`UploadRoute`: its client admitted before the body is
  read, its multipart form read in memory (never spooled to disk) with few parts, each form
  field short; the form's fields are the endpoint's parameters, so FastAPI checks them and
  states them in the API's schema.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Coroutine, Sequence
from pathlib import PurePosixPath
from typing import Annotated, Any

from fastapi import Depends, FastAPI, Header, HTTPException, Query, Request, Response
from fastapi import Path as PathParam
from fastapi.routing import APIRoute
from starlette.datastructures import FormData
from starlette.formparsers import MultiPartException, MultiPartParser

from quatmotion.server.building import LibraryBuild
from quatmotion.server.clips import ClipCatalogue
from quatmotion.server.middleware import CSRF_HEADER
from quatmotion.server.uploads import UploadGate

__all__ = [
    "CLIP_ID",
    "DEFAULT_MAX_UPLOAD",
    "MAX_TOP",
    "Build",
    "Catalogue",
    "ClipId",
    "MaxUpload",
    "TOP_RANGE",
    "QueryClipId",
    "UploadRoute",
    "Uploads",
    "parse_size",
    "require_csrf_header",
    "served_catalogue",
    "upload_name",
]

DEFAULT_MAX_UPLOAD = 50_000_000
"""Largest request body, bytes (50 MB): an upload and its form fields."""

MAX_TOP = 200
"""Most results a search or a pose search answers with."""

TOP_RANGE: dict[str, Any] = {"ge": 1, "le": MAX_TOP}
"""The range of a search's number of results, as the one place the routes read it from
(``Query(**TOP_RANGE)``, ``Form(**TOP_RANGE)``); FastAPI checks it (400) and states it in
the API's schema."""

CLIP_ID = r"^[A-Za-z0-9_.~-]{1,120}$"
"""What a clip id is (made from its name by the catalogue, :mod:`quatmotion.server.clips`)."""

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


# ---------------------------------------------------------------------------- the app's state
def served_catalogue(app: FastAPI) -> ClipCatalogue:
    """The catalogue ``app`` serves now: its files', or its build's so far."""
    build: LibraryBuild | None = app.state.build
    return build.catalogue if build is not None else app.state.catalogue  # type: ignore[no-any-return]


def get_catalogue(request: Request) -> ClipCatalogue:
    """The catalogue the app serves (a dependency of every API route)."""
    return served_catalogue(request.app)


def get_build(request: Request) -> LibraryBuild | None:
    """The library the app was started to build (None: it serves files)."""
    return request.app.state.build  # type: ignore[no-any-return]


def get_max_upload(request: Request) -> int:
    """The app's largest request body, bytes."""
    return int(request.app.state.max_upload)


def get_uploads(request: Request) -> UploadGate:
    """The admission and memory budget of the app's uploads."""
    return request.app.state.uploads  # type: ignore[no-any-return]


Catalogue = Annotated[ClipCatalogue, Depends(get_catalogue)]
Build = Annotated[LibraryBuild | None, Depends(get_build)]
MaxUpload = Annotated[int, Depends(get_max_upload)]
Uploads = Annotated[UploadGate, Depends(get_uploads)]
ClipId = Annotated[str, PathParam(pattern=CLIP_ID, description="A clip id.")]
QueryClipId = Annotated[str, Query(pattern=CLIP_ID, description="A clip id.")]


# ---------------------------------------------------------------------------- an upload's form
def require_csrf_header(
    _value: Annotated[
        str,
        Header(
            alias=CSRF_HEADER,
            description="Any value: the guard against cross-site request forgery.",
            examples=["1"],
        ),
    ],
) -> None:
    """The header a POST carries (checked by :class:`~quatmotion.server.middleware.CsrfGuard`
    before the body is read; declared here so that the API's schema states it)."""


class _InMemoryMultiPartParser(MultiPartParser):
    # Starlette spools file parts over 1 MB to a temporary file; an upload here stays in
    # memory (the body limit bounds it), so nothing of it is ever written to disk.
    spool_max_size = sys.maxsize


class _InMemoryFormRequest(Request):
    """A request whose multipart form is read in memory, with few parts and short fields."""

    def form(self, **_limits: Any) -> Any:  # FastAPI awaits it before the endpoint runs
        return self._in_memory_form()

    async def _in_memory_form(self) -> FormData:
        content_type = self.headers.get("content-type", "")
        if not content_type.lower().startswith("multipart/form-data"):
            raise HTTPException(
                400, "expected a multipart/form-data upload with a 'file' field (.amc or .bvh)"
            )
        parser = _InMemoryMultiPartParser(
            self.headers, self.stream(), max_files=2, max_fields=8, max_part_size=4096
        )
        try:
            return await parser.parse()
        except MultiPartException as error:
            raise HTTPException(400, f"malformed upload: {error.message}") from None


class UploadRoute(APIRoute):
    """A route taking an upload (module conventions): the client admitted by the app's
    :class:`~quatmotion.server.uploads.UploadGate` (429, 503) and a declared body no reading
    of which fits the parsing budget refused (413) before the body is read; its multipart
    form read in memory; the slot held until the answer."""

    def get_route_handler(self) -> Callable[[Request], Coroutine[Any, Any, Response]]:
        handler = super().get_route_handler()

        async def admitted(request: Request) -> Response:
            gate: UploadGate = request.app.state.uploads
            with gate.admitted(request.client.host if request.client else ""):
                declared = request.headers.get("content-length", "")
                if declared.isdigit():
                    gate.check(gate.least_cost(int(declared)), "an upload of this size")
                return await handler(_InMemoryFormRequest(request.scope, request.receive))

        return admitted


def upload_name(filename: str | None, suffixes: Sequence[str]) -> str:
    """The base name of an uploaded file (for messages and the clip's name; never opened),
    checked against ``suffixes``."""
    base = PurePosixPath((filename or "").replace("\\", "/")).name.strip()[:120]
    if not base:
        raise HTTPException(400, f"an uploaded file needs a name ending in {', '.join(suffixes)}")
    if not base.lower().endswith(tuple(suffixes)):
        raise HTTPException(400, f"{base}: unknown file type (expected {' or '.join(suffixes)})")
    return base
