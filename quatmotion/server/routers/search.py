"""``/api/search`` and ``/api/search/upload``: the indexed clips ranked by likeness to an
indexed clip or to an uploaded file (parsed in memory under the rules of
:mod:`quatmotion.server.uploads`, never kept)."""

from __future__ import annotations

import hashlib
import time
from typing import Annotated

from fastapi import APIRouter, HTTPException, Query, Request
from starlette.concurrency import run_in_threadpool
from starlette.datastructures import UploadFile

from quatmotion.io import MOTION_SUFFIXES
from quatmotion.server.clips import ClipCatalogue
from quatmotion.server.dependencies import (
    MAX_TOP,
    Catalogue,
    QueryClipId,
    Uploads,
    form_int,
    read_form,
    upload_name,
)
from quatmotion.server.middleware import CSRF_HEADER
from quatmotion.server.schemas import SearchHitModel, SearchResponse
from quatmotion.server.uploads import UploadGate, parse_upload
from quatmotion.viz import frame_data

__all__ = ["router"]

router = APIRouter()

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


@router.get("/api/search", response_model=SearchResponse, tags=["search"])
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


@router.post(
    "/api/search/upload",
    response_model=SearchResponse,
    tags=["search"],
    openapi_extra=_UPLOAD_BODY,
)
async def search_upload(request: Request, catalogue: Catalogue, gate: Uploads) -> SearchResponse:
    """Rank the indexed clips by likeness to an uploaded clip (multipart form: ``file``,
    an .amc, .bvh, .glb or .gltf; ``asf``, the skeleton an .amc needs; ``method``; ``top``).
    The upload is parsed in memory and not kept; a file the parser rejects gets 400 with its
    message. Requests need the header ``X-Quatmotion-Request`` (403 without). One upload at a
    time per client (429), a few at once overall (503), parsed under a memory budget (413 for
    a file that alone needs more)."""
    with gate.admitted(request.client.host if request.client else ""):
        declared = request.headers.get("content-length", "")
        if declared.isdigit():  # a body no reading of which fits the budget: refused unread
            gate.check(gate.least_cost(int(declared)), "an upload of this size")
        form = await read_form(request)
        upload = form.get("file")
        if not isinstance(upload, UploadFile):
            raise HTTPException(400, "the form needs a 'file' field holding a motion file")
        asf = form.get("asf")
        if asf is not None and not isinstance(asf, UploadFile):
            raise HTTPException(400, "the 'asf' field must be a file (the ASF skeleton)")
        method = form.get("method") or None
        top = form_int(form.get("top"), "top", 20, 1, MAX_TOP)
        name = upload_name(upload.filename, MOTION_SUFFIXES)
        asf_name = upload_name(asf.filename, (".asf",)) if asf is not None else "skeleton.asf"
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
