"""pipeline-sim compare: the culling algorithms in the papers' terms, and the image-identity check."""

import dataclasses
import json

import numpy as np
import pandas as pd
import pytest

import pipeline_sim.compare as cmp_mod
from pipeline_sim.cli import main
from pipeline_sim.compare import ALGORITHMS, compare
from pipeline_sim.config import load_arch
from pipeline_sim.scene import load_scene


@pytest.fixture(scope="module")
def small_motion(root):
    scene = load_scene(root / "workloads/scenes/compare/motion_1x.toml")
    return scene.replace(image=dataclasses.replace(scene.image, width=96, height=54, spp=8))


def test_every_algorithm_covers_the_same_samples(small_motion):
    comp = compare(small_motion, load_arch(), list(ALGORITHMS))
    assert comp.identical and not comp.differing
    t = comp.table.set_index("algorithm")
    # z-cull sits before the sample tester and culls per tile: at the same tile
    # size every algorithm passes it the same covered samples
    same_tiles = t.drop(index=["exact/pixel", "interleave_uvt", "bbox/interleave"])
    assert (same_tiles.samples_covered == t.loc["bbox", "samples_covered"]).all()
    assert t.loc["interleave_uvt", "samples_covered"] == t.loc["bbox/interleave", "samples_covered"]
    for name in ("hull", "dual_space", "two_stage"):
        assert t.loc[name, "samples_tested"] < t.loc["bbox", "samples_tested"]
    assert t.loc["interleave_uvt", "samples_tested"] < t.loc["bbox/interleave", "samples_tested"]
    assert t.loc["box+quadratic", "samples_tested"] <= t.loc["box", "samples_tested"]
    assert t.loc["exact/pixel", "samples_tested"] < t.loc["box+quadratic", "samples_tested"]
    # Interleave UVT's discrete samples give a different image, whose error is reported
    assert t.loc["bbox", "rmse"] == 0 and t.loc["interleave_uvt", "rmse"] > 0
    # a motion-only scene: the motion checks apply, the both-blur one does not
    assert {c["check"] for c in comp.checks} == {"hierarchical_5x_bbox", "linearized_vs_quadratic"}
    # brute force BBOX tests the most samples; each added test never tests more
    assert t.samples_tested.idxmax() == "bbox"
    assert t.loc["box", "samples_tested"] <= t.loc["bbox", "samples_tested"]
    assert t.loc["box+edge", "samples_tested"] <= t.loc["box", "samples_tested"]
    assert t.loc["hierarchical", "ste"] > 2 * t.loc["bbox", "ste"]
    # STE is covered / tested, computed here independently of the module
    np.testing.assert_allclose(t.ste, t.samples_covered / t.samples_tested)
    for stage in ("triangle_setup", "tile_test", "sample_test", "interpolation_setup"):
        assert (t[f"ops_{stage}"] > 0).all()


def test_compare_does_not_depend_on_timing(root):
    """compare refreshes z-cull in submission order: an algorithm's counters do not
    move with the queue depth or a unit's throughput (with the hardware-like timed
    refresh they do: on compare/both_1x at 4 spp z-cull culls more tiles with a slow
    tile test, and the sample tester tests fewer samples)."""
    scene = load_scene(root / "workloads/scenes/compare/both_1x.toml")
    scene = scene.replace(image=dataclasses.replace(scene.image, spp=4))
    names = ["bbox", "hierarchical"]
    timing = ["frame_cycles", "wall_time_s"]
    variants = ([], ["pipeline.queue_depth=32"], ["tile_test.throughput=0.05"])
    tables = [compare(scene, load_arch(overrides=v), names).table.drop(columns=timing) for v in variants]
    for t in tables[1:]:
        pd.testing.assert_frame_equal(t, tables[0])
    timed = [compare(scene, load_arch(overrides=v), names, zcull_refresh="timed").table for v in variants]
    assert (timed[2].samples_tested < timed[0].samples_tested).all()
    assert (timed[1].samples_tested != timed[0].samples_tested).any()


def test_cli_writes_table_chart_images(small_motion, root, tmp_path, capsys):
    out = tmp_path / "cmp"
    assert main(["compare", str(root / "workloads/scenes/compare/motion_1x.toml"), "--spp", "4",
                 "--algorithms", "bbox", "hierarchical", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "images identical across algorithms: yes" in printed
    table = pd.read_csv(out / "table.csv")
    assert list(table.algorithm) == ["bbox", "hierarchical"]
    info = json.loads((out / "comparison.json").read_text())
    assert info["identical_images"] is True and info["zcull_refresh"] == "ordered"
    assert (out / "comparison.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert (out / "image_bbox.png").exists() and (out / "image_hierarchical.npy").exists()


def test_cli_fails_when_images_differ(root, tmp_path, monkeypatch):
    # a setting that changes coverage is not a culling algorithm: the check must catch it
    monkeypatch.setitem(cmp_mod.ALGORITHMS, "not-conservative", ["pass.depth_test='greater'"])
    rc = main(["compare", str(root / "workloads/scenes/compare/motion_1x.toml"), "--spp", "1",
               "--algorithms", "bbox", "not-conservative", "--quiet"])
    assert rc == 1


def test_unknown_algorithm_is_a_user_error(root):
    with pytest.raises(SystemExit) as exc:  # argparse choices
        main(["compare", str(root / "workloads/scenes/motion.toml"), "--algorithms", "bboxx"])
    assert exc.value.code == 2


@pytest.mark.parametrize("name", ["defocus_1x", "motion_2x", "camera_motion_1x", "both_1x", "both_2x",
                                  "tessellated"])
def test_every_comparison_workload_gives_identical_images(root, name):
    """Issue 4's check on every comparison workload (small frames): each culling
    algorithm covers the samples BBOX covers; Interleave UVT those of BBOX on
    its own discrete sample set."""
    scene = load_scene(root / f"workloads/scenes/compare/{name}.toml")
    scene = scene.replace(image=dataclasses.replace(scene.image, width=64, height=36, spp=4))
    comp = compare(scene, load_arch(), [n for n in ALGORITHMS if n != "exact/pixel"])
    assert comp.identical, f"{name}: {comp.differing} differ"


def test_the_printed_table_says_n_a_for_a_ratio_over_nothing():
    """A scene with nothing tested has no STE and so no ratio to the baseline: 'n/a', not 'nan%' or 'nanx'."""
    from pipeline_sim.compare import format_table

    row = {"algorithm": "bbox", "tiles_tested": 0, "tiles_rejected": 0, "samples_tested": 0, "samples_covered": 0,
           "ste": float("nan"), "ste_vs_baseline": float("nan"), "samples_tested_vs_baseline": 0.0,
           "ops_triangle_setup": 0, "ops_tile_test": 0, "ops_sample_test": 0, "ops_interpolation_setup": 0,
           "depth_bytes": 0, "shader_executions": 0, "frame_cycles": 10.0, "wall_time_s": 0.1}
    text = format_table(pd.DataFrame([row]))
    assert "nan" not in text and text.count("n/a") == 2
