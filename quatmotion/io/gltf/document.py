"""A glTF document as the reader sees it (:class:`Document`): the JSON and binary chunk split
out of a ``.glb`` or ``.gltf`` (:func:`read_document`), every field checked for its type and
range where it is read, the buffers (embedded, or a file inside the document's folder) and the
accessors' values read within their limits.
"""

from __future__ import annotations

import base64
import json
import os
import re
import stat
import struct
from pathlib import Path, PurePosixPath, PureWindowsPath
from typing import Any
from urllib.parse import unquote

import numpy as np
from numpy.typing import NDArray

from quatmotion import limits
from quatmotion.errors import FormatError
from quatmotion.io.gltf.spec import (
    CM_PER_METRE,
    COMPONENTS,
    DTYPES,
    GLB_BIN,
    GLB_JSON,
    NORMALIZED_MAX,
)


def read_document(data: bytes, path: Path) -> tuple[dict[str, Any], bytes | None]:
    """The JSON document (its depth checked before parsing) and the GLB's binary chunk."""
    chunk = None
    if data[:4] == b"glTF":
        if len(data) < 20:
            raise FormatError(f"not a glTF 2.0 file: a GLB of {len(data)} bytes", path)
        _, version, length = struct.unpack_from("<4sII", data)
        if version != 2:
            raise FormatError(f"GLB version {version}: only glTF 2.0 is read", path)
        if length > len(data):
            raise FormatError(f"the GLB header says {length} bytes, the file has {len(data)}", path)
        chunks: list[tuple[int, int, bytes]] = []
        offset = 12
        while offset + 8 <= length:
            size, kind = struct.unpack_from("<II", data, offset)
            if offset + 8 + size > length:
                raise FormatError(f"the GLB chunk at byte {offset} runs past the file's end", path)
            chunks.append((offset, kind, data[offset + 8 : offset + 8 + size]))
            offset += 8 + size
        if not chunks or chunks[0][1] != GLB_JSON:
            raise FormatError("the GLB's first chunk (byte 12) is not its JSON chunk", path)
        text = chunks[0][2]
        chunk = next((body for _, kind, body in chunks[1:] if kind == GLB_BIN), None)
    else:
        text = data[3:] if data[:3] == b"\xef\xbb\xbf" else data
    limits.check("depth", limits.json_depth(text), path, "the JSON's nesting depth")
    try:
        document = json.loads(text)
    except ValueError as error:  # UnicodeDecodeError included
        raise FormatError(f"not a glTF 2.0 file ({error})", path) from None
    if not is_object(document):
        raise FormatError("not a glTF 2.0 file (its JSON is no object)", path)
    return document, chunk


def is_object(value: Any) -> bool:
    return isinstance(value, dict)


def is_index(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


class Document:
    """The document's fields, each checked for its type and range where it is read: a field
    of the wrong type is a FormatError naming it, never an exception of the code using it;
    its buffers and accessors read within their limits (the reader of the skeleton and its
    animation stands on it)."""

    def __init__(
        self,
        document: dict[str, Any],
        chunk: bytes | None,
        path: Path,
        cm_per_unit: float | None,
        folder: Path | None,
    ) -> None:
        self.document = document
        self.chunk = chunk
        self.path = path
        self.folder = folder
        self.metre = CM_PER_METRE if cm_per_unit is None else cm_per_unit
        self.given = cm_per_unit is not None
        self._buffers: dict[int, bytes] = {}
        self._accessors: dict[tuple[int, str], NDArray[np.float64]] = {}
        self.keys_read = 0
        self.nodes = self.objects(document, "nodes", "")

    def fail(self, message: str) -> FormatError:
        return FormatError(message, self.path)

    # --- typed fields -------------------------------------------------------------------------

    def objects(self, owner: dict[str, Any], key: str, where: str) -> list[dict[str, Any]]:
        """``owner[key]``: a list of objects (empty if absent)."""
        items = owner.get(key, [])
        if not isinstance(items, list) or not all(is_object(item) for item in items):
            raise self.fail(f"{where}{key} is not a list of objects")
        return items

    def index(self, owner: dict[str, Any], key: str, size: int, where: str, into: str) -> int:
        """``owner[key]``: a required index of one of ``size`` items of ``into``."""
        value = owner.get(key)
        if not is_index(value) or not 0 <= value < size:
            raise self.fail(f"{where}.{key} is {value!r}: no index of {into} (it has {size})")
        return value

    def indices(self, owner: dict[str, Any], key: str, size: int, where: str) -> list[int]:
        values = owner.get(key, [])
        if not isinstance(values, list) or not all(is_index(v) and 0 <= v < size for v in values):
            raise self.fail(f"{where}.{key} is not a list of node indices (0 to {size - 1})")
        return values

    def count(self, owner: dict[str, Any], key: str, where: str, default: int | None = None) -> int:
        """``owner[key]``: a whole number, 0 or more."""
        value = owner.get(key, default)
        if not is_index(value) or value < 0:
            raise self.fail(f"{where}.{key} is {value!r}: expected a whole number, 0 or more")
        return value

    def numbers(self, owner: dict[str, Any], key: str, n: int, where: str) -> NDArray | None:
        """``owner[key]``: ``n`` finite numbers, or None if absent."""
        value = owner.get(key)
        if value is None:
            return None
        if not (
            isinstance(value, list)
            and len(value) == n
            and all(isinstance(v, int | float) and not isinstance(v, bool) for v in value)
            and np.all(np.isfinite(value))
        ):
            raise self.fail(f"{where}.{key} is not {n} finite numbers")
        return np.asarray(value, dtype=np.float64)

    # --- data ---------------------------------------------------------------------------------

    def buffer(self, index: int) -> bytes:
        if index in self._buffers:
            return self._buffers[index]
        where = f"buffers[{index}]"
        buffer = self.objects(self.document, "buffers", "")[index]
        length = self.count(buffer, "byteLength", where)
        limits.check("file_bytes", length, self.path, f"{where}.byteLength")
        uri = buffer.get("uri")
        if uri is None:
            if self.chunk is None or index != 0:
                raise self.fail(f"{where} has no uri and is not the GLB's binary chunk")
            blob = self.chunk
        elif not isinstance(uri, str):
            raise self.fail(f"{where}.uri is not a string")
        elif uri.startswith("data:"):
            head, comma, payload = uri.partition(",")
            if not comma or not head.endswith(";base64"):
                raise self.fail(f"{where}.uri is a data URI that is not base64")
            try:
                blob = base64.b64decode(payload)
            except ValueError:
                raise self.fail(f"{where}.uri is not a valid base64 data URI") from None
        else:
            blob = self.external(where, uri, length)
        self._buffers[index] = blob
        return blob

    def external(self, where: str, uri: str, length: int) -> bytes:
        """The first ``length`` bytes of a regular file inside the glTF's folder, symbolic
        links followed. The messages for a path outside are the same whatever is there."""
        if self.folder is None:
            raise self.fail(
                f"{where}.uri names another file, which is not read for a glTF given as bytes "
                "(an upload): embed the buffers (a .glb, or a .gltf with data URIs)"
            )
        outside = self.fail(f"{where}.uri must be a relative path inside the glTF's folder")
        name = unquote(uri)
        if (
            "\0" in name
            or _SCHEME.match(name)
            or PurePosixPath(name).is_absolute()
            or PureWindowsPath(name).anchor
        ):
            raise outside
        folder = self.folder.resolve()
        target = (folder / name).resolve()
        if not target.is_relative_to(folder) or target == folder:
            raise outside
        try:  # non-blocking: a FIFO named by a file must not hang the reader
            handle = os.open(target, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
        except OSError as error:
            raise self.fail(f"{where}: cannot read {name}: {error.strerror}") from None
        with os.fdopen(handle, "rb") as file:
            if not stat.S_ISREG(os.fstat(handle).st_mode):
                raise self.fail(f"{where}.uri names {name}, which is not a regular file")
            return file.read(length)

    def accessor_count(self, index: int, field: str) -> int:
        accessors = self.objects(self.document, "accessors", "")
        if not is_index(index) or not 0 <= index < len(accessors):
            raise self.fail(f"{field}: accessors[{index}] does not exist")
        return self.count(accessors[index], "count", f"accessors[{index}]")

    def accessor(self, index: int, kind: str, field: str) -> NDArray[np.float64]:
        """The accessor's values as float64 ``(count, width)``; its count bounded by the
        caller (:meth:`accessor_count`) before this reads it."""
        key = (index, kind)
        if key not in self._accessors:
            self._accessors[key] = self._read_accessor(index, kind, field)
        return self._accessors[key]

    def _read_accessor(self, index: int, kind: str, field: str) -> NDArray[np.float64]:
        count = self.accessor_count(index, field)
        acc = self.document["accessors"][index]
        where = f"{field} (accessors[{index}])"
        if acc.get("type") != kind:
            raise self.fail(f"{where} is {acc.get('type')!r}, expected {kind}")
        component = acc.get("componentType")
        if not is_index(component) or component not in DTYPES:
            raise self.fail(f"{where} has componentType {component!r}")
        if acc.get("sparse") is not None:
            raise self.fail(f"{where} is sparse, which is not read")
        width = COMPONENTS[kind]
        dtype = np.dtype(DTYPES[component]).newbyteorder("<")
        if acc.get("bufferView") is None:
            return np.zeros((count, width))  # the specification's default
        views = self.objects(self.document, "bufferViews", "")
        v = self.index(acc, "bufferView", len(views), f"accessors[{index}]", "bufferViews")
        view = views[v]
        view_where = f"bufferViews[{v}]"
        buffers = self.objects(self.document, "buffers", "")
        blob = self.buffer(self.index(view, "buffer", len(buffers), view_where, "buffers"))
        view_start = self.count(view, "byteOffset", view_where, 0)
        view_length = self.count(view, "byteLength", view_where)
        if view_start + view_length > len(blob):
            raise self.fail(
                f"{view_where} (bytes {view_start} to {view_start + view_length}) runs past the "
                f"end of its buffer ({len(blob)} bytes)"
            )
        element = width * dtype.itemsize
        stride = view.get("byteStride", element)
        if not is_index(stride) or not element <= stride <= 252:
            raise self.fail(f"{view_where}.byteStride is {stride!r}: expected {element} to 252")
        start = self.count(acc, "byteOffset", f"accessors[{index}]", 0)
        end = start + (stride * (count - 1) + element if count else 0)
        if end > view_length:
            raise self.fail(
                f"{where} reads bytes {start} to {end} of {view_where}, which has {view_length}"
            )
        raw = np.frombuffer(blob, dtype=np.uint8, count=end - start, offset=view_start + start)
        if stride == element:
            values = raw.view(dtype).reshape(count, width)
        else:
            padded = np.zeros(stride * count, dtype=np.uint8)
            padded[: len(raw)] = raw
            values = padded.reshape(count, stride)[:, :element].copy().view(dtype)
        with np.errstate(invalid="ignore", over="ignore"):  # not finite: refused just below
            values = values.astype(np.float64)
        if acc.get("normalized") is True and component in NORMALIZED_MAX:
            values = np.maximum(values / NORMALIZED_MAX[component], -1.0)
        if not np.all(np.isfinite(values)):
            raise self.fail(f"{where} holds values that are not finite")
        return values


_SCHEME = re.compile(r"^[A-Za-z][A-Za-z0-9+.-]*:")
