"""One validation before any kernel loads: `check` accepts what `run` runs, and a
refusal is one line, exit 2, whatever the command, before numba loads a kernel.

And memory: the run's estimate from its settings is an upper bound of the
memory real runs take (peak resident set, measured in a child process), a
run that would not fit is refused in one line, and the resolved image is
converted to the PNG's 8-bit sRGB without float64 copies of the whole image.
"""

import json
import re
import subprocess
import sys
import textwrap
import tracemalloc

import numpy as np
import pytest

from pipeline_sim import preflight
from pipeline_sim.cli import main
from pipeline_sim.config import load_arch
from pipeline_sim.output import linear_to_srgb8
from pipeline_sim.preflight import FIXED_BYTES, estimate_memory
from pipeline_sim.simulation import SimOptions
from scenes import moving_sphere, scene_toml

SCENE = scene_toml(moving_sphere(), seed=2)

# modules that load (or compile) the numba kernels: none may be imported by a refused run
KERNEL_MODULES = ("pipeline_sim.jit", "pipeline_sim.render", "units.sample_tester", "units.triangle_setup",
                  "units.rop", "units.shading_cache", "units.zcull")

REFUSED = [
    # the reported case: `check` said ok, `run` refused after loading the kernels
    ("spp beyond the limit", ["--spp", "1048576"], "--spp: must be <= 16384, got 1048576"),
    ("spp not a power of two for the net pattern", ["--spp", "12"], "spp = 12 must be a power of two"),
    ("spp and the interleave pattern", ["--spp", "128", "--set", "pass.sample_pattern='interleave'"],
     "must divide pass.interleave_tuples = 64"),
    ("negative seed", ["--seed", "-1"], "--seed: must be in [0, 2^64)"),
    ("z-cull boxes of a 16384-pixel frame of 1-pixel tiles", ["--tile", "1", "--set", "zcull.time_slices=63",
     "--set", "zcull.lens_boxes=2"], None),
]


@pytest.fixture
def scene(tmp_path):
    p = tmp_path / "scene.toml"
    p.write_text(SCENE)
    return p


def refused_in_child(args: list[str]) -> tuple[int, str, list[str]]:
    """Run the CLI in a child process; return its status, stderr, and the
    kernel modules it had imported when it returned."""
    code = textwrap.dedent(f"""
        import json, sys
        from pipeline_sim.cli import main
        rc = main({args!r})
        print(json.dumps([rc, sorted(m for m in {KERNEL_MODULES!r} if m in sys.modules)]))
    """)
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    rc, loaded = json.loads(res.stdout.strip().splitlines()[-1])
    return rc, res.stderr, loaded


@pytest.mark.parametrize("name,extra,needle", REFUSED, ids=[r[0] for r in REFUSED])
def test_check_and_run_refuse_alike_before_any_kernel_loads(scene, tmp_path, name, extra, needle):
    if needle is None:  # a frame too big for any machine: 16384 x 16384 pixels of 1x1 tiles, 252 boxes each
        big = SCENE.replace("width = 48", "width = 16384").replace("height = 32", "height = 16384")
        scene.write_text(big)
        needle = "of memory ("
    out = tmp_path / "out"
    rc_check, err_check, loaded_check = refused_in_child(["check", str(scene), *extra])
    rc_run, err_run, loaded_run = refused_in_child(["run", str(scene), "--out", str(out), *extra])
    assert rc_check == rc_run == 2
    # the same one line (the memory available may change between the two children)
    same = [re.sub(r"the [\d.]+ [KMGT]iB available", "the N available", e) for e in (err_check, err_run)]
    assert same[0] == same[1], (err_check, err_run)
    assert err_run.count("\n") == 1 and needle in err_run and "Traceback" not in err_run, err_run
    assert loaded_check == loaded_run == [], loaded_run
    assert not out.exists()


def test_compare_refuses_an_algorithm_it_would_reach_later(scene, tmp_path):
    """interleave_uvt needs spp to divide its 64 tuples: at 128 spp `compare`
    used to render bbox first, then fail; now nothing is rendered."""
    rc, err, loaded = refused_in_child(["compare", str(scene), "--spp", "128", "--algorithms", "bbox",
                                        "interleave_uvt", "--out", str(tmp_path / "c")])
    assert rc == 2 and err.count("\n") == 1 and "interleave_tuples" in err and loaded == [], err
    rc, err, loaded = refused_in_child(["compare", str(scene), "--reference-spp", "12", "--algorithms", "bbox"])
    assert rc == 2 and "reference spp = 12" in err and loaded == [], err


def test_sweep_points_pass_the_same_checks(scene, tmp_path):
    """spp 12 is refused for the net pattern and accepted for the random one, in a sweep as in a run."""
    from pipeline_sim.errors import UserError
    from pipeline_sim.sweep import load_sweep

    sweep = tmp_path / "s.toml"
    sweep.write_text('[sweep]\nscene = "scene.toml"\n[grid]\n"image.spp" = [4, 12]\n')
    with pytest.raises(UserError, match=r"point image.spp=12: spp = 12 must be a power of two"):
        load_sweep(sweep)
    sweep.write_text('[sweep]\nscene = "scene.toml"\nset = ["pass.sample_pattern=\'random\'"]\n'
                     '[grid]\n"image.spp" = [4, 12]\n')
    assert len(load_sweep(sweep).points) == 2
    assert main(["check", str(scene), "--spp", "12", "--set", "pass.sample_pattern='random'"]) == 0


def test_a_run_that_does_not_fit_is_refused_in_one_line(scene, tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(preflight, "available_memory", lambda: 100 << 20)
    for args in (["check", str(scene)], ["run", str(scene), "--out", str(tmp_path / "out")],
                 ["compare", str(scene), "--algorithms", "bbox"]):
        assert main(args) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "needs about" in err and "more than the 100 MiB available" in err, err
    assert not (tmp_path / "out").exists()


MEASURE = """
import json, sys
import psutil
from pipeline_sim.cli import _load_inputs, build_parser, main
from pipeline_sim.preflight import estimate_memory
argv = {argv!r}
args = build_parser().parse_args(argv)
workload, arch = _load_inputs(args)
scene = workload.scene
img = scene.image
estimate = estimate_memory(img.width, img.height, img.spp, scene.triangle_count, arch, scene.pass_state,
                           scene.simulation).total
before = psutil.Process().memory_info().rss
assert main(argv) == 0
# VmHWM, this process's own high-water mark: ru_maxrss would keep the forking parent's (pytest's, gigabytes
# late in a full run) across fork and exec
peak = next(int(line.split()[1]) * 1024 for line in open("/proc/self/status") if line.startswith("VmHWM:"))
print(json.dumps({{"estimate": estimate, "added": peak - before}}))
"""

RUNS = {
    "one region": ["--spp", "16"],
    # 16 regions of 2 coarse-tile rows: the region terms are held and replaced many times
    "many regions": ["--spp", "64", "--set", "simulation.region_samples=100000"],
    "large tiles, conservative": ["--tile", "32", "--set", "pass.mode='conservative'"],
}


@pytest.mark.parametrize("name", sorted(RUNS))
def test_estimate_bounds_the_peak_resident_memory_of_real_runs(scene, tmp_path, name):
    scene.write_text(SCENE.replace("width = 48", "width = 640").replace("height = 32", "height = 360")
                     .replace("subdivisions = 1", "subdivisions = 5"))
    argv = ["run", str(scene), "--out", str(tmp_path / "out"), "--quiet", *RUNS[name]]
    res = subprocess.run([sys.executable, "-c", MEASURE.format(argv=argv)], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    m = json.loads(res.stdout.strip().splitlines()[-1])
    assert m["added"] <= m["estimate"], m
    # and an estimate, not a refusal of everything: within 4x of what the run took (beyond the fixed part)
    assert m["estimate"] - FIXED_BYTES <= 4 * m["added"], m


def test_estimate_terms_follow_the_settings():
    arch = load_arch()
    small = estimate_memory(320, 180, 16, 1000, arch)
    assert estimate_memory(320, 180, 16, 2000, arch).parts["triangles"] == 2 * small.parts["triangles"]
    assert estimate_memory(640, 360, 16, 1000, arch).parts["image"] == 4 * small.parts["image"]
    # a frame of more than simulation.region_samples samples holds one region's samples, not the frame's
    big = estimate_memory(8192, 8192, 16, 1000, arch)
    assert big.parts["region samples"] <= SimOptions().region_samples * preflight.BYTES["region_sample"]
    assert estimate_memory(320, 180, 16, 1000, arch, images=3).parts["image"] == 3 * small.parts["image"]
    # the sample tester's outputs of the batches it tested ahead are held too, and the colours of the
    # sample batches shading shaded ahead (at most a region's samples each)
    covered = 512 * 4 * 4 * 16 * preflight.BYTES["sample_record"]  # one tile batch's samples
    shaded = min(65536, 320 * 180 * 16) * preflight.BYTES["shaded_sample"]  # one sample batch's colours
    one_thread = estimate_memory(320, 180, 16, 1000, arch, sim=SimOptions(run_ahead=0))
    ahead = estimate_memory(320, 180, 16, 1000, arch, sim=SimOptions(run_ahead=2))
    assert ahead.parts["in flight"] - one_thread.parts["in flight"] == 2 * (covered + shaded)


def test_png_conversion_takes_no_float_copy_of_the_whole_image():
    """The 8-bit sRGB conversion of a 2048 x 2048 image (64 MiB of float32)
    used to hold five float64 copies of it at once (about 600 MiB); now a band
    of rows at a time: the 12 MiB result and a few MiB more."""
    image = np.random.default_rng(1).random((2048, 2048, 4), dtype=np.float32)
    tracemalloc.start()
    out = linear_to_srgb8(image)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert out.shape == (2048, 2048, 3) and out.dtype == np.uint8
    assert peak < out.nbytes + (48 << 20), peak / 2**20
    srgb = np.where(image[..., :3] <= 0.0031308, 12.92 * image[..., :3].astype(np.float64),
                    1.055 * np.power(image[..., :3].astype(np.float64), 1 / 2.4) - 0.055)
    np.testing.assert_array_equal(out, np.round(srgb * 255).astype(np.uint8))


def test_the_address_space_limit_counts_as_memory(tmp_path):
    """`ulimit -v` leaves a process less than the machine has: the estimate is checked against that."""
    code = ("import resource; resource.setrlimit(resource.RLIMIT_AS, (3 << 30, resource.RLIM_INFINITY));"
            "from pipeline_sim.preflight import available_memory; print(available_memory())")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    assert 0 <= int(res.stdout) < 3 << 30


def test_running_out_of_memory_anyway_is_one_line(scene, tmp_path, monkeypatch, capsys):
    import pipeline_sim.render as render

    def exhausted(*args, **kwargs):
        raise MemoryError

    monkeypatch.setattr(render, "run_pass", exhausted)
    assert main(["run", str(scene), "--out", str(tmp_path / "out")]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "out of memory" in err
    assert not (tmp_path / "out").exists() and not list(tmp_path.glob(".out.*"))
