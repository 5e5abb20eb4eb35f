"""``quatmotion report`` and the benchmark figures, on small results shaped like the real ones.

The figures come from the benchmarks' own figure code (``_figure``/``_figures``) fed with
these small results, so the test also checks that every figure is readable: a title and a
label on both axes.
"""

from __future__ import annotations

import base64
import json
import re
from pathlib import Path

import pytest
from typer.testing import CliRunner

from quatmotion.bench import _pose_figures, provenance
from quatmotion.bench import io as io_bench
from quatmotion.bench import pose as pose_bench
from quatmotion.bench import qssd as qssd_bench
from quatmotion.cli import app
from quatmotion.errors import FormatError
from quatmotion.viz import report, save_figure


def _io_result() -> dict:
    def parse(n):
        return {
            "files": n, "megabytes": 1.5 * n, "frames": 900 * n, "seconds": 0.2,
            "mb_per_s": 31.25, "cpu_seconds": 0.1, "mb_per_s_cpu": 62.5, "frames_per_s": 4500.0,
            "per_file_mb_per_s": {f"clip{i}": 20.0 + 3 * i for i in range(n)},
        }  # fmt: skip

    return {
        "parse": {"amc": parse(4), "bvh": parse(3)},
        "write": {
            "amc": {"files": 2, "megabytes": 1.0, "seconds": 0.1, "mb_per_s": 10.0},
            "bvh": {"files": 2, "megabytes": 0.8, "seconds": 0.1, "mb_per_s": 8.0},
        },
        "forward_kinematics": {
            "clip": "01_06.amc",
            "joints": 31,
            "sites": 7,
            "frames": 102660,
            "joints_frames_per_s": 1.2e6,
            "joints_and_sites_frames_per_s": 1.1e6,
        },  # fmt: skip
        "reference_max_error_cm": 2e-13,
    }


def _qssd_result() -> dict:
    curve = {"error_curve_deg": [3.0, 1.0, 0.5], "final_error_deg": 0.5}
    restored = {"restoration_quaternion": 1.0, "restoration_log": 0.95}
    return {
        "table1": {
            "K": 200,
            "L": 15,
            "iterations": 5,
            "error_unit": "degrees per joint per frame",
            "paper": {
                "walking": {
                    "qssd_train": 0.003,
                    "qssd_test": 0.0053,
                    "ksvd_train": 0.0135,
                    "ksvd_test": 0.0271,
                }
            },
            "cmu_mixed": {
                "clips": 14,
                "frames": 2468,
                "qssd_train_paper": 1.4,
                "qssd_test_paper": 1.7,
                "ksvd_train_paper": 1.5,
                "ksvd_test_paper": 1.8,
            },
        },  # fmt: skip
        "table2": {
            "iterations_timed": 2,
            "note": "wall seconds",
            "rows": [
                {
                    "N": 1000,
                    "n": 50,
                    "K": 5,
                    "L": 5,
                    "qssd_seconds": 0.9,
                    "ksvd_seconds": 0.4,
                    "paper_qssd_seconds": 1.8,
                    "paper_ksvd_seconds": 0.8,
                    "qssd_speedup_vs_paper": 2.0,
                },
                {
                    "N": 5000,
                    "n": 50,
                    "K": 10,
                    "L": 10,
                    "qssd_seconds": 3.1,
                    "ksvd_seconds": 1.0,
                    "paper_qssd_seconds": 13.3,
                    "paper_ksvd_seconds": 9.1,
                    "qssd_speedup_vs_paper": 4.3,
                },
            ],
        },  # fmt: skip
        "simulation": {
            "N": 500,
            "n": 20,
            "K": 20,
            "L": 5,
            "iterations": 3,
            "seeds": [0, 1],
            "noise": {"noiseless": {**curve, **restored}, "40dB": {**curve, **restored}},
            "ablation_noiseless": {"as_printed": {**curve, **restored}},
            "weight_scale_sweep": {
                "iterations": 3,
                "seeds": [0],
                "scales": [0.5, 1.0],
                "improved": {"restoration_quaternion": [1.0, 1.0], "restoration_log": [1, 1]},
                "as_printed": {"restoration_quaternion": [0.9, 1.0], "restoration_log": [0.8, 1]},
            },
        },  # fmt: skip
    }


def _pose_result() -> dict:
    methods = {"GPD+RDSR": 0.91, "GPD+L2": 0.85, "JO+L2": 0.8, "JOD": 0.7}
    return {
        "datasets": {
            "hdm05": {
                "transition": {
                    "test": {"pairs": 300, "clips": 5},
                    "baseline_eq35_precision": 0.75,
                    "methods": {m: {"precision": p, "fit_seconds": 1.0}
                                for m, p in methods.items()},
                    "rank_sweep": {"10": {"precision": 0.8}, "50": {"precision": 0.9}},
                    "unlabeled_sweep": {"GPD+RDSR": {"0": {"precision": 0.8},
                                                     "1000": {"precision": 0.85}}},
                },
                "retrieval": {
                    "scopes": [5, 10], "chance": 0.05, "oracle": [0.6, 0.33], "test_poses": 40,
                    "methods": {m: {"precision_at": {"5": p / 2, "10": p / 3}}
                                for m, p in methods.items()},
                },
            }
        },
        "ann": {"n_items": 1000, "meets_target": True,
                "chosen": {"ef_search": 32, "recall_at_10": 0.99, "median_ms": 0.06,
                           "p95_ms": 0.09}},
    }  # fmt: skip


@pytest.fixture(scope="module")
def benchmark_runs(tmp_path_factory) -> tuple[list[Path], list[tuple[str, list]]]:
    """The three benchmarks' JSON (with provenance) and figures, as their run() writes them,
    and what every saved figure showed: (file name, [(title, x label, y label) per axes])."""
    seen: list[tuple[str, list[tuple[str, str, str]]]] = []

    def record(figure, path, **kwargs):
        axes = [
            (ax.get_title(), ax.get_xlabel(), ax.get_ylabel())
            for ax in figure.axes
            if ax.get_label() != "<colorbar>"
        ]
        seen.append((Path(path).name, axes))
        return save_figure(figure, path, **kwargs)

    folder = tmp_path_factory.mktemp("bench")
    paths = []
    with pytest.MonkeyPatch.context() as patch:
        for module in (io_bench, qssd_bench, _pose_figures):
            patch.setattr(module, "save_figure", record)
        for name, result in (
            ("io", _io_result()),
            ("qssd", _qssd_result()),
            ("pose", _pose_result()),
        ):
            out = folder / f"{name}.json"
            result = {**provenance(name, out, True, 0), **result}
            if name == "io":
                result["figures"] = [io_bench._figure(out, result)]
            else:
                module = qssd_bench if name == "qssd" else pose_bench
                result["figures"] = module._figures(out, result)
            bench = {"io": io_bench, "qssd": qssd_bench, "pose": pose_bench}[name]
            result["tables"] = bench.summary_tables(result)  # as run() publishes them
            out.write_text(json.dumps(result), encoding="utf-8")
            paths.append(out)
    return paths, seen


def test_every_benchmark_figure_has_a_title_and_labelled_axes(benchmark_runs):
    _, seen = benchmark_runs
    assert len(seen) == 1 + 3 + 5  # io 1, qssd 3, pose 5 (Figs. 4-8 of one dataset)
    for name, axes in seen:
        for title, xlabel, ylabel in axes:
            assert title and xlabel and ylabel, f"{name}: {title!r}, {xlabel!r}, {ylabel!r}"
            assert "quick run" in title, name  # a quick run says so


def test_report_gathers_tables_figures_and_provenance(benchmark_runs, tmp_path):
    results, _ = benchmark_runs
    out = tmp_path / "report.html"
    runner = CliRunner()
    done = runner.invoke(app, ["report", *map(str, results), "-o", str(out)])
    assert done.exit_code == 0, done.output
    page = out.read_text(encoding="utf-8")
    for title in (
        "Throughput (one thread)",
        "Forward kinematics",
        "Table 1: reconstruction error",
        "Table 2: seconds per iteration",
        "Simulation (Fig. 1)",
        "hdm05: transition precision (Eq. 37), best first",
        "hdm05: pose retrieval precision@s",
        "Approximate pose index (HNSW)",
    ):
        assert f"<h4>{title}" in page, title
    for path in results:
        data = json.loads(path.read_text(encoding="utf-8"))
        assert data["command"] in page  # quatmotion bench NAME --out ... --quick --seed 0
        for figure in data["figures"]:
            encoded = base64.b64encode((path.parent / figure).read_bytes()).decode()
            assert f"data:image/png;base64,{encoded}" in page, figure
    assert page.count('<table class="provenance">') == 3 and "not recorded" not in page
    # Standalone: nothing to fetch.
    assert not re.search(r"\b(src|href)=\"(?!data:|#)", page)


def test_an_unknown_benchmark_renders_from_its_json_alone(tmp_path):
    rows = [{"clip": f"c{i}", "ratio": 10.0 + i, "arms_cm": 0.1 * i} for i in range(30)]
    result = {
        "benchmark": "compression",
        "methods": {"qssd": {"ratio": 31.5, "arms_cm": 0.42}, "wavelet": {"ratio": 12.0}},
        "per_clip": rows,
        "total_seconds": 3.5,
        "curve": list(range(100)),
    }
    path = tmp_path / "compression.json"
    path.write_text(json.dumps(result), encoding="utf-8")
    page = report.render_report([report.load_result(path)])
    assert "<h4>methods</h4>" in page and "31.5" in page and "wavelet" in page
    assert "<summary>per_clip (30 rows)</summary>" in page  # long tables start folded
    assert "100 values: min 0, median 50, max 99" in page
    assert page.count("not recorded") == 2  # neither command nor machine in this file


def test_a_benchmark_describes_its_headline_figures_and_the_report_reads_them(tmp_path):
    """The report knows no key of a new benchmark: it reads the figures its JSON names."""
    result = {
        "benchmark": "made_up",
        "jobs": {"codec": {"overhead": 0.083, "seconds": 4.25}},
        "headlines": [
            {"name": "codec overhead", "path": ["jobs", "codec", "overhead"], "unit": "",
             "better": "lower", "format": "percent"},
            {"name": "codec time", "path": ["jobs", "codec", "seconds"], "unit": "s",
             "better": "lower", "format": ""},
            {"name": "a figure this run lacks", "path": ["jobs", "index", "seconds"],
             "unit": "s", "better": "lower", "format": ""},
        ],
    }  # fmt: skip
    table = report.headline_table(result)
    assert table is not None
    assert table.rows == (
        ("codec overhead", "8.3%", "", "lower"),
        ("codec time", report.format_value(4.25), "s", "lower"),
        ("a figure this run lacks", "missing", "s", "lower"),
    )
    path = tmp_path / "made_up.json"
    path.write_text(json.dumps(result), encoding="utf-8")
    page = report.render_report([report.load_result(path)])
    assert "Headline figures" in page and "8.3%" in page
    bad = dict(result, headlines=[{"name": "x", "path": "jobs.codec", "better": "lower"}])
    with pytest.raises(ValueError, match=r"headlines\[0\] \(x\): path must be a list"):
        report.headline_table(bad)
    assert report.headline_table({"benchmark": "old"}) is None


def test_a_benchmark_publishes_its_summary_tables_and_a_malformed_one_is_named(tmp_path):
    """The report renders the tables a benchmark it has never seen publishes."""
    result = {
        "benchmark": "never_seen",
        "tables": [{"title": "Speed by size", "columns": ["clips", "ms"],
                    "rows": [[300, 4.7], [10000, 23.0]], "note": "one core"}],
    }  # fmt: skip
    [table] = report.published_tables(result)
    assert table.header == ("clips", "ms") and table.rows == ((300, 4.7), (10000, 23.0))
    path = tmp_path / "never_seen.json"
    path.write_text(json.dumps(result), encoding="utf-8")
    page = report.render_report([report.load_result(path)])
    assert "<h4>Speed by size" in page and "All results" in page
    bad = {"benchmark": "never_seen", "tables": [{"title": "T", "columns": ["a", "b"],
                                                  "rows": [[1]]}]}  # fmt: skip
    with pytest.raises(ValueError, match=r"tables\[0\] \(T\): rows must be lists of 2 cells"):
        report.published_tables(bad)
    path.write_text(json.dumps(bad), encoding="utf-8")
    assert "rows must be lists of 2 cells" in report.render_report([report.load_result(path)])


def test_report_names_bad_and_missing_files(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text('{"benchmark": "io",\n "parse": }', encoding="utf-8")
    with pytest.raises(FormatError, match=r"bad\.json:2: not JSON"):
        report.load_result(bad)
    listed = tmp_path / "x.json"
    listed.write_text(json.dumps({"benchmark": "x", "figures": ["gone.png"]}), encoding="utf-8")
    assert "figure gone.png not found" in report.render_report([report.load_result(listed)])
    done = CliRunner().invoke(app, ["report", str(bad), "-o", str(tmp_path / "r.html")])
    assert done.exit_code == 2 and "bad.json:2" in done.stderr
    assert not (tmp_path / "r.html").exists()
