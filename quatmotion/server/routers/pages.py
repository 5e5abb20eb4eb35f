"""The pages: static files of this package, each its ``<main>`` fragment
(``static/NAME.html``) in one layout (``static/_layout.html``), served with a
Content-Security-Policy that allows this origin only; they call the API and show clips with
the viewer of :mod:`quatmotion.viz` (its files, three.js included, under ``/assets/viewer/``).
"""

from __future__ import annotations

import functools
from importlib import resources
from typing import Any

from fastapi import APIRouter, FastAPI
from fastapi.responses import HTMLResponse
from fastapi.staticfiles import StaticFiles

from quatmotion.viz.viewer import static_folder

__all__ = ["PAGES", "PAGE_POLICY", "mount_assets", "router"]

PAGES = ("browse", "play", "compare", "search", "poses")
"""The pages: ``/`` (browse) and ``/play``, ``/compare``, ``/search``, ``/poses``."""

PAGE_POLICY = (
    "default-src 'none'; script-src 'self'; style-src 'self' 'unsafe-inline'; "
    "img-src 'self' data: blob:; connect-src 'self'; base-uri 'none'; form-action 'self'; "
    "frame-ancestors 'none'"
)
"""Every page's Content-Security-Policy: scripts, data and styles of this origin only."""

# Each page's title, and whether it shows the 3D viewer (which brings three.js and the
# viewer's files).
_PAGE_TITLES = {"browse": "library", "play": "play", "compare": "compare", "search": "search",
                "poses": "poses"}  # fmt: skip
_VIEWER_STYLE = '<link rel="stylesheet" href="/assets/viewer/viewer.css">\n'
_VIEWER_SCRIPTS = (
    '<script src="/assets/viewer/three.min.js"></script>\n'
    '<script src="/assets/viewer/viewer.js"></script>\n'
)

router = APIRouter(include_in_schema=False)


def _page(layout: str, name: str, fragment: Any) -> str:
    """Page ``name``: its ``<main>`` fragment in the layout, with the viewer's files if it uses
    the viewer (any page that has a ``#viewer`` element)."""
    main = fragment.read_text(encoding="utf-8")
    viewer = 'id="viewer"' in main
    return layout.format(
        title=_PAGE_TITLES[name],
        page=name,
        main=main,
        viewer_style=_VIEWER_STYLE if viewer else "",
        viewer_scripts=_VIEWER_SCRIPTS if viewer else "",
    )


def mount_assets(app: FastAPI) -> None:
    """Serve the pages' files under ``/assets/app/`` and the viewer's under
    ``/assets/viewer/``."""
    pages = resources.files("quatmotion.server").joinpath("static")
    app.mount("/assets/app", StaticFiles(directory=str(pages)), name="app-assets")
    app.mount("/assets/viewer", StaticFiles(directory=str(static_folder())), name="viewer-assets")


@functools.cache
def _page_texts() -> dict[str, str]:
    """Every page's HTML, made once per process from the packaged fragments and layout."""
    pages = resources.files("quatmotion.server").joinpath("static")
    layout = pages.joinpath("_layout.html").read_text(encoding="utf-8")
    return {name: _page(layout, name, pages.joinpath(f"{name}.html")) for name in PAGES}


def _page_endpoint(name: str) -> Any:
    def endpoint() -> HTMLResponse:
        return HTMLResponse(_page_texts()[name], headers={"content-security-policy": PAGE_POLICY})

    endpoint.__doc__ = f"The {name} page."
    return endpoint


for _name in PAGES:
    router.add_api_route(
        "/" if _name == "browse" else f"/{_name}",
        _page_endpoint(_name),
        methods=["GET"],
        name=f"page-{_name}",
    )
