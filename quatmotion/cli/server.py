"""``quatmotion serve``: the web app over a library, an index and a pose index (uvicorn)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from quatmotion.cli._app import app
from quatmotion.cli._common import (
    CliInputError,
    at_least,
    console,
    error_console,
    require_file,
    user_errors,
)


@app.command()
def serve(
    library: Annotated[
        Path | None, typer.Option(help="A .qmz library (quatmotion compress): browse, play.")
    ] = None,
    index: Annotated[
        Path | None, typer.Option(help="A .qidx index (quatmotion index build): search, labels.")
    ] = None,
    poses: Annotated[
        Path | None, typer.Option(help="A pose index (quatmotion pose index): pose search.")
    ] = None,
    port: Annotated[int, typer.Option(help="TCP port, 1 to 65535.")] = 8000,
    host: Annotated[
        str, typer.Option(help="Address to bind; other than the loopback, with a warning.")
    ] = "127.0.0.1",
    max_upload: Annotated[
        str, typer.Option(help="Largest upload (request body): e.g. 50MB, 500kB, 2MiB.")
    ] = "50MB",
) -> None:
    """Serve a local web app to browse, play, compare and search a motion library."""
    import uvicorn

    from quatmotion.server import allowed_hosts_for, create_app, is_loopback, parse_size

    with user_errors():
        if library is None and index is None:
            raise CliInputError("give --library (.qmz), --index (.qidx) or both")
        at_least("--port", port, 1, 65535)
        try:
            upload_limit = parse_size(max_upload)
        except ValueError as error:
            raise CliInputError(f"--max-upload: {error}") from None
        for path in (library, index, poses):
            if path is not None:
                require_file(path)
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
    shown = f"[{host}]" if ":" in host else host
    console.print(
        f"quatmotion serve: {len(application.state.catalogue)} clips at http://{shown}:{port}/ "
        f"(API docs at /docs; Ctrl+C stops)",
        markup=False,
        highlight=False,
        soft_wrap=True,
    )
    uvicorn.run(application, host=host, port=port, log_level="warning")
