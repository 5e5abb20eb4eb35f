"""Fuzzing quatmotion's own files: ``.qmz`` libraries, ``.qidx`` clip indexes and pose
libraries (``.npz``). Seeds are made by the writers from generated clips (plus the crafted
``.qmz`` headers of ``tests/mutants.py``); mutations know each format's structure, so most
mutants pass the framing and reach the parsers:

* ``.qmz``: a chunk's payload changed (the header's and the layouts' inflated, changed and
  deflated again) and its CRC made valid again, or the bytes changed (the framing);
* ``.qidx``: one SQL change (a cell of a random row and column set to a hostile value or its
  own value mutated, a row deleted), or the bytes changed;
* pose libraries: one array of the ``.npz`` changed (a value, its shape, its type; the graph's
  bytes), or the meta JSON, or the zip's bytes.

Each reader (:func:`read`) does what the commands do with such a file: open it, list it, decode
or query what it holds. Pose libraries reach hnswlib (C++): fuzzed in a process of their own.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import random
import sqlite3
import sys
import tempfile
import zlib
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).parents[1]))

OWN = ("qmz", "qidx")
OWN_ISOLATED = ("pose",)

_HOSTILE_SQL_VALUES: list[Any] = [
    None, -1, 0, 1, 2**31, 2**63 - 1, -(2**63), 1e308, -1e-300, float("inf"), float("nan"),
    "", "x", "../../etc/passwd", "\x1b[2J", "[" * 300, '{"a": 1}', "null", "[]", b"", b"\0",
    b"\x93NUMPY", 10**9,
]  # fmt: skip


# --- seeds ------------------------------------------------------------------------------------


@cache
def _clips() -> tuple[Path, ...]:
    from quatmotion.io import write_bvh
    from quatmotion.synthetic import generate_clip

    folder = Path(tempfile.mkdtemp(prefix="quatmotion-fuzz-seeds-"))
    out = []
    for kind, seed, frames in (("walk", 1, 40), ("run", 2, 50), ("jump", 3, 30)):
        path = folder / f"{kind}.bvh"
        write_bvh(generate_clip(kind, seed, n_frames=frames), path)
        out.append(path)
    return tuple(out)


@cache
def seeds(kind: str) -> tuple[bytes, ...]:
    """The seed files of ``kind`` (made once per process)."""
    if kind == "qmz":
        return _qmz_seeds()
    if kind == "qidx":
        from quatmotion.parallel import Runner
        from quatmotion.retrieval.index import ClipIndex

        out = _clips()[0].parent / "a.qidx"
        if not out.exists():
            ClipIndex.build(list(_clips()), out, runner=Runner.inline())
        return (out.read_bytes(),)
    if kind == "pose":
        return (_pose_seed(),)
    raise ValueError(kind)


def _qmz_seeds() -> tuple[bytes, ...]:
    from quatmotion.codec import Archive, CompressSettings
    from quatmotion.parallel import Runner

    made = []
    for method in ("best", "naive"):
        out = _clips()[0].parent / f"{method}.qmz"
        if not out.exists():  # inline: a pool's forkserver kept run.py's workers from ending
            settings = CompressSettings(max_error=2.0, method=method)
            Archive.build(list(_clips()), out, settings, runner=Runner.inline())
        made.append(out.read_bytes())
    # the whole files chosen more often than the crafted ones (refused whatever is mutated)
    return tuple(made) * 4 + tuple(hostile("qmz"))


@cache
def hostile(kind: str) -> tuple[bytes, ...]:
    """Crafted files every reader must refuse (the crafted ``.qmz`` headers)."""
    if kind != "qmz":
        return ()
    import mutants

    source = _clips()[0].parent / "best.qmz"
    if not source.exists():
        _qmz_seeds()
    refused = [k for k in mutants.QMZ_HEADERS if k.startswith(("frames_", "fps_", "settings_"))]
    out = []
    for name in [*refused, "name_twice"]:
        if name == "frames_plus_one":  # format 2 cannot tell (docs/format.md)
            continue
        path = source.parent / f"crafted-{name}.qmz"
        mutants.rewrite_qmz(source, path, mutants.QMZ_HEADERS[name])
        out.append(path.read_bytes())
    return tuple(out)


def _pose_seed() -> bytes:
    from quatmotion.pose.index import HNSWIndex
    from quatmotion.pose.library import PoseLibrary

    rng = np.random.default_rng(3)
    D, r, n = 12, 4, 60
    model = {"scale": rng.uniform(0.5, 2, D), "offset": rng.normal(size=D)}
    model["W"] = rng.normal(size=(D, r))
    lib = PoseLibrary(
        index=HNSWIndex(random_state=0, n_threads=1),
        clip_names=["a/one.amc", "b/two.bvh"],
        clip_of=np.repeat([0, 1], n // 2),
        frame_of=np.tile(np.arange(0, n // 2) * 4, 2),
        model=model,
        meta={"fps": 30.0, "file_frames": [120, 120], "file_fps": [120.0, 120.0]},
    )
    lib.index.fit(lib.project(rng.normal(size=(n, D))))
    path = _clips()[0].parent / "lib.npz"
    lib.save(path)
    return path.read_bytes()


# --- mutations --------------------------------------------------------------------------------


def mutate(kind: str, data: bytes, rng: random.Random) -> bytes:
    """One structural mutation of a file of ``kind`` (or, one time in five, of its bytes)."""
    from fuzz_corpus import _mutate_bytes

    if rng.random() < 0.2:
        return _mutate_bytes(data, rng, text=False)
    try:
        if kind == "qmz":
            return _mutate_qmz(data, rng)
        if kind == "qidx":
            return _mutate_qidx(data, rng)
        return _mutate_pose(data, rng)
    except Exception:  # noqa: BLE001 (a seed already broken: its bytes then)
        return _mutate_bytes(data, rng, text=False)


def _chunks(data: bytes) -> list[tuple[bytes, bytes]]:
    from quatmotion.codec.container import PREAMBLE_BYTES, read_chunk, scan_chunks

    f = io.BytesIO(data)
    refs = [r for r in scan_chunks(f, Path("x"), len(data)) if r.offset >= PREAMBLE_BYTES]
    return [(ref.tag, read_chunk(f, ref, Path("x"))) for ref in refs]


def _mutate_qmz(data: bytes, rng: random.Random) -> bytes:
    from fuzz_corpus import _mutate_bytes

    from quatmotion.codec.container import PREAMBLE_BYTES, write_chunk

    chunks = _chunks(data)
    share = {b"H": 3, b"S": 1, b"L": 2, b"C": 4}  # the decoders' inputs most often
    k = rng.choices(
        range(len(chunks)), [share[t] / sum(t == u for u, _ in chunks) for t, _ in chunks]
    )[0]
    tag, payload = chunks[k]
    if tag in (b"H", b"L") and rng.random() < 0.8:  # deflated: its body changed
        body = zlib.decompress(payload, -15)
        for _ in range(rng.randint(1, 2)):
            body = _mutate_bytes(body, rng, text=False)
        packer = zlib.compressobj(9, zlib.DEFLATED, -15)
        payload = packer.compress(body) + packer.flush()
    else:
        payload = _mutate_bytes(payload, rng, text=False)
    chunks[k] = (tag, payload)
    out = io.BytesIO()
    out.write(data[:PREAMBLE_BYTES])
    for tag, payload in chunks:
        write_chunk(out, tag, payload)
    return out.getvalue()


def _with_file(data: bytes, suffix: str) -> Path:
    fd, name = tempfile.mkstemp(prefix="quatmotion-fuzz-", suffix=suffix)
    with os.fdopen(fd, "wb") as fh:
        fh.write(data)
    return Path(name)


def _mutate_qidx(data: bytes, rng: random.Random) -> bytes:
    from fuzz_corpus import _mutate_bytes

    path = _with_file(data, ".qidx")
    try:
        db = sqlite3.connect(path)
        try:
            tables = [t for (t,) in db.execute("SELECT name FROM sqlite_master WHERE type='table'")]
            table = rng.choice(tables)
            columns = [c[1] for c in db.execute(f"PRAGMA table_info({table})")]
            rowids = [r for (r,) in db.execute(f"SELECT rowid FROM {table}")]
            if not rowids:
                return data
            rowid = rng.choice(rowids)
            if rng.random() < 0.1:
                db.execute(f"DELETE FROM {table} WHERE rowid = ?", (rowid,))
            else:
                column = rng.choice(columns)
                (old,) = db.execute(
                    f"SELECT {column} FROM {table} WHERE rowid = ?", (rowid,)
                ).fetchone()
                if rng.random() < 0.5 or old is None:
                    new = rng.choice(_HOSTILE_SQL_VALUES)
                elif isinstance(old, bytes):
                    new = _mutate_bytes(old, rng, text=False)
                elif isinstance(old, str):
                    new = _mutate_bytes(old.encode(), rng, text=True).decode("utf-8", "replace")
                else:
                    new = rng.choice([-old, old + 1, old * 1000, old - 1])
                db.execute(f"UPDATE {table} SET {column} = ? WHERE rowid = ?", (new, rowid))
            db.commit()
        finally:
            db.close()
        return path.read_bytes()
    finally:
        path.unlink(missing_ok=True)


def _mutate_pose(data: bytes, rng: random.Random) -> bytes:
    from fuzz_corpus import _mutate_bytes, _mutate_json

    with np.load(io.BytesIO(data), allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files}
    key = rng.choice(sorted(arrays))
    a = arrays[key]
    if key == "meta":
        meta = json.loads(str(a))
        _mutate_json(meta, rng) if isinstance(meta, dict) else None
        arrays[key] = np.asarray(json.dumps(meta))
    elif key == "index" or a.dtype == np.uint8:
        arrays[key] = np.frombuffer(_mutate_bytes(a.tobytes(), rng, text=False), dtype=np.uint8)
    else:
        kind = rng.choice(["value", "value", "shape", "dtype"])
        if kind == "value" and a.size and a.dtype.kind in "iuf":
            flat = a.copy().reshape(-1)
            nasty = [-1, 0, 2**31 - 1, 10**6] + (
                [np.nan, np.inf, 1e300] if a.dtype.kind == "f" else []
            )
            flat[rng.randrange(flat.size)] = rng.choice(nasty)
            arrays[key] = flat.reshape(a.shape)
        elif kind == "shape" and a.ndim:
            arrays[key] = rng.choice([a[:-1], a[:0], np.concatenate([a, a[:1]]), a.reshape(-1)])
        elif a.dtype.kind in "iuf":
            arrays[key] = a.astype(rng.choice([np.float32, np.int8, np.int64, np.float64]))
    out = io.BytesIO()
    np.savez(out, **arrays)
    return out.getvalue()


# --- readers ----------------------------------------------------------------------------------


def read(kind: str, data: bytes) -> str:
    """What the commands do with a file of ``kind`` holding ``data``; returns the name a
    FormatError must start with."""
    if kind == "qmz":
        from quatmotion.codec import Archive

        for recover in (False, True):
            with Archive.open(data, recover=recover) as archive:
                archive.names()
                damaged = {d.index for d in archive.damaged} if recover else set()
                for i in range(min(len(archive), 4)):
                    if i in damaged:
                        continue
                    archive.read(i)
                    archive.read_rotations(i)
                    archive.sample(i, [0.0, 0.5])
        return "<bytes>"
    path = _with_file(data, ".qidx" if kind == "qidx" else ".npz")
    try:
        if kind == "qidx":
            from quatmotion.errors import ClipNameError
            from quatmotion.retrieval.index import ClipIndex

            with ClipIndex.open(path) as index:
                rows = index.rows()
                # a clip without the default method's features: a ClipNameError saying so
                with contextlib.suppress(ClipNameError):
                    index.search(rows[0].name, k=2) if rows else None
        else:
            from quatmotion.pose.library import PoseLibrary

            lib = PoseLibrary.open(path)
            query, clip, _ = lib.pose_query(0, 0)
            lib.nearest(query, k=3, exclude_clip=clip)
    finally:
        path.unlink(missing_ok=True)
    return str(path)
