"""``quatmotion serve``: the web app over a library, an index and a pose index (uvicorn).

With no file, it serves the demo's generated library, and with a folder (``serve DIR``) that
folder's clips: either is compressed, indexed and pose-indexed first, into a temporary folder
removed when the server stops. The port is bound before anything else, so a port in use is one
``error:`` line (exit code 2) at once, and ``--port 0`` serves on a free port it names.
"""

from __future__ import annotations

import contextlib
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from quatmotion.cli._app import app
from quatmotion.cli._common import (
    CliInputError,
    JointMapOption,
    at_least,
    console,
    error_console,
    joint_map_entries,
    progress_bar,
    report_skipped,
    require_file,
    user_errors,
)

if TYPE_CHECKING:
    from quatmotion.demo import BuiltLibrary


@app.command()
def serve(
    folder: Annotated[
        Path | None,
        typer.Argument(
            help="A folder of clips to serve: compressed and indexed first, into a temporary "
            "folder. Without it and without files: the demo's generated library.",
            show_default=False,
        ),
    ] = None,
    library: Annotated[
        Path | None, typer.Option(help="A .qmz library (quatmotion compress): browse, play.")
    ] = None,
    index: Annotated[
        Path | None, typer.Option(help="A .qidx index (quatmotion index build): search, labels.")
    ] = None,
    poses: Annotated[
        Path | None, typer.Option(help="A pose index (quatmotion pose index): pose search.")
    ] = None,
    port: Annotated[int, typer.Option(help="TCP port, 1 to 65535; 0: a free one.")] = 8000,
    host: Annotated[
        str, typer.Option(help="Address to bind; other than the loopback, with a warning.")
    ] = "127.0.0.1",
    max_upload: Annotated[
        str, typer.Option(help="Largest upload (request body): e.g. 50MB, 500kB, 2MiB.")
    ] = "50MB",
    joint_map: JointMapOption = None,
) -> None:
    """Serve a local web app to browse, play, compare and search a motion library."""
    from quatmotion.server import allowed_hosts_for, create_app, is_loopback, listen, parse_size

    with contextlib.ExitStack() as stack, user_errors():
        given = [p for p in (library, index, poses) if p is not None]
        if folder is not None and given:
            raise CliInputError("give a folder of clips, or --library/--index/--poses, not both")
        if joint_map is not None and folder is None:
            raise CliInputError(
                "--joint-map applies to a folder of clips (an index stores its own)"
            )
        if poses is not None and library is None and index is None:
            raise CliInputError("--poses needs --library or --index beside it")
        at_least("--port", port, 0, 65535)
        try:
            upload_limit = parse_size(max_upload)
        except ValueError as error:
            raise CliInputError(f"--max-upload: {error}") from None
        for path in given:
            require_file(path)
        if folder is not None and not folder.is_dir():
            raise CliInputError(f"{folder}: not a folder (give files with --library, --index)")
        stack.enter_context(listen.sigterm_exits())  # SIGTERM, too, removes the temporary folder
        sock = stack.enter_context(listen.bind(host, port))  # first: a busy port fails at once
        if not given:
            work = Path(
                stack.enter_context(tempfile.TemporaryDirectory(prefix="quatmotion-serve-"))
            )
            built = _build(work, folder, joint_map_entries(joint_map))
            library, index, poses = built.library, built.index, built.poses
        application = create_app(
            library,
            index,
            poses,
            max_upload=upload_limit,
            allowed_hosts=allowed_hosts_for(host),
        )
        if not is_loopback(host):
            error_console.print(
                f"warning: --host {host} makes the app reachable from other machines; it has no "
                "login and serves the library and its search to anyone who can connect",
                markup=False,
                highlight=False,
                soft_wrap=True,
            )
        if given:
            what = ""
        elif folder is None:
            what = " of the demo's generated library"
        else:
            what = f" of {folder}"
        console.print(
            f"quatmotion serve: {len(application.state.catalogue)} clips{what} at "
            f"{listen.url_of(sock)} (API docs at /docs; Ctrl+C stops)",
            markup=False,
            highlight=False,
            soft_wrap=True,
        )
        listen.serve_on(application, sock)


def _build(work: Path, folder: Path | None, joint_map: tuple[str, ...] = ()) -> BuiltLibrary:
    """The demo's library, or ``folder``'s clips, compressed and indexed in ``work``."""
    from quatmotion.cli._kernels import ensure_kernels
    from quatmotion.demo import build_library

    ensure_kernels("read", "codec", "retrieval", "pose")
    source = str(folder) if folder is not None else "the demo's generated library"
    error_console.print(
        f"building {source}: compressed, indexed and pose-indexed in {work} (removed at exit)",
        markup=False,
        highlight=False,
        soft_wrap=True,
    )
    from quatmotion.cli.codec import _reporter  # the codec's steps, one bar each

    with progress_bar(error_console) as bar:
        built = build_library(
            work,
            [folder] if folder is not None else [],
            progress=_reporter(bar),
            joint_map=joint_map,
        )
    report_skipped(built.failed)
    return built
