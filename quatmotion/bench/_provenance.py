"""Where a benchmark's numbers come from: the command that reproduces them and the machine.

Every benchmark's JSON starts with :func:`provenance`, so a result file read months later (or
gathered by ``quatmotion report``) says what produced it. Timings depend on the machine; the
load average at the start says how busy it was.
"""

from __future__ import annotations

import contextlib
import datetime
import os
import platform
import shlex
import subprocess
import time
from collections.abc import Callable
from importlib import metadata
from pathlib import Path
from typing import Any

__all__ = ["command", "machine", "progress_log", "provenance"]


def command(name: str, out: str | Path, quick: bool, seed: int) -> str:
    """The shell command that runs benchmark ``name`` with these arguments."""
    words = ["quatmotion", "bench", name, "--out", str(out)]
    if quick:
        words.append("--quick")
    return shlex.join([*words, "--seed", str(seed)])


def machine() -> dict[str, Any]:
    """The machine and software a benchmark runs on.

    ``processor`` is the CPU model (``/proc/cpuinfo`` where there is one), ``cpus`` the
    logical CPUs and ``cpus_usable`` those this process may run on; ``memory_gib`` the physical
    memory; ``load_average_1min`` the load when asked (other work on a shared machine slows
    timings); versions of Python, NumPy, Numba and quatmotion; ``source`` the git commit of the
    package's checkout (``-dirty`` with uncommitted changes), when it is one.
    """
    record: dict[str, Any] = {
        "processor": _cpu_model(),
        "cpus": os.cpu_count(),
        "cpus_usable": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None,
        "memory_gib": _memory_gib(),
        "system": platform.platform(),
        "python": platform.python_version(),
    }
    for package in ("numpy", "numba", "quatmotion"):
        with contextlib.suppress(metadata.PackageNotFoundError):
            record[package] = metadata.version(package)
    with contextlib.suppress(OSError, AttributeError):
        record["load_average_1min"] = round(os.getloadavg()[0], 2)
    record["source"] = _git_describe()
    return record


def provenance(name: str, out: str | Path, quick: bool, seed: int) -> dict[str, Any]:
    """The records a benchmark's JSON starts with.

    Returns
    -------
    dict
        ``benchmark`` (the name), ``command`` (:func:`command`), ``machine`` (:func:`machine`),
        ``started`` (UTC, ISO 8601), ``quick`` and ``seed``.
    """
    return {
        "benchmark": name,
        "command": command(name, out, quick, seed),
        "machine": machine(),
        "started": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "quick": quick,
        "seed": seed,
    }


def _cpu_model() -> str:
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as handle:
            for line in handle:
                if line.lower().startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _memory_gib() -> float | None:
    try:
        return round(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30, 1)
    except (AttributeError, ValueError, OSError):
        return None


def _git_describe() -> str | None:
    """``git describe --always --dirty`` of the package's folder, None outside a checkout."""
    try:
        done = subprocess.run(
            ["git", "describe", "--always", "--dirty", "--abbrev=10"],
            cwd=Path(__file__).resolve().parent,
            capture_output=True,
            text=True,
            timeout=10,
            check=False,
        )
    except (OSError, subprocess.TimeoutExpired):
        return None
    if done.returncode != 0:
        return None
    return done.stdout.strip() or None


def progress_log(verbose: bool = True) -> Callable[[str], None]:
    """A benchmark's ``log(message)``: each message printed after the seconds since this call
    (nothing printed unless ``verbose``)."""
    start = time.perf_counter()

    def log(message: str) -> None:
        if verbose:
            print(f"[{time.perf_counter() - start:7.1f}s] {message}", flush=True)

    return log
