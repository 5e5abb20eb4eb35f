"""``quatmotion serve``: the web app over a library, an index and a pose index (uvicorn).

With no file, it serves the demo's generated library, and with a folder (``serve DIR``) that
folder's clips: either is indexed, compressed and pose-indexed into a temporary folder removed
when the server stops, in the background: the server listens at once, the page shows the
build's progress (stderr too) and serves each file as it is complete
(:mod:`quatmotion.server.building`). The port is bound before anything else, so a port in use
is one ``error:`` line (exit code 2) at once, and ``--port 0`` serves on a free port it names.
"""

from __future__ import annotations

import contextlib
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from quatmotion.cli._app import app
from quatmotion.cli._common import (
    LABEL_FOLDERS_HELP,
    LABELS_HELP,
    CliInputError,
    JointMapOption,
    TakeOption,
    at_least,
    console,
    error_console,
    joint_map_entries,
    labels_option,
    progress_bar,
    report_skipped,
    require_file,
    user_errors,
)

if TYPE_CHECKING:
    from quatmotion.server.building import LibraryBuild


FolderArgument = Annotated[
    Path | None,
    typer.Argument(
        help="A folder of clips to serve: indexed, compressed and pose-indexed into a "
        "temporary folder while the server already answers (the page shows the progress). "
        "Without it and without files: the demo's generated library.",
        show_default=False,
    ),
]
LibraryOption = Annotated[
    Path | None, typer.Option(help="A .qmz library (quatmotion compress): browse, play.")
]
IndexOption = Annotated[
    Path | None, typer.Option(help="A .qidx index (quatmotion index build): search, labels.")
]
PosesOption = Annotated[
    Path | None, typer.Option(help="A pose index (quatmotion pose index): pose search.")
]
LabelsOption = Annotated[
    Path | None, typer.Option(help=f"With a folder: {LABELS_HELP}", show_default=False)
]
LabelFoldersOption = Annotated[bool, typer.Option(help=f"With a folder: {LABEL_FOLDERS_HELP}")]
PortOption = Annotated[int, typer.Option(help="TCP port, 1 to 65535; 0: a free one.")]
HostOption = Annotated[
    str, typer.Option(help="Address to bind; other than the loopback, with a warning.")
]
MaxUploadOption = Annotated[
    str, typer.Option(help="Largest upload (request body): e.g. 50MB, 500kB, 2MiB.")
]
UploadMemoryOption = Annotated[
    str,
    typer.Option(
        help="Memory the parsing of uploads may use at once (an upload costs some 12 to 47 "
        "times its size, by kind); a larger upload is refused (413), others wait their turn."
    ),
]


@app.command()
def serve(
    folder: FolderArgument = None,
    library: LibraryOption = None,
    index: IndexOption = None,
    poses: PosesOption = None,
    labels: LabelsOption = None,
    label_folders: LabelFoldersOption = False,
    port: PortOption = 8000,
    host: HostOption = "127.0.0.1",
    max_upload: MaxUploadOption = "50MB",
    upload_memory: UploadMemoryOption = "2GB",
    joint_map: JointMapOption = None,
    take: TakeOption = None,
) -> None:
    """Serve a local web app to browse, play, compare and search a motion library."""
    from quatmotion.server import listen  # the application after the port: a busy one at once

    with contextlib.ExitStack() as stack, user_errors():
        given = [p for p in (library, index, poses) if p is not None]
        _check_sources(folder, library, index, poses, labels, label_folders, joint_map, take)
        at_least("--port", port, 0, 65535)
        label_map = labels_option(labels)
        stack.enter_context(listen.sigterm_exits())  # SIGTERM, too, removes the temporary folder
        sock = stack.enter_context(listen.bind(host, port))  # first: a busy port fails at once
        # the web app and the codec it decodes with (seconds of imports), once the port is ours
        from quatmotion.server import UploadGate, allowed_hosts_for, create_app, parse_size

        upload_limit = _size("--max-upload", max_upload, parse_size)
        uploads = UploadGate(memory=_size("--upload-memory", upload_memory, parse_size))
        build = None
        if not given:
            # A build stopped mid-file is waited for (LibraryBuild.stop), up to a limit.
            temporary = tempfile.TemporaryDirectory(
                prefix="quatmotion-serve-", ignore_cleanup_errors=True
            )
            work = Path(stack.enter_context(temporary))
            build = _background_build(
                work, folder, label_map, label_folders, labels, joint_map_entries(joint_map), take
            )
            stack.callback(build.stop)  # before the folder is removed (the stack unwinds LIFO)
        application = create_app(
            *((library, index, poses) if build is None else ()),
            max_upload=upload_limit,
            allowed_hosts=allowed_hosts_for(host),
            build=build,
            uploads=uploads,
        )
        _announce(host, listen.url_of(sock), application, build)
        listen.serve_on(application, sock)  # the app starts the build once it answers


def _check_sources(
    folder: Path | None,
    library: Path | None,
    index: Path | None,
    poses: Path | None,
    labels: Path | None,
    label_folders: bool,
    joint_map: object,
    take: str | None = None,
) -> None:
    """One ``error:`` line for options that do not go together or files that are not there."""
    given = [p for p in (library, index, poses) if p is not None]
    if folder is not None and given:
        raise CliInputError("give a folder of clips, or --library/--index/--poses, not both")
    if joint_map is not None and folder is None:
        raise CliInputError("--joint-map applies to a folder of clips (an index stores its own)")
    if take is not None and folder is None:
        raise CliInputError("--take applies to a folder of clips (a library holds its clips)")
    if poses is not None and library is None and index is None:
        raise CliInputError("--poses needs --library or --index beside it")
    if given and (labels is not None or label_folders):
        raise CliInputError(
            "--labels and --label-folders label the clips of a folder; label an index "
            "with quatmotion index label"
        )
    for path in given:
        require_file(path)
    if folder is not None and not folder.is_dir():
        raise CliInputError(f"{folder}: not a folder (give files with --library, --index)")
    if folder is not None:
        from quatmotion.io import MOTION_SUFFIXES, find_motion_files

        if not find_motion_files([folder]):
            raise CliInputError(
                f"{folder}: no motion files ({', '.join(MOTION_SUFFIXES)}) in it or below"
            )


def _announce(host: str, url: str, application: Any, build: LibraryBuild | None) -> None:
    """The warning of a server reachable from other machines, then where it answers."""
    from quatmotion.server import is_loopback

    if not is_loopback(host):
        error_console.print(
            f"warning: --host {host} makes the app reachable from other machines; it has no "
            "login and serves the library and its search to anyone who can connect",
            markup=False,
            highlight=False,
            soft_wrap=True,
        )
    if build is None:
        what = f"{len(application.state.catalogue)} clips"
    else:
        what = f"{build.source}, being built (the page shows the progress)"
    console.print(
        f"quatmotion serve: {what} at {url} (API docs at /docs; Ctrl+C stops)",
        markup=False,
        highlight=False,
        soft_wrap=True,
    )


def _size(option: str, text: str, parse) -> int:  # parse: quatmotion.server.parse_size
    try:
        return int(parse(text))
    except ValueError as error:
        raise CliInputError(f"{option}: {error}") from None


def _background_build(
    work: Path,
    folder: Path | None,
    labels: dict[str, str] | None,
    label_folders: bool,
    labels_file: Path | None,
    joint_map: tuple[str, ...] = (),
    take: str | None = None,
) -> LibraryBuild:
    """The demo's library, or ``folder``'s clips, to be indexed, compressed and pose-indexed
    in ``work`` while the server answers; its progress on stderr (a bar, a line per stage)."""
    from quatmotion.cli.codec import _reporter  # the build's steps, one bar each
    from quatmotion.server.building import LibraryBuild

    source = str(folder) if folder is not None else "the demo's generated library"
    error_console.print(
        f"building {source}: indexed, compressed and pose-indexed in {work} (removed at exit)",
        markup=False,
        highlight=False,
        soft_wrap=True,
    )
    bar = progress_bar(error_console)

    def say(message: str) -> None:
        error_console.print(message, markup=False, highlight=False, soft_wrap=True)

    def run(progress, publish) -> Sequence[str]:  # LibraryBuild's Progress and Publish
        from quatmotion.cli._kernels import ensure_kernels
        from quatmotion.demo import build_library

        bar.start()
        try:
            ensure_kernels("read", "codec", "retrieval", "pose")
            built = build_library(
                work,
                [folder] if folder is not None else [],
                progress=progress,
                labels=labels,
                label_folders=label_folders,
                joint_map=joint_map,
                take=take,
                on_stage=publish,
            )
        finally:
            bar.stop()
        report_skipped(built.failed)
        if built.unmatched_labels:
            say(
                f"{labels_file}: {len(built.unmatched_labels)} keys name no clip "
                f"({', '.join(built.unmatched_labels[:5])})"
            )
        return built.failed

    return LibraryBuild(source, run, echo=_reporter(bar), on_stage=say)
