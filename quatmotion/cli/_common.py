"""What every command shares: the consoles, the bad-input contract and reading clips.

The contract: bad input (a missing or malformed file, an unknown extension, name or option
value) ends a command with exit code 2 and a one-line ``error:`` message on stderr, never a
traceback. Commands wrap their work in :func:`user_errors`, which turns the package's input
errors into that message; an exception it does not know is a bug and is shown in full.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from quatmotion.errors import FormatError

if TYPE_CHECKING:
    from quatmotion.motion import Motion

__all__ = [
    "EXIT_BAD_INPUT",
    "asf_path_for",
    "CliInputError",
    "console",
    "error_console",
    "fail",
    "progress_bar",
    "read_clip",
    "require_file",
    "user_errors",
    "write_clip",
]

EXIT_BAD_INPUT = 2

console = Console()
error_console = Console(stderr=True)


class CliInputError(Exception):
    """Bad input detected by the command line itself (reported like a FormatError)."""


def fail(message: str) -> typer.Exit:
    """Print ``error: <first line of message>`` on stderr; the exit to raise (code 2)."""
    text = str(message).strip()
    first = text.splitlines()[0] if text else "failed"
    # No Rich markup or highlighting: file names may hold brackets.
    error_console.print(f"error: {first}", markup=False, highlight=False, soft_wrap=True)
    return typer.Exit(code=EXIT_BAD_INPUT)


@contextlib.contextmanager
def user_errors() -> Iterator[None]:
    """Turn bad-input exceptions into exit code 2 with a one-line message."""
    from quatmotion.datasets import DataNotFoundError, FetchError

    try:
        yield
    except FormatError as error:
        raise fail(str(error)) from None
    except (DataNotFoundError, FileNotFoundError, IsADirectoryError, NotADirectoryError) as error:
        detail = error.strerror if getattr(error, "filename", None) else None
        raise fail(f"{error.filename}: {detail}" if detail else str(error)) from None
    except (CliInputError, FetchError, ValueError, KeyError, PermissionError) as error:
        text = error.args[0] if isinstance(error, KeyError) and error.args else error
        raise fail(str(text)) from None


def require_file(path: Path) -> Path:
    """``path`` if it is an existing file, else :class:`CliInputError` saying what it is."""
    if not path.exists():
        raise CliInputError(f"{path}: no such file")
    if path.is_dir():
        raise CliInputError(f"{path}: is a folder, expected a file")
    return path


def read_clip(path: Path, skeleton: Path | None = None) -> Motion:
    """Read a motion file given on the command line (``skeleton``: the ASF of an AMC)."""
    from quatmotion.io import MOTION_SUFFIXES, read_motion

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
    return read_motion(path, skeleton)


def progress_bar(target: Console | None = None) -> Progress:
    """A Rich progress bar counting finished items (description, bar, n/total, time)."""
    return Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        console=target or console,
    )


def asf_path_for(amc: Path) -> Path:
    """Where an AMC's ASF goes so that :func:`quatmotion.io.find_asf_for_amc` finds it."""
    parts = amc.stem.split("_")
    if len(parts) >= 2 and parts[0].upper() == "HDM":
        return amc.with_name(f"{parts[0]}_{parts[1]}.asf")
    if len(parts) >= 2:
        return amc.with_name(f"{parts[0]}.asf")
    return amc.with_suffix(".asf")


def write_clip(motion: Motion, out: Path) -> list[Path]:
    """Write ``motion`` to ``out`` by extension; an AMC gets its ASF beside it (the files
    written, in order)."""
    from quatmotion.io import MOTION_SUFFIXES, write_asf, write_motion

    suffix = out.suffix.lower()
    if suffix not in MOTION_SUFFIXES:
        raise CliInputError(
            f"{out}: unknown output type {out.suffix!r} (expected {', '.join(MOTION_SUFFIXES)})"
        )
    if suffix == ".amc" and motion.skeleton.extras.get("format") != "asf":
        raise CliInputError(
            f"{out}: AMC output needs an ASF skeleton; this clip's skeleton "
            f"({motion.skeleton.name!r}) comes from a BVH, write .bvh instead"
        )
    out.parent.mkdir(parents=True, exist_ok=True)
    written = [out]
    write_motion(motion, out)
    if suffix == ".amc":
        asf = asf_path_for(out)
        write_asf(motion.skeleton, asf)
        written.append(asf)
    return written
