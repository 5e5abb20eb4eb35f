"""The clip files a command writes (``convert``, ``decompress``): their names checked before
any work starts, every file noted as it is written and removed again if the command fails."""

from __future__ import annotations

import contextlib
from pathlib import Path
from typing import TYPE_CHECKING

from quatmotion.cli._common import CliInputError

if TYPE_CHECKING:
    from quatmotion.motion import Motion, Skeleton

__all__ = ["Outputs", "clip_files", "clip_output", "write_clip"]


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


def clip_files(out: Path, skeleton: Skeleton) -> list[Path]:
    """The files writing a clip of ``skeleton`` to ``out`` makes: an AMC gets its ASF, same
    name, beside it (where :func:`quatmotion.io.find_asf_for_amc` looks first).

    Raises
    ------
    CliInputError
        For an unknown suffix, or AMC output of a skeleton that did not come from an ASF.
    """
    from quatmotion.io import WRITTEN_SUFFIXES

    suffix = out.suffix.lower()
    if suffix not in WRITTEN_SUFFIXES:
        raise CliInputError(
            f"{out}: unknown output type {out.suffix!r} (expected {', '.join(WRITTEN_SUFFIXES)})"
        )
    if suffix == ".amc" and skeleton.extras.get("format") != "asf":
        raise CliInputError(
            f"{out}: AMC output needs an ASF skeleton; this clip's skeleton "
            f"({skeleton.name!r}) comes from a BVH, write .bvh instead"
        )
    return [out, out.with_suffix(".asf")] if suffix == ".amc" else [out]


def clip_output(folder: Path, name: str, suffix: str, source: Path | None = None) -> Path:
    """Where the clip ``name`` (a name read from a file) is written in ``folder``: its
    :func:`quatmotion.io.names.relative_path`, which never leaves the folder.

    Raises
    ------
    CliInputError
        A name that cannot be made a file name inside ``folder`` (``../x``, ``/etc/x``),
        naming ``source``, the file the name was read from.
    """
    from quatmotion.io.names import relative_path

    try:
        path = folder / relative_path(name, suffix)
    except ValueError as error:
        raise CliInputError(f"{source}: {error}" if source else str(error)) from None
    base = folder.resolve()
    if not path.resolve().is_relative_to(base):  # a sub-folder that is a link out of it
        raise CliInputError(f"{path}: lies outside {folder}; not written")
    return path


def write_clip(motion: Motion, files: list[Path], outputs: Outputs) -> None:
    """Write ``motion`` to ``files`` (from :func:`clip_files`, already checked against the
    overwrite policy), each noted in ``outputs``."""
    from quatmotion.io import write_asf, write_motion

    write_motion(motion, outputs.file(files[0]))
    if len(files) > 1:
        write_asf(motion.skeleton, outputs.file(files[1]))
