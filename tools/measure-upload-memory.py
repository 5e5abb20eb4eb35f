"""Peak RSS (VmHWM) of ``quatmotion serve --index INDEX`` while N clients (127.0.0.2, .3...)
upload one motion file at once; each client's status and time, and the peak's growth over
the RSS before the uploads per byte uploaded (what ``server.uploads.PARSE_COST`` estimates).

    python tools/measure-upload-memory.py PYTHONPATH|- INDEX FILE N [ASF]

FILE is uploaded under its own name (its suffix chooses the reader); ASF beside an .amc.
PYTHONPATH: the root of another checkout, to measure its code with this Python (``-``: this
one). ``tools/make-upload-samples.py`` writes large files of every kind. Linux only (reads
/proc; the peak is reset before the uploads through ``/proc/PID/clear_refs``).
"""

from __future__ import annotations

import http.client
import os
import re
import signal
import subprocess
import sys
import tempfile
import threading
import time
import uuid
from pathlib import Path


def _status(pid: int, field: str) -> float:
    text = Path(f"/proc/{pid}/status").read_text()
    return int(re.search(rf"{field}:\s+(\d+)", text).group(1)) / 1024  # MiB


def main() -> None:
    pythonpath, index, upload, clients = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4])
    asf = Path(sys.argv[5]) if len(sys.argv) > 5 else None
    env = dict(os.environ)
    if pythonpath != "-":
        env["PYTHONPATH"] = pythonpath
    command = [sys.executable, "-c", "from quatmotion.cli import main; main()", "serve"]
    out = tempfile.NamedTemporaryFile("w+")  # noqa: SIM115 (open for the server's life)
    server = subprocess.Popen(
        [*command, "--index", index, "--port", "0"],
        stdout=out,
        stderr=subprocess.STDOUT,
        env=env,
        cwd=tempfile.gettempdir(),
    )
    while not (found := re.search(r"http://127\.0\.0\.1:(\d+)/", Path(out.name).read_text())):
        if server.poll() is not None:
            sys.exit(Path(out.name).read_text())
        time.sleep(0.2)
    port = int(found.group(1))
    time.sleep(2)
    data = Path(upload).read_bytes()
    boundary = uuid.uuid4().hex
    parts = [("file", Path(upload).name, data)]
    if asf is not None:
        parts.append(("asf", asf.name, asf.read_bytes()))
    body = b"".join(
        f'--{boundary}\r\nContent-Disposition: form-data; name="{field}"; filename="{name}"\r\n'
        "Content-Type: application/octet-stream\r\n\r\n".encode()
        + content
        + b"\r\n"
        for field, name, content in parts
    )
    body += f"--{boundary}--\r\n".encode()
    uploaded = sum(len(content) for _, _, content in parts)
    Path(f"/proc/{server.pid}/clear_refs").write_text("5")  # VmHWM from here on
    before = _status(server.pid, "VmRSS")
    results: list[tuple[int, int, float, bytes]] = []

    def post(k: int) -> None:
        connection = http.client.HTTPConnection(
            "127.0.0.1", port, timeout=1800, source_address=(f"127.0.0.{k + 2}", 0)
        )
        started = time.monotonic()
        headers = {
            "Content-Type": f"multipart/form-data; boundary={boundary}",
            "X-Quatmotion-Request": "1",
        }
        connection.request("POST", "/api/search/upload", body=body, headers=headers)
        response = connection.getresponse()
        text = response.read()
        results.append((k, response.status, time.monotonic() - started, text[:120]))

    threads = [threading.Thread(target=post, args=(k,)) for k in range(clients)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    peak = _status(server.pid, "VmHWM")
    print(
        f"{clients} concurrent uploads of {uploaded / 1e6:.1f} MB: server RSS before "
        f"{before:.0f} MiB, peak {peak:.0f} MiB, {(peak - before) * 2**20 / uploaded:.1f} "
        "bytes per byte of one upload"
    )
    for k, status, seconds, text in sorted(results):
        print(f"  client {k}: {status} in {seconds:.1f} s {text if status != 200 else ''}")
    server.send_signal(signal.SIGINT)
    server.wait(60)


if __name__ == "__main__":
    main()
