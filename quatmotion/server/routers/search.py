"""``/api/search`` and ``/api/search/upload``: the indexed clips ranked by likeness to an
indexed clip or to an uploaded file (parsed in memory under the rules of
:mod:`quatmotion.server.uploads`, never kept)."""

from __future__ import annotations

import hashlib
import time
from typing import Annotated

from fastapi import APIRouter, Depends, File, Form, HTTPException, Query, UploadFile
from starlette.concurrency import run_in_threadpool

from quatmotion.io import MOTION_SUFFIXES
from quatmotion.retrieval.search import DEFAULT_K
from quatmotion.server.clips import ClipCatalogue
from quatmotion.server.dependencies import (
    TOP_RANGE,
    Catalogue,
    QueryClipId,
    UploadRoute,
    Uploads,
    require_csrf_header,
    upload_name,
)
from quatmotion.server.schemas import ERROR_RESPONSES, SearchHitModel, SearchResponse
from quatmotion.server.uploads import UploadGate, parse_upload
from quatmotion.viz import frame_data

__all__ = ["router"]

router = APIRouter(responses=ERROR_RESPONSES)

upload_router = APIRouter(route_class=UploadRoute, responses=ERROR_RESPONSES)

_METHOD = "Search method (one the index has features for; default: its first)."
_TOP = "Results wanted."
_SUFFIXES = ", ".join(MOTION_SUFFIXES)


@router.get("/api/search", response_model=SearchResponse, tags=["search"])
def search_clip(
    clip: QueryClipId,
    catalogue: Catalogue,
    method: Annotated[str | None, Query(max_length=64, description=_METHOD)] = None,
    top: Annotated[int, Query(**TOP_RANGE, description=_TOP)] = DEFAULT_K,
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


@upload_router.post(
    "/api/search/upload",
    response_model=SearchResponse,
    tags=["search"],
    dependencies=[Depends(require_csrf_header)],
)
async def search_upload(
    catalogue: Catalogue,
    gate: Uploads,
    file: Annotated[UploadFile, File(description="The query clip: " + _SUFFIXES + ".")],
    asf: Annotated[
        UploadFile | None, File(description="The ASF skeleton of an .amc query (required then).")
    ] = None,
    method: Annotated[str | None, Form(max_length=64, description=_METHOD)] = None,
    top: Annotated[int, Form(**TOP_RANGE, description=_TOP)] = DEFAULT_K,
) -> SearchResponse:
    """Rank the indexed clips by likeness to an uploaded clip (multipart form: ``file``;
    ``asf``, the skeleton an .amc needs; ``method``; ``top``). The upload is parsed in memory
    and not kept; a file the parser rejects gets 400 with its message. Requests need the
    header ``X-Quatmotion-Request`` (403 without). One upload at a time per client (429), a
    few at once overall (503), parsed under a memory budget (413 for a file that alone needs
    more)."""
    name = upload_name(file.filename, MOTION_SUFFIXES)
    asf_name = upload_name(asf.filename, (".asf",)) if asf is not None else "skeleton.asf"
    data = await file.read()
    await file.close()  # the form's copy freed before parsing: the bytes are held once
    asf_data = await asf.read() if asf is not None else None
    if name.lower().endswith(".amc") and asf_data is None:
        raise HTTPException(
            400, f"{name}: an AMC holds no skeleton; upload its ASF file too (form field 'asf')"
        )
    cost = gate.cost(name, data) + (gate.cost(asf_name, asf_data) if asf_data is not None else 0)
    gate.check(cost, name)
    return await run_in_threadpool(
        _search_upload, catalogue, gate, cost, data, name, asf_data, asf_name, method, top
    )


router.include_router(upload_router)


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
