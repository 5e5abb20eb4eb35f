"""``/api/info`` and ``/api/clips...``: what the server serves, its clips, their frames for the
viewer and their comparison with the original files."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from fastapi import APIRouter, Query

import quatmotion
from quatmotion.io import MOTION_SUFFIXES
from quatmotion.server.clips import SORT_KEYS
from quatmotion.server.dependencies import Build, Catalogue, ClipId, MaxUpload
from quatmotion.server.schemas import ERROR_RESPONSES, ClipList, ClipModel, InfoModel, clip_model

__all__ = ["router"]

router = APIRouter(responses=ERROR_RESPONSES)


@router.get("/api/info", response_model=InfoModel, tags=["library"])
def info(catalogue: Catalogue, build: Build, max_upload: MaxUpload) -> InfoModel:
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
        building=build is not None and build.running,
    )


@router.get("/api/clips", response_model=ClipList, tags=["library"])
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


@router.get("/api/clips/{clip_id}", response_model=ClipModel, tags=["library"])
def clip(clip_id: ClipId, catalogue: Catalogue) -> ClipModel:
    """One clip."""
    return clip_model(catalogue.info(clip_id))


@router.get("/api/clips/{clip_id}/frames", tags=["viewer"])
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


@router.get("/api/clips/{clip_id}/compare", tags=["viewer"])
def compare(clip_id: ClipId, catalogue: Catalogue) -> dict[str, Any]:
    """The viewer document of a clip's original file (blue) beside its decoded version
    (green) with the per-joint error (``quatmotion.viz.view_data``); 404 when the clip is
    not in the library or its original is not available."""
    return catalogue.comparison(clip_id)
