"""Names that come from files, shown by the web app, the viewer page and the report (issue 30,
item 12): clip names, labels, skeleton joint names and file names holding quotes, ``<``,
``>``, ``&``, ``</script>``, ``javascript:`` URLs, newlines and terminal escapes reach every
context (HTML text, attributes, titles, URLs, JS strings, JSON in a page) as data: shown
as they are, never markup, never script.

The web app's pages are static: names reach them only as JSON from the API and are set as
text (``textContent``, ``setAttribute``); ids, never names, make its URLs. The viewer page
embeds its data as JSON in a ``<script type="application/json">`` (``<`` written
``\\u003c``) and the report writes every name through ``html.escape``.
"""

from __future__ import annotations

import dataclasses
import json
import re
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from quatmotion.io import write_motion
from quatmotion.motion import Motion
from quatmotion.parallel import Runner
from quatmotion.server import CSRF_HEADER, create_app
from quatmotion.server.dependencies import CLIP_ID
from quatmotion.server.routers.pages import PAGES
from quatmotion.synthetic import generate_clip
from quatmotion.viz import report
from quatmotion.viz.viewer import write_view

BASE = "http://127.0.0.1"
PWN = "document.documentElement.dataset.pwned=1"
CLIP_NAMES = (  # file names: no "/"
    "q\"uo'te <b>bold<i> &amp; more",
    f"<svg onload={PWN}>",
    f"javascript:{PWN}",
    "line\nbreak",
    "esc\x1b[2Jape\x07",
)
SCRIPT_END = f"</script><script>{PWN}</script><!--"  # a clip name in a file (an FBX take's)
LABEL = f'<img src=x onerror="{PWN}">\n"\'</script>javascript:{PWN}'
JOINTS = {"lfingers": f"<img/src=x/onerror={PWN}>", "rthumb": "\"'&</script><b>"}


def hostile(seed: int, name: str = "") -> Motion:
    """A walk whose fingers and thumb joints carry HTML in their names."""
    clip = generate_clip("walk", seed, n_frames=60)
    names = tuple(JOINTS.get(n, n) for n in clip.skeleton.joint_names)
    skeleton = dataclasses.replace(clip.skeleton, joint_names=names)
    return dataclasses.replace(clip, skeleton=skeleton, name=name or clip.name)


@pytest.fixture(scope="module")
def hostile_index(tmp_path_factory) -> Path:
    from quatmotion.retrieval import ClipIndex, IndexSettings

    root = tmp_path_factory.mktemp("hostile")
    clips = root / "clips"
    clips.mkdir()
    for seed, name in enumerate((*CLIP_NAMES, "plain")):
        write_motion(hostile(seed + 1), clips / f"{name}.bvh")
    labels = {name: LABEL for name in (*CLIP_NAMES, "plain")}
    out = root / "hostile.qidx"
    built = ClipIndex.build(
        [clips], out, IndexSettings(kinds=("motion",)), labels=labels, runner=Runner.inline()
    )
    assert len(built.added) == len(CLIP_NAMES) + 1 and not built.failures, built
    return out


@pytest.fixture(scope="module")
def client(hostile_index):
    app = create_app(index=hostile_index)
    with TestClient(app, base_url=BASE, headers={CSRF_HEADER: "1"}) as test_client:
        yield test_client


class _Markup(HTMLParser):
    """Every element and attribute of a page, and its text."""

    def __init__(self) -> None:
        super().__init__(convert_charrefs=True)
        self.tags: list[tuple[str, dict[str, str | None]]] = []
        self.text: list[str] = []
        self.title = ""
        self._in: list[str] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        self.tags.append((tag, dict(attrs)))
        self._in.append(tag)

    def handle_endtag(self, tag: str) -> None:
        if tag in self._in:
            del self._in[len(self._in) - 1 - self._in[::-1].index(tag) :]

    def handle_data(self, data: str) -> None:
        self.text.append(data)
        if self._in and self._in[-1] == "title":
            self.title += data


def _markup(page: str) -> _Markup:
    parsed = _Markup()
    parsed.feed(page)
    parsed.close()
    return parsed


# ---------------------------------------------------------------------------- the web app
def test_the_pages_hold_no_name_and_forbid_inline_script(client):
    for name in PAGES:
        response = client.get("/" if name == "browse" else f"/{name}")
        assert response.status_code == 200
        assert "pwned" not in response.text and "<b>" not in response.text
        policy = response.headers["content-security-policy"]
        assert "script-src 'self'" in policy and "unsafe-inline" not in policy.split("style")[0]


def test_the_api_gives_every_name_as_json_data_exactly(client):
    response = client.get("/api/clips")
    assert response.headers["content-type"] == "application/json"
    assert response.headers["x-content-type-options"] == "nosniff"
    listing = response.json()
    assert {c["name"] for c in listing["clips"]} == {*CLIP_NAMES, "plain"}
    assert listing["labels"] == [LABEL] and {c["label"] for c in listing["clips"]} == {LABEL}
    for clip in listing["clips"]:  # ids (URLs, attributes) are made of safe characters only
        assert re.fullmatch(CLIP_ID, clip["id"]), clip["id"]
    escaped = next(c for c in listing["clips"] if c["name"] == CLIP_NAMES[1])
    frames = client.get(f"/api/clips/{escaped['id']}/frames")
    assert frames.headers["content-type"] == "application/json"
    assert frames.json()["name"] == CLIP_NAMES[1]
    assert set(JOINTS.values()) <= set(frames.json()["point_names"])
    found = client.get("/api/search", params={"clip": escaped["id"], "top": 10}).json()
    assert found["query"] == CLIP_NAMES[1]
    assert {r["clip"] for r in found["results"]} == {*CLIP_NAMES[:1], *CLIP_NAMES[2:], "plain"}
    assert {r["label"] for r in found["results"]} == {LABEL}


def test_an_uploaded_files_name_comes_back_as_data(client, tmp_path):
    write_motion(hostile(9), tmp_path / "take.bvh")
    data = (tmp_path / "take.bvh").read_bytes()
    name = "x'<script>&amp;javascript:y"  # (a form sends '"' in a file name as %22)
    answered = client.post("/api/search/upload", files={"file": (f"{name}.bvh", data)})
    assert answered.status_code == 200, answered.text
    assert answered.json()["query"] == name
    assert set(JOINTS.values()) <= set(answered.json()["query_clip"]["point_names"])
    refused = client.post("/api/search/upload", files={"file": (f"{name}.bvh", data[:300])})
    assert refused.status_code == 400
    assert refused.headers["content-type"] == "application/json"
    assert refused.json()["detail"].startswith(f"{name}.bvh")


# ---------------------------------------------------------------------------- the viewer page
def _view(tmp_path: Path) -> tuple[str, Motion, Motion]:
    clip = hostile(1, SCRIPT_END)
    moved = clip.rotations.copy()
    moved[:, clip.skeleton.joint_names.index("lhand")] = [np.cos(0.6), 0.0, np.sin(0.6), 0.0]
    other = dataclasses.replace(clip, rotations=moved, name=CLIP_NAMES[0])
    title = " · ".join((SCRIPT_END, *CLIP_NAMES))
    path = write_view(tmp_path / "view.html", [clip], [other], title=title)
    return path.read_text(encoding="utf-8"), clip, other


def test_the_viewer_page_embeds_names_as_data(tmp_path):
    page, clip, other = _view(tmp_path)
    parsed = _markup(page)
    assert parsed.title == " · ".join((SCRIPT_END, *CLIP_NAMES))  # the names, as they are
    scripts = [attrs for tag, attrs in parsed.tags if tag == "script"]
    assert len(scripts) == page.lower().count("</script") == 4  # data, three.js, viewer, boot
    assert not any(tag in ("img", "b") for tag, _ in parsed.tags)
    data = re.search(r'<script id="quatmotion-data" type="application/json">(.*?)</script>', page)
    assert data is not None
    clips = json.loads(data.group(1))["clips"]
    assert [c["name"] for c in clips] == [clip.name, other.name]
    assert set(JOINTS.values()) <= set(clips[0]["point_names"])


# ---------------------------------------------------------------------------- the report
def test_the_report_writes_every_name_as_text(tmp_path):
    name = SCRIPT_END + CLIP_NAMES[2]
    result = {
        "benchmark": name,
        "command": f"quatmotion bench {CLIP_NAMES[0]}",
        "tables": [
            {"title": LABEL, "columns": [JOINTS["lfingers"], "ms"], "rows": [[name, 1.5]],
             "note": CLIP_NAMES[3]},
        ],
        "per_clip": [{"clip": n, "ratio": 10.0 + i} for i, n in enumerate(CLIP_NAMES)],
        "figures": [f"{CLIP_NAMES[0]}.png"],
    }  # fmt: skip
    path = tmp_path / "hostile.json"
    path.write_text(json.dumps(result), encoding="utf-8")
    page = report.render_report([report.load_result(path)], title=LABEL)
    parsed = _markup(page)
    assert {tag for tag, _ in parsed.tags} <= {
        "html", "head", "meta", "title", "style", "body", "h1", "h2", "h3", "h4", "nav", "a",
        "section", "p", "table", "thead", "tbody", "tr", "th", "td", "code", "span",
        "details", "summary", "div", "figure", "img", "figcaption",
    }  # fmt: skip
    assert not any(tag in ("script", "b", "img") for tag, _ in parsed.tags)
    for _tag, attrs in parsed.tags:
        assert not any(key.startswith("on") for key in attrs), attrs
        assert (attrs.get("href") or "#").startswith("#"), attrs
    assert parsed.title == LABEL
    text = "".join(parsed.text)
    for shown in (name, LABEL, JOINTS["lfingers"], *CLIP_NAMES, f"{CLIP_NAMES[0]}.png"):
        assert shown in text, shown


# ---------------------------------------------------------------------------- in a browser
def _ready(page, selector: str) -> None:
    page.wait_for_selector(f"{selector}, html[data-error]", state="attached", timeout=60_000)
    assert page.evaluate("document.documentElement.dataset.error || null") is None


def _injected(made: str) -> str:
    """Script counting what a name that became markup would make: the elements ``made``, or
    an attribute that runs script (``on...``, a ``javascript:`` link or source)."""
    runs = (
        "(a) => a.name.startsWith('on') || (['href', 'src', 'action', 'formaction']"
        ".includes(a.name) && /^\\s*javascript:/i.test(a.value))"
    )
    everything = "[...document.querySelectorAll('*')]"
    return (
        f"[...document.querySelectorAll('{made}')].concat("
        f"{everything}.filter((e) => [...e.attributes].some({runs}))).length"
    )


_IN_APP = _injected("main img, main b, main i, main svg, iframe, object")
_IN_VIEWER = _injected("img, svg, iframe, object")  # (its error panel has <b> of its own)


def test_hostile_names_are_shown_as_text_and_run_no_script_in_a_browser(
    browser, hostile_index, tmp_path, serve_app
):
    """The web app (served by uvicorn, as ``quatmotion serve`` does) and the viewer page in
    headless Chromium: every hostile name shown as text, in text and in title attributes; no
    element of theirs made, no script of theirs run, no link of theirs followed."""
    base = serve_app(create_app(index=hostile_index))
    page = browser.new_page(viewport={"width": 1280, "height": 800})
    errors: list[str] = []
    page.on("pageerror", lambda error: errors.append(str(error)))
    try:
        page.goto(f"{base}/")
        _ready(page, "html[data-state=ready]")
        shown = page.locator("#clips").text_content() or ""
        assert all(name in shown for name in CLIP_NAMES) and LABEL in shown
        assert page.evaluate(_IN_APP) == 0
        hrefs = page.evaluate("[...document.links].map((a) => a.getAttribute('href'))")
        assert hrefs and all(h.startswith("/") for h in hrefs), hrefs
        svg = next(c for c in page.evaluate("fetch('/api/clips').then((r) => r.json())")["clips"]
                   if c["name"] == CLIP_NAMES[1])  # fmt: skip
        page.goto(f"{base}/search?clip={svg['id']}")
        _ready(page, "html[data-state=ready]")
        titles = page.evaluate(
            "[...document.querySelectorAll('#results [title]')].map((e) => e.getAttribute('title'))"
        )
        assert set(titles) >= {*CLIP_NAMES[:1], *CLIP_NAMES[2:]}, titles
        assert page.evaluate(_IN_APP) == 0
        page.goto(f"{base}/play?clip={svg['id']}")
        _ready(page, "html[data-state=ready]")
        assert page.locator("h1").text_content() == CLIP_NAMES[1]

        _, clip, _ = _view(tmp_path)
        page.goto((tmp_path / "view.html").as_uri())
        _ready(page, "html[data-first-play-ms]")
        assert page.title().startswith(f"{SCRIPT_END} · {CLIP_NAMES[0]}")  # (spaces collapsed)
        assert SCRIPT_END in (page.locator(".qmv-labels").text_content() or "")
        assert JOINTS["lfingers"] in (page.locator(".qmv-error").text_content() or "")
        assert page.evaluate(_IN_VIEWER) == 0
        assert page.evaluate("document.scripts.length") == 4  # data, three.js, viewer, boot
        assert page.evaluate("document.documentElement.dataset.pwned || null") is None
        assert not errors, errors
    finally:
        page.close()


def test_the_servers_log_writes_an_uploaded_files_name_escaped(client, caplog, monkeypatch):
    from quatmotion.server import uploads

    def broken(*_args, **_kwargs):
        raise KeyError("accessors")

    monkeypatch.setattr(uploads, "parse_motion", broken)
    name = "\x1b[2J\x1b[31mtake.glb"
    with caplog.at_level("WARNING", logger="quatmotion.server"):
        answered = client.post("/api/search/upload", files={"file": (name, b"glTF")})
    assert answered.status_code == 400 and answered.json()["detail"].startswith(name)
    [record] = [r for r in caplog.records if r.name == "quatmotion.server"]
    assert "\x1b" not in record.getMessage() and "\\x1b[2J" in record.getMessage()
