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
* Files a command writes: never a file it reads (a folder's clips and an AMC's ASF included),
  never an existing file unless ``--force``, never a read-only one, and a destination that
  cannot be written is refused before any work (:func:`check_outputs`); a command that fails
  removes what it wrote (:class:`Outputs`).
* ``--units`` and ``--skeleton`` (:data:`UnitsOption`, :data:`SkeletonOption`) are the same on
  every command that reads motion (:func:`read_clip`, or ``units=``/``skeleton=`` of the
  library's batch functions); a doubtful clip gets a warning (:func:`warn_doubt`).
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import re
import sys
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.console import Console, ConsoleDimensions
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.segment import Segment

from quatmotion.errors import FormatError, MissingDependencyError

if TYPE_CHECKING:
    from quatmotion.io import Doubt
    from quatmotion.motion import Motion, Skeleton

__all__ = [
    "EXIT_BAD_INPUT",
    "FRAMES_HELP",
    "LABELS_HELP",
    "LABEL_FOLDERS_HELP",
    "CliInputError",
    "ForceOption",
    "ForceUnitsOption",
    "JointMapOption",
    "JsonOption",
    "SchedulerOption",
    "SkeletonOption",
    "TakeOption",
    "TranslationsOption",
    "UnitsOption",
    "WorkersOption",
    "at_least",
    "bvh_unit_label",
    "check_frame",
    "check_translations",
    "check_units",
    "check_outputs",
    "check_writable",
    "console",
    "doubt_reporter",
    "error_console",
    "fail",
    "joint_map_entries",
    "files_read",
    "labels_option",
    "number_in",
    "print_json",
    "print_mappings",
    "printable",
    "progress_bar",
    "read_clip",
    "refuse_unit",
    "report_skipped",
    "require_file",
    "require_inputs",
    "skeleton_mappings",
    "unit_label",
    "unit_text",
    "user_errors",
    "say_wrote",
    "warn",
    "warn_doubt",
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

    def _render_buffer(self, buffer: Iterable[Segment]) -> str:
        # Every text printed passes here: names and labels read from files are shown with
        # their control characters escaped (an escape sequence in a clip name must not clear
        # the screen); Rich's own cursor and colour codes are control segments and styles.
        return super()._render_buffer(
            seg if seg.control else Segment(printable(seg.text), seg.style) for seg in buffer
        )


_UNPRINTABLE = re.compile("[\x00-\x08\x0b-\x1f\x7f-\x9f\u200e\u200f\u2028-\u202e\u2066-\u2069]")


def printable(text: str) -> str:
    """``text`` with its control characters (terminal escapes, bidirectional overrides; not
    tabs and line ends) written as Python escapes (``\\x1b``): how every command shows text
    taken from a file (a clip's name, a label) on a terminal."""
    return _UNPRINTABLE.sub(lambda m: m.group().encode("unicode_escape").decode("ascii"), text)


_PIPE_WIDTH = 10_000
# No markup: what is printed holds names from files ("[/x]" would end in a MarkupError, a
# "[link=...]" would print a link); styles are given as style=, never in the text.
console = _Console(markup=False)
error_console = _Console(stderr=True, markup=False)


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


def say_wrote(path: object, what: str = "") -> None:
    """The success line of a command that wrote a file: ``wrote PATH: WHAT`` on stdout, one
    line (progress and warnings go to stderr or above the bar), the same for every command."""
    console.print(
        f"wrote {path}{f': {what}' if what else ''}", markup=False, highlight=False, soft_wrap=True
    )


class _NeverRaisedError(Exception):
    """The class of an error whose module no code imported, so none raised it."""


def _imported_error(module: str, name: str) -> type[Exception]:
    """Error class ``name`` of ``module`` if the module was imported (an ``except`` clause's
    class is looked up when an exception reaches it: importing the module for it would cost
    every command its imports)."""
    found = sys.modules.get(module)
    return getattr(found, name) if found is not None else _NeverRaisedError


@contextlib.contextmanager
def user_errors(output: Path | None = None) -> Iterator[None]:
    """Turn bad-input exceptions into exit code 2 with a one-line message.

    ``output``: what the command writes, named by an error of writing that names no file (a
    full disk under a temporary spool).
    """
    from quatmotion._atomic import WRITE_ERRNOS

    try:
        yield
    except (FormatError, MissingDependencyError) as error:
        raise fail(str(error)) from None
    except _imported_error("quatmotion.datasets.catalogue", "DataNotFoundError") as error:
        raise fail(_os_message(error)) from None
    except OSError as error:  # a file that cannot be read or written: no disk, no permission
        if getattr(error, "filename", None) is None and error.errno in WRITE_ERRNOS:
            where = f"{output}: " if output is not None else ""
            raise fail(f"{where}cannot be written: {str(error.strerror).lower()}") from None
        if getattr(error, "filename", None) is None and not isinstance(error, FileNotFoundError):
            raise  # not about a file the user named: a bug, shown in full
        raise fail(_os_message(error)) from None
    except (
        CliInputError,
        _imported_error("quatmotion.datasets.fetch", "FetchError"),
        ValueError,
        KeyError,
    ) as error:
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


def require_inputs(inputs: Iterable[Path], skeleton: Path | None = None) -> None:
    """A batch command's inputs, before any work: every file or folder exists, and the
    ``--skeleton`` given is a file (:class:`CliInputError` naming the first that is not)."""
    if skeleton is not None:
        require_file(skeleton)
    for path in inputs:
        if not path.exists():
            raise CliInputError(f"{path}: no such file or folder")


# --- options shared by several commands ------------------------------------------------------
LABELS_HELP = "CSV with columns clip,label."
LABEL_FOLDERS_HELP = "Label clips without another label by their folder's name (CLASS/file.amc)."


def labels_option(labels: Path | None) -> dict[str, str] | None:
    """The clip -> label mapping of a ``--labels`` CSV (None without the option)."""
    if labels is None:
        return None  # (before quatmotion.io: it imports Numba)
    from quatmotion.io.labels import read_labels_csv

    return read_labels_csv(require_file(labels))


def _units_value(value: str | None) -> str | float | None:
    """``--units`` as the library takes it: a unit name (lower case) or a number of cm per
    unit. A bad value is kept for :func:`check_units` to refuse with the one-line error."""
    if value is None:
        return None
    from quatmotion.io import LENGTH_UNITS, length_unit

    try:
        cm = length_unit(value)
    except ValueError:
        return value
    name = value.strip().lower()
    return name if name in LENGTH_UNITS else cm


UnitsOption = Annotated[
    str | None,
    typer.Option(
        "--units",
        help="Length unit of the input: mm, cm, dm, m, in, asf (1/0.45 inch, the CMU unit) or "
        "a number of cm per unit (2.54 for inches). Default: a BVH's is guessed from the "
        "figure's stature, with a warning when no unit makes it human; an ASF's is the one it "
        "states (given, this replaces it).",
        show_default=False,
        callback=_units_value,
    ),
]
"""``--units`` of every command that reads motion (:func:`read_clip`, and the library's batch
functions: ``units=``): the command receives a unit name or a float."""
TakeOption = Annotated[
    str | None,
    typer.Option(
        "--take",
        help="The take of an FBX file (the animation of a glTF file) to read, by name, short "
        "name (walk of Armature|walk) or number from 0. Default: of one file, the first (a "
        "warning names the others); of a collection, every take of an FBX file a clip.",
        show_default=False,
    ),
]

TranslationsOption = Annotated[
    str,
    typer.Option(
        "--bvh-translations",
        help="What position channels on BVH joints other than the root mean: absolute (they "
        "replace the OFFSET), relative (added to it), root-only (ignored but on the root), or "
        "auto: relative when they hold values near zero, else absolute.",
    ),
]
"""``--bvh-translations`` of every command that reads motion (:func:`read_clip`;
``translations`` of :class:`quatmotion.collection.ReadSettings`)."""
SkeletonOption = Annotated[
    Path | None,
    typer.Option(
        "--skeleton", "-s", help="ASF skeleton of the AMC input (else each AMC's is found by name)."
    ),
]
"""``--skeleton`` of every command that reads motion: the ASF used for every AMC input."""
JointMapOption = Annotated[
    Path | None,
    typer.Option(
        "--joint-map",
        help="Which file joint is which of the 16 body joints, where names and structure do "
        "not tell: a CSV (canonical,joint per line) or JSON object, e.g. LHip -> thigh_l. "
        "Stored in the index or pose library.",
        show_default=False,
    ),
]
"""``--joint-map`` of every command that maps a skeleton onto the 16-joint body
(:func:`joint_map_entries`)."""
ForceOption = Annotated[bool, typer.Option("--force", help="Replace existing output files.")]
JsonOption = Annotated[
    bool, typer.Option("--json", help="Print one JSON document on stdout, nothing else there.")
]
"""``--json`` of every command that reports something (:func:`print_json`)."""


def check_units(units: str | float | None) -> str | float | None:
    """``--units`` if it is a unit of :data:`quatmotion.io.LENGTH_UNITS` or a positive number
    of cm per unit, else :class:`CliInputError` listing them (before any file is read)."""
    from quatmotion.io import length_unit

    if units is not None:
        try:
            length_unit(units)
        except ValueError as error:
            raise CliInputError(f"--units: {error}") from None
    return units


def joint_map_entries(path: Path | None) -> tuple[str, ...]:
    """``--joint-map``'s file as settings store it (``"LHip=thigh_l"``...; empty without
    one): :class:`CliInputError` naming the file and line of a malformed one."""
    if path is None:
        return ()  # (before quatmotion.io: it imports Numba, which a query by name spares)
    from quatmotion.io import joint_map_pairs, read_joint_map

    require_file(path)
    try:
        return joint_map_pairs(read_joint_map(path))
    except FormatError as error:
        raise CliInputError(f"--joint-map: {error}") from None


def skeleton_mappings(refs: Iterable[object], read: object = None) -> dict[str, dict]:
    """How each skeleton of a collection maps onto the 16-joint body (what ``index ls`` and
    ``pose ls`` show): per skeleton fingerprint, its first clip read again with the
    collection's reading settings and mapped (:func:`quatmotion.pose.skeleton16.humanoid_map`):
    ``{"clip", "clips", "mapping"}`` (a one-line summary) and ``"joints"`` (canonical -> file
    joint and how), or ``"error"`` (a file gone, a skeleton not mapped)."""
    from quatmotion.collection import read_clip as read_collection_clip
    from quatmotion.pose.skeleton16 import humanoid_map

    groups: dict[str, list] = {}
    for ref in refs:
        groups.setdefault(getattr(ref, "skeleton", "") or "", []).append(ref)
    out: dict[str, dict] = {}
    for fingerprint, members in groups.items():
        entry: dict[str, object] = {"clip": members[0].name, "clips": len(members)}
        try:
            motion = read_collection_clip(members[0], read).motion  # type: ignore[arg-type]
            mapping = humanoid_map(motion.skeleton)
            entry["mapping"] = mapping.summary()
            entry["joints"] = mapping.as_dict()
        except (OSError, ValueError) as error:
            entry["error"] = str(error).splitlines()[0]
        out[fingerprint] = entry
    return out


def print_mappings(mappings: dict[str, dict]) -> None:
    """One line per skeleton of :func:`skeleton_mappings`."""
    for fingerprint, entry in mappings.items():
        how = entry.get("mapping") or f"not mapped: {entry.get('error')}"
        console.print(
            f"skeleton {fingerprint[:8] or '-'} ({entry['clips']} clips, e.g. {entry['clip']}): "
            f"16-joint body {how}",
            markup=False,
            highlight=False,
            soft_wrap=True,
        )


def check_translations(translations: str) -> str:
    """``--bvh-translations`` if it is ``auto`` or a mode of
    :data:`quatmotion.io.TRANSLATION_MODES`, else :class:`CliInputError` listing them."""
    from quatmotion.io import TRANSLATION_MODES

    if translations != "auto" and translations not in TRANSLATION_MODES:
        raise CliInputError(
            f"unknown --bvh-translations {translations!r}; choose from auto, "
            f"{', '.join(TRANSLATION_MODES)}"
        )
    return translations


def print_json(document: object) -> None:
    """``document`` as one JSON document on stdout (non-finite numbers as ``null``; NumPy
    scalars as numbers): what ``--json`` prints, and all it prints there."""
    print(json.dumps(_plain(document), indent=1, allow_nan=False))


def _plain(value: object) -> object:
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, bool) or value is None or isinstance(value, str | int):
        return value
    if hasattr(value, "item"):  # a NumPy scalar
        return _plain(value.item())  # type: ignore[attr-defined]
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    return str(value)


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
    path: Path,
    skeleton: Path | None = None,
    units: str | float | None = None,
    *,
    strict: bool = False,
    translations: str = "auto",
    take: str | None = None,
    joint_map: tuple[str, ...] = (),
) -> Motion:
    """Read a motion file given on the command line, warning about doubtful content (and
    what the reader tolerated or assumed: :func:`quatmotion.io.read_motion_checked`).

    Parameters
    ----------
    path : Path
        A motion file (:data:`quatmotion.io.MOTION_SUFFIXES`).
    skeleton : Path, optional
        The ASF of an AMC (else found as :func:`quatmotion.io.find_asf_for_amc` finds it).
    units : str or float, optional
        Length unit of the file (:data:`quatmotion.io.LENGTH_UNITS` or cm per unit); ``None``
        guesses a BVH's and takes an ASF's as stated.
    strict : bool
        Refuse (:class:`CliInputError`) a clip with coordinates beyond a kilometre instead of
        warning about it: for commands that compute on world positions.
    translations : str
        ``--bvh-translations`` (:data:`quatmotion.io.TRANSLATION_MODES` or ``"auto"``).
    take : str, optional
        ``--take``: an FBX file's take (a glTF file's animation), by name or number.
    joint_map : tuple of str
        ``--joint-map``'s entries (:func:`joint_map_entries`): the skeleton carries them.
    """
    from quatmotion.collection import with_joint_map
    from quatmotion.io import MOTION_SUFFIXES, read_motion_checked
    from quatmotion.io.fbx import FBX_SUFFIXES
    from quatmotion.io.gltf import GLTF_SUFFIXES

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
    check_translations(translations)
    if translations != "auto" and path.suffix.lower() != ".bvh":
        raise CliInputError(f"{path}: --bvh-translations applies to BVH input only")
    if take is not None and path.suffix.lower() not in (*FBX_SUFFIXES, *GLTF_SUFFIXES):
        raise CliInputError(f"{path}: --take applies to FBX and glTF input only")
    motion, doubts = read_motion_checked(
        path, skeleton, units=units, translations=translations, animation=take
    )
    for doubt in doubts:
        if strict and doubt.kind == "far":
            raise CliInputError(f"{path}: {doubt.message}: not human motion capture")
        warn_doubt(path, doubt)
    if joint_map:
        try:
            motion = with_joint_map(motion, joint_map)
        except ValueError as error:
            raise CliInputError(f"{path}: {error}") from None
    return motion


def warn_doubt(source: object, doubt: Doubt, target: Console | None = None) -> None:
    """A ``warning:`` line for a doubtful clip (:func:`quatmotion.io.implausible_values`), on
    stderr or ``target`` (a progress bar's console), saying what to do about a unit."""
    hint = ""
    if doubt.kind == "unit":
        likely = doubt.likely_unit
        hint = f"; give --units {likely} if the file is in {likely}" if likely else ""
        hint = hint or "; give the unit with --units"
    (target or error_console).print(
        f"warning: {source}: {doubt.message}{hint}", markup=False, highlight=False, soft_wrap=True
    )


def refuse_unit(source: object, doubt: Doubt) -> None:
    """For a command that declares lengths (``compress``'s error bound, in centimetres): a
    unit that makes no plausible human while another unit does is :class:`CliInputError`
    naming that unit, and ``--force-units`` to go on. Other doubts pass."""
    if doubt.kind == "unit" and doubt.likely_unit:
        raise CliInputError(
            f"{source}: {doubt.message}: likely --units {doubt.likely_unit} (--force-units "
            "keeps the unit as read)"
        )


ForceUnitsOption = Annotated[
    bool,
    typer.Option(
        "--force-units",
        help="Go on with a length unit that makes no plausible human figure while another "
        "unit would (else an error naming that unit): the error bound holds in the unit read.",
    ),
]
"""``--force-units`` of the commands that refuse a doubtful unit (:func:`refuse_unit`)."""


def doubt_reporter(
    progress: Progress, *, refuse_units: bool = False
) -> Callable[[str, Doubt], None]:
    """``on_doubt(source, doubt)`` for the library's batch functions: a warning on stderr,
    above the bar (a bar on stdout lets stderr through above it too); with ``refuse_units``,
    :func:`refuse_unit` first (it stops the batch before anything is written)."""
    target = progress.console if progress.console.stderr else None

    def report(source: str, doubt: Doubt) -> None:
        if refuse_units:
            refuse_unit(source, doubt)
        warn_doubt(source, doubt, target)

    return report


def unit_label(skeleton: Skeleton) -> dict[str, object]:
    """The length unit a clip was read in, as ``ls --json`` reports it.

    ``unit``: a name of :data:`quatmotion.io.LENGTH_UNITS`, or ``None`` for another scale;
    ``cm_per_unit``; ``unit_source``: ``"guessed"`` (a BVH's unit guessed from its size),
    ``"given"`` (read with ``--units``), ``"asf"`` (the unit an ASF states), ``"gltf"``
    (glTF's metres), ``"fbx"`` (the unit an FBX file states) or ``"cm"`` (a skeleton built
    in code, in centimetres); ``unit_guessed``.
    """
    from quatmotion.io import unit_reading

    cm, source, _ = unit_reading(skeleton)
    if source == "stated":
        source = str(skeleton.extras.get("format"))
    return _unit_fields(cm, source)


def bvh_unit_label(cm_per_unit: float, guessed: bool) -> dict[str, object]:
    """:func:`unit_label` of a BVH skeleton known by its scale alone (a ``.qmz`` header)."""
    return _unit_fields(cm_per_unit, "guessed" if guessed else "given")


def _unit_fields(cm: float, source: str) -> dict[str, object]:
    from quatmotion.io import LENGTH_UNITS

    name = next((n for n, v in LENGTH_UNITS.items() if abs(v - cm) <= 1e-9 * v), None)
    return {
        "unit": name,
        "cm_per_unit": cm,
        "unit_source": source,
        "unit_guessed": source == "guessed",
    }


def unit_text(label: dict[str, object]) -> str:
    """A :func:`unit_label` for a table: ``in (guessed)``, ``cm (given)``, ``asf (from the
    ASF)``, ``6.028 cm (from the ASF)``, ``cm``."""
    name = label["unit"] or f"{float(label['cm_per_unit']):.4g} cm"  # type: ignore[arg-type]
    how = {
        "asf": " (from the ASF)",
        "gltf": " (glTF: metres)",
        "guessed": " (guessed)",
        "given": " (given)",
    }
    return f"{name}{how.get(str(label['unit_source']), '')}"


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


def _identities(path: Path) -> set[object]:
    """What makes two names one file: the resolved path, and device and inode if it exists
    (a hard link, a bind mount)."""
    found: set[object] = {path.resolve()}
    with contextlib.suppress(OSError):
        st = path.stat()
        found.add((st.st_dev, st.st_ino))
    return found


def files_read(inputs: Iterable[Path | None]) -> list[Path]:
    """Every file a command reads for these arguments: a file itself, a folder's motion files
    (:func:`quatmotion.io.find_motion_files`, as batch commands expand it), and the ASF each
    AMC among them reads by name. ``None`` (an option not given) is left out."""
    from quatmotion.io import find_asf_for_amc, find_motion_files

    given = [Path(p) for p in inputs if p is not None and Path(p).exists()]
    try:
        found = find_motion_files(given) if given else []
    except ValueError:  # folders without a clip in them
        found = []
    for amc in [f for f in found if f.suffix.lower() == ".amc"]:
        with contextlib.suppress(FormatError, OSError):
            found.append(find_asf_for_amc(amc))
    return found


def check_outputs(
    outputs: Iterable[Path],
    inputs: Iterable[Path | None] = (),
    *,
    force: bool = False,
    replace: bool = False,
) -> None:
    """The overwrite policy, checked before any work starts: refuse to write over a file the
    command reads (:func:`files_read` of ``inputs``: folders expanded, the ASF of each AMC),
    ``--force`` or not; over a folder; over an existing file without ``force``; over a
    read-only file; or where the file cannot be written (:func:`check_writable`).

    ``replace`` says that the command rewrites an existing output by design (``append``,
    ``index add``): no ``--force`` is asked for, the other rules hold.

    Raises
    ------
    CliInputError
        Naming the first output that breaks the policy.
    """
    read: set[object] = set()
    for path in files_read(inputs):
        read |= _identities(path)
    for out in outputs:
        out = Path(out)
        if _identities(out) & read:
            raise CliInputError(f"{out}: is also an input; write the output to another file")
        if out.is_dir():
            raise CliInputError(f"{out}: is a folder, expected a file name to write")
        if out.exists() and not (force or replace):
            raise CliInputError(f"{out}: exists; pass --force to replace it")
        if out.exists() and not (out.stat().st_mode & 0o222 and os.access(out, os.W_OK)):
            raise CliInputError(f"{out}: is read-only; make it writable to replace it")
        check_writable(out)


def check_writable(path: Path, *, folder: bool = False) -> None:
    """Refuse (:class:`CliInputError`, naming ``path``) a file, or with ``folder`` a folder to
    write files in, that cannot be written: the folder it goes in, or the nearest one that
    exists (missing folders are created), is a file or not writable by this user
    (``os.access``: permissions, ACLs, a read-only file system)."""
    start = [path] if folder else []
    where = next((p for p in [*start, path.parent, *path.parents] if p.exists()), Path.cwd())
    if not where.is_dir():
        raise CliInputError(f"{path}: cannot be written: {where} is a file, not a folder")
    if not os.access(where, os.W_OK | os.X_OK):
        raise CliInputError(f"{path}: cannot be written: no permission to write in {where}")


def progress_bar(target: Console | None = None) -> Progress:
    """A Rich progress bar counting finished items (description, bar, n/total, time)."""
    return Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        console=target or console,
    )
