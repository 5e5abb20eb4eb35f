"""Step 2, the skeleton table: the archive's skeleton records and entries, each skeleton found
again in O(1) (:class:`SkeletonTable`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from quatmotion.codec.container import (
    RecordEntry,
    SkeletonEntry,
)
from quatmotion.codec.skeletons import deflate_text, same_skeleton, skeleton_record
from quatmotion.motion import Skeleton


@dataclass
class SkeletonTable:
    """The archive's skeleton records and entries, found again by dictionary lookups.

    A skeleton is keyed by :meth:`Skeleton.fingerprint`; exact equality (``same_skeleton``)
    still decides within a fingerprint's bucket, so a digest collision can never merge two
    skeletons. A record is keyed by its (kind, scale, text). Each lookup is O(1) in the number
    of skeletons already held (a library of one skeleton per clip stays linear)."""

    records: list[RecordEntry] = field(default_factory=list)
    texts: list[str] = field(default_factory=list)
    skeletons: list[SkeletonEntry] = field(default_factory=list)
    objects: list[Skeleton] = field(default_factory=list)
    new_records: list[bytes] = field(default_factory=list)
    comparisons: int = 0
    """How many exact skeleton comparisons were made (the lookups' cost, for the tests)."""

    def __post_init__(self) -> None:
        self._by_object: dict[int, int] = {}  # id() of a held object (kept alive by objects)
        self._by_fingerprint: dict[str, list[int]] = {}
        self._record_of: dict[tuple[int, float, str], int] = {}
        self._first_text: dict[int, str] = {}
        for k, s in enumerate(self.objects):
            self._by_object.setdefault(id(s), k)
            self._by_fingerprint.setdefault(s.fingerprint(), []).append(k)
        for k, (r, t) in enumerate(zip(self.records, self.texts, strict=True)):
            self._record_of.setdefault((r.kind, r.scale, t), k)
            self._first_text.setdefault(r.kind, t)

    def index(self, skeleton: Skeleton) -> int:
        """The skeleton's entry, adding it (and its record, if its text is new)."""
        k = self._by_object.get(id(skeleton))
        if k is not None and self.objects[k] is skeleton:
            return k
        fingerprint = skeleton.fingerprint()
        bucket = self._by_fingerprint.setdefault(fingerprint, [])
        for k in bucket:
            self.comparisons += 1
            if same_skeleton(self.objects[k], skeleton):
                return k
        kind, text, scale = skeleton_record(skeleton)
        key = (kind, scale, text)
        record = self._record_of.get(key)
        if record is None:
            self.new_records.append(deflate_text(text, self._first_text.get(kind, "")))
            self.records.append(RecordEntry(kind, scale))
            self.texts.append(text)
            record = len(self.records) - 1
            self._record_of[key] = record
            self._first_text.setdefault(kind, text)
        self.skeletons.append(SkeletonEntry(record, skeleton.name))
        self.objects.append(skeleton)
        k = len(self.objects) - 1
        bucket.append(k)
        self._by_object[id(skeleton)] = k
        return k
