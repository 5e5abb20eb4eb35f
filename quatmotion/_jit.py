"""Where Numba keeps the compiled kernels of quatmotion, and a word when it compiles one.

Infrastructure (any layer may use it); it imports nothing of quatmotion, and never imports
Numba itself: :func:`on_first_compile` listens from the moment something else imports it (a
command that runs no kernel, such as a single query of the default method, spares the 0.7 s
Numba's import costs).

How Numba finds a ``cache=True`` kernel's cache (``numba.core.caching``): the first of
``$NUMBA_CACHE_DIR`` (``numba.config.CACHE_DIR``), the ``__pycache__`` folder beside the
kernel's module *if it is writable*, a per-user folder (``~/.cache/numba``), and no cache at
all. The folder is chosen once per kernel, when its module is imported (the decorator runs),
and the choice needs a folder it can write: a cache another user filled, in a folder this user
may not write, is never read. Each process keeps compiled kernels in memory, so every pool
worker loads (or, cold, compiles) its own copy: a cold library built on two workers compiled
every kernel twice at once.

Policy (:func:`configure_cache`, run when ``quatmotion`` is imported, before any kernel
module): ``$NUMBA_CACHE_DIR`` when the user set it; else Numba's default, the package's
``__pycache__`` folders, when the package folder is writable (a virtual environment, a source
tree); else, for a read-only install, a per-user folder (``$XDG_CACHE_HOME/quatmotion/numba``),
or one in the temporary folder when even that cannot be written. The choice goes into the
environment, so pool workers, the fork server and local Dask workers use the same folder.
"""

from __future__ import annotations

import contextlib
import importlib.machinery
import os
import sys
import threading
from collections.abc import Callable, MutableMapping
from pathlib import Path
from typing import Any

__all__ = [
    "CACHE_ENV",
    "PACKAGE_DIR",
    "cache_location",
    "configure_cache",
    "on_first_compile",
    "user_cache_dir",
]

CACHE_ENV = "NUMBA_CACHE_DIR"
PACKAGE_DIR = Path(__file__).resolve().parent


def _writable_folder(path: Path) -> bool:
    """Whether ``path`` exists or can be made, and a file can be created in it (Numba's test)."""
    try:
        path.mkdir(parents=True, exist_ok=True)
        # a file made and removed without importing tempfile, which every import of the
        # package would pay for (the runtime's import budget, issue 32)
        probe = path / f".quatmotion-probe-{os.getpid()}-{threading.get_ident()}"
        os.close(os.open(probe, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o600))
        os.unlink(probe)
    except OSError:
        return False
    return True


def user_cache_dir(environ: MutableMapping[str, str] | None = None) -> Path:
    """This user's cache folder for quatmotion's kernels (not created here)."""
    env = os.environ if environ is None else environ
    if sys.platform == "darwin":
        base = Path.home() / "Library" / "Caches"
    elif sys.platform == "win32":
        base = Path(env.get("LOCALAPPDATA") or Path.home() / "AppData" / "Local")
    else:
        base = Path(env.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return base / "quatmotion" / "numba"


def configure_cache(
    environ: MutableMapping[str, str] | None = None, package_dir: Path = PACKAGE_DIR
) -> str | None:
    """Choose the folder of the compiled kernels (see the module's policy).

    Parameters
    ----------
    environ : mapping, optional
        Where ``NUMBA_CACHE_DIR`` is read and set (default ``os.environ``).
    package_dir : Path
        The package's folder, whose ``__pycache__`` Numba uses when it is writable.

    Returns
    -------
    str or None
        The folder set or kept in ``NUMBA_CACHE_DIR``; ``None`` for Numba's default (the
        package's ``__pycache__`` folders).
    """
    env = os.environ if environ is None else environ
    chosen = env.get(CACHE_ENV) or None
    if chosen is None and not _writable_folder(package_dir / "__pycache__"):
        candidates = [user_cache_dir(env)]
        uid = os.getuid() if hasattr(os, "getuid") else os.getpid()
        import tempfile

        candidates.append(Path(tempfile.gettempdir()) / f"quatmotion-numba-{uid}")
        for folder in candidates:
            if _writable_folder(folder):
                chosen = str(folder)
                env[CACHE_ENV] = chosen
                break
    numba = sys.modules.get("numba")
    if chosen and numba is not None and environ is None:
        # Numba was imported first: its configuration was read already; kernels decorated from
        # now on (quatmotion's) read this.
        numba.config.CACHE_DIR = chosen
    return chosen


def cache_location() -> str:
    """Where the compiled kernels are, for a message: a folder, or the package's
    ``__pycache__`` folders."""
    folder = os.environ.get(CACHE_ENV)
    if folder:
        return folder
    return f"{PACKAGE_DIR}/**/__pycache__"


_announced = threading.Event()
_listener_installed = False
_listener_lock = threading.Lock()


def on_first_compile(callback: Callable[[], None]) -> None:
    """Call ``callback()`` once in this process, when Numba starts compiling a kernel of
    quatmotion (not when it loads one from the cache).

    A later call replaces the callback; it is not called again after the first compile. Numba
    is not imported here: when it is not imported yet, the listener is installed right after
    its import (a kernel compiles at its first call, after its module imported Numba).
    """
    global _callback
    _callback = callback
    with _listener_lock:
        if _listener_installed:
            return
        if "numba" not in sys.modules:
            if not any(isinstance(f, _AfterNumbaImport) for f in sys.meta_path):
                sys.meta_path.insert(0, _AfterNumbaImport())
            return
    _install_listener()


def _install_listener() -> None:
    """Register the compile listener with Numba's events (once)."""
    global _listener_installed
    with _listener_lock:
        if _listener_installed:
            return
        from numba.core import event

        class _FirstCompile(event.Listener):
            def on_start(self, ev: event.Event) -> None:
                dispatcher = ev.data.get("dispatcher") if isinstance(ev.data, dict) else None
                module = getattr(getattr(dispatcher, "py_func", None), "__module__", "") or ""
                if module.startswith("quatmotion.") and not _announced.is_set():
                    _announced.set()
                    with contextlib.suppress(Exception):  # a message must not fail the work
                        _callback()

            def on_end(self, ev: event.Event) -> None:
                pass

        event.register("numba:compile", _FirstCompile())
        _listener_installed = True


# Finder and loader by protocol, not by importlib.abc's base classes: importing importlib.abc
# (and the importlib.resources it brings) is most of what ``import quatmotion`` costs.
class _AfterNumbaImport:
    """Finds nothing itself: when ``numba`` is about to be imported, wraps its loader so that
    the compile listener is installed once the package has run (then leaves ``sys.meta_path``)."""

    def find_spec(self, fullname, path, target=None):  # type: ignore[no-untyped-def]
        if fullname != "numba":
            return None
        with contextlib.suppress(ValueError):
            sys.meta_path.remove(self)
        spec = importlib.machinery.PathFinder.find_spec(fullname, path, target)
        if spec is not None and spec.loader is not None:
            spec.loader = _ThenListen(spec.loader)
        return spec


class _ThenListen:
    """A module loader that installs the compile listener after the module ran."""

    def __init__(self, loader: Any) -> None:
        self._loader = loader

    def __getattr__(self, name: str) -> object:  # resources, is_package... of the real loader
        return getattr(self._loader, name)

    def create_module(self, spec):  # type: ignore[no-untyped-def]
        return self._loader.create_module(spec)

    def exec_module(self, module) -> None:  # type: ignore[no-untyped-def]
        self._loader.exec_module(module)
        with contextlib.suppress(Exception):  # a message must not fail the import
            _install_listener()


def _nothing() -> None:
    pass


_callback: Callable[[], None] = _nothing
