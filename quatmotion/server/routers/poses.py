"""``/api/poses``: the poses nearest to a frame of a clip (the pose index the server has)."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query

from quatmotion.server.dependencies import TOP_RANGE, Catalogue, QueryClipId
from quatmotion.server.schemas import ERROR_RESPONSES, PoseHitModel, PoseResponse

__all__ = ["router"]

router = APIRouter(responses=ERROR_RESPONSES)


@router.get("/api/poses", response_model=PoseResponse, tags=["search"])
def pose_search(
    clip: QueryClipId,
    catalogue: Catalogue,
    frame: Annotated[int, Query(ge=0, description="Frame of the clip, from 0.")],
    k: Annotated[int, Query(**TOP_RANGE, description="Poses wanted.")] = 10,
    other_clips: Annotated[bool, Query(description="Leave out the clip's own poses.")] = False,
) -> PoseResponse:
    """The poses nearest to a frame of a clip, under the pose index's learned distance."""
    found, hits = catalogue.pose_search(clip, frame, k=k, other_clips=other_clips)
    return PoseResponse(clip=clip, frame=found, results=[PoseHitModel(**h.__dict__) for h in hits])
