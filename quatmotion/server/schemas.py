"""The JSON the web app's API answers with: pydantic models, from which FastAPI makes the
OpenAPI schema (``/openapi.json``, shown at ``/docs``)."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, Field

__all__ = [
    "ERROR_RESPONSES",
    "BuildModel",
    "ClipList",
    "ClipModel",
    "InfoModel",
    "PoseHitModel",
    "PoseResponse",
    "SearchHitModel",
    "SearchResponse",
    "clip_model",
    "ErrorModel",
]


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


def clip_model(info: Any) -> ClipModel:
    """The API model of a :class:`~quatmotion.server.clips.ClipInfo`."""
    return ClipModel(**info.as_dict())


class ErrorModel(BaseModel):
    """Every error's answer."""

    detail: str = Field(description="What is wrong, one line (a file's errors name it).")


ERROR_RESPONSES: dict[int | str, dict[str, Any]] = {
    "4XX": {
        "model": ErrorModel,
        "description": "400 a malformed or invalid request (the field named), or an upload "
        "its reader refuses; 403 a POST without the X-Quatmotion-Request header or from "
        "another site; 404 a clip or file the server does not have; 413 a body over the "
        "limit or an upload over the parsing budget; 415 a kind of file this server cannot "
        "read; 429 a second upload of one client.",
    },
    503: {
        "model": ErrorModel,
        "description": "Not yet: the library is still being built, or the uploads' slots "
        "are taken (Retry-After says when to ask again).",
    },
}
"""The error answers of every API route, as the API's schema states them (FastAPI's 422 for
an invalid request is answered 400 here: :mod:`quatmotion.server.handlers`)."""
