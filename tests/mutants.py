"""A mutation corpus of quatmotion's own files (``.qmz``, ``.qidx``, pose libraries) and the
check every command must pass on each: exit 0 (or 1, a batch's partial success), or exit 2 with
one ``error:`` line; never a traceback, never a signal, in bounded time and memory.

Used by ``tests/test_hostile_files.py``; also a script, for longer runs than the suite's:

    python tests/mutants.py KIND FILE OUT_FOLDER [--seed N] [--count N]

writes ``count`` mutants of ``FILE`` (truncations, flipped bytes, crafted headers) into
``OUT_FOLDER``. The crafted ``.qmz`` headers carry a valid CRC (they pass the framing and
reach the parsers); flips and cuts exercise the framing.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import resource
import sqlite3
import subprocess
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

import numpy as np

TIME_LIMIT_S = 60.0
"""Wall seconds a command may take on a mutant (the campaign's 20 s, with room for a loaded
test machine's first imports)."""
MEMORY_LIMIT_BYTES = 2 << 30
"""The address space a command may reserve on a mutant: over it, an allocation fails."""


# --- generic byte mutations -----------------------------------------------------------------


def truncations(data: bytes, rng: np.random.Generator, n: int) -> Iterator[tuple[str, bytes]]:
    """``data`` cut at ``n`` places: the first bytes, the last, and random ones."""
    cuts = {0, 1, 9, 10, len(data) // 2, len(data) - 1}
    cuts |= {int(c) for c in rng.integers(0, len(data), size=max(n - len(cuts), 0))}
    for cut in sorted(c for c in cuts if 0 <= c < len(data))[:n]:
        yield f"cut{cut}", data[:cut]


def flips(data: bytes, rng: np.random.Generator, n: int) -> Iterator[tuple[str, bytes]]:
    """``data`` with one random byte replaced, ``n`` times."""
    for _ in range(n):
        pos = int(rng.integers(len(data)))
        bad = bytearray(data)
        bad[pos] = int(rng.integers(256))
        yield f"flip{pos}", bytes(bad)


# --- .qmz -----------------------------------------------------------------------------------


def rewrite_qmz(source: Path, out: Path, edit: Callable[[object], object]) -> Path:
    """``source`` written again to ``out`` with its header changed by ``edit(header)`` (a new
    :class:`~quatmotion.codec.container.Header`), every chunk's CRC valid, in its own format
    version (2 or the current one)."""
    from quatmotion.codec import Archive
    from quatmotion.codec.container import write_container

    with Archive.open(source) as archive:
        header = archive.header
        version = archive.version
        records, layouts, clips = archive.payloads()
    with open(out, "wb") as fh:
        if version == 2:
            _write_version_2(fh, edit(header), records, layouts, clips)
        else:
            write_container(fh, edit(header), records, layouts, clips)
    return out


def _write_version_2(fh, header, records, layouts, clips) -> None:
    """A version 2 file (``docs/format.md``): version 3's header without the take fields."""
    from unittest import mock

    from quatmotion.codec import container

    def ref_v2(w, entry) -> None:
        ref = entry.ref
        w.raw(bytes.fromhex(ref.sha256)).string(ref.path or "").string(ref.skeleton_path or "")
        w.string(ref.skeleton).string(ref.units).u8(int(ref.units_guessed))

    with mock.patch.object(container, "_write_ref", ref_v2):
        head = header.to_bytes()
    fh.write(container.MAGIC + (2).to_bytes(2, "little"))
    container.write_chunk(fh, b"H", head)
    for tag, chunks in ((b"S", records), (b"L", layouts), (b"C", clips)):
        for payload in chunks:
            container.write_chunk(fh, tag, payload)


def _clip(header, i: int, **changes):
    clips = list(header.clips)
    clips[i] = dataclasses.replace(clips[i], **changes)
    return dataclasses.replace(header, clips=tuple(clips))


QMZ_HEADERS: dict[str, Callable[[object], object]] = {
    "name_parent": lambda h: _clip(h, 0, name="../../escaped"),
    "name_absolute": lambda h: _clip(h, 0, name="/tmp/quatmotion-escaped"),
    "name_escape": lambda h: _clip(h, 0, name="x\x1b[2J\x1b]0;owned\x07"),
    "name_twice": lambda h: _clip(h, 1, name=h.clips[0].name),
    "frames_plus_one": lambda h: _clip(h, 0, n_frames=h.clips[0].n_frames + 1),
    "frames_1e9": lambda h: _clip(h, 0, n_frames=10**9),
    "frames_2e40": lambda h: _clip(h, 0, n_frames=2**40),
    "frames_zero": lambda h: _clip(h, 0, n_frames=0),
    "fps_zero": lambda h: _clip(h, 0, fps=0.0),
    "fps_nan": lambda h: _clip(h, 0, fps=float("nan")),
    "fps_inf": lambda h: _clip(h, 0, fps=float("inf")),
    "fps_negative": lambda h: _clip(h, 0, fps=-30.0),
    "settings_corrupt": lambda h: dataclasses.replace(h, settings=b"{not json"),
    "settings_deep": lambda h: dataclasses.replace(h, settings=b"[" * 100_000 + b"]" * 100_000),
    "settings_not_object": lambda h: dataclasses.replace(h, settings=b"[1, 2]"),
}
"""Crafted headers (valid framing and CRC): every one must be refused by every command."""


def qmz_mutants(
    source: Path, folder: Path, rng: np.random.Generator, n_bytes: int = 12
) -> list[Path]:
    """The crafted headers of :data:`QMZ_HEADERS`, ``n_bytes`` cuts and ``n_bytes`` flips."""
    folder.mkdir(parents=True, exist_ok=True)
    out = [rewrite_qmz(source, folder / f"{k}.qmz", edit) for k, edit in QMZ_HEADERS.items()]
    data = source.read_bytes()
    for name, bad in [*truncations(data, rng, n_bytes), *flips(data, rng, n_bytes)]:
        path = folder / f"{name}.qmz"
        path.write_bytes(bad)
        out.append(path)
    return out


# --- .qidx ----------------------------------------------------------------------------------

QIDX_SQL: dict[str, str] = {
    "no_blobs": "DROP TABLE blobs",
    "no_features": "DROP TABLE features",
    "deep_settings": "UPDATE meta SET value = '{}' WHERE key = 'settings'".format(
        "[" * 50_000 + "]" * 50_000
    ),
    "settings_corrupt": "UPDATE meta SET value = '{oops' WHERE key = 'settings'",
    "frames_negative": "UPDATE clips SET frames = -5",
    "frames_zero": "UPDATE clips SET frames = 0",
    "fps_zero": "UPDATE clips SET fps = 0",
    "fps_negative": "UPDATE clips SET fps = -1",
    "fps_text": "UPDATE clips SET fps = 'fast'",
    "feature_garbage": "UPDATE features SET data = X'00010203'",
    "feature_pickle": "UPDATE features SET data = X'934e554d5059010076007b276465736372273a20277c4f272c2027666f727472616e5f6f72646572273a2046616c73652c20277368617065273a202834292c207d2020202020202020202020202020202020202020202020202020202020200a'",  # noqa: E501
    "label_escape": "UPDATE clips SET label = 'x' || char(27) || '[2J' || char(27) || ']0;t' || char(7)",  # noqa: E501
    "name_escape": "UPDATE clips SET name = name || char(27) || '[2J'",
    "version_text": "UPDATE meta SET value = 'two' WHERE key = 'version'",
}
"""Crafted clip indexes: SQL run on a copy of a good one."""


def qidx_mutants(
    source: Path, folder: Path, rng: np.random.Generator, n_bytes: int = 8
) -> list[Path]:
    """The crafted indexes of :data:`QIDX_SQL`, ``n_bytes`` cuts and ``n_bytes`` flips."""
    folder.mkdir(parents=True, exist_ok=True)
    data = source.read_bytes()
    out = []
    for name, sql in QIDX_SQL.items():
        path = folder / f"{name}.qidx"
        path.write_bytes(data)
        db = sqlite3.connect(path)
        with db:
            db.execute(sql)
        db.close()
        out.append(path)
    for name, bad in [*truncations(data, rng, n_bytes), *flips(data, rng, n_bytes)]:
        path = folder / f"{name}.qidx"
        path.write_bytes(bad)
        out.append(path)
    return out


# --- pose libraries (.npz) ------------------------------------------------------------------


def rewrite_npz(source: Path, out: Path, edit: Callable[[dict], dict]) -> Path:
    """A pose library's arrays changed by ``edit(arrays)`` (``meta`` as a dict)."""
    import json

    with np.load(source, allow_pickle=False) as data:
        arrays = {k: data[k] for k in data.files}
    arrays["meta"] = json.loads(str(arrays["meta"]))
    arrays = edit(arrays)
    meta = arrays["meta"]  # a dict, or raw text (JSON no encoder writes)
    arrays["meta"] = np.asarray(meta if isinstance(meta, str) else json.dumps(meta))
    with open(out, "wb") as fh:
        np.savez(fh, **arrays)
    return out


def _meta(**changes):
    def edit(a):
        a["meta"].update(changes)
        return a

    return edit


def _array(key, f):
    def edit(a):
        a[key] = f(a[key])
        return a

    return edit


def _index_bytes(f):
    return _array("index", lambda b: np.frombuffer(f(b.tobytes()), dtype=np.uint8))


def _poke(offset: int, value: bytes):
    return lambda b: b[:offset] + value + b[offset + len(value) :]


POSE_EDITS: dict[str, Callable[[dict], dict]] = {
    "dim_plus_7": lambda a: _meta(dim=a["meta"]["dim"] + 7)(a),
    "dim_minus_1": lambda a: _meta(dim=a["meta"]["dim"] - 1)(a),
    "dim_zero": _meta(dim=0),
    "dim_huge": _meta(dim=2**40),
    "dim_text": _meta(dim="many"),
    "fps_zero": _meta(fps=0),
    "fps_negative": _meta(fps=-30),
    "index_empty": _array("index", lambda b: b[:0]),
    "index_half": _array("index", lambda b: b[: len(b) // 2]),
    "index_count_up": _index_bytes(_poke(16, (10**6).to_bytes(8, "little"))),
    "index_max_elements": _index_bytes(_poke(8, (2**50).to_bytes(8, "little"))),
    "index_enterpoint": _index_bytes(_poke(52, (10**8).to_bytes(4, "little"))),
    "index_maxlevel": _index_bytes(_poke(48, (1000).to_bytes(4, "little"))),
    "index_link_out": _index_bytes(_poke(96 + 4, (10**7).to_bytes(4, "little"))),
    "index_link_count": _index_bytes(_poke(96, (60000).to_bytes(2, "little"))),
    "index_size_per_element": _index_bytes(_poke(24, (7).to_bytes(8, "little"))),
    "index_M": _index_bytes(_poke(72, (10**6).to_bytes(8, "little"))),
    "clip_of_out": _array("clip_of", lambda c: c + 1000),
    "clip_of_negative": _array("clip_of", lambda c: c - 1000),
    "frame_of_negative": _array("frame_of", lambda f: f - 10**6),
    "clip_of_short": _array("clip_of", lambda c: c[:-3]),
    "clip_names_empty": _array("clip_names", lambda c: c[:0]),
    "model_W_wrong": _array("model_W", lambda w: w[:, :-1]),
    "meta_deep": lambda a: {**a, "meta": '{"x": ' + "[" * 5000 + "]" * 5000 + "}"},
    "meta_not_object": lambda a: {**a, "meta": "[1, 2]"},
}
"""Crafted pose libraries: every one must be refused (or answered correctly) by every command,
and none may reach hnswlib's native code with sizes that disagree."""


POSE_ANSWERED = {"index_max_elements"}
"""Crafted libraries that are answered correctly: the graph's capacity is not trusted (the
reader makes room for the items the catalogue holds), so a huge one costs nothing."""


def pose_mutants(
    source: Path, folder: Path, rng: np.random.Generator, n_bytes: int = 6
) -> list[Path]:
    """The crafted libraries of :data:`POSE_EDITS`, ``n_bytes`` cuts and ``n_bytes`` flips."""
    folder.mkdir(parents=True, exist_ok=True)
    out = []
    for name, edit in POSE_EDITS.items():
        out.append(rewrite_npz(source, folder / f"{name}.npz", edit))
    data = source.read_bytes()
    for name, bad in [*truncations(data, rng, n_bytes), *flips(data, rng, n_bytes)]:
        path = folder / f"{name}.npz"
        path.write_bytes(bad)
        out.append(path)
    return out


# --- running commands -----------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Outcome:
    args: tuple[str, ...]
    returncode: int
    stdout: str
    stderr: str
    seconds: float
    peak_rss_bytes: int

    def problem(self, allowed: Sequence[int] = (0, 1, 2)) -> str | None:
        """What breaks the contract, or None."""
        where = " ".join(self.args)
        if self.returncode < 0:
            return f"{where}: killed by signal {-self.returncode}"
        if "Traceback" in self.stderr:
            return f"{where}: traceback\n{self.stderr[-2000:]}"
        if self.returncode not in allowed:
            return f"{where}: exit {self.returncode}\n{self.stderr[-1000:]}"
        if self.returncode == 2:
            errors = [line for line in self.stderr.splitlines() if line.startswith("error:")]
            if len(errors) != 1:
                return f"{where}: exit 2 without one error: line\n{self.stderr[-1000:]}"
        if self.seconds > TIME_LIMIT_S:
            return f"{where}: took {self.seconds:.0f} s"
        return None


def _limit_memory() -> None:
    resource.setrlimit(resource.RLIMIT_DATA, (MEMORY_LIMIT_BYTES, MEMORY_LIMIT_BYTES))


def run_command(args: Sequence[str], cwd: Path | None = None) -> Outcome:
    """``quatmotion ARGS`` in a subprocess, its data segment limited to
    :data:`MEMORY_LIMIT_BYTES` (over it an allocation fails: a ``MemoryError``, which must
    not be a traceback either), killed after :data:`TIME_LIMIT_S`."""
    env = {**os.environ, "COLUMNS": "200", "NO_COLOR": "1"}
    t0 = time.perf_counter()
    proc = subprocess.Popen(
        [str(Path(sys.executable).parent / "quatmotion"), *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=cwd,
        env=env,
        preexec_fn=_limit_memory,  # noqa: PLW1509 (no threads in the test process's fork)
    )
    try:
        out, err = proc.communicate(timeout=TIME_LIMIT_S * 2)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate()
    seconds = time.perf_counter() - t0
    peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss * 1024
    return Outcome(tuple(args), proc.returncode, out, err, seconds, peak)


def run_commands(commands: Sequence[Sequence[str]]) -> list[Outcome]:
    """Each command's outcome, all run in one subprocess (in-process there, by Typer's runner:
    one interpreter start for the lot). A signal that ends the subprocess is reported as the
    outcome of the command it was running."""
    import json

    env = {**os.environ, "COLUMNS": "200", "NO_COLOR": "1"}
    proc = subprocess.Popen(
        [sys.executable, __file__, "--run"],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        preexec_fn=_limit_memory,  # noqa: PLW1509 (no threads in the test process's fork)
    )
    try:
        out, err = proc.communicate(json.dumps([list(c) for c in commands]), TIME_LIMIT_S * 20)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate()
    outcomes = [Outcome(**{**json.loads(line), "args": tuple(json.loads(line)["args"])})
                for line in out.splitlines() if line.startswith("{")]  # fmt: skip
    if proc.returncode != 0:  # died inside the next command
        args = tuple(commands[len(outcomes)]) if len(outcomes) < len(commands) else ("?",)
        outcomes.append(Outcome(args, proc.returncode or -1, "", err[-3000:], 0.0, 0))
    return outcomes


def _run_here(commands: list[list[str]]) -> None:
    import json

    from typer.testing import CliRunner

    from quatmotion.cli import app

    runner = CliRunner()
    for args in commands:
        t0 = time.perf_counter()
        result = runner.invoke(app, args)
        stderr = result.stderr
        code = result.exit_code
        if result.exception is not None and not isinstance(result.exception, SystemExit):
            import traceback

            stderr += "Traceback\n" + "".join(traceback.format_exception(result.exception))
            code = 99
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
        line = {"args": args, "returncode": code, "stdout": result.stdout[-2000:],
                "stderr": stderr[-3000:], "seconds": time.perf_counter() - t0,
                "peak_rss_bytes": peak}  # fmt: skip
        print(json.dumps(line), flush=True)


def main(argv: Sequence[str] | None = None) -> None:
    import json

    if argv is None and sys.argv[1:] == ["--run"]:
        _run_here(json.loads(sys.stdin.read()))
        return
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("kind", choices=("qmz", "qidx", "pose"))
    parser.add_argument("file", type=Path)
    parser.add_argument("out", type=Path)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--count", type=int, default=12)
    args = parser.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    make = {"qmz": qmz_mutants, "qidx": qidx_mutants, "pose": pose_mutants}[args.kind]
    for path in make(args.file, args.out, rng, args.count):
        print(path)


if __name__ == "__main__":
    main()
