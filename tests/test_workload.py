"""Workload kinds: the registry, the scene kind, and the two-pass example of docs/workloads.md run
as written, against independent computations (numpy over the first pass's image, the render API)."""

import dataclasses
import json
import re
import sys
import tomllib
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import workloads.apps
from pipeline_sim import workload as W
from pipeline_sim.cli import main
from pipeline_sim.config import load_arch
from pipeline_sim.errors import UserError
from pipeline_sim.render import render_scene
from pipeline_sim.scene import load_scene
from scenes import moving_sphere, scene_toml

SMALL = scene_toml(moving_sphere(), seed=2, lens_radius=0.05)


def example(root, lang: str) -> str:
    """The example's ``lang`` block of docs/workloads.md."""
    text = (root / "docs/workloads.md").read_text().split("## Example", 1)[1]
    (block,) = re.findall(rf"```{lang}\n(.*?)```", text, flags=re.S)
    return block


@pytest.fixture
def registry(monkeypatch):
    """The registry as shipped, restored after the test (a test adds application folders)."""
    monkeypatch.setattr(W, "_KINDS", dict(W._KINDS))
    monkeypatch.setattr(W, "_discovered", [False])
    monkeypatch.setattr(workloads.apps, "__path__", list(workloads.apps.__path__))


@pytest.fixture
def negative(root, tmp_path, registry, monkeypatch):
    """docs/workloads.md's example installed as an application folder found by discovery; its
    file renders a small scene. Returns the workload file."""
    apps = tmp_path / "apps"
    app = apps / "negative"
    app.mkdir(parents=True)
    (app / "__init__.py").write_text(example(root, "python"))
    (tmp_path / "small.toml").write_text(SMALL)
    toml = example(root, "text")
    assert tomllib.loads(toml)["kind"] == "negative"
    (app / "negative.toml").write_text(toml.replace("../../scenes/static.toml", "../../small.toml"))
    workloads.apps.__path__.append(str(apps))
    monkeypatch.delitem(sys.modules, "workloads.apps.negative", raising=False)
    return app / "negative.toml"


def test_a_file_without_kind_is_a_scene_and_kind_scene_is_the_same(tmp_path, registry):
    plain = tmp_path / "plain.toml"
    plain.write_text(SMALL)
    named = tmp_path / "named.toml"
    named.write_text('kind = "scene"\n' + SMALL)
    arch = load_arch()
    a, b = (W.load_workload(p, arch) for p in (plain, named))
    assert type(a) is type(b) is W.SceneWorkload
    assert a.digest == load_scene(plain).digest   # the scene reader's digest: the file's bytes
    for w in (a, b):
        w.check()
    ra, rb = a.run(), b.run()
    direct = render_scene(load_scene(plain), arch)
    assert list(ra.passes) == ["main"] and ra.total() is ra.final
    np.testing.assert_array_equal(ra.final.image, direct.image)
    np.testing.assert_array_equal(rb.final.image, direct.image)
    pd.testing.assert_frame_equal(ra.final.counters.drop(columns="timing_dependent"),
                                  direct.counters.drop(columns="timing_dependent"))


def test_unknown_kind_is_one_line_with_the_nearest_name(tmp_path, negative, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text('kind = "negativ"\n')
    assert main(["run", str(bad), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert "bad.toml: kind: unknown workload kind 'negativ' (did you mean 'negative'?)" in err
    assert "scene" in err and not (tmp_path / "o").exists()
    bad.write_text("kind = 3\n")
    with pytest.raises(UserError, match="bad.toml: kind: expected a string"):
        W.read_workload(bad)


def test_discovery_finds_the_application_folders(negative):
    assert "negative" in W.kinds() and "scene" in W.kinds()
    cls, data = W.read_workload(negative)
    assert cls.kind == "negative" and cls.__module__ == "workloads.apps.negative"
    assert data == cls.file_schema(scene="../../small.toml")   # the file validated against the kind's schema


def test_two_pass_workload_against_numpy(negative, tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["run", str(negative), "--out", str(out), "--spp", "8", "--quiet"]) == 0
    passes = out / "passes"
    assert sorted(p.name for p in passes.iterdir()) == ["negative", "scene"]
    first = np.load(passes / "scene" / "image.npy")
    second = np.load(passes / "negative" / "image.npy")
    # the first pass is the scene as the render API renders it
    scene = load_scene(tmp_path / "small.toml")
    scene = scene.replace(image=dataclasses.replace(scene.image, spp=8))
    np.testing.assert_array_equal(first, render_scene(scene, load_arch()).image)
    # the second samples it at each pixel's centre and writes its negative
    np.testing.assert_allclose(second[..., :3], 1.0 - first[..., :3], atol=1e-6)
    assert np.all(second[..., 3] == 1.0)
    results = json.loads((out / "results.json").read_text())
    np.testing.assert_allclose(results["mean_rgb"], 1.0 - first[..., :3].astype(np.float64).mean(axis=(0, 1)),
                               atol=1e-6)
    info = json.loads((out / "run.json").read_text())
    assert info["kind"] == "negative" and [p["name"] for p in info["passes"]] == ["scene", "negative"]
    scene_pass, neg = info["passes"]
    assert (neg["textures"], neg["spp"], neg["sample_pattern"], neg["shader"]) == (["scene"], 1, "table",
                                                                                    "negative_shader")
    assert neg["state"]["shading_mode"] == "per_sample" and scene_pass["state"]["shading_mode"] == "cache"
    assert neg["arch_changes"] == {} and scene_pass["arch_changes"] == {}
    assert info["workload"]["image"]["spp"] == 8 and info["results"] == ["mean_rgb"]
    assert "arrays" not in info and "figures" not in info  # listed only for a workload that returns some
    # totals: every counter the sum of the two passes'
    per_pass = pd.concat([pd.read_csv(passes / n / "counters.csv") for n in ("scene", "negative")])
    summed = per_pass.groupby(["unit", "counter"]).value.sum()
    assert info["headline"]["samples_tested"] == summed["sample_tester", "samples_tested"]
    assert info["headline"]["shader_executions"] == summed["shading", "shader_executions"]
    assert info["frame_cycles"] == pytest.approx(scene_pass["frame_cycles"] + neg["frame_cycles"])
    md = (out / "report.md").read_text()
    assert "![image](passes/negative/image.png)" in md and "## Passes" in md and "mean_rgb" in md
    assert main(["check", str(negative)]) == 0
    assert "ok: the negative of" in capsys.readouterr().out


def test_compare_and_sweep_point_run_the_workload(negative, tmp_path, capsys):
    from pipeline_sim.sweep import run_point

    out = tmp_path / "cmp"
    assert main(["compare", str(negative), "--spp", "4", "--algorithms", "bbox", "hierarchical",
                 "--out", str(out), "--quiet"]) == 0
    cmp = json.loads((out / "comparison.json").read_text())
    assert cmp["kind"] == "negative" and cmp["identical_images"]
    rows = {r["algorithm"]: r for r in cmp["rows"]}
    # the full-screen pass tests the same 48 x 32 samples whatever the algorithm, all covered
    assert rows["bbox"]["samples_tested"] > rows["hierarchical"]["samples_tested"] >= 48 * 32
    assert main(["compare", str(negative), "--reference-spp", "16"]) == 2
    assert "has no single image to measure" in capsys.readouterr().err
    spec = {"sweep": "s.toml", "scene": str(negative), "arch": None, "set": [], "metrics": ["rmse"],
            "reference": {}}
    summary = run_point(spec, {"image.spp": 4, "tile_traverser.tile_size": 8}, tmp_path / "sweep")
    assert summary["status"] == "ok", summary.get("error")
    assert summary["rmse"] is None   # nothing to measure a two-pass workload against
    point = tmp_path / "sweep" / "points" / summary["point_id"]
    first = np.load(point / "passes" / "scene" / "image.npy")
    np.testing.assert_array_equal(np.load(point / "image.npy"), np.load(point / "passes" / "negative" / "image.npy"))
    np.testing.assert_allclose(np.load(point / "image.npy")[..., :3], 1.0 - first[..., :3], atol=1e-6)
    run = json.loads((point / "run.json").read_text())
    assert run["arch"]["tile_traverser"]["tile_size"] == 8 and run["workload"]["image"]["spp"] == 4
    assert json.loads((point / "results.json").read_text())["mean_rgb"]


def test_pass_names_must_name_files(tmp_path):
    from pipeline_sim.output import file_name

    assert file_name("shadow_map.0", "pass") == "shadow_map.0"
    for bad in ("", "..", "a/b", ".hidden", "x y"):
        with pytest.raises(UserError, match="cannot name a file"):
            file_name(bad, "pass")


def test_report_reads_a_run_folder(negative, tmp_path, capsys):
    """`report` of a run folder writes its report again from the files alone: the same Markdown
    (figures aside), the same pass images embedded."""
    out = tmp_path / "run"
    assert main(["run", str(negative), "--out", str(out), "--quiet"]) == 0
    assert main(["report", str(out)]) == 2
    assert "give -o FILE.html" in capsys.readouterr().err
    again = tmp_path / "again.html"
    assert main(["report", str(out), "-o", str(again)]) == 0
    figures = sorted(p.name for p in (tmp_path / "again_files").glob("*.png"))
    assert figures == sorted(p.name for p in (out / "report_files").iterdir()) and len(figures) == 6
    body = lambda text: [ln for ln in text.splitlines() if "wall" not in ln and "_files/" not in ln]  # noqa: E731
    assert body(again.with_suffix(".md").read_text()) == body((out / "report.md").read_text())
    assert "data:image/png;base64," in again.read_text()
    # run again (the report beside it is the tool's own) and refused where a file is the user's
    assert main(["report", str(out), "-o", str(again)]) == 0
    mine = tmp_path / "mine.html"
    mine.write_text("my notes")
    assert main(["report", str(out), "-o", str(mine)]) == 2 and mine.read_text() == "my notes"


def test_a_sweep_runs_any_kind(negative, tmp_path):
    """A sweep over the two-pass kind: every point loaded and checked as its workload (a spp the
    workload's check refuses names the point), then run end to end; each point's image is the
    negative of its own first pass (numpy), with no single image to measure against a reference."""
    from pipeline_sim.sweep import load_sweep, run_sweep

    sweep = tmp_path / "s.toml"
    sweep.write_text(f'[sweep]\nscene = "{negative.relative_to(tmp_path)}"\nmetrics = ["rmse"]\n'
                     '[grid]\n"image.spp" = [1, 4]\n"tile_test.algorithm" = ["bbox", "hierarchical"]\n')
    spec = load_sweep(sweep)
    assert len(spec.points) == 4 and spec.scene == negative.resolve()
    frame = run_sweep(spec, tmp_path / "out", executor="serial", progress=False)
    assert (frame.status == "ok").all(), frame.error.tolist()
    assert frame.rmse.isna().all()
    for pid in frame.point_id:
        point = tmp_path / "out" / "points" / pid
        first = np.load(point / "passes" / "scene" / "image.npy")
        np.testing.assert_allclose(np.load(point / "image.npy")[..., :3], 1.0 - first[..., :3], atol=1e-6)
        assert json.loads((point / "run.json").read_text())["kind"] == "negative"
    sweep.write_text(sweep.read_text().replace("[1, 4]", "[1, 3]"))
    with pytest.raises(UserError, match=r"s.toml: point image.spp=3, tile_test.algorithm=\"bbox\": "
                                        r"spp = 3 must be a power of two"):
        load_sweep(sweep)


@pytest.mark.parametrize("text, expected", [
    ('kind = "negative"\nscen = "x.toml"\n', "negative.toml: unknown key 'scen' (did you mean 'scene'?); "
                                             "known keys: scene"),
    ('kind = "negative"\nscene = 3\n', "negative.toml: scene: expected a string, got 3"),
    ('kind = "negative"\n', "negative.toml: scene: missing required key (the scene file whose negative is drawn"),
])
def test_a_kind_s_file_schema_validates_its_file(negative, text, expected, capsys):
    """The example kind declares its file's keys (file_schema): load_workload refuses a file that does
    not match them in one line naming the file and the key, before the kind's load runs."""
    negative.write_text(text)
    with pytest.raises(UserError) as err:
        W.load_workload(negative, load_arch())
    assert str(err.value).startswith(str(negative)) and expected in str(err.value), str(err.value)
    assert main(["check", str(negative)]) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1


def test_the_docs_list_each_kind_s_file_keys(negative):
    """docs/workloads.md's generated list of kinds gives each registered kind's keys from its schema."""
    from pipeline_sim.docgen import workload_kinds

    W.kinds()  # discovers the example
    text = workload_kinds()
    assert "### `scene`" in text and "### `negative`" in text
    assert "| `scene` | string | required | the scene file whose negative is drawn, relative to this file |" in text


def test_from_settings_applies_the_image_settings_its_file_has_and_refuses_others_in_one_line():
    @dataclasses.dataclass(frozen=True)
    class Settings:
        spp: int = 4
        seed: int = 0

    class Kind(W.Workload):
        kind = "settings-test"

    w = Kind.from_settings(Path("f.toml"), Settings(), load_arch(), {"spp": 16})
    assert w.settings_file == Settings(spp=16, seed=0)
    with pytest.raises(UserError) as e:
        Kind.from_settings(Path("f.toml"), Settings(), load_arch(), {"width": 40, "spp": 16})
    assert str(e.value) == ("f.toml: a settings-test workload has no image setting width; set what it stands "
                            "for in the file")

    class Advised(Kind):
        image_refusals = {"width": "draws a fixed 8x8 image"}
        file_schema = Settings

    with pytest.raises(UserError) as e:
        Advised.load(Path("f.toml"), Settings(), load_arch(), {"width": 40})
    assert str(e.value) == "f.toml: --width: a settings-test workload draws a fixed 8x8 image"
    assert Advised.load(Path("f.toml"), Settings(), load_arch(), {"seed": 3}).settings_file == Settings(seed=3)
