"""A saved, searchable pose library: "poses like frame F of clip C".

Every pose of a motion library is described by the GPD, scaled (min-max, clipped to the library's
range, then unit length), projected by a learned metric ``W``, and put in an HNSW graph
(:class:`~quatmotion.pose.index.HNSWIndex`). In the projected space the learned distance
``sqrt((x - y)^T W W^T (x - y))`` is plain Euclidean distance, so an L2 index answers
learned-metric queries. :meth:`PoseLibrary.build` learns the metric from the library itself,
on transition pairs labelled by Kovar's windowed point-cloud distance (:func:`training_set`),
by the registered method of that name (``quatmotion.pose.methods.METHODS[metric_name]``,
whose ``projection_`` the library stores: ``bench pose`` scores that same code, trained on
the same kind of set, as its ``"pose index default"`` row):

* ``"GPD+LOGIT"`` (the default; docs/performance.md compares it in ``bench pose_blend``):
  non-negative weights per GPD dimension by logistic regression on good and bad pairs
  (:class:`~quatmotion.pose.metric.PairLogistic`); ``W`` is the diagonal of their square
  roots, dimensions of weight 0 left out.
* ``"GPD+LMS"``: the same with least-squares weights.
* ``"GPD+RDSR"`` (the GPD paper): RDSR of rank ``rank`` from the similar pairs and an
  unlabeled random sample.

A library of a single clip has no cross-clip pairs: then consecutive frames serve as the
similar pairs, and (for LMS) poses at least a second apart as the dissimilar ones.

Conventions
-----------
* Clips are prepared by :meth:`PoseClip.from_motion` (resampled, put on the canonical body of
  one stature); queries go through :meth:`PoseLibrary.prepare_query`, so they are described
  alike whatever their skeleton.
* Features are clipped to the library's range after the min-max step: a query from another
  body or motion may exceed the range in a few features (nearly constant ones, such as the
  spread of a rigid pelvis), and unclipped they would dominate its unit-length vector, so that
  every such query lands on the same few poses.
* Frame numbers count from 0 in the clip's file, before any resampling (an AMC file's frame 1
  is frame 0). Asking for a frame outside a clip, or a clip that is not there, is an error
  naming what there is.
* A library file is one ``.npz`` holding the serialised HNSW graph, the projection model and the
  pose catalogue (clip names, frame numbers, fps), with a ``meta`` record naming the format
  (``quatmotion-pose-library``) and its version; it is written to a temporary file and then
  renamed, so a reader never sees half a library. Reading checks both, raising
  :class:`~quatmotion.FormatError`.
"""

from __future__ import annotations

import dataclasses
import errno
import functools
import json
import math
import os
import pathlib
import time
import zipfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from numbers import Integral, Real
from typing import Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from quatmotion._atomic import atomic_output
from quatmotion._deprecated import warn_renamed
from quatmotion._format import FileFormat, npy_header
from quatmotion._settings import Interval, Settings, StrOptions
from quatmotion.collection import (
    BuildReport,
    ClipRef,
    ClipSource,
    ReadSettings,
    content_hash,
    find_clips,
    name_apart,
    read_clip,
    with_joint_map,
)
from quatmotion.errors import FormatError
from quatmotion.io import Doubt
from quatmotion.io.names import match_clip
from quatmotion.limits import check, load_json
from quatmotion.motion import Motion
from quatmotion.parallel import Failure, Runner, Scheduler, imap_batch
from quatmotion.pose import labels
from quatmotion.pose.data import PoseClip, PoseData
from quatmotion.pose.index import HNSWIndex
from quatmotion.pose.methods import METHODS, pose_features, project_features
from quatmotion.pose.ranges import DEFAULT_METRIC, FPS_RANGE
from quatmotion.pose.transition import TransitionClassifier

__all__ = [
    "DEFAULT_METRIC",
    "METRICS",
    "PoseLibrary",
    "PoseMatch",
    "PoseSettings",
    "ProjectedClip",
    "load_pose_clip",
    "project_gpd",
    "projected_clip",
]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

FORMAT = FileFormat("quatmotion-pose-library", 3, 2, "a quatmotion pose library")
"""3: the clips' references and the settings in ``meta``; 2 (0.3.0, still read): poses on the
canonical body, features clipped to the library's range."""
_FORMAT = FORMAT.name
_VERSION = FORMAT.version
HEIGHT_RANGE = (50.0, 300.0)  # cm: a stature from a small child to beyond the tallest adult
_NOT_A_LIBRARY = (
    f"not a quatmotion pose library (expected a file written by 'quatmotion pose index': "
    f"format {_FORMAT}, {FORMAT.versions_text()})"
)
# Fewer transition pairs than this teach a metric too little: use consecutive frames instead.
_MIN_TRANSITION_PAIRS = 10
_FAR_APART_S = 1.0  # fallback dissimilar pairs: poses of one clip at least this far apart

METRICS: tuple[str, ...] = ("GPDR+LOGIT", "GPDR+LMS", "GPD+LMS", "GPD+LOGIT", "GPD+RDSR")
"""The pose distances :meth:`PoseLibrary.build` can learn."""


def _at_least(n: int) -> Interval:
    return Interval(Integral, n, None, closed="left")


@dataclasses.dataclass(frozen=True)
class PoseSettings(Settings):
    """How a pose library is built (stored in its ``meta``, shown by ``pose ls``).

    Attributes
    ----------
    fps : float
        Frame rate the poses are sampled at (:data:`FPS_RANGE`).
    height : float
        Stature of the canonical body every skeleton is put on, cm (:data:`HEIGHT_RANGE`).
    metric : str
        The pose distance learned (:data:`METRICS`).
    rank : int
        Rank of RDSR's projection.
    n_unlabeled : int
        Unlabeled poses for RDSR's sparse-representation term.
    n_pairs : int
        Transition pairs wanted (similar, and as many dissimilar for LMS).
    seed : int
        Of the sample, the pairs and the graph.
    fit_poses : int
        Poses (of clips drawn at random) the distance is learned on.
    M, ef_construction : int
        HNSW graph parameters.
    flush_poses : int
        Vectors per insertion into the graph.
    index_threads : int
        Threads inserting into the graph (1: the same bytes whatever ran the jobs).
    chunk_size : int or None
        Clips per task of the index pass (None: :meth:`PoseLibrary.build_streamed` chooses).
    read : ReadSettings
        How the clips are read (``strict``: a clip beyond a kilometre is refused).
    """

    fps: float = 30.0
    height: float = 170.0
    metric: str = DEFAULT_METRIC
    rank: int = 50
    n_unlabeled: int = 5000
    n_pairs: int = 500
    seed: int = 0
    fit_poses: int = 20_000
    M: int = 16
    ef_construction: int = 100
    flush_poses: int = 4096
    index_threads: int = 1
    chunk_size: int | None = None
    read: ReadSettings = dataclasses.field(default_factory=ReadSettings)

    _parameter_constraints: ClassVar[dict[str, list[Any]]] = {
        "fps": [Interval(Real, *FPS_RANGE, closed="both")],
        "height": [Interval(Real, *HEIGHT_RANGE, closed="both")],
        "metric": [StrOptions(set(METRICS))],
        "rank": [_at_least(1)],
        "n_unlabeled": [_at_least(1)],
        "n_pairs": [_at_least(1)],
        "seed": [_at_least(0)],
        "fit_poses": [_at_least(1)],
        "M": [_at_least(2)],
        "ef_construction": [_at_least(1)],
        "flush_poses": [_at_least(1)],
        "index_threads": [_at_least(1)],
        "chunk_size": [_at_least(1), None],
        "read": [ReadSettings],
    }


@dataclass(frozen=True)
class PoseMatch:
    """One pose found by :meth:`PoseLibrary.nearest`.

    Attributes
    ----------
    rank : int
        From 1, nearest first.
    clip : int
        Clip number (into ``PoseLibrary.clip_names``).
    name : str
        The clip's name as indexed.
    frame : int
        Frame number in the clip's file, from 0.
    seconds : float or None
        ``frame`` over the file's frame rate (None for a library that does not store it).
    distance : float
        Learned pose distance to the query.
    """

    rank: int
    clip: int
    name: str
    frame: int
    seconds: float | None
    distance: float


@dataclass
class PoseLibrary:
    """A searchable pose library: projection model, HNSW index and pose catalogue.

    Attributes
    ----------
    index : HNSWIndex
        Over the projected poses; item ``i`` is pose ``i`` of the catalogue.
    clip_names : list of str
        One per clip (file paths as given when indexing).
    clip_of : ndarray of int, shape (N,)
        Clip of every indexed pose.
    frame_of : ndarray of int, shape (N,)
        Frame number of every indexed pose, in the clip's file (before any subsampling).
    model : dict of str to ndarray
        The projection: ``scale`` and ``offset`` (shape (D,), the GPD normalisation of Eq. 38),
        ``W`` (shape (D, r), the metric's projection); poses map to
        ``unit(clip(scale * gpd + offset, 0, 1)) @ W``.
    meta : dict
        JSON-serialisable settings (fps, frame step, height, method, labels used...).
    pose_rows : ndarray of float32, shape (N, m), optional
        Every indexed pose described for the transition judge (``model``'s ``transition_*``
        arrays, :class:`~quatmotion.pose.transition.TransitionClassifier`); ``None`` in a
        library without one (built before it, or from clips that gave no good and bad
        transitions to learn from).
    """

    index: HNSWIndex
    clip_names: list[str]
    clip_of: IntArray
    frame_of: IntArray
    model: dict[str, FloatArray]
    meta: dict[str, Any] = field(default_factory=dict)
    refs: list[ClipRef] = field(default_factory=list)
    settings: PoseSettings | None = None
    version: int = FORMAT.version
    path: pathlib.Path | None = None
    pose_rows: NDArray[np.float32] | None = None

    # -- the collection surface ------------------------------------------------------------
    @property
    def format(self) -> FileFormat:
        """The format, with the version this library was read in (the current one if built)."""
        return dataclasses.replace(FORMAT, version=self.version)

    def clips(self) -> tuple[ClipRef, ...]:
        """Every clip's reference, in catalogue order. A version-2 library stored none: its
        clips' paths (resolved against the library's folder) give them, the content hash of
        the file found (of the name, where the file is gone: matching no other clip)."""
        if self.refs:
            return tuple(self.refs)
        from quatmotion.collection import unique_names

        base = None if self.path is None else self.path.resolve().parent
        paths = []
        for name in self.clip_names:
            p = pathlib.Path(name)
            if not p.is_absolute() and base is not None and (base / p).is_file():
                p = base / p
            paths.append(pathlib.Path(os.path.abspath(p)))
        out = []
        for p, name in zip(paths, unique_names(paths), strict=True):
            asf = None
            try:
                if p.suffix.lower() == ".amc":
                    from quatmotion.collection import find_skeleton

                    asf = find_skeleton(p)
                sha = content_hash(p, asf)
            except (OSError, FormatError):
                import hashlib

                sha = hashlib.sha256(f"missing clip {p}".encode()).hexdigest()
            out.append(ClipRef(name, sha, str(p), None if asf is None else str(asf)))
        return tuple(out)

    @classmethod
    def open(cls, path: str | os.PathLike[str], ef_search: int = 64) -> PoseLibrary:
        """Read a library (any version from :data:`FORMAT`'s ``oldest_readable``).

        Raises
        ------
        FormatError
            Not a quatmotion pose library, or a version this code does not read.
        """
        try:
            arrays = _load_arrays(path)
            meta = load_json(str(arrays.get("meta", "null")), path, "meta")
            if not isinstance(meta, dict) or meta.get("format") != _FORMAT:
                raise FormatError(_NOT_A_LIBRARY, path)
            version = FORMAT.check(meta.get("format"), meta.get("version"), path)
            refs = [ClipRef.from_dict(r, path) for r in meta.pop("clips", [])]
            stored = meta.pop("settings", None)
            settings = None if stored is None else PoseSettings.from_dict(stored, path)
            model = {k[6:]: arrays[k] for k in arrays if k.startswith("model_")}
            n_items, dim = _check_catalogue(arrays, meta, model, refs)
            index = HNSWIndex.from_bytes(
                arrays["index"].tobytes(), dim=dim, ef_search=ef_search, n_items=n_items
            )
            return cls(
                pose_rows=arrays.get("pose_rows"),
                index=index,
                clip_names=[str(n) for n in arrays["clip_names"]],
                clip_of=arrays["clip_of"].astype(np.int64),
                frame_of=arrays["frame_of"].astype(np.int64),
                model=model,
                meta=meta,
                refs=refs,
                settings=settings,
                version=version,
                path=pathlib.Path(path),
            )
        except FormatError:
            raise
        except (IsADirectoryError, FileNotFoundError, PermissionError):
            raise
        except _MalformedError as exc:
            raise FormatError(f"malformed pose library: {exc}", path) from None
        except (KeyError, ValueError, TypeError, OSError, EOFError, zipfile.BadZipFile) as exc:
            # np.load's own message (pickled data, a bad zip...) says nothing about what the
            # file should have been.
            raise FormatError(_NOT_A_LIBRARY, path) from exc

    @classmethod
    def _build_file(
        cls,
        sources: Sequence[Any],
        out: str | os.PathLike[str],
        settings: PoseSettings | None = None,
        *,
        runner: Runner | str | Scheduler | None = None,
        workers: int | None = None,
        progress: Callable[[str, int, int], None] | None = None,
        log: Callable[[str], None] | None = None,
        on_doubt: Callable[[str, Doubt], None] | None = None,
    ) -> BuildReport:
        """Build the library of ``sources`` (files, folders, motions in memory) into ``out``
        (:meth:`build_streamed` on the clips :func:`quatmotion.collection.find_clips` finds,
        each read by :func:`quatmotion.collection.read_clip`); the settings and the clips'
        references are stored in the file.

        Returns
        -------
        BuildReport
            ``added`` the clips indexed, ``failures`` the others; ``details["library"]`` the
            library written.

        Raises
        ------
        ValueError
            No clip could be read.
        """
        settings = settings or PoseSettings()
        report = BuildReport(path=pathlib.Path(out), settings=settings)
        errors: list[tuple[str, str]] = []
        found = find_clips(sources, settings.read, on_error=errors)
        report.failures += [Failure(i, p, reason) for i, (p, reason) in enumerate(errors)]
        load = functools.partial(
            load_pose_source, fps=settings.fps, height=settings.height, read=settings.read
        )
        library, failures = cls.build_streamed(
            found,
            load,
            fit_poses=settings.fit_poses,
            rank=settings.rank,
            n_unlabeled=settings.n_unlabeled,
            n_pairs=settings.n_pairs,
            seed=settings.seed,
            M=settings.M,
            ef_construction=settings.ef_construction,
            metric_name=settings.metric,
            workers=workers,
            scheduler=runner.scheduler if isinstance(runner, Runner) else runner,
            chunk_size=settings.chunk_size,
            flush_poses=settings.flush_poses,
            index_threads=settings.index_threads,
            progress=progress,
            log=log,
            on_doubt=on_doubt,
        )
        failed = {f.index for f in failures}
        library.refs = [s.ref() for i, s in enumerate(found) if i not in failed]
        library.settings = settings
        library.save(out)
        report.added = list(library.refs)
        report.failures += failures
        report.details["library"] = library
        return report

    @classmethod
    def add(
        cls,
        path: str | os.PathLike[str],
        sources: Sequence[Any],
        *,
        skeleton: str | os.PathLike[str] | None = None,
        units: str | float | None = None,
        joint_map: Sequence[str] | None = None,
        runner: Runner | str | Scheduler | None = None,
        workers: int | None = None,
        progress: Callable[[str, int, int], None] | None = None,
        log: Callable[[str], None] | None = None,
        on_doubt: Callable[[str, Doubt], None] | None = None,
    ) -> BuildReport:
        """Add ``sources`` to the library at ``path`` with its stored settings and distance
        (nothing is learned again): each new clip is read, projected and inserted into the
        graph; a clip whose content the library already holds is skipped; a new clip whose
        name a stored clip of another file has is named by the collection's rule
        (:func:`~quatmotion.collection.unique_names` over the two paths). The file is
        rewritten whole (temporary file, then rename). ``skeleton``, ``units`` and
        ``joint_map`` (``"Canonical=joint"`` entries) replace the stored
        :class:`~quatmotion.collection.ReadSettings`' for the new clips.

        Raises
        ------
        FileNotFoundError
            No library at ``path``.
        ValueError
            A version-2 library (it stored no settings: rebuild it), or no clip could be read.
        """
        path = pathlib.Path(path)
        if not path.is_file():
            raise FileNotFoundError(errno.ENOENT, "no pose library", str(path))
        library = cls.open(path)
        settings = library.settings
        if settings is None:
            raise ValueError(f"{path}: a version-{library.version} library stores no settings; "
                             "build it again to add clips")  # fmt: skip
        given = {
            "skeleton": None if skeleton is None else os.fspath(skeleton),
            "units": units,
            "joint_map": None if joint_map is None else tuple(joint_map),
        }
        given = {k: v for k, v in given.items() if v is not None}
        if given:  # how the new clips are read, over the stored reading settings
            read = dataclasses.replace(settings.read, **given)
            settings = dataclasses.replace(settings, read=read)
        report = BuildReport(path=path, settings=settings, details={"resumed": True})
        report.details["clips_before"] = len(library.clip_names)
        errors: list[tuple[str, str]] = []
        found = find_clips(sources, settings.read, on_error=errors)
        report.failures += [Failure(i, p, reason) for i, (p, reason) in enumerate(errors)]
        held = {r.sha256 for r in library.clips()}
        refs = list(library.clips())
        new: list[ClipSource] = []
        for source in found:
            if source.sha256 in held:
                report.skipped.append(source.ref())
                continue
            ref = name_apart(source.ref(), refs, path)
            refs.append(ref)
            held.add(source.sha256)
            new.append(dataclasses.replace(source, name=ref.name))
        if not new:
            report.details["library"] = library
            return report
        load = functools.partial(
            load_pose_source, fps=settings.fps, height=settings.height, read=settings.read
        )
        scheduler = runner.scheduler if isinstance(runner, Runner) else runner
        failed: dict[int, Failure] = {}
        n_old = len(library.clip_names)
        capacity = library.index.n_items_ * (n_old + len(new)) // max(1, n_old)
        graph = _Graph(library.index, flush_poses=settings.flush_poses, capacity=capacity)
        catalogue = _index_pass(
            new, list(range(len(new))), load, library.model,
            fps=library.meta["fps"], height=library.meta["height_cm"], graph=graph,
            failed=failed, chunk_size=settings.chunk_size,
            batch={"workers": workers, "scheduler": scheduler},
            progress=None if progress is None else functools.partial(progress, "index"),
            on_doubt=on_doubt, metric=library.metric,
        )  # fmt: skip
        graph.close()
        if not catalogue.names:
            raise ValueError(_none_read(len(new), failed))
        library._extend(catalogue)
        added = [s.ref() for i, s in enumerate(new) if i not in failed]
        library.refs = list(library.clips()) + added
        library.save(path)
        report.added = added
        report.failures += [dataclasses.replace(failed[i], item=new[i]) for i in sorted(failed)]
        report.details["library"] = library
        say = log or (lambda _msg: None)
        say(f"added {len(added)} clips to {path} ({len(report.skipped)} already there)")
        return report

    def _extend(self, catalogue: _Catalogue) -> None:
        """Append the catalogue's clips (their vectors already in the graph)."""
        fields = catalogue.library_fields(self.meta["fps"], {})
        if self.pose_rows is not None:
            self.pose_rows = np.concatenate([self.pose_rows, fields["pose_rows"]])
        self.clip_of = np.concatenate([self.clip_of, fields["clip_of"] + len(self.clip_names)])
        self.frame_of = np.concatenate([self.frame_of, fields["frame_of"]])
        self.clip_names = [*self.clip_names, *fields["clip_names"]]
        extra = fields["meta"]
        self.meta = {
            **self.meta,
            "file_fps": [*self.meta.get("file_fps", []), *extra["file_fps"]],
            "file_frames": [*self.meta.get("file_frames", []), *extra["file_frames"]],
            "skeletons": sorted({*self.meta.get("skeletons", []), *extra["skeletons"]}),
        }

    @classmethod
    def build(
        cls,
        sources: Sequence[Any],
        out: str | os.PathLike[str] | None = None,
        settings: PoseSettings | None = None,
        **options: Any,
    ) -> Any:
        """Build a library: ``build(sources, out, settings, *, runner, workers, progress, log,
        on_doubt) -> BuildReport`` writes the file (the collection surface); without ``out``,
        ``build(clips, *, rank, ...)`` learns on prepared :class:`PoseClip` items in memory
        and returns the :class:`PoseLibrary` (:meth:`build_in_memory`)."""
        if out is None:
            if settings is not None:
                options = {
                    "rank": settings.rank, "n_unlabeled": settings.n_unlabeled,
                    "n_pairs": settings.n_pairs, "seed": settings.seed, "M": settings.M,
                    "ef_construction": settings.ef_construction,
                    "metric_name": settings.metric, **options,
                }  # fmt: skip
            return cls.build_in_memory(sources, **options)
        return cls._build_file(sources, out, settings, **options)

    @classmethod
    def build_in_memory(
        cls,
        clips: Sequence[PoseClip],
        *,
        rank: int = 50,
        n_unlabeled: int = 5000,
        n_pairs: int = 500,
        seed: int = 0,
        M: int = 16,
        ef_construction: int = 100,
        metric: Any = None,
        metric_name: str = DEFAULT_METRIC,
        log: Callable[[str], None] | None = None,
    ) -> PoseLibrary:
        """Learn a pose distance on the clips' own poses, project every pose and index it.

        The steps: GPD of every pose; positive pairs (good transitions by Kovar's windowed
        point-cloud distance, :func:`~quatmotion.pose.labels.transition_labels`, or
        consecutive frames when the clips yield fewer than 10); the min-max (clipped) + unit-length
        scaling fitted on the unlabeled sample and the pairs; the metric learned from them;
        every pose projected by it into an HNSW index.

        Parameters
        ----------
        clips : sequence of PoseClip
            All prepared at the same frame rate and height (:meth:`PoseClip.from_motion`).
        rank : int
            Rank of the projection ``W`` (its dimensions).
        n_unlabeled : int
            Unlabeled poses for the metric's sparse-representation term.
        n_pairs : int
            Positive transition pairs wanted.
        seed : int
        M, ef_construction : int
            HNSW graph parameters.
        metric : estimator, optional
            For ``"GPD+RDSR"``: unfitted, with ``fit(X_unlabeled, positive_pairs)`` and
            ``components_`` of shape ``(rank, D)`` after fitting; default
            ``RDSR(n_components=rank)``.
        metric_name : {"GPDR+LOGIT", "GPDR+LMS", "GPD+LOGIT", "GPD+LMS", "GPD+RDSR"}
            The pose distance to learn (module docstring); ``rank`` applies to RDSR only.
        log : callable, optional
            Called with progress messages.

        Returns
        -------
        PoseLibrary
        """
        if not clips:
            raise ValueError("no clips to index")
        # The in-memory case of the streamed build: every clip is the sample (fit_poses is all
        # their poses, so the distance is learned on all clips in input order) and the index
        # pass runs inline on the clips as given.
        library, failures = cls.build_streamed(
            list(clips),
            _as_given,
            fit_poses=max(1, sum(len(c) for c in clips)),
            rank=rank,
            n_unlabeled=n_unlabeled,
            n_pairs=n_pairs,
            seed=seed,
            M=M,
            ef_construction=ef_construction,
            metric=metric,
            metric_name=metric_name,
            scheduler="inline",
            log=log,
        )
        if failures:
            first = failures[0]
            raise ValueError(f"clip {clips[first.index].name!r}: {first.message}")
        return library

    @classmethod
    def build_streamed(
        cls,
        sources: Sequence[Any],
        load: Callable[[Any], PoseClip],
        *,
        fit_poses: int = 20_000,
        rank: int = 50,
        n_unlabeled: int = 5000,
        n_pairs: int = 500,
        seed: int = 0,
        M: int = 16,
        ef_construction: int = 100,
        metric: Any = None,
        metric_name: str = DEFAULT_METRIC,
        workers: int | None = None,
        scheduler: str | Scheduler | None = None,
        chunk_size: int | None = None,
        flush_poses: int = 4096,
        index_threads: int = 1,
        progress: Callable[[str, int, int], None] | None = None,
        log: Callable[[str], None] | None = None,
        on_doubt: Callable[[str, Doubt], None] | None = None,
    ) -> tuple[PoseLibrary, list[Failure]]:
        """Build a library of any size in bounded memory, the clips prepared in parallel.

        Two passes over ``sources``, each a batch of :mod:`quatmotion.parallel` (local process
        pool, or Dask with ``scheduler``):

        1. *Learn*: clips are loaded in a seeded random order until they hold ``fit_poses``
           poses (at least two clips); the distance is learned on that sample exactly as
           :meth:`build` learns it on all clips (in input order), so a library smaller than
           ``fit_poses`` gets the model :meth:`build` would give it.
        2. *Index*: every clip is loaded again in a worker, described and projected there; the
           vectors (float32, ``rank`` per pose) come back in input order and go into the
           HNSW graph ``flush_poses`` at a time, on ``index_threads`` threads: with one (the
           default) the library is the same bytes whatever the scheduler and the number of
           workers.

        Memory holds the sample, a window of projected clips and the index itself; neither
        all poses nor their GPD features are ever in one array.

        Parameters
        ----------
        sources : sequence
            One item per clip, passed to ``load`` (file paths, generator specs...).
        load : callable
            ``load(source) -> PoseClip``, module-level (picklable), every clip at the same
            frame rate and height; an exception skips that clip (reported, never fatal).
        fit_poses : int
            Poses the distance is learned on (the sample grows a clip at a time to this).
        rank, n_unlabeled, n_pairs, seed, M, ef_construction, metric, metric_name
            As for :meth:`build`.
        workers, scheduler
            Where the clips are prepared: :func:`quatmotion.parallel.imap_batch`.
        chunk_size : int, optional
            Clips per task of the index pass. Each task carries the projection model (its
            size: docs/performance.md), so by default eight clips share one once there are
            at least 64 clips, else every clip is a task. The learn pass sends clips one by one.
        flush_poses : int
            Vectors per insertion into the HNSW graph.
        index_threads : int
            Threads inserting into the graph, in this process. One keeps the library the
            same bytes whatever the scheduler; more insert faster (the insertion is the part
            of the build that does not spread over workers), but the graph then depends on
            thread timing (its search results barely).
        progress : callable, optional
            ``progress(stage, done, total)`` with stage ``"learn"`` (clips loaded for the
            sample, out of all clips; stops when the sample is complete) or ``"index"``.
        log : callable, optional
            Called with progress messages.
        on_doubt : callable, optional
            ``on_doubt(clip name, doubt)`` for each of a clip's :attr:`PoseClip.doubts`, once,
            in the index pass.

        Returns
        -------
        library : PoseLibrary
            Over the clips that could be read, in input order (their failures left out).
        failures : list of Failure
            Clips skipped, in input order, each with a one-line reason.

        Raises
        ------
        ValueError
            No clip could be read, or the parameters are out of range.
        """
        say = log or (lambda _msg: None)
        sources = list(sources)
        if not sources:
            raise ValueError("no clips to index")
        for name, value in (
            ("fit_poses", fit_poses),
            ("flush_poses", flush_poses),
            ("index_threads", index_threads),
        ):
            if value < 1:
                raise ValueError(f"{name} must be at least 1, got {value}")
        batch = {"workers": workers, "scheduler": scheduler}

        def stage(name: str) -> Callable[[int, int], None] | None:
            return None if progress is None else functools.partial(progress, name)

        sample = _draw_sample(sources, load, fit_poses, seed, batch, stage("learn"))
        say(f"learning the distance on {len(sample.clips)} clips ({sample.n_poses} poses)")
        model, meta, sample_poses = _learn_projection(
            sample.clips,
            rank=rank,
            n_unlabeled=n_unlabeled,
            n_pairs=n_pairs,
            seed=seed,
            metric=metric,
            metric_name=metric_name,
            say=say,
        )
        judge, judged = _learn_transitions(
            sample.clips, n_pairs=n_pairs, n_unlabeled=n_unlabeled, seed=seed, say=say,
            poses=sample_poses,
        )  # fmt: skip
        del sample_poses
        model, meta = {**model, **judge}, {**meta, **judged}
        fps, height = sample.clips[0].fps, sample.clips[0].height
        failed = sample.failed
        kept = [i for i in range(len(sources)) if i not in failed]
        graph = _Graph(
            HNSWIndex(
                M=M, ef_construction=ef_construction, n_threads=index_threads, random_state=seed
            ),
            flush_poses=flush_poses,
            capacity=int(1.05 * sample.n_poses / len(sample.clips) * len(kept)),
        )
        n_fit_clips, n_fit_poses = len(sample.clips), sample.n_poses
        del sample
        t0 = time.perf_counter()
        catalogue = _index_pass(
            sources, kept, load, model, fps=fps, height=height, graph=graph, failed=failed,
            chunk_size=chunk_size, batch=batch, progress=stage("index"), on_doubt=on_doubt,
            metric=meta["metric"],
        )  # fmt: skip
        index = graph.close()
        if not catalogue.names:
            raise ValueError(_none_read(len(sources), failed))
        seconds = time.perf_counter() - t0
        say(f"indexed {index.n_items_} poses of {len(catalogue.names)} clips: {seconds:.1f} s")
        meta = {**meta, "fit_clips": n_fit_clips, "fit_poses": n_fit_poses}
        library = cls(index=index, model=model, **catalogue.library_fields(fps, meta))
        return library, [failed[i] for i in sorted(failed)]

    def prepare_query(self, motion: Motion) -> PoseClip:
        """``motion`` prepared as the indexed clips were (same frame rate and body height)."""
        return PoseClip.from_motion(motion, fps=self.meta["fps"], height=self.meta.get("height_cm"))

    @property
    def metric(self) -> str:
        """The registered method (:data:`quatmotion.pose.methods.METHODS`) the library learned;
        libraries of 0.3.0 that did not record it learned ``GPD+RDSR``."""
        return str(self.meta.get("metric", "GPD+RDSR"))

    def features(self, poses: PoseData) -> FloatArray:
        """Raw feature rows of ``poses`` for the library's metric (GPD, or GPD with the root's
        travel for ``GPDR+...``), shape (N, D): what :meth:`project` maps."""
        return pose_features(poses, self.metric)

    def project(self, raw: ArrayLike) -> FloatArray:
        """Map raw feature rows (:meth:`features`) to the index space.

        Parameters
        ----------
        raw : array_like, shape (N, D)
            :meth:`features` output (for a ``GPD+...`` library, the GPD itself).

        Returns
        -------
        ndarray, shape (N, r)
        """
        raw = np.asarray(raw, dtype=np.float64)
        expected = np.shape(self.model["scale"])[0]
        if raw.ndim != 2 or raw.shape[1] != expected:
            raise ValueError(
                f"feature rows have shape {raw.shape}, expected (N, {expected}) "
                f"({self.metric}: rows of PoseLibrary.features)"
            )
        return project_gpd(raw, self.model)

    def project_poses(self, poses: PoseData) -> FloatArray:
        """``poses`` in the index space, shape (N, r): ``project(features(poses))``."""
        return self.project(self.features(poses))

    def find(self, clip: str | int, frame: int) -> int:
        """Catalogue number of the indexed pose nearest in time to ``frame`` of ``clip``.

        Parameters
        ----------
        clip : str or int
            See :meth:`clip_number`.
        frame : int
            Frame number in the clip's file, from 0.

        Raises
        ------
        ValueError
            For a clip that is not there (naming close names) or a frame outside the clip
            (naming its frames).
        """
        c = self.clip_number(clip)
        n_frames = self.file_frames(c)
        if not 0 <= frame < n_frames:
            raise ValueError(
                f"frame {frame} is out of range: {self.clip_names[c]} has frames 0 to "
                f"{n_frames - 1} (frames count from 0; an AMC file's frame 1 is frame 0)"
            )
        rows = np.flatnonzero(self.clip_of == c)
        if len(rows) == 0:
            raise ValueError(f"clip {self.clip_names[c]!r} has no indexed pose")
        return int(rows[np.argmin(np.abs(self.frame_of[rows] - frame))])

    def file_frames(self, clip: int) -> int:
        """Frames of clip number ``clip``'s file (its last indexed frame + 1 in libraries that
        did not record it)."""
        recorded = self.meta.get("file_frames")
        if recorded and recorded[clip] is not None:
            return int(recorded[clip])
        return int(self.frame_of[self.clip_of == clip].max(initial=-1)) + 1

    def clip_number(self, clip: str | int) -> int:
        """The number of an indexed clip.

        Parameters
        ----------
        clip : str or int
            The clip's name (its path as indexed), a unique end of it (the file name, its stem,
            or trailing folders), or its number from 0; digits are read as a number only when
            no clip is named so (:func:`quatmotion.io.names.match_clip`, the rule of every
            command).

        Raises
        ------
        ValueError
            (:class:`~quatmotion.errors.ClipNameError`) Naming up to five close names when none
            matches, or the matches when several do.
        """
        return match_clip(clip, self.clip_names, "the pose library")

    def search(self, vectors: ArrayLike, k: int = 10) -> tuple[IntArray, FloatArray]:
        """Approximate nearest indexed poses of projected query vectors, ``(Q, k)`` each."""
        return self.index.query(vectors, k)

    def pose_query(self, clip: str | int, frame: int) -> tuple[FloatArray, int, int]:
        """The projected vector ``(1, r)`` of an indexed pose, its clip number and frame.

        The pose is the one indexed nearest in time to ``frame`` of ``clip`` (:meth:`find`).
        """
        item = self.find(clip, frame)
        return self.index.vectors([item]), int(self.clip_of[item]), int(self.frame_of[item])

    def motion_query(self, motion: Motion, frame: int) -> tuple[FloatArray, int]:
        """The projected vector ``(1, r)`` of a clip's pose near ``frame`` and that pose's
        frame number (the query prepared as the library was, :meth:`prepare_query`)."""
        clip, row = self._sampled_pose(motion, frame)
        return self.project_poses(clip.poses[row : row + 1]), row * clip.step

    def _sampled_pose(self, motion: Motion, frame: int) -> tuple[PoseClip, int]:
        """``motion`` prepared as the library was, and the row of its pose nearest ``frame``."""
        clip = self.prepare_query(motion)
        return clip, min(max(int(round(frame / clip.step)), 0), len(clip) - 1)

    def transition_start(
        self, frame: int, *, clip: str | int | None = None, motion: Motion | None = None
    ) -> NDArray[np.float32]:
        """The pose a transition leaves from, described for the judge, shape (1, m): the
        indexed pose of :meth:`pose_query` (``clip``) or the sampled pose of
        :meth:`motion_query` (``motion``), the same pose those queries use."""
        if (clip is None) == (motion is None):
            raise ValueError("give exactly one of clip and motion")
        self._judge()  # a library without a judge says so first
        assert self.pose_rows is not None
        if clip is not None:
            return self.pose_rows[[self.find(clip, frame)]]
        prepared, row = self._sampled_pose(motion, frame)
        return self.describe(prepared.poses[row : row + 1])

    def describe(self, poses: PoseData) -> NDArray[np.float32]:
        """``poses`` described for the library's transition judge, shape (N, m).

        Raises
        ------
        ValueError
            The library has no transition judge (:attr:`pose_rows` is None), saying why.
        """
        return self._judge().describe(poses).astype(np.float32)

    def _judge(self) -> TransitionClassifier:
        judge = transition_judge(self.model)
        if judge is None or self.pose_rows is None:
            why = self.meta.get("transitions", "the library was built before its judge existed")
            raise ValueError(f"this pose library has no transition judge ({why}); rebuild it")
        return judge

    def nearest(
        self,
        query: ArrayLike,
        k: int = 10,
        *,
        exclude_clip: int | None = None,
        transition_from: ArrayLike | None = None,
        candidates: int = 256,
    ) -> list[PoseMatch]:
        """The ``k`` indexed poses nearest to one projected query vector, or, with
        ``transition_from``, the ``k`` best poses to jump to from the query.

        Parameters
        ----------
        query : array_like, shape (1, r)
            From :meth:`pose_query`, :meth:`motion_query` or :meth:`project`.
        k : int
            Poses wanted, at least 1 (fewer when the library holds fewer).
        exclude_clip : int, optional
            Leave out the poses of this clip (e.g. the query's own).
        transition_from : array_like, shape (1, m), optional
            The query pose described for the transition judge (:meth:`describe`, or
            ``pose_rows[i]`` of an indexed pose): the ``max(candidates, k)`` nearest poses are
            re-ranked by the judge's probability that a transition from the query into each
            plays badly, which is then each match's ``distance`` (0 good .. 1 bad).
        candidates : int
            Nearest poses the judge re-ranks.

        Returns
        -------
        list of PoseMatch
        """
        if k < 1:
            raise ValueError(f"k must be at least 1, got {k}")
        n_items = self.index.n_items_
        own = 0 if exclude_clip is None else int(np.sum(self.clip_of == exclude_clip))
        wanted = k if transition_from is None else max(k, candidates)
        ids, dist = self.search(query, min(n_items, wanted + own))
        ids, dist = ids[0], dist[0]
        if exclude_clip is not None:
            keep = self.clip_of[ids] != exclude_clip
            ids, dist = ids[keep], dist[keep]
        if transition_from is not None:
            judge = self._judge()
            assert self.pose_rows is not None  # _judge checked
            start = np.asarray(transition_from, dtype=np.float64).reshape(1, -1)
            bad = judge.score_rows(np.repeat(start, len(ids), axis=0), self.pose_rows[ids])
            order = np.argsort(bad, kind="stable")
            ids, dist = ids[order], bad[order]
        file_fps = self.meta.get("file_fps")
        out = []
        for rank, (i, d) in enumerate(zip(ids[:k], dist[:k], strict=True), start=1):
            c, f = int(self.clip_of[i]), int(self.frame_of[i])
            seconds = f / file_fps[c] if file_fps else None
            out.append(PoseMatch(rank, c, self.clip_names[c], f, seconds, float(d)))
        return out

    def save(self, path: str | os.PathLike[str]) -> None:
        """Write the library to ``path`` (one ``.npz``; temporary file, then rename)."""
        path = pathlib.Path(path)
        meta = dict(self.meta)
        meta.update(format=_FORMAT, version=_VERSION, dim=self.index.dim_)
        if self.refs:  # a library built from files (a version-2 one's are derived on reading)
            meta["clips"] = [r.to_dict() for r in self.refs]
        if self.settings is not None:
            meta["settings"] = self.settings.to_dict()
        payload = {
            "index": np.frombuffer(self.index.to_bytes(), dtype=np.uint8),
            "clip_names": np.asarray(self.clip_names, dtype=str),
            "clip_of": self.clip_of,
            "frame_of": self.frame_of,
            "meta": np.asarray(json.dumps(meta)),
        }
        payload.update({f"model_{k}": v for k, v in self.model.items()})
        if self.pose_rows is not None:
            payload["pose_rows"] = self.pose_rows
        with atomic_output(path) as temp, temp.open("wb") as fh:
            np.savez(fh, **payload)

    @classmethod
    def load(cls, path: str | os.PathLike[str], ef_search: int = 64) -> PoseLibrary:
        """:meth:`open` (the name before 0.4.0; warns)."""
        warn_renamed("PoseLibrary.load", "PoseLibrary.open")
        return cls.open(path, ef_search)


class _MalformedError(ValueError):
    """A pose library whose arrays disagree (the message says which)."""


def _load_arrays(path: str | os.PathLike[str]) -> dict[str, np.ndarray]:
    """A library's arrays, each member's declared size checked (against the limits and its
    header's shape) before NumPy allocates it; no objects."""
    with zipfile.ZipFile(path) as archive:
        for info in archive.infolist():
            check("file_bytes", info.file_size, path, f"member {info.filename}")
            with archive.open(info) as fh:
                shape, dtype = npy_header(fh)
            if (
                dtype.hasobject
                or int(np.prod(shape, dtype=object)) * dtype.itemsize > info.file_size
            ):
                raise _MalformedError(f"member {info.filename} declares more data than it holds")
    with np.load(path, allow_pickle=False) as data:
        return {k: data[k] for k in data.files}


def _check_catalogue(
    arrays: dict[str, np.ndarray], meta: dict[str, Any], model: dict[str, Any], refs: list
) -> tuple[int, int]:
    """Every stored count and shape against the others (what indexes what), before anything
    is searched; returns the poses and the index's dimension.

    Raises
    ------
    _MalformedError
        Naming the first that disagrees.
    """
    names, clip_of, frame_of = arrays["clip_names"], arrays["clip_of"], arrays["frame_of"]
    n_clips = len(names) if names.ndim == 1 else -1
    if n_clips < 1 or names.dtype.kind != "U":
        raise _MalformedError("it names no clips")
    for key, a in (("clip_of", clip_of), ("frame_of", frame_of)):
        if a.ndim != 1 or a.dtype.kind not in "iu" or len(a) != len(clip_of) or not len(a):
            raise _MalformedError(f"{key} is not one whole number per pose")
    if clip_of.min() < 0 or clip_of.max() >= n_clips:
        raise _MalformedError(f"clip_of names clips outside 0 to {n_clips - 1}")
    if frame_of.min() < 0:
        raise _MalformedError("frame_of holds negative frames")
    dim = meta.get("dim")
    if isinstance(dim, bool) or not isinstance(dim, int) or not 1 <= dim <= 1 << 16:
        raise _MalformedError(f"meta.dim is {dim!r}")
    W, scale, offset = model.get("W"), model.get("scale"), model.get("offset")
    if W is None or scale is None or offset is None:
        raise _MalformedError("the projection model is missing")
    if W.ndim != 2 or W.shape[1] != dim or scale.shape != (W.shape[0],) != offset.shape:
        raise _MalformedError(f"the projection model's shapes disagree with meta.dim {dim}")
    if not all(np.all(np.isfinite(a)) for a in (W, scale, offset)):
        raise _MalformedError("the projection model holds values that are not finite")
    rows = arrays.get("pose_rows")
    if rows is not None and (rows.ndim != 2 or len(rows) != len(clip_of)):
        raise _MalformedError("pose_rows is not one row per pose")
    check("fps", _number(meta.get("fps"), "fps"), None, "meta.fps")
    height = meta.get("height_cm")
    if height is not None and not (math.isfinite(_number(height, "height_cm")) and height > 0):
        raise _MalformedError(f"meta.height_cm is {height!r}")
    for key, least in (("file_frames", 1), ("file_fps", 0)):
        values = meta.get(key)
        if values is None:
            continue
        if not isinstance(values, list) or len(values) != n_clips:
            raise _MalformedError(f"meta.{key} is not one value per clip")
        for v in values:
            if v is not None and not (_number(v, key) > least and math.isfinite(v)):
                raise _MalformedError(f"meta.{key} holds {v!r}")
    if refs and len(refs) != n_clips:
        raise _MalformedError(f"{len(refs)} clip references for {n_clips} clips")
    judge = {k: v for k, v in model.items() if k.startswith(_TRANSITION)}
    if judge:
        TransitionClassifier.from_arrays(
            {k[len(_TRANSITION) :]: v for k, v in judge.items()},
            n_features=None if rows is None else 2 * rows.shape[1],
        )
    return len(clip_of), dim


def _number(value: object, key: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise _MalformedError(f"meta.{key} is {value!r}, not a number")
    return float(value)


def _labelled_pairs(
    clips: Sequence[PoseClip],
    clip_offsets: labels.ClipOffsets,
    n_pairs: int,
    rng: np.random.Generator,
    say: Callable[[str], None],
    dissimilar: bool,
) -> tuple[IntArray, NDArray[np.bool_], str]:
    """Pose pairs ``(P, 2)`` (indices into the concatenated clips), whether each is similar,
    and where they came from; dissimilar pairs only if ``dissimilar``."""
    if len(clips) >= 2:
        try:
            found, thresholds = labels.transition_labels(
                [c.local for c in clips],
                [c.world for c in clips],
                clips[0].fps,
                n_positive=n_pairs,
                n_negative=n_pairs if dissimilar else 0,
                n_queries=max(2000, 4 * n_pairs),
                random_state=rng,
            )
            p = found.pairs
            pairs = np.stack([clip_offsets(p[:, 0], p[:, 1]), clip_offsets(p[:, 2], p[:, 3])], 1)
            similar = np.asarray(found.labels, dtype=bool)
            say(f"{int(similar.sum())} similar pairs below {thresholds[0]:.2f} cm")
            if similar.sum() >= _MIN_TRANSITION_PAIRS and (
                not dissimilar or (~similar).sum() >= _MIN_TRANSITION_PAIRS
            ):
                return pairs, similar, "transition pairs (Kovar point-cloud distance)"
        except ValueError as exc:
            say(f"no transition pairs ({exc})")
    n_poses = clip_offsets.n_poses
    within = np.flatnonzero(np.isin(np.arange(n_poses - 1) + 1, clip_offsets.starts, invert=True))
    take = rng.permutation(within)[:n_pairs]
    if len(take) == 0:
        raise ValueError("the library needs a clip of at least two frames to learn a pose distance")
    pairs = np.stack([take, take + 1], axis=1)
    if not dissimilar:
        return pairs, np.ones(len(pairs), dtype=bool), "consecutive frames"
    clip_of = clip_offsets.clip_of()
    frame_of = clip_offsets.frame_of()
    gap = max(1, int(round(_FAR_APART_S * clips[0].fps)))
    a = rng.integers(0, n_poses, 20 * n_pairs)
    b = rng.integers(0, n_poses, 20 * n_pairs)
    far = (clip_of[a] != clip_of[b]) | (np.abs(frame_of[a] - frame_of[b]) >= gap)
    apart = np.stack([a[far], b[far]], axis=1)[:n_pairs]
    if len(apart) == 0:
        raise ValueError("the library is too short to learn a pose distance with dissimilar pairs")
    both = np.concatenate((pairs, apart))
    similar = np.r_[np.ones(len(pairs), dtype=bool), np.zeros(len(apart), dtype=bool)]
    return both, similar, f"consecutive frames; poses {_FAR_APART_S:g} s apart as dissimilar"


def training_set(
    clips: Sequence[PoseClip],
    *,
    n_unlabeled: int,
    n_pairs: int,
    seed: int,
    dissimilar: bool,
    say: Callable[[str], None] = lambda message: None,
) -> tuple[IntArray, IntArray, NDArray[np.bool_], str]:
    """What a library's metric learns from: unlabeled poses (N',), pose pairs (P, 2) (indices
    into the concatenated clips), whether each pair is similar, and where the pairs came from.

    Transition pairs of Kovar's point-cloud distance across clips; consecutive frames (and poses
    a second apart as dissimilar, if ``dissimilar``) when the clips yield too few. Seeded:
    the same clips and seed give the same set.
    """
    rng = np.random.default_rng(seed)
    clip_offsets = labels.ClipOffsets(np.array([len(c) for c in clips]))
    pairs, similar, pairs_from = _labelled_pairs(
        clips, clip_offsets, n_pairs, rng, say, dissimilar=dissimilar
    )
    unlabeled = rng.permutation(clip_offsets.n_poses)[:n_unlabeled]
    return unlabeled, pairs, similar, pairs_from


def _learn_projection(
    clips: Sequence[PoseClip],
    *,
    rank: int,
    n_unlabeled: int,
    n_pairs: int,
    seed: int,
    metric: Any,
    metric_name: str,
    say: Callable[[str], None],
) -> tuple[dict[str, FloatArray], dict[str, Any], PoseData]:
    """The GPD scaling and the metric's projection learned on ``clips``.

    Returns the model (``scale``, ``offset``, ``W``), the settings for the library's ``meta``
    and the clips' poses joined (their GPD computed, for the next step to reuse).
    """
    if metric_name not in METRICS:
        raise ValueError(f"unknown pose metric {metric_name!r}; choose from {', '.join(METRICS)}")
    for name, value in (("rank", rank), ("n_unlabeled", n_unlabeled), ("n_pairs", n_pairs)):
        if value < 1:
            raise ValueError(f"{name} must be at least 1, got {value}")
    fps, height = clips[0].fps, clips[0].height
    if any(c.fps != fps or c.height != height for c in clips):
        raise ValueError("every clip must be prepared at the same frame rate and height")
    poses = PoseData.concat([c.poses for c in clips])
    t0 = time.perf_counter()
    raw = pose_features(poses, metric_name)
    say(f"{metric_name.split('+')[0]} of {len(poses)} poses: {time.perf_counter() - t0:.1f} s")
    # The metric is the registered method of that name (one implementation with the benchmark).
    options: dict[str, Any] = {"random_state": seed}
    if metric_name.endswith("+RDSR"):
        options["n_components"] = min(rank, raw.shape[1])
        if metric is not None:
            options = {"estimator": metric}
    method = METHODS[metric_name](**options)
    unlabeled, pairs, similar, pairs_from = training_set(
        clips, n_unlabeled=n_unlabeled, n_pairs=n_pairs, seed=seed,
        dissimilar=method.uses_dissimilar, say=say,
    )  # fmt: skip
    t0 = time.perf_counter()
    method.fit_features(raw[unlabeled], raw[pairs[:, 0]], raw[pairs[:, 1]], similar)
    projection = method.projection_
    W = projection["W"]
    rank = W.shape[1]
    del raw
    say(f"{metric_name} metric of rank {rank}: {time.perf_counter() - t0:.1f} s")
    model = {"scale": projection["scale"], "offset": projection["offset"], "W": W}
    meta = {
        "fps": fps,
        "height_cm": height,
        "rank": rank,
        "n_unlabeled": len(unlabeled),
        "metric": metric_name,
        "n_positive_pairs": int(similar.sum()),
        "n_negative_pairs": int((~similar).sum()),
        "positive_pairs_from": pairs_from,
        "seed": seed,
    }
    return model, meta, poses


def _as_given(clip: PoseClip) -> PoseClip:
    """The ``load`` of an in-memory build: the clips are already prepared."""
    return clip


@dataclass
class _Sample:
    """The clips the distance is learned on, in input order, and the clips that failed."""

    clips: list[PoseClip]
    failed: dict[int, Failure]
    n_poses: int


def _draw_sample(
    sources: list[Any],
    load: Callable[[Any], PoseClip],
    fit_poses: int,
    seed: int,
    batch: dict[str, Any],
    progress: Callable[[int, int], None] | None,
) -> _Sample:
    """Step 1 of the build: clips loaded in a seeded order until they hold ``fit_poses``
    poses (at least two clips), returned in input order."""
    order = np.random.default_rng([seed, len(sources)]).permutation(len(sources))
    failed: dict[int, Failure] = {}
    drawn: list[tuple[int, PoseClip]] = []
    n_poses = 0
    with imap_batch(load, [sources[i] for i in order], progress=progress, **batch) as stream:
        for outcome in stream:
            where = int(order[outcome.index])
            if outcome.failure is not None:
                failed[where] = dataclasses.replace(outcome.failure, index=where)
                continue
            drawn.append((where, outcome.value))
            n_poses += len(outcome.value)
            if n_poses >= fit_poses and len(drawn) >= 2:
                break
    if not drawn:
        raise ValueError(_none_read(len(sources), failed))
    drawn.sort(key=lambda pair: pair[0])
    return _Sample([clip for _, clip in drawn], failed, n_poses)


class _Graph:
    """The HNSW graph filled in input order, ``flush_poses`` vectors per insertion (with one
    thread the graph is a function of the vectors and the chunking alone)."""

    def __init__(self, index: HNSWIndex, *, flush_poses: int, capacity: int) -> None:
        self.index, self.flush_poses, self.capacity = index, flush_poses, capacity
        self._pending: list[NDArray[np.float32]] = []
        self._n_pending = 0

    def add(self, vectors: NDArray[np.float32]) -> None:
        self._pending.append(vectors)
        self._n_pending += len(vectors)
        if self._n_pending >= self.flush_poses:
            self._flush()

    def _flush(self) -> None:
        self.index.partial_fit(np.concatenate(self._pending), capacity=self.capacity)
        self._pending, self._n_pending = [], 0

    def close(self) -> HNSWIndex:
        if self._pending:
            self._flush()
        return self.index


@dataclass
class _Catalogue:
    """What the library records of each indexed clip, in input order."""

    names: list[str] = field(default_factory=list)
    lengths: list[int] = field(default_factory=list)
    steps: list[int] = field(default_factory=list)
    file_frames: list[int | None] = field(default_factory=list)
    kinds: set[str] = field(default_factory=set)
    rows: list[NDArray[np.float32]] = field(default_factory=list)

    def add(self, clip: ProjectedClip) -> None:
        if clip.rows is not None:
            self.rows.append(clip.rows)
        self.names.append(clip.name)
        self.lengths.append(len(clip.vectors))
        self.steps.append(clip.step)
        self.file_frames.append(clip.file_frames)
        self.kinds.update([clip.skeleton_kind] if clip.skeleton_kind else [])

    def library_fields(self, fps: float, meta: dict[str, Any]) -> dict[str, Any]:
        """The :class:`PoseLibrary` fields of the clips (the model and index apart)."""
        offsets = labels.ClipOffsets(np.array(self.lengths))
        return {
            "pose_rows": np.concatenate(self.rows) if self.rows else None,
            "clip_names": self.names,
            "clip_of": offsets.clip_of(),
            "frame_of": offsets.frame_of() * np.repeat(self.steps, offsets.lengths),
            "meta": {
                **meta,
                "file_fps": [fps * s for s in self.steps],
                "file_frames": self.file_frames,
                "skeletons": sorted(self.kinds),
            },
        }


def _index_pass(
    sources: list[Any],
    kept: list[int],
    load: Callable[[Any], PoseClip],
    model: dict[str, FloatArray],
    *,
    fps: float,
    height: float,
    graph: _Graph,
    failed: dict[int, Failure],
    chunk_size: int | None,
    batch: dict[str, Any],
    progress: Callable[[int, int], None] | None,
    on_doubt: Callable[[str, Doubt], None] | None,
    metric: str,
) -> _Catalogue:
    """Step 2 of the build: every clip loaded and projected in a worker, its vectors inserted
    in input order; failures (and clips prepared at another rate) added to ``failed``."""
    job = functools.partial(projected_clip, load=load, model=model, metric=metric)
    if chunk_size is None:
        chunk_size = 8 if len(kept) >= 64 else 1
    catalogue = _Catalogue()
    items = [sources[i] for i in kept]
    with imap_batch(job, items, progress=progress, chunk_size=chunk_size, **batch) as stream:
        for outcome in stream:
            where = kept[outcome.index]
            if outcome.failure is not None:
                failed[where] = dataclasses.replace(outcome.failure, index=where)
                continue
            clip = outcome.value
            if clip.fps != fps or clip.height != height:
                message = (
                    f"prepared at {clip.fps:g} fps and height {clip.height}, the library at "
                    f"{fps:g} fps and height {height} (its file rate is no multiple of it)"
                )
                failed[where] = Failure(where, sources[where], message)
                continue
            for doubt in clip.doubts if on_doubt is not None else ():
                on_doubt(clip.name, doubt)
            catalogue.add(clip)
            graph.add(clip.vectors)
    return catalogue


def _none_read(n_sources: int, failed: dict[int, Failure]) -> str:
    """The error when every clip failed: its distinct reasons (a few), in input order."""
    reasons = list(dict.fromkeys(str(failed[i]) for i in sorted(failed)))
    more = f"; and {len(reasons) - 3} other reasons" if len(reasons) > 3 else ""
    return f"none of the {n_sources} clips could be read: {'; '.join(reasons[:3])}{more}"


def project_gpd(raw_gpd: ArrayLike, model: dict[str, FloatArray]) -> FloatArray:
    """Raw feature rows (the GPD, or :func:`~quatmotion.pose.methods.pose_features` of the
    library's metric) mapped to a library's index space:
    ``unit(clip(scale * x + offset, 0, 1)) @ W``.

    Parameters
    ----------
    raw_gpd : array_like, shape (N, D)
    model : dict
        ``scale`` and ``offset`` of shape (D,), ``W`` of shape (D, r).

    Returns
    -------
    ndarray, shape (N, r)
    """
    # Clipped to the library's range (see the module's conventions), as the method learned it.
    return project_features(raw_gpd, {**model, "clip": True})


@dataclass(frozen=True)
class ProjectedClip:
    """A clip as the index pass of :meth:`PoseLibrary.build_streamed` needs it.

    Attributes
    ----------
    name : str
    fps : float
        Frame rate after resampling.
    step : int
        File frames per kept frame.
    height : float or None
        Stature of the canonical body, centimetres.
    file_frames : int or None
        Frames of the clip's file, before resampling.
    skeleton_kind : str or None
        The skeleton family it came from.
    vectors : ndarray of float32, shape (T, r)
        Every pose projected into the index space.
    doubts : tuple of Doubt
        :attr:`PoseClip.doubts`.
    """

    name: str
    fps: float
    step: int
    height: float | None
    file_frames: int | None
    skeleton_kind: str | None
    vectors: NDArray[np.float32]
    doubts: tuple[Doubt, ...] = ()
    rows: NDArray[np.float32] | None = None


def projected_clip(
    source: Any, *, load: Callable[[Any], PoseClip], model: dict, metric: str = "GPD+LOGIT"
) -> ProjectedClip:
    """Load one clip and project its poses' ``metric`` features (the per-clip job run by batch
    workers)."""
    clip = load(source)
    vectors = project_gpd(pose_features(clip.poses, metric), model).astype(np.float32)
    judge = transition_judge(model)
    rows = None if judge is None else judge.describe(clip.poses).astype(np.float32)
    return ProjectedClip(
        clip.name, clip.fps, clip.step, clip.height, clip.file_frames, clip.skeleton_kind,
        vectors, clip.doubts, rows,
    )  # fmt: skip


_TRANSITION = "transition_"  # prefix of the transition judge's arrays in a library's model


def transition_judge(model: dict[str, Any]) -> TransitionClassifier | None:
    """The transition judge stored in a library's ``model`` (``transition_*`` arrays), or None."""
    arrays = {k[len(_TRANSITION) :]: v for k, v in model.items() if k.startswith(_TRANSITION)}
    return TransitionClassifier.from_arrays(arrays) if arrays else None


def _learn_transitions(
    clips: Sequence[PoseClip],
    *,
    n_pairs: int,
    n_unlabeled: int,
    seed: int,
    say: Callable[[str], None],
    poses: PoseData | None = None,
) -> tuple[dict[str, Any], dict[str, Any]]:
    """Step 1b of the build: the transition judge learned on the sample's blended-transition
    labels (:mod:`quatmotion.pose.blend_labels`), as ``transition_*`` model arrays, and what
    ``meta`` records of it; nothing when the clips give too few good or bad transitions.
    ``poses``: the clips' poses joined, if step 1 has them (their GPD is not computed again)."""
    from quatmotion.pose.blend_labels import blended_transition_labels

    if len(clips) < 2:
        return {}, {"transitions": "not learned: one clip"}
    rng = np.random.default_rng([seed, 20])
    try:
        found, _ = blended_transition_labels(
            [c.local for c in clips], [c.world for c in clips], clips[0].fps,
            n_positive=n_pairs, n_negative=n_pairs, n_queries=max(2000, 4 * n_pairs),
            random_state=rng,
        )  # fmt: skip
    except ValueError as exc:
        say(f"no transition judge ({exc})")
        return {}, {"transitions": f"not learned: {exc}"}
    good = np.asarray(found.labels, dtype=bool)
    if good.sum() < _MIN_TRANSITION_PAIRS or (~good).sum() < _MIN_TRANSITION_PAIRS:
        reason = f"{int(good.sum())} good and {int((~good).sum())} bad transitions"
        say(f"no transition judge ({reason})")
        return {}, {"transitions": f"not learned: {reason}"}
    t0 = time.perf_counter()
    offsets = labels.ClipOffsets(np.array([len(c) for c in clips]))
    if poses is None:
        poses = PoseData.concat([c.poses for c in clips])
    p = found.pairs
    a, b = offsets(p[:, 0], p[:, 1]), offsets(p[:, 2], p[:, 3])
    unlabeled = rng.permutation(len(poses))[:n_unlabeled]
    judge = TransitionClassifier(random_state=seed).fit(poses[unlabeled], poses[a], poses[b], good)
    say(f"transition judge on {len(good)} blended transitions: {time.perf_counter() - t0:.1f} s")
    arrays = {f"{_TRANSITION}{k}": v for k, v in judge.to_arrays().items()}
    return arrays, {"transitions": {"good": int(good.sum()), "bad": int((~good).sum())}}


def load_pose_source(
    source: ClipSource, *, fps: float, height: float, read: ReadSettings
) -> PoseClip:
    """Read one clip of a collection (:func:`quatmotion.collection.read_clip`) and prepare it
    for a pose library (the per-clip job of :meth:`PoseLibrary.build`: module level).

    The clip is named by its file's path (its name for a clip made in memory); a clip beyond a
    kilometre is refused (``read.strict``: its features would overflow).
    """
    motion, _, doubts = read_clip(source, dataclasses.replace(read, strict=True))
    name = str(source.path) if source.path is not None else source.name
    with np.errstate(all="ignore"):
        clip = PoseClip.from_motion(motion, fps=fps, height=height, name=name)
    return dataclasses.replace(clip, doubts=tuple(doubts))


def load_pose_clip(
    path: str | os.PathLike[str],
    *,
    fps: float,
    height: float,
    skeleton: str | os.PathLike[str] | None = None,
    units: str | None = None,
    joint_map: Sequence[str] = (),
) -> PoseClip:
    """Read a motion file and prepare it for a pose library (a batch job: module level).

    Parameters
    ----------
    path : str or Path
        An ``.amc`` (its ASF found by :func:`quatmotion.io.read_amc`'s rules, else
        ``skeleton``) or ``.bvh``.
    fps, height : float
        As for :meth:`PoseClip.from_motion`.
    skeleton : str or Path, optional
        The ASF of AMC files (else each one's is found by name).
    units : str, optional
        Length unit of a BVH file (:data:`quatmotion.io.BVH_UNITS`); guessed when None.
    joint_map : sequence of str
        A user's humanoid map, ``"Canonical=joint"`` entries
        (:attr:`quatmotion.collection.ReadSettings.joint_map`).

    Returns
    -------
    PoseClip
        Named by ``str(path)``, with the file's unit and frame-rate doubts
        (:attr:`PoseClip.doubts`).

    Raises
    ------
    ValueError
        For a clip with coordinates beyond a kilometre: not human motion capture, and its
        features would overflow.
    """
    from quatmotion.io import implausible_values, read_motion

    path = pathlib.Path(path)
    amc = path.suffix.lower() == ".amc"
    motion = read_motion(path, skeleton if amc else None, units=None if amc else units)
    if joint_map:
        motion = with_joint_map(motion, joint_map)
    doubts = implausible_values(motion)
    for doubt in doubts:
        if doubt.kind == "far":
            raise ValueError(f"{path}: {doubt.message}: not human motion capture")
    # A clip that cannot be described fails with a message, not NumPy's overflow warnings.
    with np.errstate(all="ignore"):
        clip = PoseClip.from_motion(motion, fps=fps, height=height, name=str(path))
    return dataclasses.replace(clip, doubts=tuple(doubts))
