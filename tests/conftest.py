"""Fixtures shared by the test modules."""

from __future__ import annotations

import functools
import http.server
import threading
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from quatmotion.datasets import data_root


class QuietHandler(http.server.SimpleHTTPRequestHandler):
    """Serves files without logging each request to stderr."""

    def log_message(self, format, *args):  # noqa: A002 (the base class's signature)
        pass


@pytest.fixture()
def serve_directory() -> Iterator[Callable[..., str]]:
    """Start static HTTP servers on 127.0.0.1 (free port, a thread each) for one test.

    Call it with a folder (and optionally a handler class); it returns the base URL. Every
    server it started is shut down when the test ends. Nothing but the loopback is reached.
    """
    started: list[tuple[http.server.ThreadingHTTPServer, threading.Thread]] = []

    def start(directory: Path, handler: type = QuietHandler) -> str:
        server = http.server.ThreadingHTTPServer(
            ("127.0.0.1", 0), functools.partial(handler, directory=str(directory))
        )
        thread = threading.Thread(target=server.serve_forever, daemon=True)
        thread.start()
        started.append((server, thread))
        return f"http://127.0.0.1:{server.server_address[1]}"

    yield start
    for server, thread in started:
        server.shutdown()
        server.server_close()
        thread.join(timeout=5)


# The real mocap folder ($QUATMOTION_DATA, else ../shared/data): tests that read it are marked
# ``needs_data`` and skip, naming the folder, only where it is absent (CI always has it).
DATA = data_root(must_exist=False)
needs_data = pytest.mark.skipif(
    not DATA.is_dir(), reason=f"mocap data folder {DATA} absent (set QUATMOTION_DATA)"
)
