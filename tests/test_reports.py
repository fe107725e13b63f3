"""The sweep report, its figures and the one-run report.

A synthetic sweep results folder is built from tiny real renders (32x18),
laid out as the sweep engine writes it; the sweep module itself is not used.
"""

from __future__ import annotations

import base64
import dataclasses
import json
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from matplotlib import colormaps
from matplotlib.figure import Figure

from pipeline_sim import load_arch, load_scene, render_scene
from pipeline_sim.accuracy import error_map
from pipeline_sim.errors import UserError
from pipeline_sim.output_folder import MARKER
from pipeline_sim.workload import WorkloadResult
from reports import figures as F
from reports.run_report import headline, html_report, markdown_report, summary_text, unit_table
from reports.sweep_report import build_report, load_sweep, representative_point, select_images

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
OPS = ("add", "mul", "madd", "rcp", "compare")


# ---------------------------------------------------------------------------
# fixtures


@pytest.fixture(scope="module")
def scene(root):
    s = load_scene(root / "workloads/scenes/default.toml")
    return s.replace(image=dataclasses.replace(s.image, width=32, height=18, spp=2))


@pytest.fixture(scope="module")
def tiny_result(scene):
    return render_scene(scene, load_arch())


def _write_point(d: Path, pid: str, result, reference) -> dict:
    d.mkdir(parents=True)
    np.save(d / "image.npy", result.image)
    emap = error_map(result.image, reference)
    np.save(d / "error_map.npy", emap)
    (d / "image.png").write_bytes(b"")  # not read by the report
    result.counters.to_csv(d / "counters.csv", index=False)
    result.timing.units.to_csv(d / "timing.csv", index=False)
    result.timing.queues.to_csv(d / "queues.csv", index=False)
    trace = {"units": {u: [list(s) for s in segs] for u, segs in result.timing.traces.items()},
             "queues": {c: [list(s) for s in ser] for c, ser in result.timing.queue_series.items()},
             "frame_cycles": result.timing.frame_cycles}
    (d / "trace.json").write_text(json.dumps(trace))
    (d / "run.json").write_text(json.dumps({"id": pid}))
    hd = headline(result)
    c = result.counters
    diff = result.image[..., :3].astype(float) - reference[..., :3].astype(float)
    rmse = float(np.sqrt(np.mean(diff ** 2)))
    t = result.timing.units
    return {"frame_cycles": hd["frame_cycles"], "wall_time_s": hd["wall_time_s"],
            "ops_total": int(c[c.counter.isin(OPS)].value.sum()), "samples_tested": hd["samples_tested"],
            "samples_covered": hd["samples_covered"], "ste": hd["ste"], "shader_executions": hd["shader_executions"],
            "shader_executions_per_pixel": hd["shader_executions_per_pixel"],
            "depth_bytes_per_pixel": hd["depth_bytes_per_pixel"],
            "bottleneck_unit": str(t.loc[t.busy.idxmax(), "unit"]), "rmse": rmse,
            "psnr": float(-20 * np.log10(rmse)) if rmse > 0 else float("inf"), "ssim": float("nan"),
            "flip": float(emap.mean())}


@pytest.fixture(scope="module")
def sweep_dir(tmp_path_factory, scene, root):
    """A results folder: spp {1, 2, 4} x tile {4, 8} from real renders, plus one failed point."""
    d = tmp_path_factory.mktemp("sweep")
    arch = load_arch()
    reference = render_scene(scene.replace(image=dataclasses.replace(scene.image, spp=16)), arch).image
    (d / "reference").mkdir()
    np.save(d / "reference" / "0123abcd.npy", reference)
    points, rows, results = [], [], []
    k = 0
    for spp in (1, 2, 4):
        for tile in (4, 8):
            pid = f"p{k:02d}{spp}{tile}ab"
            k += 1
            params = {"image.spp": spp, "tile_traverser.tile_size": tile}
            points.append({"id": pid, "params": params})
            r = render_scene(scene.replace(image=dataclasses.replace(scene.image, spp=spp)),
                             load_arch(overrides=[f"tile_traverser.tile_size={tile}"]))
            row = {"point_id": pid, "status": "ok", "error": "", **params,
                   **_write_point(d / "points" / pid, pid, r, reference)}
            rows.append(row)
            for rec in r.counters.itertuples():
                results.append({"point_id": pid, "kind": "counter", "unit": rec.unit, "name": rec.counter,
                                "value": rec.value})
            results.append({"point_id": pid, "kind": "summary", "unit": "", "name": "frame_cycles",
                            "value": row["frame_cycles"]})
    bad = "deadbeef"
    points.append({"id": bad, "params": {"image.spp": 8, "tile_traverser.tile_size": 3}})
    rows.append({"point_id": bad, "status": "error", "image.spp": 8, "tile_traverser.tile_size": 3,
                 "error": "--set: [tile_traverser]: tile_size = 3 must be a power of two"})
    cols = ["point_id", "status", "error", "image.spp", "tile_traverser.tile_size", "frame_cycles", "wall_time_s",
            "ops_total", "samples_tested", "samples_covered", "ste", "shader_executions",
            "shader_executions_per_pixel", "depth_bytes_per_pixel", "bottleneck_unit", "rmse", "psnr", "ssim", "flip"]
    pd.DataFrame(rows).reindex(columns=cols).to_csv(d / "points.csv", index=False)
    pd.DataFrame(results).to_csv(d / "results.csv", index=False)
    spec = {"scene": str(root / "workloads/scenes/default.toml"), "arch": arch.to_dict(),
            "fixed_set": ["zcull.time_slices=4"], "metrics": ["rmse", "flip"],
            "reference": {"kind": "pipeline", "spp": 16, "seed": 0}, "points": points}
    (d / "sweep.json").write_text(json.dumps(spec))
    return d


# ---------------------------------------------------------------------------
# HTML checking


VOID = {"area", "base", "br", "col", "embed", "hr", "img", "input", "link", "meta", "source", "track", "wbr"}


class _Checker(HTMLParser):
    def __init__(self):
        super().__init__(convert_charrefs=True)
        self.stack: list[str] = []
        self.errors: list[str] = []
        self.imgs: list[dict] = []
        self.refs: list[str] = []
        self.tags: list[str] = []
        self.text: list[str] = []

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        self.tags.append(tag)
        if tag == "img":
            self.imgs.append(a)
        for k in ("src", "href"):
            if k in a:
                self.refs.append(a[k] or "")
        if tag not in VOID:
            self.stack.append(tag)

    def handle_startendtag(self, tag, attrs):
        self.handle_starttag(tag, attrs)
        if tag not in VOID:
            self.stack.pop()

    def handle_endtag(self, tag):
        if tag in VOID:
            return
        if not self.stack or self.stack[-1] != tag:
            self.errors.append(f"unexpected </{tag}> (open: {self.stack[-3:]})")
            if tag in self.stack:
                while self.stack and self.stack.pop() != tag:
                    pass
        else:
            self.stack.pop()

    def handle_data(self, data):
        self.text.append(data)


def _check_html(text: str) -> _Checker:
    assert text.lstrip().lower().startswith("<!doctype html>")
    p = _Checker()
    p.feed(text)
    p.close()
    assert not p.errors, p.errors
    assert not p.stack, f"unclosed tags {p.stack}"
    for t in ("html", "head", "body", "title"):
        assert t in p.tags
    for ref in p.refs:
        assert not ref.lower().startswith(("http:", "https:", "//")), ref
    for img in p.imgs:
        src = img.get("src", "")
        assert src.startswith("data:image/png;base64,"), src[:40]
        data = base64.b64decode(src.split(",", 1)[1], validate=True)
        assert data.startswith(PNG_SIGNATURE)
        assert img.get("alt")
    assert "http://" not in text and "https://" not in text
    assert "<script" not in text.lower() and "<link" not in text.lower()
    return p


# ---------------------------------------------------------------------------
# the sweep report


def test_sweep_report_structure(sweep_dir, tmp_path):
    out = tmp_path / "out" / "report.html"
    path = build_report(sweep_dir, out)
    assert path == out and out.is_file()
    text = out.read_text()
    p = _check_html(text)
    slugs = [img.get("data-figure") for img in p.imgs]
    assert slugs[0] == "accuracy_cost", slugs
    for s in ("cycle_breakdown", "params_metrics", "images", "pipeline", "timeline"):
        assert s in slugs
    body = " ".join(p.text)
    # failed points and their errors
    assert "deadbeef" in body and "must be a power of two" in body
    # counters table
    for col in ("STE (covered / tested)", "shader execs / px", "depth bytes / px", "bottleneck"):
        assert col in body
    # the Markdown twin and its PNGs
    md = out.with_suffix(".md")
    assert md.is_file()
    mtext = md.read_text()
    files = out.parent / "report_files"
    links = [line.split("](", 1)[1].rstrip(")") for line in mtext.splitlines() if line.startswith("![")]
    assert len(links) == len(p.imgs) and links[0].endswith("accuracy_cost.png")
    for link in links:
        assert link.startswith("report_files/")
        assert (out.parent / link).read_bytes().startswith(PNG_SIGNATURE)
    marker = json.loads((files / MARKER).read_text())
    assert sorted(f.name for f in files.iterdir() if f.name != MARKER) == sorted(Path(link).name for link in links)
    assert sorted(marker["files"]) == sorted(Path(link).name for link in links)
    assert "deadbeef" in mtext
    # no temporary files are left behind
    assert sorted(x.name for x in out.parent.iterdir()) == ["report.html", "report.md", "report_files"]
    # writing the report again replaces the figure folder whole: a figure that is gone goes with it
    (files / "old_figure.png").write_bytes(PNG_SIGNATURE)
    st = (files / "old_figure.png").stat()
    marker["files"]["old_figure.png"] = [st.st_size, st.st_mtime_ns]
    (files / MARKER).write_text(json.dumps(marker))
    build_report(sweep_dir, out)
    assert not (files / "old_figure.png").exists()
    assert sorted(x.name for x in out.parent.iterdir()) == ["report.html", "report.md", "report_files"]


def test_sweep_report_never_replaces_what_it_did_not_write(sweep_dir, tmp_path):
    """An existing report.html, report.md or report_files/ that pipeline-sim did not write is refused."""
    for name, content in (("r.html", "<html>my notes</html>"), ("r.md", "# My project\n## pipeline-sim sweep: notes\n")):
        path = tmp_path / name
        path.write_text(content)
        with pytest.raises(UserError, match="not written by pipeline-sim"):
            build_report(sweep_dir, tmp_path / "r.html")
        assert path.read_text() == content
        assert not (tmp_path / "r_files").exists()
        path.unlink()
    (tmp_path / "r_files").mkdir()
    (tmp_path / "r_files" / "keep.txt").write_text("mine")
    with pytest.raises(UserError, match="not written by pipeline-sim"):
        build_report(sweep_dir, tmp_path / "r.html")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r_files"]
    # --force writes the report, and leaves the foreign file in the figure folder alone
    build_report(sweep_dir, tmp_path / "r.html", force=True)
    assert (tmp_path / "r_files" / "keep.txt").read_text() == "mine"
    assert len(list((tmp_path / "r_files").glob("*.png"))) >= 5


def test_sweep_report_selection_and_representative(sweep_dir):
    sw = load_sweep(sweep_dir)
    assert sw.swept == ["image.spp", "tile_traverser.tile_size"]
    assert len(sw.ok) == 6 and list(sw.failed.point_id) == ["deadbeef"]
    ids = select_images(sw, "flip", "frame_cycles", max_images=3)
    # many points: the best of each spp
    ok = sw.ok.set_index("point_id")
    assert sorted(ok.loc[ids, "image.spp"]) == [1, 2, 4]
    for pid in ids:
        spp = ok.loc[pid, "image.spp"]
        assert ok.loc[pid, "flip"] == ok[ok["image.spp"] == spp]["flip"].min()
    # the default tile size (4) is in the arch: the representative point has it
    pid, why = representative_point(sw, "frame_cycles")
    assert ok.loc[pid, "tile_traverser.tile_size"] == 4 and "default" in why


def test_not_a_sweep_folder(tmp_path, sweep_dir):
    with pytest.raises(UserError, match="not a sweep results folder") as e:
        build_report(tmp_path, tmp_path / "r.html")
    assert "\n" not in str(e.value)
    with pytest.raises(UserError, match="not a sweep results folder"):
        build_report(tmp_path / "missing", tmp_path / "r.html")
    (tmp_path / "sweep.json").write_text("{not json")
    with pytest.raises(UserError, match="not valid JSON"):
        build_report(tmp_path, tmp_path / "r.html")
    with pytest.raises(UserError, match="metric") as e:
        build_report(sweep_dir, tmp_path / "r.html", metric="flipp")
    assert "did you mean 'flip'" in str(e.value)
    assert not (tmp_path / "r.html").exists()


# ---------------------------------------------------------------------------
# figures


def _brute_front(c, e):
    n = len(c)
    out = np.zeros(n, bool)
    for i in range(n):
        if not (np.isfinite(c[i]) and np.isfinite(e[i])):
            continue
        out[i] = not any(np.isfinite(c[j]) and np.isfinite(e[j]) and c[j] <= c[i] and e[j] <= e[i]
                         and (c[j] < c[i] or e[j] < e[i]) for j in range(n))
    return out


def test_pareto_front_matches_brute_force():
    rng = np.random.default_rng(1)
    for trial in range(300):
        n = int(rng.integers(0, 30))
        if trial % 3 == 0:  # ties and duplicates
            c = rng.integers(0, 5, n).astype(float)
            e = rng.integers(0, 5, n).astype(float)
        else:
            c = rng.lognormal(size=n)
            e = rng.random(n)
        if trial % 5 == 0 and n:
            c[rng.integers(0, n)] = np.nan
            e[rng.integers(0, n)] = np.inf
        np.testing.assert_array_equal(F.pareto_front(c, e), _brute_front(c, e))


def test_utilization_colors_follow_the_colormap():
    util = {"triangle_setup": 0.2, "tile_traverser": 0.1, "tile_test": 0.05, "zcull": 0.0, "sample_tester": 0.62,
            "shading": 0.3, "rop": 0.15}
    colors = F.utilization_colors(util)
    cm = colormaps[F.UTIL_CMAP]
    assert np.allclose(colors["sample_tester"], cm(1.0))
    assert np.allclose(colors["zcull"], cm(0.0))
    assert np.allclose(colors["shading"], cm(0.3 / 0.62))
    # a higher utilization never gets a lower position in the colormap
    norm = F.utilization_norm(util)
    order = sorted(util, key=util.get)
    assert [norm(util[u]) for u in order] == sorted(norm(util[u]) for u in order)


def test_pipeline_diagram_colors_units_by_utilization(tiny_result):
    t = tiny_result.timing
    fig = F.pipeline_diagram(t.units, t.queues)
    colors = F.utilization_colors(dict(zip(t.units.unit, t.units.utilization)))
    faces = [tuple(p.get_facecolor()) for p in fig.axes[0].patches]
    busiest = t.units.loc[t.units.utilization.idxmax(), "unit"]
    assert any(np.allclose(f, colors[busiest]) for f in faces)
    assert np.allclose(colors[busiest], colormaps[F.UTIL_CMAP](1.0))
    assert F.figure_png(fig).startswith(PNG_SIGNATURE)


def test_queue_labels_count_records_against_the_capacity():
    """Queue labels give mean, peak and capacity in one unit, the capacity's: a
    queue whose peak reached its capacity is red; an old queues.csv (occupancy
    in batches, depth in default-size batches) gets no capacity to compare."""
    units = pd.DataFrame({"unit": ["triangle_setup", "tile_traverser"], "busy": [5.0, 9.0], "starved": [5.0, 1.0],
                          "blocked": [0.0, 0.0], "batches": [2, 2], "utilization": [0.5, 0.9]})
    queues = pd.DataFrame({"channel": ["input", "triangle_setup->tile_traverser"], "capacity_records": [256, 2048],
                           "mean_records": [126.07, 999.6], "peak_records": [256, 1500]})
    assert F.queue_columns(queues) == ("records", "capacity_records", "mean_records", "peak_records")
    assert F.queue_capacities(queues) == {"input": 256, "triangle_setup->tile_traverser": 2048}
    texts = {t.get_text(): t.get_color() for t in F.pipeline_diagram(units, queues).axes[0].texts}
    assert texts["input\nmean 126\npeak 256/256"] == "#b00020"  # full
    assert texts["mean 1k\npeak 1.5k/2.05k"] == "black"
    legacy = pd.DataFrame({"channel": ["input"], "depth": [4], "mean_occupancy": [1.5], "peak_occupancy": [4]})
    assert F.queue_columns(legacy) == ("batches", None, "mean_occupancy", "peak_occupancy")
    assert F.queue_capacities(legacy) == {}
    texts = {t.get_text(): t.get_color() for t in F.pipeline_diagram(units, legacy).axes[0].texts}
    assert texts["input\nmean 1.5\npeak 4"] == "black"


def test_timeline_bins_long_traces(tiny_result):
    t = tiny_result.timing
    # binning keeps the time in each state exactly
    for unit, segs in t.traces.items():
        edges, frac = F.bin_trace(segs, t.frame_cycles, 50)
        w = np.diff(edges)
        for state in F.STATES:
            total = sum(b - a for a, b, s in segs if s == state)
            assert np.isclose((frac[state] * w).sum(), total, rtol=1e-9, atol=1e-6)
    for ch, ser in t.queue_series.items():
        edges, mean, mx = F.bin_series(ser, t.frame_cycles, 40)
        assert np.isclose((mean * np.diff(edges)).sum() / t.frame_cycles,
                          t.queues.set_index("channel").loc[ch, "mean_records"], rtol=1e-6, atol=1e-9)
        assert mx.max() == max(level for _, level in ser)
        assert np.all(mean <= mx + 1e-9)
    fig = F.timeline(t.traces, t.queue_series, t.frame_cycles, max_segments=5, bins=100)
    assert isinstance(fig, Figure) and "binned" in fig.get_suptitle()


def test_accuracy_cost_and_params_figures():
    rng = np.random.default_rng(0)
    df = pd.DataFrame({"image.spp": np.repeat([1, 2, 4, 8], 3), "tile_traverser.tile_size": [4, 8, 16] * 4})
    df["frame_cycles"] = df["image.spp"] * 1000.0 * (1 + rng.random(len(df)))
    df["ops_total"] = df["frame_cycles"] * 30
    df["wall_time_s"] = 0.01 * df["image.spp"]
    df["flip"] = 0.2 / np.sqrt(df["image.spp"]) + 0.01 * rng.random(len(df))
    fig = F.accuracy_cost(df, metric="flip", label_params=["tile_traverser.tile_size"])
    assert len(fig.axes) == 3 and fig.axes[0].get_xscale() == "log"
    fig = F.params_vs_metrics(df, ["image.spp", "tile_traverser.tile_size"], ["flip", "frame_cycles"])
    assert len(fig.axes) >= 4
    for f in (fig, F.cycle_breakdown(pd.DataFrame(columns=["unit", "busy", "starved", "blocked"]))):
        assert F.figure_png(f).startswith(PNG_SIGNATURE)


def test_png_data_uri_never_contains_http():
    png = F.figure_png(F.image_grid([("a", np.zeros((4, 6, 4), np.float32), np.zeros((4, 6), np.float32))]))
    uri = F.png_data_uri(png)
    assert uri.startswith("data:image/png;base64,") and "http" not in uri.lower()
    # force the padding path: bytes that encode to "http" right after the header (33 bytes, 3-aligned)
    spoiled = png[:33] + base64.b64decode("http") + png[33:]
    assert "http" in base64.b64encode(spoiled).decode()
    uri = F.png_data_uri(spoiled)
    assert "http" not in uri.lower()
    assert base64.b64decode(uri.split(",", 1)[1]).startswith(PNG_SIGNATURE)


# ---------------------------------------------------------------------------
# the one-run report


def test_run_report_has_the_three_figures(tiny_result, tmp_path):
    info = {"kind": "scene", "workload": {"file": "workloads/scenes/default.toml"}}
    run = WorkloadResult({"main": tiny_result})
    text = html_report(run, info)
    p = _check_html(text)
    slugs = [img.get("data-figure") for img in p.imgs]
    assert {"cycle_breakdown", "pipeline", "timeline"} <= set(slugs)
    assert "http" not in text.split("<body>")[1]
    # markdown: text only without files_dir, PNGs with it
    md = markdown_report(run, info)
    assert "report_files" not in md and "frame cycles" in md and "![image](passes/main/image.png)" in md
    files = tmp_path / "report_files"
    md = markdown_report(run, info, files_dir=files)
    links = [line.split("](", 1)[1].rstrip(")") for line in md.splitlines() if line.startswith("![")]
    pngs = [link for link in links if link.startswith("report_files/")]
    assert len(pngs) == 3
    for link in pngs:
        assert (tmp_path / link).read_bytes().startswith(PNG_SIGNATURE)
    # the other entry points keep working
    assert "STE" in summary_text(run, title="t")
    assert len(unit_table(tiny_result)) == 7


def test_sweep_report_reads_the_nested_layout(sweep_dir, tmp_path):
    """sweep.json as the engine nests it: settings under "spec", points with "point_id", no resolved arch."""
    import shutil

    d = tmp_path / "nested"
    shutil.copytree(sweep_dir, d)
    flat = json.loads((d / "sweep.json").read_text())
    nested = {"spec": {"scene": flat["scene"], "arch": None, "set": flat["fixed_set"], "metrics": flat["metrics"],
                       "reference": flat["reference"]},
              "points": [{"point_id": p["id"], "params": p["params"]} for p in flat["points"]]}
    (d / "sweep.json").write_text(json.dumps(nested))
    sw = load_sweep(d)
    assert sw.spec["scene"] == flat["scene"] and sw.spec["fixed_set"] == flat["fixed_set"]
    assert sw.spec["arch"]["tile_traverser"]["tile_size"] == 4  # the default, loaded
    pid, _ = representative_point(sw, "frame_cycles")
    assert sw.ok.set_index("point_id").loc[pid, "tile_traverser.tile_size"] == 4
    (tmp_path / "r").mkdir()
    (tmp_path / "r" / "sweep.html").write_text("old")   # a file the user wrote: replaced only when forced
    out = build_report(d, tmp_path / "r" / "sweep.html", metric="psnr", cost="ops_total", force=True)
    p = _check_html(out.read_text())
    assert p.imgs[0]["data-figure"] == "accuracy_cost"
    assert (tmp_path / "r" / "sweep.md").is_file() and (tmp_path / "r" / "sweep_files").is_dir()
    assert sorted(x.name for x in (tmp_path / "r").iterdir()) == ["sweep.html", "sweep.md", "sweep_files"]


def test_a_run_of_many_passes_draws_the_figures_of_its_costliest_passes(tiny_result):
    import dataclasses

    from reports.run_report import MAX_PASS_FIGURES

    def scaled(r, k):  # the same pass with k times the frame cycles
        return dataclasses.replace(r, timing=dataclasses.replace(r.timing, frame_cycles=r.timing.frame_cycles * k))

    weights = [3, 9, 1, 7, 5, 2]  # six passes; the costliest four by frame cycles: p1, p3, p4, p0
    run = WorkloadResult({f"p{i}": scaled(tiny_result, k) for i, k in enumerate(weights)})
    text = html_report(run, {"kind": "x", "workload": {"file": "x.toml"}})
    slugs = [img.get("data-figure") for img in _check_html(text).imgs]
    drawn = sorted({s.split("_", 1)[0] for s in slugs if s})
    assert MAX_PASS_FIGURES == 4 and drawn == ["p0", "p1", "p3", "p4"]
    assert "Figures of the 4 passes with the most frame cycles, of 6" in text
