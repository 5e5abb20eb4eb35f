"""The start method of local pool workers: a fork server, and workers that leave ``__main__``
alone unless the job needs it.

Why a fork server: plain ``fork`` is unsafe in a process that runs threads (a Rich progress
bar, Numba's threading layer, a web server), and ``spawn`` pays the imports (NumPy, Numba,
quatmotion) again in every worker; the fork server imports them once and forks clean workers
from a process that runs no threads.

Why not the main script: a spawned or fork-server worker re-runs the parent's main script
(as ``__mp_main__``) before it unpickles anything, so that functions and classes defined there
can be found. A script that calls ``codec.Archive.build`` at its top level, without an
``if __name__ == "__main__":`` guard, then calls it again in every worker, which dies trying to
start a pool of its own: the README's example failed exactly so. The jobs of quatmotion are
module-level functions of its own modules, and their items are its own objects: a worker finds
them by importing those modules, and needs the main script only when the job (or an item)
refers to something defined there. :func:`context` gives both kinds of worker; the batch asks
for the one importing ``__main__`` only when the pickled task names it.

This subclasses the fork server's ``Popen`` of the standard library (the same in Python 3.11 to
3.13), because ``multiprocessing`` has no option for it; loky (joblib's executor) makes the
same choice, ``init_main_module=False``, for the same reason.
"""

from __future__ import annotations

import io
import multiprocessing
import os
from multiprocessing import context as _mp_context
from multiprocessing import forkserver, popen_forkserver, reduction, spawn, util
from typing import Any

__all__ = ["context"]

# What spawn.prepare() reads to re-run the parent's main script in the child.
_MAIN_KEYS = ("init_main_from_path", "init_main_from_name")


class _PopenWithoutMain(popen_forkserver.Popen):
    """``popen_forkserver.Popen`` whose child does not import the parent's ``__main__``."""

    def _launch(self, process_obj: Any) -> None:
        # The standard library's _launch, but for the two keys dropped from prep_data.
        prep_data = spawn.get_preparation_data(process_obj._name)
        for key in _MAIN_KEYS:
            prep_data.pop(key, None)
        buf = io.BytesIO()
        _mp_context.set_spawning_popen(self)
        try:
            reduction.dump(prep_data, buf)
            reduction.dump(process_obj, buf)
        finally:
            _mp_context.set_spawning_popen(None)
        self.sentinel, w = forkserver.connect_to_new_process(self._fds)
        _parent_w = os.dup(w)
        self.finalizer = util.Finalize(self, util.close_fds, (_parent_w, self.sentinel))
        with open(w, "wb", closefd=True) as f:
            f.write(buf.getbuffer())
        self.pid = forkserver.read_signed(self.sentinel)


class _ProcessWithoutMain(_mp_context.ForkServerProcess):
    @staticmethod
    def _Popen(process_obj: Any) -> _PopenWithoutMain:  # noqa: N802 (the base class's name)
        return _PopenWithoutMain(process_obj)


class _ForkServerWithoutMain(_mp_context.ForkServerContext):
    Process = _ProcessWithoutMain  # type: ignore[assignment]


_WITHOUT_MAIN = _ForkServerWithoutMain()


def context(*, import_main: bool) -> multiprocessing.context.BaseContext:
    """The fork-server context of a local pool; its workers import the parent's ``__main__``
    (as ``multiprocessing`` does by default) only when ``import_main`` is true."""
    if import_main:
        return multiprocessing.get_context("forkserver")
    return _WITHOUT_MAIN
