"""What every command shares: the consoles, the bad-input contract, reading clips, writing files.

The contract: bad input (a missing or malformed file, an unknown extension, name or option
value) ends a command with exit code 2 and a one-line ``error:`` message on stderr, never a
traceback. Commands wrap their work in :func:`user_errors`, which turns the package's input
errors into that message; an exception it does not know is a bug and is shown in full. Input
that is readable but doubtful (a guessed unit that makes an implausible figure, coordinates
kilometres away) gets a ``warning:`` line on stderr and the command goes on.

Conventions every command keeps:

* Frames are numbered from 0 in the clip's file (:data:`FRAMES_HELP`); an out-of-range frame
  is an error naming the valid range (:func:`check_frame`).
* Files a command writes: never one of its inputs, never an existing file unless ``--force``
  (:func:`check_outputs`); a command that fails removes what it wrote (:class:`Outputs`).
* ``--units`` (:data:`UnitsOption`) names the length unit of BVH input wherever a file is read
  (:func:`read_clip`).
"""

from __future__ import annotations

import contextlib
import math
import os
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.console import Console, ConsoleDimensions
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from quatmotion.errors import FormatError

if TYPE_CHECKING:
    from quatmotion.motion import Motion, Skeleton

__all__ = [
    "EXIT_BAD_INPUT",
    "FRAMES_HELP",
    "CliInputError",
    "ForceOption",
    "Outputs",
    "SchedulerOption",
    "SkeletonOption",
    "UnitsOption",
    "WorkersOption",
    "at_least",
    "check_frame",
    "check_outputs",
    "clip_files",
    "console",
    "error_console",
    "fail",
    "number_in",
    "progress_bar",
    "read_clip",
    "report_skipped",
    "require_file",
    "user_errors",
    "warn",
    "write_clip",
]

EXIT_BAD_INPUT = 2

FRAMES_HELP = "frames count from 0; an AMC file's frame 1 is frame 0"
"""How every command numbers frames, for help texts and messages."""


class _Console(Console):
    """A Rich console as wide as its longest line when its output is not a terminal.

    Rich folds text to the terminal's width, or to 80 columns when the output is a pipe or a
    file; a file path folded across two lines is useless to a script. Whether the output is a
    terminal is asked at every print, so a test runner's swapped streams are seen too.
    """

    @property
    def size(self) -> ConsoleDimensions:
        size = super().size
        return size if self.is_terminal else ConsoleDimensions(_PIPE_WIDTH, size.height)


_PIPE_WIDTH = 10_000
console = _Console()
error_console = _Console(stderr=True)


class CliInputError(Exception):
    """Bad input detected by the command line itself (reported like a FormatError)."""


def fail(message: str) -> typer.Exit:
    """Print ``error: <first line of message>`` on stderr; the exit to raise (code 2)."""
    text = str(message).strip()
    first = text.splitlines()[0] if text else "failed"
    # No Rich markup or highlighting: file names may hold brackets.
    error_console.print(f"error: {first}", markup=False, highlight=False, soft_wrap=True)
    return typer.Exit(code=EXIT_BAD_INPUT)


def warn(message: str) -> None:
    """Print ``warning: <message>`` on stderr (one line; the command goes on)."""
    error_console.print(f"warning: {message}", markup=False, highlight=False, soft_wrap=True)


@contextlib.contextmanager
def user_errors() -> Iterator[None]:
    """Turn bad-input exceptions into exit code 2 with a one-line message."""
    from quatmotion.datasets import DataNotFoundError, FetchError

    try:
        yield
    except FormatError as error:
        raise fail(str(error)) from None
    except DataNotFoundError as error:
        raise fail(_os_message(error)) from None
    except OSError as error:  # a file that cannot be read or written: no disk, no permission
        if getattr(error, "filename", None) is None and not isinstance(error, FileNotFoundError):
            raise  # not about a file the user named: a bug, shown in full
        raise fail(_os_message(error)) from None
    except (CliInputError, FetchError, ValueError, KeyError) as error:
        text = error.args[0] if isinstance(error, KeyError) and error.args else error
        raise fail(str(text)) from None


def _os_message(error: OSError | Exception) -> str:
    """``<file>: <reason>`` without ``[Errno N]``, naming the file the user gave (an atomic
    write's temporary file is named in ``filename``, the target in ``filename2``)."""
    filename = getattr(error, "filename2", None) or getattr(error, "filename", None)
    detail = getattr(error, "strerror", None)
    if filename is None or detail is None:
        return str(error)
    return f"{filename}: {detail.lower()}"


def require_file(path: Path) -> Path:
    """``path`` if it is an existing file, else :class:`CliInputError` saying what it is."""
    if not path.exists():
        raise CliInputError(f"{path}: no such file")
    if path.is_dir():
        raise CliInputError(f"{path}: is a folder, expected a file")
    return path


# --- options shared by several commands ------------------------------------------------------

UnitsOption = Annotated[
    str | None,
    typer.Option(
        "--units",
        help="Length unit of BVH input: cm, mm, m, in or asf (1/0.45 inch, the CMU unit). "
        "Default: guessed from the skeleton's size.",
        show_default=False,
    ),
]
SkeletonOption = Annotated[
    Path | None,
    typer.Option("--skeleton", "-s", help="ASF skeleton of AMC input (else found by name)."),
]
ForceOption = Annotated[bool, typer.Option("--force", help="Replace existing output files.")]

WorkersOption = Annotated[
    int | None,
    typer.Option(help="Worker processes (default: one per CPU; 1 runs in this process)."),
]
"""``--workers`` of every batch command (:mod:`quatmotion.parallel`)."""

SchedulerOption = Annotated[
    str | None,
    typer.Option(
        help="Dask scheduler, tcp://HOST:PORT (default: $QUATMOTION_SCHEDULER, else local)."
    ),
]
"""``--scheduler`` of every batch command (:func:`quatmotion.parallel.resolve_scheduler`)."""


def report_skipped(failures: Iterable[object]) -> None:
    """One ``skipped ...`` line on stderr per input a batch command left out."""
    for failure in failures:
        error_console.print(f"skipped {failure}", markup=False, highlight=False, soft_wrap=True)


def read_clip(
    path: Path, skeleton: Path | None = None, units: str | None = None, *, strict: bool = False
) -> Motion:
    """Read a motion file given on the command line, warning about doubtful content.

    Parameters
    ----------
    path : Path
        A ``.amc`` or ``.bvh`` file.
    skeleton : Path, optional
        The ASF of an AMC (else found as :func:`quatmotion.io.find_asf_for_amc` finds it).
    units : str, optional
        Length unit of a BVH (:data:`quatmotion.io.BVH_UNITS`); ``None`` guesses it.
    strict : bool
        Refuse (:class:`CliInputError`) a clip with coordinates beyond a kilometre instead of
        warning about it: for commands that compute on world positions.
    """
    from quatmotion.io import MOTION_SUFFIXES, implausible_values, read_motion

    require_file(path)
    if path.suffix.lower() not in MOTION_SUFFIXES:
        raise CliInputError(
            f"{path}: unknown motion file type {path.suffix!r} "
            f"(expected {', '.join(MOTION_SUFFIXES)})"
        )
    if skeleton is not None:
        require_file(skeleton)
        if path.suffix.lower() != ".amc":
            raise CliInputError("--skeleton applies to AMC input only (a BVH has its own)")
    if units is not None and path.suffix.lower() != ".bvh":
        raise CliInputError(f"{path}: --units applies to BVH input only (an ASF states its unit)")
    motion = read_motion(path, skeleton, units=units)
    for doubt in implausible_values(motion):
        if strict and doubt.kind == "far":
            raise CliInputError(f"{path}: {doubt.message}: not human motion capture")
        hint = "; give the unit with --units" if doubt.kind == "unit" else ""
        warn(f"{path}: {doubt.message}{hint}")
    return motion


# --- numbers and frames ------------------------------------------------------------------------


def at_least(option: str, value: int, minimum: int, maximum: int | None = None) -> int:
    """``value`` if ``minimum <= value (<= maximum)``, else :class:`CliInputError` naming the
    option and the valid range."""
    if value < minimum or (maximum is not None and value > maximum):
        bound = f"at least {minimum}" if maximum is None else f"from {minimum} to {maximum}"
        raise CliInputError(f"{option} must be {bound}, got {value}")
    return value


def number_in(option: str, value: float, low: float, high: float) -> float:
    """``value`` if it is a number from ``low`` to ``high``, else :class:`CliInputError`."""
    if not (math.isfinite(value) and low <= value <= high):
        raise CliInputError(f"{option} must be from {low:g} to {high:g}, got {value:g}")
    return value


def check_frame(frame: int, n_frames: int, what: str) -> int:
    """``frame`` if it is a frame of a clip of ``n_frames`` frames, counting from 0.

    Raises
    ------
    CliInputError
        Naming the valid range, e.g. ``frame 5000 is out of range: walk.bvh has frames 0 to 99``.
    """
    if not 0 <= frame < n_frames:
        raise CliInputError(
            f"frame {frame} is out of range: {what} has frames 0 to {n_frames - 1} ({FRAMES_HELP})"
        )
    return frame


# --- files written -----------------------------------------------------------------------------


def _same_file(a: Path, b: Path) -> bool:
    try:
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except OSError:
        return False


def check_outputs(
    outputs: Iterable[Path], inputs: Iterable[Path] = (), *, force: bool = False
) -> None:
    """The overwrite policy: refuse to write over an input, a folder, or (without ``force``) an
    existing file.

    Raises
    ------
    CliInputError
        Naming the first output that breaks the policy.
    """
    inputs = [Path(p) for p in inputs]
    for out in outputs:
        out = Path(out)
        if any(_same_file(out, p) or out.resolve() == p.resolve() for p in inputs):
            raise CliInputError(f"{out}: is also an input; write the output to another file")
        if out.is_dir():
            raise CliInputError(f"{out}: is a folder, expected a file name to write")
        if out.exists() and not force:
            raise CliInputError(f"{out}: exists; pass --force to replace it")


class Outputs:
    """Files and folders a command is writing, removed again if the command fails.

    ``with Outputs() as outputs:`` then :meth:`folder` before creating a folder and
    :meth:`file` before writing a file: when the block raises, the files are deleted and the
    folders the block created are removed, so a failed command leaves nothing behind (each file
    itself is written atomically, so a replaced file is either old or new, never half).
    """

    def __init__(self) -> None:
        self._files: list[Path] = []
        self._folders: list[Path] = []

    def folder(self, path: Path) -> Path:
        """Create ``path`` (and missing parents); remember the ones created here."""
        missing = [p for p in [path, *path.parents] if not p.exists()]
        path.mkdir(parents=True, exist_ok=True)
        self._folders.extend(sorted(missing, key=lambda p: len(p.parts)))
        return path

    def file(self, path: Path) -> Path:
        """Note that ``path`` is about to be written (its folder is created if missing)."""
        self.folder(path.parent)
        self._files.append(path)
        return path

    def __enter__(self) -> Outputs:
        return self

    def __exit__(self, kind: type | None, *_: object) -> None:
        if kind is None:
            return
        for path in self._files:
            with contextlib.suppress(OSError):
                path.unlink()
        for folder in reversed(self._folders):  # deepest first
            with contextlib.suppress(OSError):  # not empty: something else is in it, keep it
                folder.rmdir()


def progress_bar(target: Console | None = None) -> Progress:
    """A Rich progress bar counting finished items (description, bar, n/total, time)."""
    return Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        console=target or console,
    )


def clip_files(out: Path, skeleton: Skeleton) -> list[Path]:
    """The files writing a clip of ``skeleton`` to ``out`` makes: an AMC gets its ASF, same
    name, beside it (where :func:`quatmotion.io.find_asf_for_amc` looks first).

    Raises
    ------
    CliInputError
        For an unknown suffix, or AMC output of a skeleton that did not come from an ASF.
    """
    from quatmotion.io import MOTION_SUFFIXES

    suffix = out.suffix.lower()
    if suffix not in MOTION_SUFFIXES:
        raise CliInputError(
            f"{out}: unknown output type {out.suffix!r} (expected {', '.join(MOTION_SUFFIXES)})"
        )
    if suffix == ".amc" and skeleton.extras.get("format") != "asf":
        raise CliInputError(
            f"{out}: AMC output needs an ASF skeleton; this clip's skeleton "
            f"({skeleton.name!r}) comes from a BVH, write .bvh instead"
        )
    return [out, out.with_suffix(".asf")] if suffix == ".amc" else [out]


def write_clip(motion: Motion, files: list[Path], outputs: Outputs) -> None:
    """Write ``motion`` to ``files`` (from :func:`clip_files`, already checked against the
    overwrite policy), each noted in ``outputs``."""
    from quatmotion.io import write_asf, write_motion

    write_motion(motion, outputs.file(files[0]))
    if len(files) > 1:
        write_asf(motion.skeleton, outputs.file(files[1]))
