"""The 3D viewer: motion clips animated as skeletons, in one standalone HTML page.

Conventions
-----------
* The page is built from the package's static assets (``quatmotion/viz/static``): three.js
  (r187, MIT, vendored as one script with OrbitControls by ``tools/vendor-three/build.sh``;
  its licence is ``LICENSE.three.txt``), the viewer script ``viewer.js`` (which exposes
  ``window.QuatmotionViewer``), its style ``viewer.css`` and the template ``view.html``.
* Everything is inline and the page carries a Content-Security-Policy of
  ``default-src 'none'``: it opens offline and cannot fetch anything.
* The clips travel as :mod:`quatmotion.viz.frame_data` payloads inside a JSON document
  (:func:`view_data`), the same document a web server can hand to
  ``QuatmotionViewer.show(element, data)`` after serving the scripts from
  :func:`static_folder`.
* Positions in centimetres, Y up; frames count from 0.
"""

from __future__ import annotations

import html
import json
import re
from collections.abc import Sequence
from importlib import resources
from pathlib import Path
from typing import Any, Literal

from quatmotion._atomic import atomic_write_text
from quatmotion.motion import Motion
from quatmotion.viz import frame_data

__all__ = ["Layout", "asset", "render_view", "static_folder", "view_data", "write_view"]

Layout = Literal["side", "overlay"]
"""``"side"``: each clip in its own viewport, side by side; ``"overlay"``: in one viewport."""

ASSETS = ("three.min.js", "LICENSE.three.txt", "viewer.js", "viewer.css", "view.html")
"""The static files the viewer needs, all in :func:`static_folder`."""


def static_folder() -> Path:
    """The folder of the viewer's static files (for a web server to serve them)."""
    return Path(str(resources.files("quatmotion.viz").joinpath("static")))


def asset(name: str) -> str:
    """The text of one of :data:`ASSETS`."""
    if name not in ASSETS:
        raise ValueError(f"unknown viewer asset {name!r}; the assets are {', '.join(ASSETS)}")
    return (static_folder() / name).read_text(encoding="utf-8")


def view_data(
    motions: Sequence[Motion],
    compare: Sequence[Motion] | None = None,
    *,
    ghost: int = 0,
    layout: Layout | None = None,
    autoplay: bool = True,
    loop: bool = True,
) -> dict[str, Any]:
    """The JSON document the viewer shows (``QuatmotionViewer.show(element, data)``).

    Parameters
    ----------
    motions : sequence of Motion
        Clips to show, at least one, each with at least one frame.
    compare : sequence of Motion, optional
        One clip per entry of ``motions``, any skeleton and length: each is shown in green
        beside (or over) its partner in blue, each clip at its own length on one clock (the
        shorter holds its last frame). When the two share skeleton, frame rate and frame count
        the page also shows the per-joint error of the current frame and an error-over-time
        strip; otherwise it says why it shows none
        (:func:`quatmotion.viz.frame_data.comparison_obstacle`).
    ghost : int, keyword-only
        A faint pose every ``ghost`` frames (0: none). The page caps a trail at 600 poses.
    layout : {"side", "overlay"}, optional, keyword-only
        Default: side by side when there are several clips.
    autoplay, loop : bool, keyword-only
        Start playing on load; start again at the end.

    Returns
    -------
    dict
        ``clips`` (frame-data payloads), ``pairs`` (``reference`` and ``compared`` clip
        indices, ``errors`` with ``arms_cm`` and ``max_cm``, or ``errors`` None and
        ``no_error`` saying why), ``layout``, ``ghost``, ``autoplay``, ``loop``.
    """
    if not motions:
        raise ValueError("nothing to view: give at least one motion")
    for motion in [*motions, *(compare or ())]:
        if motion.n_frames == 0:
            raise ValueError(f"clip {motion.name!r} has no frames")
    if isinstance(ghost, bool) or not isinstance(ghost, int) or ghost < 0:
        raise ValueError(f"ghost must be 0 (off) or a number of frames, got {ghost!r}")
    if layout not in (None, "side", "overlay"):
        raise ValueError(f"layout must be 'side' or 'overlay', got {layout!r}")
    clips: list[dict[str, Any]] = []
    pairs: list[dict[str, Any]] = []
    if compare is None:
        clips = [frame_data.encode_clip(m) for m in motions]
    else:
        if len(compare) != len(motions):
            raise ValueError(
                f"{len(compare)} comparison clip(s) for {len(motions)} clip(s): give one for each"
            )
        for reference, compared in zip(motions, compare, strict=True):
            pair: dict[str, Any] = {"reference": len(clips), "compared": len(clips) + 1}
            reason = frame_data.comparison_obstacle(reference, compared)
            if reason is None:
                a, b, errors = frame_data.encode_comparison(reference, compared)
                pair.update(errors=errors, arms_cm=errors["arms_cm"], max_cm=errors["max_cm"])
            else:
                a, b = frame_data.encode_clip(reference), frame_data.encode_clip(compared)
                pair.update(errors=None, arms_cm=None, max_cm=None, no_error=reason)
            pairs.append(pair)
            clips += [a, b]
    return {
        "clips": clips,
        "pairs": pairs,
        "layout": layout or ("side" if len(clips) > 1 else "overlay"),
        "ghost": ghost,
        "autoplay": autoplay,
        "loop": loop,
    }


def render_view(data: dict[str, Any], title: str) -> str:
    """The standalone page showing ``data`` (from :func:`view_data`)."""
    # "<" written as \u003c: nothing inside the data ("</script>", "<!--") can end its element.
    text = json.dumps(data, separators=(",", ":"), allow_nan=False).replace("<", "\\u003c")
    three = asset("three.min.js")
    if "</script" in three.lower():  # tools/vendor-three/build.sh refuses such a build too
        raise RuntimeError("the vendored three.min.js contains '</script' and cannot be inlined")
    values = {
        "TITLE": html.escape(title),
        "VIEWER_CSS": asset("viewer.css"),
        "THREE_JS": three,
        "VIEWER_JS": asset("viewer.js"),
        "DATA": text,
    }
    # One pass over the template: a marker-like string inside a value is never substituted.
    return re.sub(r"@@([A-Z_]+)@@", lambda m: values[m.group(1)], asset("view.html"))


def write_view(
    path: str | Path,
    motions: Sequence[Motion],
    compare: Sequence[Motion] | None = None,
    *,
    ghost: int = 0,
    layout: Layout | None = None,
    title: str | None = None,
) -> Path:
    """Write the standalone viewer page of ``motions`` to ``path`` atomically.

    Parameters are those of :func:`view_data`; ``title`` defaults to the clips' names.

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    data = view_data(motions, compare, ghost=ghost, layout=layout)
    names = ", ".join(dict.fromkeys(c["name"] for c in data["clips"]))
    atomic_write_text(path, render_view(data, title or f"quatmotion view: {names}"))
    return Path(path)
