"""A library built while the web app already answers: ``quatmotion serve DIR`` listens at once
and serves each file of the build as it is complete.

Conventions
-----------
* The build is a function ``run(progress, publish)`` given by the caller (the command passes
  :func:`quatmotion.demo.build_library`); it runs in a thread of the server's process (its
  batch steps in worker processes), calls ``progress(step, done, total)`` as it goes and
  ``publish(library, index, poses)`` each time a file is complete, and returns the
  ``"file: reason"`` of the clips it left out.
* The app serves the catalogue of the files last published (:attr:`LibraryBuild.catalogue`;
  an empty one before the first), so the clip list fills in stage by stage: the index first
  (the clips, their labels, play from the original files, search), then the library
  (compressed sizes, compare), then the pose index (pose search).
* While the build runs, what is not there yet (a clip id, search before the index) is a 503
  with ``Retry-After``, not a 404: it may come. ``GET /api/build`` says where the build is;
  the pages show it.
* :meth:`LibraryBuild.stop` (the server's shutdown) asks the build to end at its next progress
  report (:class:`BuildStoppedError` raised there) and waits for it, so the caller can remove the
  build's folder afterwards.
* Thread safety: every method may be called from any thread; the state is under one lock.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, Literal

from quatmotion.server.clips import ClipCatalogue

__all__ = ["BuildStoppedError", "BuildRun", "LibraryBuild", "Publish", "Progress"]

Progress = Callable[[str, int, int], None]
Publish = Callable[["Path | None", "Path | None", "Path | None"], None]
BuildRun = Callable[[Progress, Publish], Sequence[str]]

_STOP_WAIT_S = 60.0  # a clip being compressed finishes before the next progress report


class BuildStoppedError(Exception):
    """Raised into the build by its progress report once :meth:`LibraryBuild.stop` was called."""


class LibraryBuild:
    """A build running beside the server, its progress, and the catalogue of its files so far.

    Parameters
    ----------
    source : str
        What is built, for people (``"clips/"``, ``"the demo's generated library"``).
    run : callable
        ``run(progress, publish) -> failures`` (module conventions).
    echo : callable, optional
        Also told every progress report (the command's progress bar on stderr).
    on_stage : callable, optional
        ``on_stage(message)``: a line for people each time a stage is served and at the end.
    """

    def __init__(
        self,
        source: str,
        run: BuildRun,
        *,
        echo: Progress | None = None,
        on_stage: Callable[[str], None] | None = None,
    ) -> None:
        self.source = source
        self._run = run
        self._echo = echo
        self._on_stage = on_stage or (lambda _message: None)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._catalogue = ClipCatalogue.empty()
        self._opened: list[ClipCatalogue] = []
        self._state: Literal["building", "ready", "failed", "stopped"] = "building"
        self._step, self._done, self._total = "starting", 0, 0
        self._served: list[str] = []
        self._failed: list[str] = []
        self._message = ""
        self._started = time.monotonic()
        self._seconds: float | None = None

    # ------------------------------------------------------------------ running
    def start(self) -> LibraryBuild:
        """Start the build in a thread (once); returns self."""
        if self._thread is None:
            self._started = time.monotonic()
            self._thread = threading.Thread(target=self._main, name="quatmotion-build", daemon=True)
            self._thread.start()
        return self

    def _main(self) -> None:
        try:
            failed = list(self._run(self.progress, self.publish))
        except BuildStoppedError:
            self._end("stopped", "stopped before it finished")
        except Exception as error:  # the build's own error, shown in the page and on stderr
            text = str(error).strip().splitlines()
            self._end("failed", text[0] if text else type(error).__name__)
        else:
            with self._lock:
                self._failed = failed
            self._end("ready", "")

    def _end(self, state: Literal["ready", "failed", "stopped"], message: str) -> None:
        with self._lock:
            self._state, self._message = state, message
            self._seconds = time.monotonic() - self._started
            clips, seconds = len(self._catalogue), self._seconds
        if state == "ready":
            self._on_stage(f"built in {seconds:.0f} s: {clips} clips served")
        elif state == "failed":
            self._on_stage(f"the build failed: {message}")

    def progress(self, step: str, done: int, total: int) -> None:
        """Record where the build is; raises :class:`BuildStoppedError` once stopping."""
        if self._stop.is_set():
            raise BuildStoppedError
        with self._lock:
            self._step, self._done, self._total = step, int(done), int(total)
        if self._echo is not None:
            self._echo(step, done, total)

    def publish(self, library: Path | None, index: Path | None, poses: Path | None) -> None:
        """Serve these files from now on (each complete). The catalogue serving before stays
        open until :meth:`stop`: a request may still be reading from it."""
        if self._stop.is_set():
            raise BuildStoppedError
        catalogue = ClipCatalogue.open(library, index, poses)
        stage = "poses" if poses else "library" if library else "index"
        with self._lock:
            self._opened.append(catalogue)
            self._catalogue = catalogue
            self._served.append(stage)
            seconds = time.monotonic() - self._started
        what = {
            "index": "listed, playable from their files and searchable",
            "library": "compressed (compare with the originals)",
            "poses": "pose-indexed (pose search)",
        }[stage]
        self._on_stage(f"{len(catalogue)} clips {what} after {seconds:.0f} s")

    def stop(self, timeout: float = _STOP_WAIT_S) -> None:
        """Stop the build at its next progress report, wait for it (up to ``timeout`` s),
        and close every catalogue it opened."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)
        with self._lock:
            opened, self._opened = self._opened, []
            self._catalogue = ClipCatalogue.empty()
        for catalogue in opened:
            catalogue.close()

    # ------------------------------------------------------------------ reading
    @property
    def catalogue(self) -> ClipCatalogue:
        """The catalogue of the files last published (empty before the first)."""
        with self._lock:
            return self._catalogue

    @property
    def running(self) -> bool:
        """Whether the build is still going (what is missing may still come)."""
        with self._lock:
            return self._state == "building"

    def where(self) -> str:
        """Where the build is, for a message: ``"compress: encode 12/39"``."""
        with self._lock:
            if self._total:
                return f"{self._step} {self._done}/{self._total}"
            return self._step

    def status(self) -> dict[str, Any]:
        """JSON-ready: ``state`` (building, ready, failed, stopped), ``source``, the current
        ``step`` with ``done``/``total``, the stages ``served`` so far (index, library,
        poses), ``clips`` served, ``failed`` (``"file: reason"`` of clips left out),
        ``message`` (why it failed) and ``seconds`` since it started (its length once ended)."""
        with self._lock:
            seconds = self._seconds
            if seconds is None:
                seconds = time.monotonic() - self._started
            return {
                "state": self._state,
                "source": self.source,
                "step": self._step,
                "done": self._done,
                "total": self._total,
                "served": list(self._served),
                "clips": len(self._catalogue),
                "failed": list(self._failed),
                "message": self._message,
                "seconds": round(seconds, 1),
            }
