"""The caustics workload (workloads/apps/caustics, Nilsson12 §4) against references computed another way.

* flat water: every pixel of the top view wholly inside the lit square has the closed-form irradiance
  E0 |L_z| T, T the Fresnel transmittance computed here from Snell's angles (sine and tangent forms);
* photons: the rasterized floor irradiance converges to the photon trace's histogram as the photons grow
  (the error falls like 1 / sqrt(photons), not to a floor);
* per beam, on the top view: the pixels a beam shades are exactly those its moving triangle touches at some
  time of a dense sampling (a polygon test of its own, tests/triangles.py), lie inside the hull of its six
  projected vertices (scipy), and include every pixel where its photons land;
* fill rate: the moving triangle with exact intervals shades fewer pixels than the bounding prism and no
  more than the tile test's intervals; per pixel, the prism covers what the hull covers;
* a light pointing up, waves steep enough to shadow the surface and a camera that does not see the whole
  pool in front of it are refused in one line;
* docs/caustics.md's example runs as written.
"""

import dataclasses
import math

import numba as nb
import numpy as np
import pytest
from scipy.spatial import ConvexHull

from pipeline_sim.config import load_arch
from pipeline_sim.errors import UserError
from pipeline_sim.render import run_passes
from pipeline_sim.schema import build
from pipeline_sim.shaders import IN_T_HI, IN_T_LO, IN_TRIANGLE, IN_X, IN_Y, append_record
from pipeline_sim.targets import AppendBuffer
from pipeline_sim.workload import load_workload
from triangles import touches
from workloads.apps.caustics import Caustics, Settings, make_beams, reference_photon_irradiance, water_surface
from runs import run_doc_example

WAVES = [{"amplitude": 0.012, "wavelength": 0.45, "direction": 20.0},
         {"amplitude": 0.006, "wavelength": 0.3, "direction": 110.0, "phase": 30.0}]
SMALL = {"cells": 8, "resolution": 32, "width": 48, "height": 36, "photons": 0, "waves": WAVES}


def workload(**keys) -> Caustics:
    return Caustics.load("test.toml", build(Settings, {**SMALL, **keys}, "test.toml"), load_arch(), {})


@pytest.fixture(scope="module")
def wavy():
    return workload().run()


def test_flat_water_lights_the_floor_evenly_at_the_closed_form():
    res = workload(waves=[], fill_rate=False).run()
    light = np.array([0.25, 0.15, -1.0]) / np.linalg.norm([0.25, 0.15, -1.0])
    theta_i = math.acos(-light[2])
    theta_t = math.asin(math.sin(theta_i) / 1.33)
    rs = math.sin(theta_i - theta_t) ** 2 / math.sin(theta_i + theta_t) ** 2
    rp = math.tan(theta_i - theta_t) ** 2 / math.tan(theta_i + theta_t) ** 2
    expected = -light[2] * (1.0 - 0.5 * (rs + rp))
    flat = res.results["flat"]
    assert flat["pixels"] > 300
    assert flat["expected"] == pytest.approx(expected, rel=1e-12)
    assert flat["max_rel_deviation"] < 1e-5


def test_rasterized_irradiance_converges_to_the_photon_histogram(wavy):
    s = build(Settings, SMALL, "test.toml")
    top = wavy.passes["top.light"].images["light"][0][..., 0].astype(np.float64)

    def error(n, seed):
        ref = reference_photon_irradiance(s, n, seed)
        return np.abs(top - ref).sum() / ref.sum()

    few, many = error(20_000, 1), error(320_000, 2)
    print(f"relative L1 error: {few:.4f} with 20k photons, {many:.4f} with 320k")
    assert many < few / 2.5  # sqrt(16) = 4 for pure noise; a bias would stall it
    assert many < 0.08


@nb.njit
def record_shader(inputs, params, textures, out, append):
    rec = np.empty(5, np.float32)
    for i in range(inputs.shape[1]):
        rec[0], rec[1], rec[2] = inputs[IN_TRIANGLE, i], inputs[IN_X, i], inputs[IN_Y, i]
        rec[3], rec[4] = inputs[IN_T_LO, i], inputs[IN_T_HI, i]
        append_record(append, rec)
        out[i, 0] = out[i, 1] = out[i, 2] = out[i, 3] = 1.0


def test_each_beam_shades_exactly_the_pixels_its_moving_triangle_touches():
    w = workload(cells=2, resolution=24, waves=[{"amplitude": 0.03, "wavelength": 0.7, "direction": 30.0}])
    s = w.data
    beams = make_beams(s, water_surface(s))
    receivers, light = w._passes("top", beams, ("exact",))
    light = dataclasses.replace(light, shader=record_shader,
                                append=AppendBuffer(fields=("beam", "x", "y", "t_lo", "t_hi"), capacity=10_000))
    rec = run_passes([receivers, light])["top.light"].append.records
    assert len(rec) < 10_000
    res = s.resolution

    def pixels(world):  # the top view's pixel positions, from its definition: [0, size]^2, row 0 at y = size
        return np.stack([world[..., 0] / s.size * res, (s.size - world[..., 1]) / s.size * res], axis=-1)

    times = np.linspace(0.0, 1.0, 2001)
    rng = np.random.default_rng(3)
    for b in range(len(beams.p)):
        shaded = {(int(x), int(y)) for _, x, y, _, _ in rec[rec[:, 0] == b]}
        section = pixels((1 - times)[:, None, None] * beams.p[b] + times[:, None, None] * beams.q[b])
        dense = {(x, y) for x in range(res) for y in range(res) if touches(section, x, y).any()}
        assert shaded == dense, f"beam {b}: {sorted(shaded ^ dense)[:5]}"
        six = pixels(np.concatenate([beams.p[b], beams.q[b]]))
        hull = six[ConvexHull(six).vertices][None]
        assert all(touches(hull, x, y, grow=1e-6)[0] for x, y in shaded), f"beam {b} leaves its hull"
        lam = rng.dirichlet([0.3, 0.3, 0.3], 4000)  # photons of the beam land at these barycentrics
        land = pixels(lam @ beams.q[b])
        deposits = {(int(x), int(y)) for x, y in np.floor(land) if 0 <= x < res and 0 <= y < res}
        assert deposits <= shaded, f"beam {b}: photons land in unshaded pixels {sorted(deposits - shaded)[:5]}"


def test_moving_triangles_shade_fewer_pixels_than_the_prism(wavy):
    ex = wavy.results["executions"]
    print("shader executions:", ex, "ratio to the prism:", wavy.results["ratio_to_prism"])
    assert ex["exact"] < ex["prism"]
    assert ex["exact"] <= ex["tile"]
    assert ex["exact"] <= ex["hull"] * 1.001  # the hull of six holds the beam (up to the 1e-7 px margin)
    heat = wavy.tables["heat_eye"]
    assert (heat["prism"] >= heat["hull"]).all()
    assert heat["exact"].sum() == ex["exact"] == wavy.passes["eye.light"].counter("shading", "shader_executions")


def test_the_prism_count_bounds_every_beam():
    """The solid the prism method counts (the six prism vertices and the end triangle) holds every point of
    every beam (dense sections (1 - t) p + t q at random barycentrics), checked by a Delaunay point location
    apart from the plane construction; its bottom vertices lie on the floor."""
    from scipy.spatial import Delaunay

    from workloads.apps.caustics import prism_vertices

    w = workload(cells=4, resolution=24, waves=[{"amplitude": 0.03, "wavelength": 0.7, "direction": 30.0}])
    beams = make_beams(w.data, water_surface(w.data))
    prism = prism_vertices(beams.p, beams.q)
    rng = np.random.default_rng(5)
    lam = rng.dirichlet([1.0, 1.0, 1.0], 200)
    t = rng.uniform(0.0, 1.0, 200)[:, None]
    for b in range(len(beams.p)):
        solid = Delaunay(np.concatenate([prism[b], beams.q[b]]))
        points = (1.0 - t) * (lam @ beams.p[b]) + t * (lam @ beams.q[b])
        inside = solid.find_simplex(points, tol=1e-9) >= 0
        assert inside.all(), f"beam {b}: {points[~inside][:3]}"
    assert np.allclose(np.sort(prism[..., 2], axis=1)[:, :3], 0.0, atol=1e-12)


@pytest.mark.parametrize("text, message", [
    ("light = [0.1, 0.0, 0.5]", "light: the light must point down"),
    ("[[waves]]\namplitude = 0.05\nwavelength = 0.05", "waves: too steep for the light"),
    ("depth = 0.01\n[[waves]]\namplitude = 0.02\nwavelength = 1.0", "waves: their amplitudes"),
    ("eye = [0.5, 0.5, 0.2]\nlook_at = [0.5, 1.5, 0.2]", "eye: the eye view's camera must see the whole pool"),
    ("eye = [0.5, 0.5, 2.0]\nlook_at = [0.5, 0.5, 0.0]", "look_at: the eye view must not look straight up or down"),
    ("eye = [0.5, 0.5, 2.0]\nlook_at = [0.5, 0.5, 2.0]", "look_at: the eye view must not look straight up or down"),
])
def test_bad_surfaces_are_refused_in_one_line(tmp_path, text, message):
    path = tmp_path / "bad.toml"
    path.write_text(f'kind = "caustics"\n{text}\n')
    with pytest.raises(UserError) as err:
        load_workload(path, load_arch()).check()
    assert message in str(err.value) and "\n" not in str(err.value)


def test_the_doc_example_runs_as_written():
    scope, _ = run_doc_example("caustics.md")
    assert scope["r"]["beams"] == 2 * 8 * 8
