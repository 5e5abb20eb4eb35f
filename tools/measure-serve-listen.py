"""Time from launching ``quatmotion serve DIR --port 0`` to its first ``/api/info`` answer, the
build's progress every 10 s (where the server has ``/api/build``), then every clip's compare.

    python tools/measure-serve-listen.py PYTHONPATH|- DIR [serve options...]

PYTHONPATH: the root of another checkout, to measure its code with this Python (``-``: this
one).
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.request
from pathlib import Path


def main() -> None:
    env = dict(os.environ)
    if sys.argv[1] != "-":
        env["PYTHONPATH"] = sys.argv[1]
    command = [sys.executable, "-c", "from quatmotion.cli import main; main()", "serve"]
    out = tempfile.NamedTemporaryFile("w+")  # noqa: SIM115 (open for the server's life)
    err = tempfile.NamedTemporaryFile("w+")  # noqa: SIM115
    started = time.monotonic()
    server = subprocess.Popen(
        [*command, *sys.argv[2:], "--port", "0"],
        stdout=out,
        stderr=err,
        env=env,
        cwd=tempfile.gettempdir(),
    )
    url = ""

    def get(path: str):
        with urllib.request.urlopen(url + path, timeout=300) as response:
            return json.load(response)

    try:
        while True:
            if server.poll() is not None:
                sys.exit(Path(err.name).read_text())
            found = re.search(r"http://127\.0\.0\.1:\d+/", Path(out.name).read_text())
            if found:
                url = found.group(0)
                try:
                    get("api/info")
                    break
                except OSError:
                    pass
            time.sleep(0.1)
        print(f"time to listen (first /api/info answer): {time.monotonic() - started:.1f} s")
        while True:
            try:
                build = get("api/build")
            except urllib.error.HTTPError:
                build = {"state": "none (built before listening)"}
            if build["state"] != "building":
                break
            print(
                f"  {time.monotonic() - started:6.1f} s  {build['step']} "
                f"{build['done']}/{build['total']}, served {build['served']}",
                flush=True,
            )
            time.sleep(10)
        print(f"built after {time.monotonic() - started:.1f} s: {build['state']}")
        clips = get("api/clips")["clips"]
        print(len(clips), "clips; labels:", sorted({c["label"] for c in clips}))
        codes: dict[int, list[str]] = {}
        for clip in clips:
            try:
                get(f"api/clips/{clip['id']}/compare")
                codes.setdefault(200, []).append(clip["name"])
            except urllib.error.HTTPError as error:
                codes.setdefault(error.code, []).append(f"{clip['name']}: {error.read()[:100]}")
        for code, names in codes.items():
            print(f"compare {code}: {len(names)} clips, e.g. {names[:3]}")
    finally:
        server.send_signal(signal.SIGINT)
        server.wait(60)


if __name__ == "__main__":
    main()
