"""What the web app serves: the clips of a library, an index and a pose index, joined on the
clips' content hash.

Conventions
-----------
* A clip is addressed by its **id**, a string made here from the clip's name (letters,
  digits, ``_ . -``; ``~2``, ``~3``... when names repeat). Ids are only keys of a dictionary
  built when the catalogue opens: no request value ever becomes a path. The files read are
  the ones the server was started with and the clip sources those files name.
* A clip of the ``.qmz`` library, a row of the ``.qidx`` index and a clip of the pose index
  are the same clip when their :func:`clip_key` (the content SHA-256 of the clip's files,
  ``ClipRef.sha256``) is the same; each file's clip joins one clip of each other file at most.
  Where names repeat (two ``take_001`` in two folders), a clip is named by its path relative
  to the colliding files' folder (``collection.unique_names``). The index gives the label and
  the original file (for the comparison with the decoded clip). Index clips not in the
  library are served from their original files.
* An original file is used only while it is the file that was indexed: its content hash
  (the index's SHA-256 of the motion file, then its ASF) must still match.
* Frames count from 0, positions in centimetres, durations in seconds.
* Thread safety: the methods may be called from several threads at once (the server runs
  them in a thread pool). The open ``.qmz`` file and the pose index are read under a lock; the
  ``.qidx`` index is opened per search (an SQLite connection belongs to one thread).
"""

from __future__ import annotations

import dataclasses
import re
import threading
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

from quatmotion import codec
from quatmotion.collection import (
    ClipRef,
    ReadSettings,
    content_hash,
    find_skeleton,
    read_clip,
    unique_names,
)
from quatmotion.errors import FormatError
from quatmotion.motion import Motion
from quatmotion.pose.library import PoseLibrary
from quatmotion.retrieval.index import ClipIndex, ClipRow
from quatmotion.retrieval.methods import DEFAULT_METHOD, METHODS
from quatmotion.retrieval.search import DEFAULT_K, method_keys, query_row, search
from quatmotion.viz import frame_data, view_data

__all__ = [
    "SORT_KEYS",
    "ClipCatalogue",
    "ClipInfo",
    "ClipNotFoundError",
    "UnavailableError",
    "PoseHit",
    "SearchHit",
    "clip_key",
]

SORT_KEYS = (
    "name",
    "label",
    "frames",
    "duration_s",
    "compressed_bytes",
    "declared_max_error_cm",
    "declared_arms_cm",
)
"""Columns the clip list sorts by."""

_ID_CHARS = re.compile(r"[^A-Za-z0-9_.-]+")
_PAYLOAD_CACHE = 16  # decoded clips kept ready to send (a few MB each at most)


class ClipNotFoundError(KeyError):
    """No clip has this id (the message names it)."""

    def __str__(self) -> str:
        return str(self.args[0]) if self.args else "no such clip"


class UnavailableError(LookupError):
    """The clip exists but what was asked of it cannot be had (no original, no index...)."""


@dataclass(frozen=True)
class ClipInfo:
    """One clip as the browse page lists it.

    Attributes
    ----------
    id : str
        Its address in the API.
    name : str
        The clip's name (its file stem).
    label : str
        From the index ('' when unlabelled or not indexed).
    frames : int
    fps : float
    compressed_bytes : int or None
        Its own chunk in the ``.qmz`` library (None when not in the library).
    declared_max_error_cm, declared_arms_cm : float or None
        The largest joint-position error and the ARMS the library file declares for it.
    in_library, in_index, in_poses : bool
        Where it is: the ``.qmz`` library, the ``.qidx`` index, the pose index.
    has_original : bool
        Its original file (named by the index) exists, so it compares with its decoded version
        when it is also in the library.
    """

    id: str
    name: str
    label: str
    frames: int
    fps: float
    compressed_bytes: int | None
    declared_max_error_cm: float | None
    declared_arms_cm: float | None
    in_library: bool
    in_index: bool
    in_poses: bool
    has_original: bool

    @property
    def duration_s(self) -> float:
        """Length in seconds."""
        return self.frames / self.fps

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready, ``duration_s`` included."""
        return {**dataclasses.asdict(self), "duration_s": self.duration_s}


@dataclass(frozen=True)
class SearchHit:
    """One ranked clip of a search: ``id`` is None for an indexed clip the catalogue lacks."""

    rank: int
    id: str | None
    clip: str
    label: str
    distance: float | None


@dataclass(frozen=True)
class PoseHit:
    """One pose found: ``id`` is None for a pose-index clip the catalogue lacks."""

    rank: int
    id: str | None
    clip: str
    frame: int
    seconds: float | None
    distance: float


@dataclass(frozen=True)
class _Entry:
    info: ClipInfo
    library_position: int | None
    row: ClipRow | None
    pose_clip: int | None
    original: ClipRef | None  # the clip's file: the index's reference, else the library's


@dataclass
class _Slot:
    """One clip of the catalogue while the files are joined: its place in each file."""

    position: int | None = None
    library_name: str = ""
    row: ClipRow | None = None
    row_name: str = ""
    pose_clip: int | None = None


def clip_key(clip: Any, by_name: Mapping[str, str] | None = None) -> str | None:
    """The key on which the catalogue joins a clip of a library, an index or a pose index: the
    content SHA-256 of its motion file then its skeleton (``ClipRef.sha256``); None when unknown.

    ``clip`` is anything with a ``sha256`` (a ``ClipRef``, an index row) or a ``ref`` read
    from a file (a library's clip entry, version 2 on), a path of a motion
    file (hashed here, with the ASF an AMC's lookup finds), or a clip known by name only (a
    library entry written before clip references; a string that names no file): its key is
    ``by_name[name]`` then.
    """
    sha = getattr(clip, "sha256", None)
    ref = getattr(clip, "ref", None)
    if not sha and ref is not None and ref.path:  # hashed from its files, not from memory
        sha = ref.sha256
    if sha:
        return str(sha)
    if isinstance(clip, str | Path):
        path = Path(clip)
        if path.is_file():
            try:
                skeleton = find_skeleton(path) if path.suffix.lower() == ".amc" else None
                return content_hash(path, skeleton)
            except (FormatError, OSError):
                return None
        name = str(clip)
    else:
        name = str(getattr(clip, "name", ""))
    return (by_name or {}).get(name) if name else None


def _keys_by_name(sides: Sequence[tuple[Sequence[str], Sequence[str | None]]]) -> dict[str, str]:
    """The key of every name that stands for one clip on each side and one key across them."""
    keys: dict[str, set[str]] = {}
    for names, side_keys in sides:
        count = Counter(names)
        for name, key in zip(names, side_keys, strict=True):
            if key and count[name] == 1:
                keys.setdefault(name, set()).add(key)
            elif count[name] > 1:
                keys.setdefault(name, set()).add("")  # ambiguous on this side
    return {name: next(iter(k)) for name, k in keys.items() if len(k) == 1 and "" not in k}


def _display_names(paths: Sequence[str], names: Sequence[str]) -> list[str]:
    """``names`` as they are where they are unique, else names made from ``paths`` (the path
    relative to the colliding files' common folder, :func:`collection.unique_names`)."""
    count = Counter(names)
    colliding = [i for i, n in enumerate(names) if count[n] > 1]
    out = list(names)
    if colliding:
        for i, made in zip(
            colliding, unique_names([Path(paths[i]) for i in colliding]), strict=True
        ):
            out[i] = made
    return out


class ClipCatalogue:
    """The clips the web app serves, from a ``.qmz`` library, a ``.qidx`` index and a pose
    index (any of them; at least the library or the index).

    Use :meth:`open`; close with :meth:`close` (or as a context manager).

    Attributes
    ----------
    library_path, index_path, poses_path : Path or None
        The files given.
    methods : tuple of str
        Retrieval methods whose features the index holds (the default first).
    """

    def __init__(
        self,
        library_path: Path | None,
        index_path: Path | None,
        poses_path: Path | None,
        archive: codec.Archive | None,
        rows: Sequence[ClipRow],
        methods: Sequence[str],
        poses: PoseLibrary | None,
        read: ReadSettings | None = None,
    ) -> None:
        self.library_path = library_path
        self.index_path = index_path
        self.poses_path = poses_path
        self.methods = tuple(methods)
        self._archive = archive
        self._poses = poses
        self._read = read or ReadSettings()  # how the index read the originals
        self._archive_lock = threading.Lock()
        self._poses_lock = threading.Lock()
        self._entries: dict[str, _Entry] = {}
        self._by_row: dict[int, str] = {}
        self._by_pose_clip: dict[int, str] = {}
        self._join(rows)
        self._payload = lru_cache(maxsize=_PAYLOAD_CACHE)(self._encode)

    # ------------------------------------------------------------------ opening
    @classmethod
    def open(
        cls,
        library: str | Path | None = None,
        index: str | Path | None = None,
        poses: str | Path | None = None,
    ) -> ClipCatalogue:
        """Open the files and join their clips.

        Parameters
        ----------
        library : path, optional
            A ``.qmz`` library (``quatmotion compress``).
        index : path, optional
            A ``.qidx`` index (``quatmotion index build``): labels, search, originals.
        poses : path, optional
            A pose index (``quatmotion pose index``): pose search.

        Raises
        ------
        ValueError
            Neither a library nor an index given.
        FileNotFoundError, FormatError
            A file missing or not of its format (naming it).
        """
        if library is None and index is None:
            raise ValueError("nothing to serve: give a library (.qmz), an index (.qidx) or both")
        archive = codec.Archive.open(Path(library)) if library is not None else None
        try:
            rows: list[ClipRow] = []
            methods: list[str] = []
            read = None
            if index is not None:
                with ClipIndex.open(index) as idx:
                    rows = idx.rows()
                    stored = set().union(*idx.feature_keys().values())
                    read = idx.settings.read
                methods = [m for m in METHODS if set(method_keys(m)) <= stored]
                methods.sort(key=lambda m: m != DEFAULT_METHOD)
            pose_library = PoseLibrary.open(poses) if poses is not None else None
        except BaseException:
            if archive is not None:
                archive.close()
            raise
        return cls(
            Path(library) if library is not None else None,
            Path(index) if index is not None else None,
            Path(poses) if poses is not None else None,
            archive,
            rows,
            methods,
            pose_library,
            read,
        )

    @classmethod
    def empty(cls) -> ClipCatalogue:
        """A catalogue of no clip and no file (a server whose library is still being built)."""
        return cls(None, None, None, None, [], [], None)

    def close(self) -> None:
        """Close the library file."""
        if self._archive is not None:
            self._archive.close()

    def __enter__(self) -> ClipCatalogue:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _join(self, rows: Sequence[ClipRow]) -> None:
        """One catalogue clip per content: the library's clips, the index's rows and the pose
        index's clips joined on :func:`clip_key`; a clip whose key is unknown, or a second clip
        of one file with a key already joined, gets a row of its own."""
        archive = self._archive
        row_names = _display_names([r.path for r in rows], [r.name for r in rows])
        pose_paths = list(self._poses.clip_names) if self._poses is not None else []
        pose_names = _display_names(pose_paths, [Path(n).stem for n in pose_paths])
        row_keys = [clip_key(r) for r in rows]
        refs = self._poses.refs if self._poses is not None else []  # version 3 on: hashes
        pose_keys = [r.sha256 for r in refs] if refs else [clip_key(n) for n in pose_paths]
        # The clips whose key is known, by the name a library written before clip references
        # gives them (names that occur once only).
        by_name = _keys_by_name([(row_names, row_keys), (pose_names, pose_keys)])
        slots: list[_Slot] = []
        by_key: dict[str, list[_Slot]] = {}

        def slot_for(key: str | None, side: str) -> _Slot:
            for slot in by_key.get(key, []) if key else []:
                if getattr(slot, side) is None:
                    return slot
            slot = _Slot()
            slots.append(slot)
            if key:
                by_key.setdefault(key, []).append(slot)
            return slot

        if archive is not None:
            for position, clip in enumerate(archive.entries):
                slot = slot_for(clip_key(clip, by_name), "position")
                slot.position, slot.library_name = position, clip.name
        for row, name, key in zip(rows, row_names, row_keys, strict=True):
            slot = slot_for(key, "row")
            slot.row, slot.row_name = row, name
        for number, key in enumerate(pose_keys):
            for slot in by_key.get(key, []) if key else []:
                if slot.pose_clip is None:
                    slot.pose_clip = number
                    break
        used: set[str] = set()
        for slot in slots:
            self._add(slot, used)

    def _add(self, slot: _Slot, used: set[str]) -> None:
        archive, row, position = self._archive, slot.row, slot.position
        original: ClipRef | None = None
        if row is not None:
            original = dataclasses.replace(row.ref, path=row.path)  # where the index found it
        elif position is not None and archive is not None:
            original = _located(archive.entries[position].ref, self.library_path)
        has_original = original is not None and original.path is not None
        has_original = has_original and Path(str(original.path)).is_file()  # type: ignore[union-attr]
        if position is not None:
            assert archive is not None
            clip = archive.entries[position]
            name = slot.library_name or clip.name
            info = ClipInfo(
                id=_unique_id(name, used),
                name=name,
                label=row.label if row else "",
                frames=clip.n_frames,
                fps=clip.fps,
                compressed_bytes=archive.chunk_bytes(position),
                declared_max_error_cm=float(clip.max_error),
                declared_arms_cm=float(clip.arms),
                in_library=True,
                in_index=row is not None,
                in_poses=slot.pose_clip is not None,
                has_original=has_original,
            )
        else:
            assert row is not None
            name = slot.row_name or row.name
            info = ClipInfo(
                id=_unique_id(name, used),
                name=name,
                label=row.label,
                frames=row.frames,
                fps=row.fps,
                compressed_bytes=None,
                declared_max_error_cm=None,
                declared_arms_cm=None,
                in_library=False,
                in_index=True,
                in_poses=slot.pose_clip is not None,
                has_original=has_original,
            )
        self._entries[info.id] = _Entry(info, position, row, slot.pose_clip, original)
        if row is not None:
            self._by_row[row.id] = info.id
        if slot.pose_clip is not None:
            self._by_pose_clip[slot.pose_clip] = info.id

    # ------------------------------------------------------------------ listing
    def __len__(self) -> int:
        return len(self._entries)

    @property
    def has_index(self) -> bool:
        return self.index_path is not None

    @property
    def has_poses(self) -> bool:
        return self._poses is not None

    def clips(
        self, *, label: str | None = None, sort: str = "name", descending: bool = False
    ) -> list[ClipInfo]:
        """The clips, those of ``label`` only if given, sorted by a column of
        :data:`SORT_KEYS` (clips without a value last, whatever the order)."""
        if sort not in SORT_KEYS:
            raise ValueError(f"cannot sort by {sort!r}; choose from {', '.join(SORT_KEYS)}")
        infos = [e.info for e in self._entries.values()]
        if label is not None:
            infos = [i for i in infos if i.label == label]
        present = [i for i in infos if getattr(i, sort) is not None]
        absent = [i for i in infos if getattr(i, sort) is None]
        present.sort(key=lambda i: (getattr(i, sort), i.name, i.id), reverse=descending)
        return present + absent

    def labels(self) -> list[str]:
        """The labels in use, sorted ('' for unlabelled clips included when there are some)."""
        return sorted({e.info.label for e in self._entries.values()})

    def info(self, clip_id: str) -> ClipInfo:
        """The clip with this id (:class:`ClipNotFoundError` naming it otherwise)."""
        return self._entry(clip_id).info

    def _entry(self, clip_id: str) -> _Entry:
        entry = self._entries.get(clip_id)
        if entry is None:
            raise ClipNotFoundError(f"no clip with id {clip_id!r}")
        return entry

    # ------------------------------------------------------------------ motions
    def motion(self, clip_id: str) -> Motion:
        """The clip: decoded from the library, else read from its original file."""
        entry = self._entry(clip_id)
        if entry.library_position is not None:
            return self._decoded(entry)
        return self._original(entry)

    def frames(self, clip_id: str, start: int | None = None, stop: int | None = None) -> dict:
        """The viewer payload (:func:`quatmotion.viz.frame_data.encode_clip`) of frames
        ``start:stop`` of a clip (all by default; ``0 <= start < stop <= frames``)."""
        info = self.info(clip_id)
        first = 0 if start is None else start
        last = info.frames if stop is None else stop
        if not 0 <= first < last <= info.frames:
            raise ValueError(
                f"frames {first}:{last} are not within clip {info.name!r} "
                f"(frames 0 to {info.frames - 1}, stop exclusive)"
            )
        return self._payload(clip_id, first, last)

    def _encode(self, clip_id: str, start: int, stop: int) -> dict:
        motion = self.motion(clip_id)
        if (start, stop) == (0, motion.n_frames):
            return frame_data.encode_clip(motion)
        span = f"frame {start}" if stop == start + 1 else f"frames {start}-{stop - 1}"
        return frame_data.encode_clip(motion.slice(start, stop), f"{motion.name} {span}")

    def comparison(self, clip_id: str) -> dict:
        """The viewer document (:func:`quatmotion.viz.view_data`) of a clip's original file
        (blue) beside its decoded version from the library (green), with the per-joint error.

        Raises
        ------
        UnavailableError
            The clip is not in the library, or its original file is not available.
        """
        entry = self._entry(clip_id)
        if entry.library_position is None:
            raise UnavailableError(f"clip {entry.info.name!r} is not in the library (.qmz)")
        original = dataclasses.replace(self._original(entry), name=f"{entry.info.name} (original)")
        decoded = dataclasses.replace(self._decoded(entry), name=f"{entry.info.name} (decoded)")
        return view_data([original], [decoded], layout="side")

    def _decoded(self, entry: _Entry) -> Motion:
        assert self._archive is not None and entry.library_position is not None
        with self._archive_lock:  # one file handle: its seeks and reads must not interleave
            return self._archive.read(entry.library_position)

    def _original(self, entry: _Entry) -> Motion:
        """The clip's original file (named by the index, else by the library), read as it was
        indexed, when it is still the file indexed or compressed (its content hash)."""
        ref, name = entry.original, entry.info.name
        if ref is None or ref.path is None:
            raise UnavailableError(
                f"clip {name!r} has no original file: neither the index (.qidx) nor the "
                "library (.qmz) names one"
            )
        path = Path(ref.path)
        if not path.is_file():
            raise UnavailableError(f"the original file of clip {name!r} is missing")
        try:
            skeleton = _skeleton_of(ref, path)
            if content_hash(path, skeleton, ref.take) != ref.sha256:
                raise UnavailableError(
                    f"the original file of clip {name!r} changed since it was indexed"
                )
            located = dataclasses.replace(
                ref, skeleton_path=None if skeleton is None else str(skeleton)
            )
            return read_clip(located, self._read).motion
        except (FormatError, OSError) as error:
            reason = getattr(error, "reason", None) or str(error)
            raise UnavailableError(
                f"the original file of clip {name!r} cannot be read: {reason}"
            ) from None

    # ------------------------------------------------------------------ search
    def search(
        self,
        query: str | Motion,
        *,
        method: str | None = None,
        top: int = DEFAULT_K,
        sha256: str | None = None,
    ) -> tuple[str, list[SearchHit], str | None]:
        """Rank the indexed clips by likeness to ``query``: a clip id, or a motion (an upload,
        whose bytes hash to ``sha256``); the indexed clip the query is left out
        (:func:`quatmotion.retrieval.search.query_row`).

        Returns
        -------
        (method, hits, left_out)
            The method used (the index's best when None), the ranked clips, and the name of
            the indexed clip left out as the query itself (None: the query is none).

        Raises
        ------
        UnavailableError
            No index, or a query clip that is not in it.
        ValueError
            A method the index has no features for; a query the method cannot compare.
        """
        if self.index_path is None:
            raise UnavailableError("search needs an index (.qidx): start the server with --index")
        name = method or (self.methods[0] if self.methods else DEFAULT_METHOD)
        if name not in self.methods:
            raise ValueError(
                f"the index has no features for method {name!r}; "
                f"it has {', '.join(self.methods) or 'none'}"
            )
        target: str | Motion = query
        if isinstance(query, str):
            entry = self._entry(query)
            if entry.row is None:
                raise UnavailableError(f"clip {entry.info.name!r} is not in the index (.qidx)")
            target = entry.row.path  # unique in the index, unlike a name
        with ClipIndex.open(self.index_path) as index:
            by_path = {r.path: r.id for r in index.rows()}
            if isinstance(target, Motion) and index.settings.read.joint_map:
                from quatmotion.collection import with_joint_map  # the index's user map

                target = with_joint_map(target, index.settings.read.joint_map, if_fits=True)
            own = query_row(index, target, sha256=sha256)
            results = search(index, target, method=name, k=top, sha256=sha256)
        hits = [
            SearchHit(
                rank=r.rank,
                id=self._by_row.get(by_path.get(r.path, -1)),
                clip=r.clip,
                label=r.label,
                distance=r.as_dict()["distance"],  # type: ignore[arg-type]
            )
            for r in results
        ]
        return name, hits, None if own is None else own.name

    def pose_search(
        self, clip_id: str, frame: int, *, k: int = 10, other_clips: bool = False
    ) -> tuple[int, list[PoseHit]]:
        """The poses nearest to frame ``frame`` of a clip under the pose index's learned metric.

        Returns
        -------
        (frame, hits)
            The frame of the indexed pose used as the query (the one nearest in time) and the
            poses found, nearest first.

        Raises
        ------
        UnavailableError
            No pose index, or a clip that is not in it.
        """
        entry = self._entry(clip_id)
        if self._poses is None:
            raise UnavailableError("pose search needs a pose index: start the server with --poses")
        if entry.pose_clip is None:
            raise UnavailableError(f"clip {entry.info.name!r} is not in the pose index")
        if not 0 <= frame < entry.info.frames:
            raise ValueError(
                f"frame {frame} is not within clip {entry.info.name!r} "
                f"(frames 0 to {entry.info.frames - 1})"
            )
        with self._poses_lock:
            query, own, found = self._poses.pose_query(entry.pose_clip, frame)
            matches = self._poses.nearest(query, k, exclude_clip=own if other_clips else None)
        hits = [
            PoseHit(
                rank=m.rank,
                id=self._by_pose_clip.get(m.clip),
                clip=Path(m.name).stem,
                frame=m.frame,
                seconds=m.seconds,
                distance=m.distance,
            )
            for m in matches
        ]
        return found, hits


def _unique_id(name: str, used: set[str]) -> str:
    """An id for ``name``: its safe characters, made unique with ``~2``, ``~3``..."""
    base = _ID_CHARS.sub("_", name).strip("._") or "clip"
    base = base[:100]
    candidate, n = base, 1
    while candidate in used:
        n += 1
        candidate = f"{base}~{n}"
    used.add(candidate)
    return candidate


def _located(ref: ClipRef | None, library: Path | None) -> ClipRef | None:
    """A library's clip reference with its files as found now (:meth:`ClipRef.locate`
    against the library's folder); None for a version 1 clip (no reference)."""
    if ref is None:
        return None
    path, skeleton = ref.locate(library.parent if library is not None else None)
    return dataclasses.replace(
        ref,
        path=None if path is None else str(path),
        skeleton_path=None if skeleton is None else str(skeleton),
    )


def _skeleton_of(ref: ClipRef, path: Path) -> Path | None:
    """The ASF an AMC was read with: the one its reference names when still there, else the
    one the lookup finds (:func:`quatmotion.collection.find_skeleton`)."""
    if path.suffix.lower() != ".amc":
        return None
    if ref.skeleton_path and Path(ref.skeleton_path).is_file():
        return Path(ref.skeleton_path)
    return find_skeleton(path)
