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
The library is a package by job: :mod:`~quatmotion.pose.library.settings` (what a library is
built with), :mod:`~quatmotion.pose.library.clips` (a clip read, prepared and projected: the
per-clip jobs), :mod:`~quatmotion.pose.library.learn` (the distance learned on a sample),
:mod:`~quatmotion.pose.library.transitions` (the transition judge),
:mod:`~quatmotion.pose.library.build` (the build's named steps),
:mod:`~quatmotion.pose.library.file` (the ``.npz`` file) and this module, the library itself
(its collection surface and its queries).

Conventions
-----------
* Clips are prepared by :meth:`PoseClip.from_motion` (resampled, put on the canonical body of
  one stature); queries go through :meth:`PoseLibrary.prepare_query`, so they are described
  alike whatever their skeleton (:mod:`~quatmotion.pose.library.clips`: why features are
  clipped to the library's range).
* Frame numbers count from 0 in the clip's file, before any resampling (an AMC file's frame 1
  is frame 0). Asking for a frame outside a clip, or a clip that is not there, is an error
  naming what there is.
* A library file is one ``.npz`` (:mod:`~quatmotion.pose.library.file`), written to a
  temporary file and then renamed; reading checks it, raising :class:`~quatmotion.FormatError`.
"""

from __future__ import annotations

import dataclasses
import errno
import functools
import os
import pathlib
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from quatmotion._deprecated import warn_renamed
from quatmotion._format import FileFormat
from quatmotion.collection import (
    BuildReport,
    ClipRef,
    ClipSource,
    find_clips,
    name_apart,
)
from quatmotion.io import Doubt
from quatmotion.io.names import match_clip
from quatmotion.motion import Motion
from quatmotion.parallel import Failure, Runner, Scheduler
from quatmotion.pose.data import PoseClip, PoseData
from quatmotion.pose.index import HNSWIndex
from quatmotion.pose.library._old_names import (
    old_add,
    old_build,
    old_build_in_memory,
    old_build_streamed,
)
from quatmotion.pose.library.build import Catalogue, as_given, build_fields, index_more
from quatmotion.pose.library.clips import load_pose_source, project_gpd
from quatmotion.pose.library.file import (
    FORMAT,
    derived_refs,
    read_library,
    read_settings,
    write_library,
)
from quatmotion.pose.library.settings import PoseSettings
from quatmotion.pose.library.transitions import transition_judge
from quatmotion.pose.methods import pose_features
from quatmotion.pose.transition import TransitionClassifier

__all__ = ["PoseLibrary", "PoseMatch"]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


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
        return derived_refs(self.clip_names, self.path)

    def __enter__(self) -> PoseLibrary:
        return self

    def __exit__(self, *exc_info: object) -> None:
        """Nothing to release: a library is read whole into memory."""

    @classmethod
    def open(cls, path: str | os.PathLike[str], ef_search: int = 64) -> PoseLibrary:
        """Read a library (any version from :data:`FORMAT`'s ``oldest_readable``).

        Raises
        ------
        FormatError
            Not a quatmotion pose library, or a version this code does not read.
        """
        return cls(**read_library(path, ef_search))

    # -- building: the collection surface (collection.kind.Kind) ------------------------------
    @classmethod
    @old_build
    def build(
        cls,
        sources: Iterable[Any],
        out: str | os.PathLike[str],
        settings: PoseSettings | None = None,
        *,
        runner: Runner | str | Scheduler | None = None,
        progress: Callable[[str, int, int], None] | None = None,
        on_doubt: Callable[[str, Doubt], None] | None = None,
        log: Callable[[str], None] | None = None,
    ) -> BuildReport:
        """Build the library of ``sources`` (files, folders, motions in memory) into ``out``:
        :meth:`build_streamed` on the clips :func:`quatmotion.collection.find_clips` finds,
        each read by :func:`quatmotion.collection.read_clip`; the settings and the clips'
        references are stored in the file.

        Parameters
        ----------
        sources : iterable
            Files, folders (searched recursively), motions or clip sources.
        out : str or Path
            The library file to write (temporary file, then rename).
        settings : PoseSettings, optional
            How the library is built (None: the defaults); checked once, when made.
        runner : Runner, optional
            Where the clips are prepared (a scheduler name or :class:`Scheduler` is read by
            :meth:`Runner.resolve`; None: ``QUATMOTION_SCHEDULER``, else a local pool).
        progress, on_doubt, log : callable, optional
            As for :meth:`build_streamed`.

        Returns
        -------
        BuildReport
            ``added`` the clips indexed, ``failures`` the others; ``details["library"]`` the
            :class:`PoseLibrary` written.

        Raises
        ------
        ValueError
            No clip could be read.
        """
        settings = settings or PoseSettings()
        report = BuildReport(path=pathlib.Path(out), settings=settings)
        found = _find(sources, settings, report)
        load = functools.partial(
            load_pose_source, fps=settings.fps, height=settings.height, read=settings.read
        )
        library, failures = cls.build_streamed(
            found,
            load,
            settings,
            runner=_runner(runner),
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
    @old_add
    def add(
        cls,
        path: str | os.PathLike[str],
        sources: Iterable[Any],
        settings: PoseSettings | None = None,
        *,
        runner: Runner | str | Scheduler | None = None,
        progress: Callable[[str, int, int], None] | None = None,
        on_doubt: Callable[[str, Doubt], None] | None = None,
        log: Callable[[str], None] | None = None,
    ) -> BuildReport:
        """Add ``sources`` to the library at ``path`` with its stored distance (nothing is
        learned again): each new clip is read, projected and inserted into the graph; a clip
        whose content the library already holds is skipped; a new clip whose name a stored
        clip of another file has is named by the collection's rule
        (:func:`~quatmotion.collection.unique_names` over the two paths). The file is
        rewritten whole (temporary file, then rename).

        ``settings`` (None: the stored ones, :meth:`stored_settings`) say how the new clips
        are read (``read``) and batched (``chunk_size``, ``flush_poses``); what shaped the
        library (its rate, body, distance, sample, graph) must be the stored values.

        Raises
        ------
        FileNotFoundError
            No library at ``path``.
        ValueError
            A version-2 library (it stored no settings: rebuild it), settings that would
            change what the library was built with, or no clip could be read.
        """
        path = pathlib.Path(path)
        if not path.is_file():
            raise FileNotFoundError(errno.ENOENT, "no pose library", str(path))
        library = cls.open(path)
        settings = _settings_to_add(library, settings)
        report = BuildReport(path=path, settings=settings, details={"resumed": True})
        report.details["clips_before"] = len(library.clip_names)
        report.details["library"] = library
        new = library._new_sources(_find(sources, settings, report), report)
        if not new:
            return report
        load = functools.partial(
            load_pose_source, fps=settings.fps, height=settings.height, read=settings.read
        )
        catalogue, failed = index_more(
            library.index, library.model, library.meta, len(library.clip_names), new, load,
            settings, runner=_runner(runner), progress=progress, on_doubt=on_doubt,
        )  # fmt: skip
        library._extend(catalogue)
        added = [s.ref() for i, s in enumerate(new) if i not in failed]
        library.refs = list(library.clips()) + added
        library.save(path)
        report.added = added
        report.failures += [dataclasses.replace(failed[i], item=new[i]) for i in sorted(failed)]
        say = log or (lambda _msg: None)
        say(f"added {len(added)} clips to {path} ({len(report.skipped)} already there)")
        return report

    @staticmethod
    def stored_settings(path: str | os.PathLike[str]) -> PoseSettings | None:
        """The settings the library at ``path`` was built with (None for a version-2 library),
        read without reading its graph."""
        return read_settings(path)

    def _new_sources(self, found: list[ClipSource], report: BuildReport) -> list[ClipSource]:
        """The clips of ``found`` this library does not hold (the others into
        ``report.skipped``), named apart from its clips."""
        held = {r.sha256 for r in self.clips()}
        refs = list(self.clips())
        new: list[ClipSource] = []
        for source in found:
            if source.sha256 in held:
                report.skipped.append(source.ref())
                continue
            ref = name_apart(source.ref(), refs, report.path)
            refs.append(ref)
            held.add(source.sha256)
            new.append(dataclasses.replace(source, name=ref.name))
        return new

    def _extend(self, catalogue: Catalogue) -> None:
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
    @old_build_in_memory
    def build_in_memory(
        cls,
        clips: Sequence[PoseClip],
        settings: PoseSettings | None = None,
        *,
        log: Callable[[str], None] | None = None,
        estimator: Any = None,
    ) -> PoseLibrary:
        """Learn a pose distance on the clips' own poses, project every pose and index it,
        in this process (the build of :meth:`build_streamed` with every clip the sample).

        The steps: the features of every pose; positive pairs (good transitions by Kovar's
        windowed point-cloud distance, :func:`~quatmotion.pose.labels.transition_labels`, or
        consecutive frames when the clips yield fewer than 10); the min-max (clipped) +
        unit-length scaling fitted on the unlabeled sample and the pairs; the metric learned
        from them; every pose projected by it into an HNSW index.

        Parameters
        ----------
        clips : sequence of PoseClip
            All prepared at the same frame rate and height (:meth:`PoseClip.from_motion`).
        settings : PoseSettings, optional
            How the library is built (``fps``, ``height``, ``read`` and ``fit_poses`` apart:
            the clips are prepared and all of them learned on).
        log : callable, optional
            Called with progress messages.
        estimator : estimator, optional
            For a ``+RDSR`` metric: unfitted, with ``fit(X_unlabeled, positive_pairs)`` and
            ``components_`` of shape ``(rank, D)`` after fitting; default
            ``RDSR(n_components=rank)``.

        Returns
        -------
        PoseLibrary
        """
        settings = settings or PoseSettings()
        if not clips:
            raise ValueError("no clips to index")
        # Every clip is the sample (fit_poses is all their poses, so the distance is learned on
        # all clips in input order) and the index pass runs inline on the clips as given.
        settings = settings.replace(fit_poses=max(1, sum(len(c) for c in clips)))
        fields, failures = build_fields(
            list(clips), as_given, settings, runner=Runner.inline(), log=log, estimator=estimator
        )
        if failures:
            first = failures[0]
            raise ValueError(f"clip {clips[first.index].name!r}: {first.message}")
        return cls(**fields)

    @classmethod
    @old_build_streamed
    def build_streamed(
        cls,
        sources: Sequence[Any],
        load: Callable[[Any], PoseClip],
        settings: PoseSettings | None = None,
        *,
        runner: Runner | str | Scheduler | None = None,
        progress: Callable[[str, int, int], None] | None = None,
        on_doubt: Callable[[str, Doubt], None] | None = None,
        log: Callable[[str], None] | None = None,
        estimator: Any = None,
    ) -> tuple[PoseLibrary, list[Failure]]:
        """Build a library of any size in bounded memory, the clips prepared in parallel
        (not written: :meth:`save`; :meth:`build` reads files and writes the library).

        Two passes over ``sources``, each a batch of ``runner``:

        1. *Learn*: clips are loaded in a seeded random order until they hold
           ``settings.fit_poses`` poses (at least two clips); the distance is learned on that
           sample exactly as :meth:`build_in_memory` learns it on all clips (in input order),
           so a library smaller than ``fit_poses`` gets the model it would give.
        2. *Index*: every clip is loaded again in a worker, described and projected there; the
           vectors (float32, ``rank`` per pose) come back in input order and go into the
           HNSW graph ``flush_poses`` at a time, on ``index_threads`` threads: with one (the
           default) the library is the same bytes whatever the runner.

        Memory holds the sample, a window of projected clips and the index itself; neither
        all poses nor their GPD features are ever in one array.

        Parameters
        ----------
        sources : sequence
            One item per clip, passed to ``load`` (file paths, generator specs...).
        load : callable
            ``load(source) -> PoseClip``, module-level (picklable), every clip at the same
            frame rate and height; an exception skips that clip (reported, never fatal).
        settings : PoseSettings, optional
            How the library is built (None: the defaults; ``fps``, ``height`` and ``read``
            are ``load``'s to apply).
        runner : Runner, optional
            Where the clips are prepared (as for :meth:`build`).
        progress : callable, optional
            ``progress(stage, done, total)`` with stage ``"learn"`` (clips loaded for the
            sample, out of all clips; stops when the sample is complete) or ``"index"``.
        on_doubt : callable, optional
            ``on_doubt(clip name, doubt)`` for each of a clip's :attr:`PoseClip.doubts`, once,
            in the index pass.
        log : callable, optional
            Called with progress messages.
        estimator : estimator, optional
            As for :meth:`build_in_memory`.

        Returns
        -------
        library : PoseLibrary
            Over the clips that could be read, in input order (their failures left out).
        failures : list of Failure
            Clips skipped, in input order, each with a one-line reason.

        Raises
        ------
        ValueError
            No clip could be read.
        """
        fields, failures = build_fields(
            sources, load, settings or PoseSettings(), runner=_runner(runner),
            progress=progress, log=log, on_doubt=on_doubt, estimator=estimator,
        )  # fmt: skip
        return cls(**fields), failures

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
        write_library(
            path, index=self.index, clip_names=self.clip_names, clip_of=self.clip_of,
            frame_of=self.frame_of, model=self.model, meta=self.meta, refs=self.refs,
            settings=self.settings, pose_rows=self.pose_rows,
        )  # fmt: skip

    @classmethod
    def load(cls, path: str | os.PathLike[str], ef_search: int = 64) -> PoseLibrary:
        """:meth:`open` (the name before 0.4.0; warns)."""
        warn_renamed("PoseLibrary.load", "PoseLibrary.open")
        return cls.open(path, ef_search)


def _find(sources: Iterable[Any], settings: PoseSettings, report: BuildReport) -> list[ClipSource]:
    """The clips of ``sources`` (:func:`~quatmotion.collection.find_clips`), those that could
    not be found or read into ``report.failures``."""
    errors: list[tuple[str, str]] = []
    found = find_clips(sources, settings.read, on_error=errors)
    report.failures += [Failure(i, p, reason) for i, (p, reason) in enumerate(errors)]
    return found


# What shaped a library: an add cannot change it (how new clips are read and batched can).
_SHAPING = ("fps", "height", "metric", "rank", "n_unlabeled", "n_pairs", "seed", "fit_poses",
            "M", "ef_construction")  # fmt: skip


def _settings_to_add(library: PoseLibrary, settings: PoseSettings | None) -> PoseSettings:
    """The settings an add to ``library`` runs with: ``settings``, or the stored ones."""
    stored = library.settings
    if stored is None:
        raise ValueError(f"{library.path}: a version-{library.version} library stores no "
                         "settings; build it again to add clips")  # fmt: skip
    if settings is None:
        return stored
    changed = [f for f in _SHAPING if getattr(settings, f) != getattr(stored, f)]
    if changed:
        shown = ", ".join(f"{f}={getattr(stored, f)!r}" for f in changed)
        raise ValueError(
            f"{library.path}: the library was built with {shown}; an add keeps what the "
            "library was built with (give its stored settings, PoseLibrary.stored_settings, "
            "with another read)"
        )
    return settings


def _runner(runner: Runner | str | Scheduler | None) -> Runner:
    """Where a batch runs: ``runner``, or the :class:`Runner` of a scheduler name or
    :class:`Scheduler` (None: ``QUATMOTION_SCHEDULER``, else a local pool)."""
    return runner if isinstance(runner, Runner) else Runner.resolve(runner)
