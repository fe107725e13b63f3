"""Broken mesh files: one line naming the file and what is wrong with it, exit 2.

Garbage bytes, truncated and corrupted copies of the shipped meshes, in every
supported format, go through `pipeline-sim check` (in this process, with
stderr captured, so that a stray warning or log line from the mesh library
counts as a second line). Each must give exit status 2 and exactly one line
that names the file and says it is not a valid file of its format (or names
the precise problem the loader checks: no triangles, non-finite
coordinates, indices out of range), with no traceback and no mention of a
missing Python module.
"""

import contextlib
import io
import random
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pipeline_sim.cli import main
from scenes import mesh_object, scene_toml

ROOT = Path(__file__).resolve().parent.parent
MESHES = ROOT / "workloads" / "meshes"
FORMATS = {".obj": "OBJ", ".stl": "STL", ".ply": "PLY", ".off": "OFF", ".gltf": "glTF", ".glb": "GLB"}
# a minimal valid file for the formats without a shipped mesh
EXTRA = {
    ".off": b"OFF\n4 2 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n3 0 1 2\n3 0 2 3\n",
    ".gltf": (b'{"asset": {"version": "2.0"}, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}], "meshes": '
              b'[{"primitives": [{"attributes": {"POSITION": 0}}]}], "accessors": [{"bufferView": 0, '
              b'"componentType": 5126, "count": 3, "type": "VEC3", "max": [1, 1, 0], "min": [0, 0, 0]}], '
              b'"bufferViews": [{"buffer": 0, "byteLength": 36}], "buffers": [{"byteLength": 36, "uri": '
              b'"data:application/octet-stream;base64,AAAAAAAAAAAAAAAAAACAPwAAAAAAAAAAAAAAAAAAgD8AAAAA"}]}'),
}
VALID = {p.suffix: p.read_bytes() for p in MESHES.iterdir() if p.suffix in FORMATS} | EXTRA
# what the loader may say besides "not a valid <format> file": checks of its own
OWN_CHECKS = ("mesh file has no triangles", "mesh file has non-finite", "mesh file has face indices out of range")


def check(tmp_path: Path, suffix: str, data: bytes) -> tuple[int, str]:
    mesh = tmp_path / f"broken{suffix}"
    mesh.write_bytes(data)
    scene = tmp_path / "scene.toml"
    scene.write_text(scene_toml(mesh_object(mesh.name), width=8, height=8, spp=1, eye_y=0.0))
    err, out = io.StringIO(), io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
        code = main(["check", str(scene)])
    return code, err.getvalue()


def assert_reported(code: int, err: str, suffix: str) -> None:
    assert code == 2, err
    assert err.count("\n") == 1 and err.endswith("\n"), err
    assert "Traceback" not in err and "No module named" not in err, err
    assert f"broken{suffix}" in err, err
    assert f"not a valid {FORMATS[suffix]} file" in err or any(c in err for c in OWN_CHECKS), err


def corpus() -> list[tuple[str, str, bytes]]:
    """Per format: random bytes, the valid file truncated at several points,
    and the valid file with a few bytes overwritten (seeded, reproducible)."""
    rng = random.Random(11)
    cases = []
    for suffix, valid in sorted(VALID.items()):
        for i in range(3):
            cases.append((suffix, f"garbage{i}", bytes(rng.getrandbits(8) for _ in range(rng.randint(1, 600)))))
        for frac in (0.1, 0.35, 0.6, 0.9):
            cases.append((suffix, f"truncated{frac}", valid[: int(len(valid) * frac)]))
        for i in range(4):
            b = bytearray(valid)
            for _ in range(8):
                b[rng.randrange(len(b))] = rng.getrandbits(8)
            if bytes(b) != valid:
                cases.append((suffix, f"corrupted{i}", bytes(b)))
    return cases


@pytest.mark.parametrize("suffix,name,data", corpus(), ids=[f"{s[1:]}-{n}" for s, n, _ in corpus()])
def test_broken_mesh_is_one_line_naming_the_file(tmp_path, suffix, name, data):
    code, err = check(tmp_path, suffix, data)
    if code == 0 and not name.startswith("garbage"):
        return  # a prefix of a text mesh, or a byte changed inside a number or a name, can be a valid file
    assert_reported(code, err, suffix)


@pytest.mark.parametrize("suffix", sorted(FORMATS))
def test_random_bytes_say_the_file_is_not_of_its_format(tmp_path, suffix):
    """The reported cases: garbage in an .obj or .stl file named a missing
    optional module of the mesh library, and in a .gltf file said only the
    file name."""
    data = bytes(random.Random(suffix).getrandbits(8) for _ in range(2000))
    code, err = check(tmp_path, suffix, data)
    assert_reported(code, err, suffix)
    assert f"not a valid {FORMATS[suffix]} file" in err


@pytest.mark.parametrize("suffix", sorted(FORMATS))
def test_valid_files_still_load(tmp_path, suffix):
    code, err = check(tmp_path, suffix, VALID[suffix])
    assert code == 0, err


@settings(max_examples=60)
@given(suffix=st.sampled_from(sorted(FORMATS)), data=st.binary(max_size=300))
def test_arbitrary_bytes_never_escape_as_a_traceback(tmp_path_factory, suffix, data):
    code, err = check(tmp_path_factory.mktemp("m"), suffix, data)
    if code != 0:
        assert_reported(code, err, suffix)
