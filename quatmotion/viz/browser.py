"""A headless Chromium to play viewer pages in: for the browser tests and the viewer benchmark.

Conventions
-----------
* The browser is Debian's ``chromium`` (``make browser`` installs it), or the binary named by
  ``$QUATMOTION_CHROMIUM``, driven by Playwright through ``executable_path``: Playwright's own
  browser download is not used. Playwright is a development dependency (the ``dev`` extras),
  imported only when a browser is launched.
* :data:`CHROMIUM_ARGS` run it headless on a closed network: without the background-networking
  switches Chromium keeps opening connections that such a network refuses. WebGL still works
  with ``--disable-gpu`` (Chromium falls back to SwiftShader, on the CPU).
* The viewer page forbids ``eval`` (its Content-Security-Policy), which Playwright's
  ``wait_for_function`` needs: wait on selectors (the page sets ``data-first-play-ms`` and
  ``data-frame`` on ``<html>``) and read state with ``page.evaluate``.
"""

from __future__ import annotations

import contextlib
import os
import shutil
from collections.abc import Iterator
from pathlib import Path
from typing import Any

__all__ = [
    "CHROMIUM_ARGS",
    "chromium_executable",
    "headless_chromium",
    "missing_browser",
    "time_to_first_play",
]

CHROMIUM_ARGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
)


def chromium_executable() -> str | None:
    """``$QUATMOTION_CHROMIUM``, else a ``chromium`` on the PATH, else None."""
    return (
        os.environ.get("QUATMOTION_CHROMIUM")
        or shutil.which("chromium")
        or shutil.which("chromium-browser")
    )


def missing_browser() -> str | None:
    """Why no browser can be launched here (None when one can), naming the fix."""
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        return "the playwright Python package is not installed (run `make browser`)"
    if chromium_executable() is None:
        return "no chromium on the PATH and QUATMOTION_CHROMIUM unset (run `make browser`)"
    return None


@contextlib.contextmanager
def headless_chromium() -> Iterator[Any]:
    """A running headless Chromium (a Playwright ``Browser``), closed on exit.

    Raises ``RuntimeError`` with :func:`missing_browser`'s reason when there is none.
    """
    reason = missing_browser()
    if reason:
        raise RuntimeError(f"cannot start a browser: {reason}")
    from playwright.sync_api import sync_playwright

    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(
            executable_path=chromium_executable(), args=list(CHROMIUM_ARGS)
        )
        try:
            yield browser
        finally:
            browser.close()


def time_to_first_play(browser: Any, page_path: str | Path, *, timeout_ms: float = 30_000) -> float:
    """Milliseconds from navigation start to the first frame drawn while playing.

    Opens ``page_path`` (a standalone viewer page) in a fresh page of ``browser`` at
    1280 x 800 and reads the page's own ``performance.now()`` stamp of its first played frame.
    """
    page = browser.new_page(viewport={"width": 1280, "height": 800})
    try:
        page.goto(Path(page_path).resolve().as_uri())
        page.wait_for_selector(
            "html[data-first-play-ms], html[data-error]", state="attached", timeout=timeout_ms
        )
        error = page.evaluate("document.documentElement.dataset.error || null")
        if error:
            raise RuntimeError(f"{page_path}: the viewer failed: {error}")
        return float(page.evaluate("Number(document.documentElement.dataset.firstPlayMs)"))
    finally:
        page.close()
