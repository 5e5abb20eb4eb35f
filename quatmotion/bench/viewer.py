"""The 3D viewer page on a long clip: its size, and how soon it plays in a real browser.

``run(out, quick, seed)`` builds standalone viewer pages (:func:`quatmotion.viz.write_view`)
of 10,000-frame clips on a 31-joint skeleton (joints and end sites drawn):

* ``cmu``: real frames, the CMU clips of one subject (the one with the most frames, clips by
  size) concatenated and cut to 10,000 frames; skipped without the data folder.
* ``synthetic_walk``: :func:`quatmotion.synthetic.generate_clip` ``("walk", seed)``,
  which walks about 100 m, so the page's root-relative quantisation is exercised at range.
* ``compare``: the ``cmu`` clip (else the walk) against itself with every quaternion component
  rounded to 2 decimals, a stand-in for a decoded clip: two clips and the error data.

For each page: bytes (whole page, frame data, three.js), seconds to build and write it, the
stated quantisation bound and the largest decoding error measured against forward kinematics,
and the **time to first play** (:func:`quatmotion.viz.browser.time_to_first_play`:
milliseconds from navigation start to the first frame drawn while playing) over fresh page
loads in headless Chromium (5 loads, ``quick``: 2), median and maximum. Without Playwright or
Chromium the times are recorded as skipped, with the reason. Targets (issue 12): under 6 MB,
playing within 2 s.
"""

from __future__ import annotations

import json
import pathlib
import statistics
import tempfile
import time
from typing import Any

import numpy as np

from quatmotion._atomic import atomic_write_json
from quatmotion.bench._provenance import provenance
from quatmotion.datasets import DataNotFoundError, catalogue
from quatmotion.motion import Motion, forward_kinematics
from quatmotion.synthetic import generate_clip
from quatmotion.viz import frame_data, viewer
from quatmotion.viz.browser import headless_chromium, missing_browser, time_to_first_play

FRAMES = 10_000
TARGET_BYTES = 6_000_000
TARGET_FIRST_PLAY_MS = 2_000.0


def _cmu_clip() -> Motion | None:
    """10,000 real CMU frames of one subject's clips, concatenated (None without the data)."""
    try:
        entries = catalogue(collection="cmu")
    except DataNotFoundError:
        return None
    by_subject: dict[pathlib.Path, list] = {}
    for entry in entries:
        by_subject.setdefault(entry.path.parent, []).append(entry)
    for subject in sorted(
        by_subject, key=lambda s: -sum(e.path.stat().st_size for e in by_subject[s])
    ):
        clips = []
        for entry in sorted(by_subject[subject], key=lambda e: -e.path.stat().st_size):
            clips.append(entry.load())
            if sum(c.n_frames for c in clips) >= FRAMES:
                first = clips[0]
                return Motion(
                    first.skeleton,
                    first.fps,
                    np.concatenate([c.root_translation for c in clips])[:FRAMES],
                    np.concatenate([c.rotations for c in clips])[:FRAMES],
                    name=f"cmu_{subject.name}_{FRAMES}",
                )
    return None


def _rounded(motion: Motion) -> Motion:
    rotations = np.round(motion.rotations, 2)
    rotations /= np.linalg.norm(rotations, axis=-1, keepdims=True)
    return Motion(motion.skeleton, motion.fps, motion.root_translation, rotations, name="rounded")


def _page(path: pathlib.Path, motions: list[Motion], compare: list[Motion] | None) -> dict:
    start = time.perf_counter()
    viewer.write_view(path, motions, compare)
    seconds = time.perf_counter() - start
    page = path.read_text(encoding="utf-8")
    begin = page.index('<script id="quatmotion-data"')
    data = json.loads(page[page.index(">", begin) + 1 : page.index("</script>", begin)])
    worst, bound = 0.0, 0.0
    for motion, payload in zip([*motions, *(compare or [])], _clip_order(data), strict=True):
        expected = forward_kinematics(motion).all_positions()
        worst = max(worst, float(np.abs(frame_data.decode_clip(payload) - expected).max()))
        bound = max(bound, payload["max_quantisation_cm"])
    three = len(viewer.asset("three.min.js").encode())
    return {
        "clips": [m.name for m in motions] + [m.name for m in compare or []],
        "frames": motions[0].n_frames,
        "points": motions[0].n_joints + motions[0].skeleton.n_sites,
        "page_bytes": path.stat().st_size,
        "frame_data_bytes": len(json.dumps(data, separators=(",", ":"))),
        "three_js_bytes": three,
        "write_seconds": seconds,
        "max_quantisation_cm": bound,
        "max_decoding_error_cm": worst,
        "under_6_mb": path.stat().st_size < TARGET_BYTES,
    }


def _clip_order(data: dict) -> list[dict]:
    """Payloads in the order of ``motions`` then ``compare`` (pairs interleave them)."""
    if not data["pairs"]:
        return data["clips"]
    references = [data["clips"][p["reference"]] for p in data["pairs"]]
    return references + [data["clips"][p["compared"]] for p in data["pairs"]]


def run(out: pathlib.Path, quick: bool = False, seed: int = 0) -> dict:
    """Measure viewer pages of 10,000-frame clips; write JSON to ``out``.

    Parameters
    ----------
    out : pathlib.Path
        JSON destination (no figures).
    quick : bool
        Two page loads per page instead of five.
    seed : int
        Seed of the synthetic walk.

    Returns
    -------
    dict
        The JSON content: per page (``cmu``, ``synthetic_walk``, ``compare``) its sizes,
        bounds and ``first_play_ms`` (``median``, ``max``, ``loads``), or ``skipped``.
    """
    out = pathlib.Path(out)
    result: dict[str, Any] = {**provenance("viewer", out, quick, seed), "pages": {}}
    cmu = _cmu_clip()
    walk = generate_clip("walk", seed, n_frames=FRAMES)
    pages = {"synthetic_walk": ([walk], None)}
    if cmu is None:
        result["pages"]["cmu"] = {"skipped": "no CMU data folder with 10,000 frames of a subject"}
    else:
        pages = {"cmu": ([cmu], None), **pages}
    reference = cmu or walk
    pages["compare"] = ([reference], [_rounded(reference)])
    loads = 2 if quick else 5
    reason = missing_browser()
    with tempfile.TemporaryDirectory() as folder:
        written = {}
        for name, (motions, compare) in pages.items():
            written[name] = pathlib.Path(folder) / f"{name}.html"
            result["pages"][name] = _page(written[name], motions, compare)
        if reason:
            result["browser"] = {"skipped": reason}
        else:
            with headless_chromium() as browser:
                result["browser"] = {"version": browser.version}
                for name, path in written.items():
                    times = [time_to_first_play(browser, path) for _ in range(loads)]
                    result["pages"][name]["first_play_ms"] = {
                        "median": statistics.median(times),
                        "max": max(times),
                        "loads": times,
                        "under_2_s": max(times) < TARGET_FIRST_PLAY_MS,
                    }
    result["note"] = (
        "first_play_ms: from navigation start to the first frame drawn while playing, fresh "
        "pages in one headless Chromium (SwiftShader WebGL, no GPU), 1280x800"
    )
    atomic_write_json(out, result)
    return result
