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
* An upload's multipart form is read in memory (:func:`read_form`, never spooled to disk) with
  few parts, each form field short.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import PurePosixPath
from typing import Annotated, Any

from fastapi import Depends, FastAPI, HTTPException, Query, Request
from fastapi import Path as PathParam
from starlette.formparsers import MultiPartException, MultiPartParser

from quatmotion.server.building import LibraryBuild
from quatmotion.server.clips import ClipCatalogue
from quatmotion.server.uploads import UploadGate

__all__ = [
    "CLIP_ID",
    "DEFAULT_MAX_UPLOAD",
    "MAX_TOP",
    "Build",
    "Catalogue",
    "ClipId",
    "MaxUpload",
    "QueryClipId",
    "Uploads",
    "form_int",
    "parse_size",
    "read_form",
    "served_catalogue",
    "upload_name",
]

DEFAULT_MAX_UPLOAD = 50_000_000
"""Largest request body, bytes (50 MB): an upload and its form fields."""

MAX_TOP = 200
"""Most results a search or a pose search answers with."""

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
class _InMemoryMultiPartParser(MultiPartParser):
    # Starlette spools file parts over 1 MB to a temporary file; an upload here stays in
    # memory (the body limit bounds it), so nothing of it is ever written to disk.
    spool_max_size = sys.maxsize


async def read_form(request: Request) -> Any:
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


def form_int(value: object, name: str, default: int, low: int, high: int) -> int:
    """A form field's integer (``default`` when absent), 400 unless in ``low..high``."""
    if value is None or value == "":
        return default
    try:
        number = int(str(value))
    except ValueError:
        raise HTTPException(400, f"{name} must be an integer, got {str(value)[:40]!r}") from None
    if not low <= number <= high:
        raise HTTPException(400, f"{name} must lie in {low}..{high}, got {number}")
    return number


def upload_name(filename: str | None, suffixes: Sequence[str]) -> str:
    """The base name of an uploaded file (for messages and the clip's name; never opened),
    checked against ``suffixes``."""
    base = PurePosixPath((filename or "").replace("\\", "/")).name.strip()[:120]
    if not base:
        raise HTTPException(400, f"an uploaded file needs a name ending in {', '.join(suffixes)}")
    if not base.lower().endswith(tuple(suffixes)):
        raise HTTPException(400, f"{base}: unknown file type (expected {' or '.join(suffixes)})")
    return base
