"""Where the web app listens: the socket bound before anything else, then served by uvicorn.

The socket is bound here, not by uvicorn, so that a port in use or refused is known before the
app is built and before its URL is printed (uvicorn reported it after both, as a raw
``[Errno 98]`` line and exit code 3), and so that port 0 gives the port the system picked,
known before the URL is printed. The same socket is then handed to uvicorn, so no other
program can take the port in between.
"""

from __future__ import annotations

import contextlib
import errno
import signal
import socket
import threading
from collections.abc import Iterator
from typing import Any

__all__ = ["PortError", "bind", "serve_on", "sigterm_exits", "url_of"]

_BACKLOG = 2048  # uvicorn's default


class PortError(ValueError):
    """The address cannot be listened on (in use, not allowed, not this machine's)."""


def bind(host: str, port: int) -> socket.socket:
    """A TCP socket listening on ``host:port``; uvicorn serves it later (:func:`serve_on`).

    It listens at once: a port that is only bound can still be bound by another program that
    sets ``SO_REUSEADDR`` (uvicorn does) while the library is being built; a listening one
    cannot. A client that connects before the app is served waits in the queue.

    Parameters
    ----------
    host : str
        An address or host name of this machine (``127.0.0.1``, ``::1``, ``0.0.0.0``...).
    port : int
        0 to 65535; 0 lets the system pick a free port (read it with :func:`url_of`).

    Raises
    ------
    PortError
        One line saying what is wrong and what to do: the port is in use, needs privileges,
        or the host is not an address of this machine.
    """
    try:
        infos = socket.getaddrinfo(
            host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE | socket.AI_NUMERICSERV
        )
    except socket.gaierror as error:
        raise PortError(
            f"--host {host}: not an address of this machine ({error.strerror})"
        ) from None
    family, kind, proto, _, address = infos[0]
    sock = socket.socket(family, kind, proto)
    try:
        # As uvicorn does: a port left in TIME_WAIT by the last run can be bound again at
        # once; one another socket is bound to still refuses (EADDRINUSE).
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind(address)
        sock.listen(_BACKLOG)
    except OSError as error:
        sock.close()
        raise PortError(_reason(host, port, error)) from None
    return sock


def _reason(host: str, port: int, error: OSError) -> str:
    where = f"port {port} on {host}"
    if error.errno == errno.EADDRINUSE:
        return f"{where} is in use (another server?): choose another with --port, or --port 0"
    if error.errno == errno.EACCES:
        return f"{where}: permission denied (ports below 1024 need privileges); use --port 0"
    if error.errno == errno.EADDRNOTAVAIL:
        return f"--host {host} is not an address of this machine"
    return f"cannot listen on {where}: {(error.strerror or str(error)).lower()}"


def url_of(sock: socket.socket) -> str:
    """``http://HOST:PORT/`` of a bound socket (the real port when 0 was asked for)."""
    host, port = sock.getsockname()[:2]
    shown = f"[{host}]" if ":" in host else host
    return f"http://{shown}:{port}/"


def serve_on(application: Any, sock: socket.socket, *, log_level: str = "warning") -> None:
    """Serve ``application`` with uvicorn on the bound socket until Ctrl+C or SIGTERM.

    uvicorn shuts down gracefully, then raises the signal again: Ctrl+C ends in
    ``KeyboardInterrupt`` (exit code 130), SIGTERM in its default action (the process ends at
    once) unless :func:`sigterm_exits` is in force. The socket is closed at the end.
    """
    import uvicorn

    try:
        config = uvicorn.Config(application, log_level=log_level, backlog=_BACKLOG)
        server = uvicorn.Server(config)
        server.run(sockets=[sock])
    finally:
        sock.close()
    if server.should_exit:
        # A signal stopped it, yet run() returned instead of raising (seen once on a loaded
        # machine: exit code 0 for Ctrl+C; not reproduced). Suspected: uvicorn re-raises the
        # signal into asyncio's SIGINT handler, which only cancels the main task, and a task
        # that ends first absorbs the cancel. Ctrl+C must still end as an interrupt.
        raise KeyboardInterrupt


@contextlib.contextmanager
def sigterm_exits() -> Iterator[None]:
    """While inside, SIGTERM raises ``SystemExit(143)`` instead of ending the process on the
    spot, so that what the caller opened (a temporary folder) is cleaned up; in the main
    thread only (elsewhere, nothing changes)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, _exit_on_sigterm)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _exit_on_sigterm(signum: int, _frame: Any) -> None:
    raise SystemExit(128 + signum)
