"""Error metrics and reference images (pipeline_sim.accuracy)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from pipeline_sim import UserError, load_arch, load_scene, render_scene
from pipeline_sim.accuracy import (METRICS, ReferenceSpec, error_map, error_metrics, reference_image,
                                   to_display)
from pipeline_sim.config import apply_settings
from pipeline_sim.output import linear_to_srgb8
from pipeline_sim.pass_state import PassState
from pipeline_sim.simulation import SimOptions

W, H = 32, 18


def tiny(root, width=W, height=H, spp=4):
    scene = load_scene(root / "workloads/scenes/default.toml")
    return scene.replace(image=dataclasses.replace(scene.image, width=width, height=height, spp=spp))


@pytest.fixture(scope="module")
def scene(root):
    return tiny(root)


@pytest.fixture(scope="module")
def refs(scene):
    """The two default references of the tiny default scene (motion blur + defocus)."""
    return {kind: reference_image(scene, ReferenceSpec(kind=kind)) for kind in ("pipeline", "accumulation")}


def grey(value=0.5, shape=(H, W)):
    img = np.full(shape + (4,), value, np.float32)
    img[..., 3] = 1.0
    return img


def noisy(sigma, seed=0):
    img = grey()
    img[..., :3] += np.random.default_rng(seed).normal(0.0, sigma, (H, W, 3)).astype(np.float32)
    return img


# --- metrics ----------------------------------------------------------------


def test_to_display_matches_png_curve():
    img = np.random.default_rng(1).uniform(-0.2, 1.3, (H, W, 4)).astype(np.float32)
    img[0, 0, 0] = np.nan
    d = to_display(img)
    assert d.shape == (H, W, 3) and d.dtype == np.float32
    assert d.min() >= 0.0 and d.max() <= 1.0
    assert np.abs(np.round(d * 255.0) - linear_to_srgb8(img)).max() <= 1


def test_identical_images():
    img = noisy(0.1)
    m = error_metrics(img, img.copy())
    assert tuple(m) == METRICS
    assert m["rmse"] == 0.0 and m["psnr"] == math.inf
    assert m["ssim"] == pytest.approx(1.0, abs=1e-12)
    assert m["flip"] == pytest.approx(0.0, abs=1e-7)


def test_alpha_is_ignored():
    a, b = grey(), grey()
    b[..., 3] = 0.0
    assert error_metrics(a, b)["rmse"] == 0.0


@pytest.mark.parametrize("sigma", [0.01, 0.03, 0.1])
def test_known_noise_level(sigma):
    m = error_metrics(noisy(sigma), grey())
    assert m["rmse"] == pytest.approx(sigma, rel=0.05)
    assert m["psnr"] == pytest.approx(20.0 * math.log10(1.0 / sigma), abs=0.5)


def test_flip_and_ssim_grow_with_noise():
    ms = [error_metrics(noisy(s), grey()) for s in (0.005, 0.02, 0.08)]
    flips = [m["flip"] for m in ms]
    ssims = [m["ssim"] for m in ms]
    assert 0.0 < flips[0] < flips[1] < flips[2] <= 1.0
    assert 1.0 > ssims[0] > ssims[1] > ssims[2]


def test_error_map():
    img, ref = noisy(0.05), grey()
    fmap = error_map(img, ref)
    assert fmap.shape == (H, W) and fmap.dtype == np.float32
    assert fmap.min() >= 0.0 and fmap.max() <= 1.0
    assert float(fmap.mean()) == pytest.approx(error_metrics(img, ref)["flip"], rel=1e-5, abs=1e-7)
    assert not error_map(ref, ref).any()


def test_mismatched_images_raise():
    with pytest.raises(UserError):
        error_metrics(grey(), grey(shape=(H, W + 1)))
    with pytest.raises(UserError):
        error_map(grey()[..., 0], grey()[..., 0])


# --- references -------------------------------------------------------------


@pytest.mark.parametrize("kwargs", [
    dict(kind="path_tracer"), dict(kind="pipelin"), dict(spp=100), dict(spp=0), dict(passes=0),
    dict(passes=-3), dict(spp=2.0), dict(seed=-1),
])
def test_bad_specs(kwargs):
    with pytest.raises(UserError) as info:
        ReferenceSpec(**kwargs)
    assert "\n" not in str(info.value)


def test_references_agree(refs):
    """The two independent references (per-pixel scrambled net vs one jointly
    stratified point per pass) agree within their noise. Measured on this
    32x18 motion-blurred, defocused scene: rmse 0.0031, flip 0.006, while the
    4 spp pipeline is 0.027 away (and 64 spp 0.0053)."""
    a, b = refs["pipeline"], refs["accumulation"]
    assert a.shape == b.shape == (H, W, 4) and a.dtype == b.dtype == np.float32
    assert np.isfinite(a).all() and np.isfinite(b).all()
    m = error_metrics(a, b)
    assert m["rmse"] < 0.008
    assert m["psnr"] > 42.0
    assert m["flip"] < 0.02
    assert abs(float(np.mean(a[..., :3] - b[..., :3]))) < 0.002  # no bias between them


def test_pipeline_converges_to_both_references(scene, refs):
    arch = load_arch()
    err = {}
    for spp in (4, 64):
        img = render_scene(scene.replace(image=dataclasses.replace(scene.image, spp=spp)), arch).image
        err[spp] = {kind: error_metrics(img, ref) for kind, ref in refs.items()}
    for kind in refs:
        assert err[4][kind]["rmse"] > 2.0 * err[64][kind]["rmse"]
        assert err[4][kind]["flip"] > err[64][kind]["flip"]


def test_accumulation_converges(scene, refs):
    few = reference_image(scene, ReferenceSpec(kind="accumulation", passes=8))
    assert error_metrics(few, refs["pipeline"])["rmse"] > 2.0 * error_metrics(refs["accumulation"],
                                                                              refs["pipeline"])["rmse"]


def test_reference_ignores_scene_spp_seed_and_timing(root, scene):
    spec = ReferenceSpec(spp=16)
    other = tiny(root, spp=64)
    other = other.replace(image=dataclasses.replace(other.image, seed=99))
    other, arch = apply_settings(other, load_arch(), [
        "pass.shading_mode='cache'", "zcull.time_slices=1", "pipeline.queue_depth=1", "tile_test.edge_test=false",
        "tile_test.algorithm='bbox'", "shading.shader_cycles=7", "simulation.region_samples=4096"])
    assert np.array_equal(reference_image(other, spec, arch=arch), reference_image(scene, spec))


def test_cache(scene, tmp_path, monkeypatch):
    spec = ReferenceSpec(spp=16)
    first = reference_image(scene, spec, cache_dir=tmp_path / "refs")  # created when missing
    files = list((tmp_path / "refs").iterdir())
    assert [f.name for f in files] == [f"{spec.key(scene)}.npy"]
    assert first.shape == (H, W, 4) and first.dtype == np.float32

    import pipeline_sim.accuracy as acc

    def boom(*args, **kwargs):
        raise AssertionError("rendered although cached")

    monkeypatch.setattr(acc, "_render_reference", boom)
    second = reference_image(scene, spec, cache_dir=str(tmp_path / "refs"))
    assert second.dtype == np.float32 and np.array_equal(first, second)


def test_cache_recovers_from_a_corrupt_file(scene, tmp_path):
    spec = ReferenceSpec(spp=16)
    path = tmp_path / f"{spec.key(scene)}.npy"
    path.write_bytes(b"not an npy file")
    fresh = reference_image(scene, spec)
    assert np.array_equal(reference_image(scene, spec, cache_dir=tmp_path), fresh)
    assert np.array_equal(np.load(path), fresh)
    assert [f.name for f in tmp_path.iterdir()] == [path.name]  # no temporary files left


def test_keys(root, scene):
    base = ReferenceSpec()
    k = base.key(scene)
    assert len(k) >= 16 and int(k, 16) >= 0
    assert k == ReferenceSpec().key(tiny(root))  # stable across loads
    # the scene's own spp and seed do not matter
    assert k == base.key(scene.replace(image=dataclasses.replace(scene.image, spp=64, seed=5)))
    others = {
        dataclasses.replace(base, spp=128).key(scene),
        dataclasses.replace(base, seed=1).key(scene),
        ReferenceSpec(kind="accumulation").key(scene),
        base.key(tiny(root, width=W + 1)),
        base.key(tiny(root, height=H + 1)),
        base.key(scene.replace(camera=dataclasses.replace(scene.camera, fov_y=30.0))),
        base.key(load_scene(root / "workloads/scenes/static.toml").replace(image=scene.image)),
        base.key(scene.replace(pass_state=PassState(depth_test="greater"))),
    }
    assert k not in others and len(others) == 8
    # passes is irrelevant to a pipeline reference, spp to an accumulation one
    assert k == dataclasses.replace(base, passes=16).key(scene)
    acc = ReferenceSpec(kind="accumulation")
    assert acc.key(scene) == dataclasses.replace(acc, spp=16).key(scene)
    assert acc.key(scene) != dataclasses.replace(acc, passes=16).key(scene)
    # cost-model changes do not change the key
    assert k == base.key(scene, load_arch(overrides=["zcull.time_slices=8", "shading.cores=4"]))
    assert k == base.key(scene.replace(simulation=SimOptions(tiles_per_batch=3)))


def test_reference_keeps_the_image_settings_such_as_clip_planes(scene):
    """A sweep point with a user clip plane is scored against a reference with that clip plane.

    The reference must equal a plain per-sample render with the same clip at
    the reference's spp, seed and sample pattern (`net`, the declared reference
    of pass.sample_pattern, not the default net5); before the settings declared
    their effects, the reference reset the whole tile-test section and dropped
    the plane.
    """
    clip = "pass.clip.t_hi=0.3"
    spec = ReferenceSpec(spp=16)
    clipped, bbox = apply_settings(scene, load_arch(), [clip, "tile_test.algorithm='bbox'"])
    assert clipped.pass_state.clip.t_hi == 0.3
    clipped_ref = reference_image(clipped, spec, arch=bbox)
    at_reference = scene.replace(image=dataclasses.replace(scene.image, spp=16, seed=spec.seed))
    direct = render_scene(*apply_settings(at_reference, load_arch(),
                                          [clip, "pass.shading_mode='per_sample'", "pass.sample_pattern='net'"])).image
    assert np.array_equal(clipped_ref, direct)
    unclipped_ref = reference_image(scene, spec)
    point = render_scene(*apply_settings(scene.replace(image=dataclasses.replace(scene.image, spp=8)), load_arch(),
                                         [clip])).image
    assert error_metrics(point, clipped_ref)["rmse"] < 0.5 * error_metrics(point, unclipped_ref)["rmse"]
    assert spec.key(clipped) != spec.key(scene)
