"""The web app's JSON API through FastAPI's TestClient: browse, play data, compare, search by an
indexed clip and by upload, pose search, and the safety rules (ids not paths, upload limits,
parser messages, host check, the event loop kept free while a search runs)."""

from __future__ import annotations

import re
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient
from typer.testing import CliRunner

from quatmotion import codec
from quatmotion.errors import FormatError
from quatmotion.io import read_motion, write_asf, write_motion
from quatmotion.motion import forward_kinematics
from quatmotion.retrieval.search import DEFAULT_K
from quatmotion.server import CSRF_HEADER, allowed_hosts_for, create_app, is_loopback, parse_size
from quatmotion.server import clips as clips_module
from quatmotion.server.dependencies import MAX_TOP
from quatmotion.synthetic import generate_clip
from quatmotion.viz import frame_data

BASE = "http://127.0.0.1"  # the app answers loopback host names only
POST_HEADERS = {CSRF_HEADER: "1"}  # as the pages send it (CSRF guard)


@pytest.fixture(scope="module")
def client(motion_library):
    app = create_app(motion_library["library"], motion_library["index"], motion_library["poses"])
    with TestClient(app, base_url=BASE, headers=POST_HEADERS) as test_client:
        yield test_client


def _files(folder: Path) -> list[str]:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


# ------------------------------------------------------------------------------ browse
def test_browse_lists_every_clip_with_the_library_and_index_facts(client, motion_library):
    data = client.get("/api/clips").json()
    by_name = {c["name"]: c for c in data["clips"]}
    assert sorted(by_name) == sorted(
        [f"{k}_{s}" for k in ("walk", "squat", "jumping_jack") for s in range(2)] + ["kick_0"]
    )
    assert data["labels"] == ["jumping_jack", "kick", "squat", "walk"]
    with codec.Archive.open(motion_library["library"]) as archive:
        for position, entry in enumerate(archive.entries):
            clip = by_name[entry.name]
            assert clip["id"] == entry.name
            assert clip["label"] == entry.name.rsplit("_", 1)[0]
            assert clip["frames"] == entry.n_frames == 120
            assert clip["duration_s"] == pytest.approx(120 / entry.fps)
            assert clip["compressed_bytes"] == archive.chunk_bytes(position)
            assert clip["declared_max_error_cm"] == pytest.approx(entry.max_error)
            assert clip["declared_arms_cm"] == pytest.approx(entry.arms)
            assert clip["in_library"] and clip["in_index"] and clip["has_original"]
    # Indexed but not compressed: served from its original file, no library facts.
    kick = by_name["kick_0"]
    assert not kick["in_library"] and kick["in_index"] and kick["compressed_bytes"] is None
    assert all(c["in_poses"] for c in data["clips"])
    one = client.get("/api/clips/walk_1").json()
    assert one == by_name["walk_1"]


@pytest.mark.parametrize(
    "column",
    ["name", "label", "frames", "duration_s", "compressed_bytes", "declared_max_error_cm"],
)
def test_browse_sorts_by_any_column_with_missing_values_last(client, column):
    for order in ("asc", "desc"):
        clips = client.get("/api/clips", params={"sort": column, "order": order}).json()["clips"]
        values = [c[column] for c in clips if c[column] is not None]
        assert values == sorted(values, reverse=order == "desc")
        present = [c[column] is not None for c in clips]
        assert present == sorted(present, reverse=True)  # None only at the end


def test_browse_filters_by_label(client):
    clips = client.get("/api/clips", params={"label": "squat"}).json()["clips"]
    assert [c["name"] for c in clips] == ["squat_0", "squat_1"]
    assert client.get("/api/clips", params={"label": "nothing"}).json()["clips"] == []
    bad = client.get("/api/clips", params={"sort": "path"})
    assert bad.status_code == 400 and "sort" in bad.json()["detail"]


def test_info_names_files_not_paths(client, motion_library):
    info = client.get("/api/info").json()
    assert info["library"] == "lib.qmz" and info["index"] == "lib.qidx"
    assert info["clips"] == 7 and info["default_method"] == info["methods"][0]
    assert info["max_upload_bytes"] == 50_000_000
    assert str(motion_library["clips"].parent) not in client.get("/api/info").text
    assert str(motion_library["clips"]) not in client.get("/api/search?clip=walk_0").text


# ------------------------------------------------------------------------------ play data
def test_frames_are_the_decoded_library_clip(client, motion_library):
    payload = client.get("/api/clips/walk_0/frames").json()
    with codec.Archive.open(motion_library["library"]) as archive:
        decoded = archive.read("walk_0")
    expected = forward_kinematics(decoded).all_positions()
    shown = frame_data.decode_clip(payload)
    assert shown.shape == expected.shape == (120, shown.shape[1], 3)
    assert np.max(np.abs(shown - expected)) <= payload["max_quantisation_cm"] + 1e-6
    part = client.get("/api/clips/walk_0/frames", params={"start": 40, "stop": 41}).json()
    assert part["n_frames"] == 1 and part["name"] == "walk_0 frame 40"
    np.testing.assert_allclose(frame_data.decode_clip(part)[0], expected[40], atol=0.01)
    for start, stop in ((10, 5), (0, 121), (120, 121)):
        bad = client.get("/api/clips/walk_0/frames", params={"start": start, "stop": stop})
        assert bad.status_code == 400, (start, stop)


def test_an_index_only_clip_plays_from_its_original_file(client, motion_library):
    payload = client.get("/api/clips/kick_0/frames").json()
    original = read_motion(motion_library["clips"] / "kick_0.bvh")
    expected = forward_kinematics(original).all_positions()
    assert np.max(np.abs(frame_data.decode_clip(payload) - expected)) <= (
        payload["max_quantisation_cm"] + 1e-6
    )
    missing = client.get("/api/clips/kick_0/compare")
    assert missing.status_code == 404 and "not in the library" in missing.json()["detail"]


def test_compare_shows_the_original_beside_the_decoded_clip(client, motion_library):
    data = client.get("/api/clips/squat_1/compare").json()
    original = read_motion(motion_library["clips"] / "squat_1.bvh")
    reference, compared = (frame_data.decode_clip(c) for c in data["clips"])
    truth = forward_kinematics(original).all_positions()
    assert np.max(np.abs(reference - truth)) <= data["clips"][0]["max_quantisation_cm"] + 1e-6
    pair = data["pairs"][0]
    assert (pair["reference"], pair["compared"]) == (0, 1)
    declared = client.get("/api/clips/squat_1").json()["declared_max_error_cm"]
    # The codec's bound holds on every frame and it declares what it reached.
    assert 0 < pair["max_cm"] <= 1.0 + 1e-6
    assert pair["max_cm"] == pytest.approx(declared, abs=1e-3)
    assert np.max(np.linalg.norm(compared - truth, axis=-1)) == pytest.approx(
        pair["max_cm"], abs=0.01
    )


# ------------------------------------------------------------------------------ search
def test_search_by_an_indexed_clip_ranks_its_kind_first(client):
    response = client.get("/api/search", params={"clip": "walk_0", "top": 10})
    assert response.status_code == 200
    data = response.json()
    assert data["query"] == "walk_0" and data["query_id"] == "walk_0"
    results = data["results"]
    assert [r["rank"] for r in results] == list(range(1, 7))  # every other indexed clip
    assert "walk_0" not in [r["clip"] for r in results]
    assert results[0]["clip"] == "walk_1" and results[0]["label"] == "walk"
    assert all(r["id"] == r["clip"] for r in results)
    assert set(results[0]) == {"rank", "id", "clip", "label", "distance"}  # no server path
    top2 = client.get("/api/search", params={"clip": "squat_0", "top": 2}).json()["results"]
    assert [r["clip"] for r in top2][:1] == ["squat_1"] and len(top2) == 2


def test_search_methods_are_checked(client):
    other = client.get("/api/search", params={"clip": "walk_0", "method": "dtw-positions"})
    assert other.status_code == 200 and other.json()["method"] == "dtw-positions"
    for method in ("paper-qssd", "no-such-method"):
        bad = client.get("/api/search", params={"clip": "walk_0", "method": method})
        assert bad.status_code == 400 and "no features for method" in bad.json()["detail"]
    assert client.get("/api/search", params={"clip": "walk_0", "top": 0}).status_code == 400


def test_search_by_an_uploaded_bvh_leaves_out_the_indexed_clip_it_is(client, motion_library):
    before = _files(motion_library["clips"].parent)
    data = (motion_library["clips"] / "squat_1.bvh").read_bytes()
    response = client.post(
        "/api/search/upload", files={"file": ("my take.bvh", data)}, data={"top": "3"}
    )
    assert response.status_code == 200, response.text
    body = response.json()
    assert body["query"] == "my take" and body["query_id"] is None
    # the same bytes are the indexed squat_1: left out, as a search by its id leaves it out
    assert body["left_out"] == "squat_1"
    by_id = client.get("/api/search", params={"clip": "squat_1", "top": 3}).json()
    assert by_id["left_out"] == "squat_1"
    assert [(r["clip"], r["distance"]) for r in body["results"]] == [
        (r["clip"], r["distance"]) for r in by_id["results"]
    ]
    assert len(body["results"]) == 3
    assert frame_data.decode_clip(body["query_clip"]).shape[0] == 120
    assert _files(motion_library["clips"].parent) == before  # nothing stored beside the library


def test_search_by_an_uploaded_amc_needs_and_takes_its_asf(client, tmp_path):
    clip = generate_clip("walk", 7, n_frames=120)
    write_motion(clip, tmp_path / "walk_7.amc")
    write_asf(clip.skeleton, tmp_path / "walk.asf")
    amc = (tmp_path / "walk_7.amc").read_bytes()
    asf = (tmp_path / "walk.asf").read_bytes()
    alone = client.post("/api/search/upload", files={"file": ("walk_7.amc", amc)})
    assert alone.status_code == 400 and "ASF" in alone.json()["detail"]
    both = client.post(
        "/api/search/upload", files={"file": ("walk_7.amc", amc), "asf": ("walk.asf", asf)}
    )
    assert both.status_code == 200, both.text
    assert both.json()["results"][0]["label"] == "walk"
    assert both.json()["left_out"] is None  # a take the index does not hold


@pytest.mark.parametrize(
    ("files", "expected"),
    [
        ({"file": ("cut.bvh", b"HIERARCHY\nROOT Hips\n{\n  OFFSET 0 0\n")}, r"^cut\.bvh:\d+: "),
        ({"file": ("binary.bvh", b"HIERARCHY\x00\x01\x02")}, r"^binary\.bvh:1: not a text file"),
        ({"file": ("notes.txt", b"hello")}, r"^notes\.txt: unknown file type"),
        ({"file": ("", b"HIERARCHY")}, r"needs a name|'file' field"),
        ({"other": ("x.bvh", b"HIERARCHY")}, r"'file' field"),
        (
            {"file": ("a.amc", b":DEGREES\n1\nroot 0 0 0 0 0 0\n"), "asf": ("bad.asf", b"no")},
            r"^bad\.asf",
        ),
    ],
)
def test_a_bad_upload_gets_400_with_the_parsers_one_line_message(client, files, expected):
    response = client.post("/api/search/upload", files=files)
    assert response.status_code == 400, response.text
    detail = response.json()["detail"]
    assert "\n" not in detail and re.search(expected, detail), detail


def test_an_upload_that_is_not_a_multipart_form_gets_400(client):
    for kwargs in (
        {"json": {"file": "x"}},
        {"content": b"garbage", "headers": {"content-type": "multipart/form-data; boundary=b"}},
    ):
        response = client.post("/api/search/upload", **kwargs)
        assert response.status_code == 400, response.text


# ------------------------------------------------------------------------------ poses
def test_pose_search_finds_the_frame_itself_and_then_other_clips(client):
    own = client.get("/api/poses", params={"clip": "walk_0", "frame": 40, "k": 3}).json()
    assert own["clip"] == "walk_0" and own["frame"] == 40
    first = own["results"][0]
    assert (first["id"], first["frame"]) == ("walk_0", 40)
    assert first["distance"] == pytest.approx(0.0, abs=1e-4)
    others = client.get(
        "/api/poses", params={"clip": "walk_0", "frame": 40, "k": 5, "other_clips": True}
    ).json()["results"]
    assert len(others) == 5 and all(r["clip"] != "walk_0" for r in others)
    distances = [r["distance"] for r in others]
    assert distances == sorted(distances)
    late = client.get("/api/poses", params={"clip": "walk_0", "frame": 120})
    assert late.status_code == 400 and "not within" in late.json()["detail"]


def test_without_an_index_or_pose_index_those_features_say_so(motion_library):
    app = create_app(motion_library["library"])
    with TestClient(app, base_url=BASE) as only_library:
        clips = only_library.get("/api/clips").json()["clips"]
        assert len(clips) == 6 and not any(c["in_index"] for c in clips)
        assert all(c["has_original"] for c in clips)  # the library names its clips' files
        search = only_library.get("/api/search", params={"clip": "walk_0"})
        assert search.status_code == 404 and "--index" in search.json()["detail"]
        poses = only_library.get("/api/poses", params={"clip": "walk_0", "frame": 0})
        assert poses.status_code == 404 and "--poses" in poses.json()["detail"]
        compare = only_library.get("/api/clips/walk_0/compare")
        assert compare.status_code == 200, compare.text


# ------------------------------------------------------------------------------ safety
TRAVERSALS = [
    "/api/clips/../../etc/passwd",
    "/api/clips/..%2F..%2Fetc%2Fpasswd",
    "/api/clips/..%252F..%252Fetc%252Fpasswd",
    "/api/clips/%2Fetc%2Fpasswd",
    "/api/clips/%2Fetc%2Fpasswd/frames",
    "/api/clips/..%5C..%5Cwalk_0/frames",
    "/api/clips/~/frames",
    "/api/search?clip=../../etc/passwd",
    "/api/search?clip=%2Fetc%2Fpasswd",
    "/api/search?clip=..%2F..%2Flib.qidx",
    "/api/poses?clip=/etc/passwd&frame=0",
    "/assets/viewer/../../server/app.py",
    "/assets/viewer/..%2F..%2Fserver%2Fapp.py",
    "/assets/viewer/%2e%2e/%2e%2e/errors.py",
    "/assets/app/..%2F..%2F..%2Fpyproject.toml",
    "/assets/app/%2Fetc%2Fpasswd",
    "/assets/docs/..%2F..%2Ffastapi%2F__init__.py",
]


@pytest.mark.parametrize("url", TRAVERSALS)
def test_path_traversal_attempts_get_400_or_404(client, url):
    response = client.get(url)
    assert response.status_code in (400, 404), (url, response.status_code, response.text[:200])
    assert "root:" not in response.text and "import" not in response.text


def test_an_uploaded_file_name_is_never_a_path(client, motion_library):
    before = _files(motion_library["clips"].parent)
    data = (motion_library["clips"] / "walk_1.bvh").read_bytes()
    for name in ("../../evil.bvh", "/tmp/evil.bvh", "..\\..\\evil.bvh"):
        response = client.post("/api/search/upload", files={"file": (name, data)})
        assert response.status_code == 200, response.text
        assert response.json()["query"] == "evil"
    assert _files(motion_library["clips"].parent) == before


def test_an_oversized_upload_gets_413_and_nothing_is_kept(motion_library):
    data = (motion_library["clips"] / "walk_1.bvh").read_bytes()
    limit = len(data) + 4096  # the file and its multipart framing fit, twice it does not
    app = create_app(motion_library["library"], motion_library["index"], max_upload=limit)
    before = _files(motion_library["clips"].parent)
    with TestClient(app, base_url=BASE, headers=POST_HEADERS) as small:
        fits = small.post("/api/search/upload", files={"file": ("walk.bvh", data)})
        assert fits.status_code == 200, fits.text
        big = small.post("/api/search/upload", files={"file": ("walk.bvh", data + data)})
        assert big.status_code == 413 and str(limit) in big.json()["detail"]

        def chunks():  # no Content-Length: counted as it arrives
            for i in range(0, 2 * len(data), 8192):
                yield (data + data)[i : i + 8192]

        chunked = small.post(
            "/api/search/upload",
            content=chunks(),
            headers={"content-type": "multipart/form-data; boundary=x"},
        )
        assert chunked.status_code == 413
        assert small.get("/api/clips").status_code == 200  # still serving
    assert _files(motion_library["clips"].parent) == before


def test_requests_for_another_host_name_are_refused(client):
    # A page of another site whose name resolves to 127.0.0.1 (DNS rebinding) cannot read.
    assert client.get("/api/clips", headers={"host": "evil.example"}).status_code == 400
    assert client.get("/api/clips", headers={"host": "localhost:8000"}).status_code == 200


def test_the_server_answers_while_a_search_runs(client, monkeypatch):
    started, release = threading.Event(), threading.Event()
    real_search = clips_module.search

    def slow_search(*args, **kwargs):
        started.set()
        release.wait(timeout=30)  # held until the other request has been answered
        return real_search(*args, **kwargs)

    monkeypatch.setattr(clips_module, "search", slow_search)
    outcome: dict[str, object] = {}

    def searching() -> None:
        outcome["response"] = client.get("/api/search", params={"clip": "walk_0"})

    thread = threading.Thread(target=searching)
    thread.start()
    try:
        assert started.wait(timeout=30), "the search never started"
        t0 = time.perf_counter()
        answered = client.get("/api/clips")
        elapsed = time.perf_counter() - t0
        assert answered.status_code == 200 and not release.is_set()
        assert elapsed < 10, f"another request waited {elapsed:.1f} s for the search"
    finally:
        release.set()
        thread.join(timeout=60)
    assert outcome["response"].status_code == 200  # type: ignore[union-attr]


# ------------------------------------------------------------------------------ pages, docs
def test_pages_load_only_the_apps_own_assets(client):
    for page in ("/", "/play?clip=walk_0", "/compare?clip=walk_0", "/search", "/poses"):
        response = client.get(page)
        assert response.status_code == 200 and "text/html" in response.headers["content-type"]
        policy = response.headers["content-security-policy"]
        assert "default-src 'none'" in policy and "script-src 'self'" in policy
        references = re.findall(r'(?:src|href)="([^"]+)"', response.text)
        assert references and "http" not in response.text
        for ref in references:
            if ref.startswith("data:"):
                continue
            assert ref.startswith("/"), ref
            if ref.startswith("/assets/"):
                assert client.get(ref).status_code == 200, ref
    docs = client.get("/docs")
    assert docs.status_code == 200
    for ref in re.findall(r"(?:src|href|url)\s*[=:]\s*['\"]([^'\"]+)['\"]", docs.text):
        assert ref.startswith("/"), ref  # Swagger UI from the app, not a CDN


def test_openapi_documents_every_api_route(client):
    spec = client.get("/openapi.json").json()
    paths = spec["paths"]
    for path in (
        "/api/info",
        "/api/clips",
        "/api/clips/{clip_id}",
        "/api/clips/{clip_id}/frames",
        "/api/clips/{clip_id}/compare",
        "/api/search",
        "/api/search/upload",
        "/api/poses",
    ):
        assert path in paths, path
    upload = paths["/api/search/upload"]["post"]
    ref = upload["requestBody"]["content"]["multipart/form-data"]["schema"]["$ref"]
    form = spec["components"]["schemas"][ref.rsplit("/", 1)[1]]
    assert form["required"] == ["file"] and {"asf", "method", "top"} <= set(form["properties"])
    assert [p["name"] for p in upload["parameters"]] == [CSRF_HEADER]
    assert all(p.startswith("/api/") for p in paths)
    # a search's number of results: one range and one default, made from the code's constants
    query_top = next(p for p in paths["/api/search"]["get"]["parameters"] if p["name"] == "top")
    for schema in (form["properties"]["top"], query_top["schema"]):
        assert (schema["minimum"], schema["maximum"]) == (1, MAX_TOP)
        assert schema["default"] == DEFAULT_K
    pose_k = next(p for p in paths["/api/poses"]["get"]["parameters"] if p["name"] == "k")
    assert pose_k["schema"]["maximum"] == MAX_TOP
    # errors as the app answers them: {"detail"} with a 4xx (never FastAPI's 422) or 503
    for operations in paths.values():
        for operation in operations.values():
            assert {"200", "4XX", "503"} <= set(operation["responses"]), operation
            assert "422" not in operation["responses"]
    assert spec["components"]["schemas"]["ErrorModel"]["required"] == ["detail"]


def test_a_number_of_results_out_of_range_is_400_naming_it(client):
    walk = {"clip": "walk_0"}
    for top in (0, MAX_TOP + 1, "many"):
        response = client.get("/api/search", params={**walk, "top": top})
        assert response.status_code == 400 and response.json()["detail"].startswith("top:")
    data = b"HIERARCHY"
    upload = client.post(
        "/api/search/upload", files={"file": ("w.bvh", data)}, data={"top": str(MAX_TOP + 1)}
    )
    assert upload.status_code == 400, upload.text
    assert upload.json()["detail"].startswith("the 'top' field of the form:")


# ------------------------------------------------------------------------------ factory, CLI
def test_the_factory_checks_its_files(motion_library, tmp_path):
    with pytest.raises(ValueError, match="nothing to serve"):
        create_app()
    broken = tmp_path / "broken.qmz"
    broken.write_bytes(motion_library["library"].read_bytes()[:-40])
    with pytest.raises(FormatError):
        create_app(broken)
    with pytest.raises(FileNotFoundError):
        create_app(index=tmp_path / "missing.qidx")
    with pytest.raises(ValueError, match="max_upload"):
        create_app(motion_library["library"], max_upload=0)


def test_sizes_and_hosts():
    assert parse_size("50MB") == 50_000_000
    assert parse_size("2MiB") == 2 * 2**20
    assert parse_size(" 500 kB ") == 500_000 and parse_size("1000") == 1000
    for bad in ("", "lots", "-1MB", "0", "1TB", "nanMB"):
        with pytest.raises(ValueError):
            parse_size(bad)
    assert is_loopback("127.0.0.1") and is_loopback("::1") and is_loopback("localhost")
    assert not is_loopback("0.0.0.0") and not is_loopback("192.168.1.2")
    assert allowed_hosts_for("127.0.0.1") != ("*",) and allowed_hosts_for("0.0.0.0") == ("*",)


def test_serve_command_checks_input_and_warns_off_the_loopback(motion_library, monkeypatch):
    from quatmotion.cli import app as cli
    from quatmotion.server import listen

    runner = CliRunner()
    lonely = runner.invoke(cli, ["serve", "--poses", str(motion_library["poses"])])
    assert lonely.exit_code == 2 and "--poses needs --library or --index" in lonely.output
    missing = runner.invoke(cli, ["serve", "--library", "/nonexistent/lib.qmz"])
    assert missing.exit_code == 2 and "no such file" in missing.output
    bad_size = runner.invoke(
        cli, ["serve", "--library", str(motion_library["library"]), "--max-upload", "lots"]
    )
    assert bad_size.exit_code == 2 and "not a size" in bad_size.output
    bad_port = runner.invoke(
        cli, ["serve", "--library", str(motion_library["library"]), "--port", "65536"]
    )
    assert bad_port.exit_code == 2
    assert bad_port.output.strip() == "error: --port must be from 0 to 65535, got 65536"
    started: dict[str, object] = {}

    def serve_on(application, sock):
        started.update(app=application, address=sock.getsockname())
        sock.close()

    monkeypatch.setattr(listen, "serve_on", serve_on)
    local = runner.invoke(
        cli, ["serve", "--library", str(motion_library["library"]), "--port", "0"]
    )
    assert local.exit_code == 0, local.output
    assert started["address"][0] == "127.0.0.1"
    assert "warning" not in local.output and "6 clips" in local.output
    wide = runner.invoke(
        cli,
        ["serve", "--library", str(motion_library["library"]), "--host", "0.0.0.0", "--port", "0"],
    )
    assert wide.exit_code == 0 and "warning: --host 0.0.0.0" in wide.output


def test_clips_of_one_stem_in_two_folders_stay_two_rows_joined_on_their_content(tmp_path):
    """Two ``take_001`` in s1/ and s2/ and a third clip, in a library, an index and a pose
    index: three rows, named apart by their relative paths, each joined across the three
    files (labels, pose search, compare with its own original)."""
    import dataclasses

    from quatmotion.parallel import Runner
    from quatmotion.pose.data import PoseClip
    from quatmotion.pose.library import PoseLibrary, PoseSettings
    from quatmotion.retrieval import ClipIndex, IndexSettings

    files = {
        "s1/take_001": ("walk", 1),
        "s2/take_001": ("squat", 2),
        "s1/kick_0": ("kick", 0),
    }
    paths = {}
    for name, (kind, seed) in files.items():
        path = tmp_path / "clips" / f"{name}.bvh"
        path.parent.mkdir(parents=True, exist_ok=True)
        write_motion(generate_clip(kind, seed, n_frames=90), path)
        paths[name] = path
    labels = {str(p): files[n][0] for n, p in paths.items()}
    report = ClipIndex.build(
        [tmp_path / "clips"], tmp_path / "c.qidx", IndexSettings(kinds=("motion",)),
        labels=labels, runner=Runner.inline(),
    )  # fmt: skip
    assert len(report.added) == 3 and not report.failures, report
    display = {"s1/take_001": "s1/take_001", "s2/take_001": "s2/take_001", "s1/kick_0": "kick_0"}
    motions = [dataclasses.replace(read_motion(p), name=display[n]) for n, p in paths.items()]
    codec.Archive.build(motions, tmp_path / "c.qmz", codec.CompressSettings(max_error=1.0))
    prepared = [
        PoseClip.from_motion(read_motion(p), fps=30, height=170, name=str(p))
        for p in paths.values()
    ]
    settings = PoseSettings(n_pairs=50, n_unlabeled=200)
    PoseLibrary.build_in_memory(prepared, settings).save(tmp_path / "p.idx")

    for served in (
        create_app(tmp_path / "c.qmz", tmp_path / "c.qidx", tmp_path / "p.idx"),
        create_app(index=tmp_path / "c.qidx", poses=tmp_path / "p.idx"),
    ):
        with TestClient(served, base_url=BASE) as client:
            rows = client.get("/api/clips").json()["clips"]
            assert sorted(r["name"] for r in rows) == ["kick_0", "s1/take_001", "s2/take_001"]
            assert all(r["in_index"] and r["in_poses"] for r in rows)
            by_name = {r["name"]: r for r in rows}
            assert by_name["s1/take_001"]["label"] == "walk"
            assert by_name["s2/take_001"]["label"] == "squat"
            payloads = []
            for name in ("s1/take_001", "s2/take_001"):
                clip_id = by_name[name]["id"]
                payloads.append(client.get(f"/api/clips/{clip_id}/frames").json())
                hits = client.get("/api/poses", params={"clip": clip_id, "frame": 10}).json()
                assert hits["results"][0]["id"] == clip_id  # the pose clip is this clip's own
                if rows[0]["in_library"]:
                    compare = client.get(f"/api/clips/{clip_id}/compare")
                    assert compare.status_code == 200, compare.text
            assert payloads[0] != payloads[1]  # each row plays its own clip
            served.state.catalogue.close()


def test_clip_key_is_the_content_hash_whatever_names_the_clip(tmp_path):
    path = tmp_path / "a" / "take_001.bvh"
    path.parent.mkdir()
    write_motion(generate_clip("walk", 4, n_frames=30), path)
    from quatmotion.collection import content_hash

    sha = content_hash(path)
    assert clips_module.clip_key(path) == sha == clips_module.clip_key(str(path))
    assert clips_module.clip_key(type("Ref", (), {"sha256": "abc"})()) == "abc"
    assert clips_module.clip_key("take_001", {"take_001": sha}) == sha
    assert clips_module.clip_key("take_001") is None
    assert clips_module.clip_key(tmp_path / "missing.bvh") is None


def test_the_names_server_app_held_before_its_split_warn_and_still_work():
    from quatmotion.server import app as app_module
    from quatmotion.server import dependencies, middleware

    with pytest.warns(DeprecationWarning, match=r"server\.app\.parse_size moved to .*0\.6\.0"):
        assert app_module.parse_size is dependencies.parse_size
    with pytest.warns(DeprecationWarning, match="server.middleware.CSRF_HEADER"):
        assert app_module.CSRF_HEADER == middleware.CSRF_HEADER == CSRF_HEADER
    with pytest.raises(AttributeError, match="no attribute 'nothing'"):
        app_module.nothing  # noqa: B018
