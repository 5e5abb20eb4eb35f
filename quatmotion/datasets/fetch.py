"""Download CMU motion-capture subjects (ASF skeleton + AMC trials) over HTTP.

Conventions
-----------
* The server follows the CMU site's layout: ``{base_url}/subjects/SS/SS.asf`` and
  ``{base_url}/subjects/SS/SS_TT.amc`` with two-digit (or wider) subject and trial numbers.
* Files land in ``dest/SS/`` (the data folder's ``cmu/`` layout, so :func:`catalogue` finds
  them). Each is written to a temporary file in the same folder and renamed when complete:
  an interrupted download never leaves a half-written clip.
* A subject's trials come from the CMU index (``cmu_bvh/cmu-mocap-index-text.txt`` in the data
  folder) when it lists the subject, else by probing ``TT = 01, 02, ...`` until the server
  answers 404.
* Only the standard library talks to the network (``urllib``); Rich draws the progress bars.
"""

from __future__ import annotations

import contextlib
import http.client
import urllib.error
import urllib.request
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path

from rich.console import Console
from rich.progress import (
    BarColumn,
    DownloadColumn,
    Progress,
    TextColumn,
    TimeRemainingColumn,
    TransferSpeedColumn,
)

from quatmotion._atomic import atomic_output
from quatmotion.datasets.catalogue import cmu_index, data_root

__all__ = ["DEFAULT_CMU_BASE_URL", "FetchError", "cmu_trials", "cmu_url", "fetch_cmu"]

DEFAULT_CMU_BASE_URL = "http://mocap.cs.cmu.edu"
"""The CMU Graphics Lab Motion Capture Database site (its ``subjects/`` folder layout)."""

_CHUNK_BYTES = 1 << 16
_MAX_PROBED_TRIALS = 99


class FetchError(RuntimeError):
    """A download failed (network error, HTTP error other than a probe's 404, bad argument)."""


def _subject_id(subject: int | str) -> str:
    try:
        number = int(subject)
    except (TypeError, ValueError):
        raise FetchError(f"CMU subject must be a number, got {subject!r}") from None
    if number < 1:
        raise FetchError(f"CMU subject must be positive, got {subject!r}")
    return f"{number:02d}"


def cmu_url(
    subject: int | str, trial: int | None = None, base_url: str = DEFAULT_CMU_BASE_URL
) -> str:
    """URL of a subject's ASF (``trial=None``) or of one trial's AMC.

    Parameters
    ----------
    subject : int or str
        Subject number (``2`` or ``"02"``).
    trial : int, optional
        Trial number; ``None`` for the skeleton.
    base_url : str
        Site root; ``/subjects/SS/...`` is appended.

    Returns
    -------
    str
    """
    ss = _subject_id(subject)
    name = f"{ss}.asf" if trial is None else f"{ss}_{int(trial):02d}.amc"
    return f"{base_url.rstrip('/')}/subjects/{ss}/{name}"


def cmu_trials(subject: int | str, index: Mapping[str, str] | None = None) -> list[int]:
    """Trial numbers the CMU index lists for ``subject`` (empty when it does not list it).

    Parameters
    ----------
    subject : int or str
    index : mapping, optional
        ``{"SS_TT": description}`` as from :func:`~quatmotion.datasets.cmu_index` (default:
        the index in the data folder, if any).

    Returns
    -------
    list of int
        Sorted trial numbers.
    """
    ss = _subject_id(subject)
    index = cmu_index() if index is None else index
    trials = set()
    for key in index:
        head, _, tail = key.partition("_")
        if head.isdigit() and tail.isdigit() and f"{int(head):02d}" == ss:
            trials.add(int(tail))
    return sorted(trials)


def _open(url: str, timeout: float):  # -> http.client.HTTPResponse
    request = urllib.request.Request(url, headers={"User-Agent": "quatmotion-fetch"})
    return urllib.request.urlopen(request, timeout=timeout)  # noqa: S310 (http by design)


def _download(url: str, target: Path, timeout: float, progress: Progress | None) -> int:
    """Stream ``url`` into ``target`` atomically; the byte count. A 404 is FileNotFoundError."""
    target.parent.mkdir(parents=True, exist_ok=True)
    try:
        response = _open(url, timeout)
    except urllib.error.HTTPError as error:
        if error.code == 404:
            raise FileNotFoundError(url) from None
        raise FetchError(f"{url}: HTTP {error.code} {error.reason}") from None
    except (urllib.error.URLError, OSError, http.client.HTTPException) as error:
        raise FetchError(f"{url}: {getattr(error, 'reason', error)}") from None
    written = 0
    task = None
    try:
        with atomic_output(target, suffix=".part") as temp, response, temp.open("wb") as out:
            length = response.headers.get("Content-Length")
            if progress is not None:
                task = progress.add_task(target.name, total=int(length) if length else None)
            while chunk := response.read(_CHUNK_BYTES):
                out.write(chunk)
                written += len(chunk)
                if task is not None:
                    progress.update(task, advance=len(chunk))
            if length is not None and written != int(length):
                raise FetchError(f"{url}: got {written} of {length} bytes")
    except (OSError, urllib.error.URLError, http.client.HTTPException) as error:
        raise FetchError(f"{url}: download failed ({type(error).__name__}: {error})") from None
    return written


def fetch_cmu(
    subjects: Iterable[int | str],
    dest: str | Path | None = None,
    base_url: str = DEFAULT_CMU_BASE_URL,
    trials: Iterable[int] | None = None,
    index: Mapping[str, str] | None = None,
    overwrite: bool = False,
    timeout: float = 30.0,
    console: Console | None = None,
    show_progress: bool = True,
) -> list[Path]:
    """Download the ASF and AMC files of CMU subjects.

    Parameters
    ----------
    subjects : iterable of int or str
        Subject numbers, e.g. ``[1, 2]``.
    dest : str or Path, optional
        Destination folder; files go to ``dest/SS/``. Default: ``cmu/`` in the data folder.
    base_url : str
        Server root with the CMU ``subjects/SS/`` layout.
    trials : iterable of int, optional
        Trials to fetch for every subject; default: the index's list, else probe until a 404.
    index : mapping, optional
        CMU index ``{"SS_TT": description}`` (default: the data folder's, if present).
    overwrite : bool
        Download files that already exist (otherwise they are kept and skipped).
    timeout : float
        Seconds to wait for the server per request.
    console : rich.console.Console, optional
        Where the progress bars go (default: a new console on stderr).
    show_progress : bool
        Draw progress bars.

    Returns
    -------
    list of pathlib.Path
        Every file now present for the request (downloaded or already there), skeletons first
        per subject.

    Raises
    ------
    FetchError
        On a network or HTTP error (a 404 other than the one that ends probing included).
    """
    ss_list = [_subject_id(s) for s in subjects]
    if not ss_list:
        raise FetchError("no subjects given")
    if timeout <= 0:
        raise FetchError(f"timeout must be positive, got {timeout}")
    target_root = Path(dest) if dest is not None else data_root(must_exist=False) / "cmu"
    index = cmu_index() if index is None else index
    fixed_trials = None if trials is None else sorted({int(t) for t in trials})
    progress = _download_bar(console) if show_progress else None
    files: list[Path] = []

    def get(url: str, target: Path) -> bool:
        if target.exists() and not overwrite:
            files.append(target)
            return True
        try:
            _download(url, target, timeout, progress)
        except FileNotFoundError:
            return False
        files.append(target)
        return True

    with progress if progress is not None else contextlib.nullcontext():
        for ss in ss_list:
            listed = fixed_trials if fixed_trials is not None else cmu_trials(ss, index)
            _fetch_subject(ss, listed, target_root / ss, base_url, get)
    return files


def _download_bar(console: Console | None) -> Progress:
    return Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        DownloadColumn(),
        TransferSpeedColumn(),
        TimeRemainingColumn(),
        console=console or Console(stderr=True),
        transient=False,
    )


def _fetch_subject(
    ss: str,
    trials: Sequence[int] | None,
    folder: Path,
    base_url: str,
    get: Callable[[str, Path], bool],
) -> None:
    """One subject's ASF, then its trials' AMC files: those listed (each must exist), or
    without a list every trial from 1 until the first the server does not have. ``get(url,
    target)`` is False for a file the server does not have."""
    if not get(cmu_url(ss, None, base_url), folder / f"{ss}.asf"):
        raise FetchError(f"{cmu_url(ss, None, base_url)}: not found (HTTP 404)")
    if trials:
        for tt in trials:
            url = cmu_url(ss, tt, base_url)
            if not get(url, folder / f"{ss}_{tt:02d}.amc"):
                raise FetchError(f"{url}: not found (HTTP 404)")
        return
    for tt in range(1, _MAX_PROBED_TRIALS + 1):
        if not get(cmu_url(ss, tt, base_url), folder / f"{ss}_{tt:02d}.amc"):
            break
