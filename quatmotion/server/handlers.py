"""The web app's exception handlers: every error a JSON ``{"detail": "<one line>"}``.

A request FastAPI finds invalid (a path or query value) is 400 naming the field; a clip or
a file the server does not have is 404, or 503 with ``Retry-After`` while a library is being
built (it may still come); any other ``ValueError`` (``FormatError`` included) is bad input,
400 with its first line.
"""

from __future__ import annotations

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse

from quatmotion.server.building import LibraryBuild
from quatmotion.server.clips import ClipNotFoundError, UnavailableError

__all__ = ["add_error_handlers", "error_response"]


def error_response(status: int, message: object) -> JSONResponse:
    """``{"detail": ...}`` with the first line of ``message``."""
    text = str(message).strip()
    return JSONResponse({"detail": text.splitlines()[0] if text else "error"}, status_code=status)


async def invalid(_request: Request, error: RequestValidationError) -> JSONResponse:
    """400 naming the first invalid field (``clip_id: String should match pattern...``, ``the
    'file' field of the form: Field required``)."""
    first = error.errors()[0] if error.errors() else {}
    where = [str(p) for p in first.get("loc", ())]
    if where[:1] == ["body"]:
        where = [f"the '{'.'.join(where[1:])}' field of the form"]
    text = ".".join(p for p in where if p not in ("path", "query", "header"))
    return error_response(400, f"{text}: {first.get('msg', 'invalid request')}")


async def missing(request: Request, error: Exception) -> JSONResponse:
    """404, or while a build runs 503 with ``Retry-After`` (what is missing may come)."""
    build: LibraryBuild | None = request.app.state.build
    if build is not None and build.running:
        where = build.where()
        response = error_response(503, f"{error} (the library is still being built: {where})")
        response.headers["retry-after"] = "2"
        return response
    return error_response(404, error)


async def bad_input(_request: Request, error: ValueError) -> JSONResponse:
    """400 with the error's first line (a parser's names its file and line)."""
    return error_response(400, error)


def add_error_handlers(app: FastAPI) -> None:
    """Install the handlers above on ``app``."""
    app.add_exception_handler(RequestValidationError, invalid)  # type: ignore[arg-type]
    app.add_exception_handler(ClipNotFoundError, missing)
    app.add_exception_handler(UnavailableError, missing)
    app.add_exception_handler(ValueError, bad_input)  # type: ignore[arg-type]
