"""``/api/build``: where the library the server was started to build is
(``quatmotion serve DIR``, :mod:`quatmotion.server.building`)."""

from __future__ import annotations

from fastapi import APIRouter

from quatmotion.server.dependencies import Build
from quatmotion.server.schemas import ERROR_RESPONSES, BuildModel

__all__ = ["router"]

router = APIRouter(responses=ERROR_RESPONSES)


@router.get("/api/build", response_model=BuildModel, tags=["library"])
def build_status(build: Build) -> BuildModel:
    """Where the library the server was started to build is (``quatmotion serve DIR``):
    its step, the stages served so far, the clips left out. ``state`` is ``none`` for a
    server started with its files."""
    if build is None:
        return BuildModel(state="none")
    return BuildModel(**build.status())
