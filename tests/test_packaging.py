"""Packaging: the wheel builds without warnings and carries every shipped data file."""

import shutil
import subprocess
import sys
import zipfile

import pytest


@pytest.mark.slow
def test_wheel_builds_without_warnings_and_ships_the_data(root, tmp_path):
    # built from a copy: setuptools leaves build/ and *.egg-info in the tree it builds
    src = tmp_path / "src"
    shutil.copytree(root, src, ignore=shutil.ignore_patterns(".git", ".venv", "__pycache__", ".hypothesis", "runs",
                                                             "bench-results", "build", "*.egg-info"))
    res = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-cache-dir", "-w", str(tmp_path),
                          str(src)], capture_output=True, text=True, cwd=tmp_path)
    assert res.returncode == 0, res.stderr[-2000:]
    text = res.stdout + res.stderr
    # pip's own notes about this machine's package indexes are not the project's
    lines = [ln for ln in text.splitlines() if "Warning" in ln or "deprecat" in ln.lower()]
    assert not lines, "\n".join(lines)
    (wheel,) = tmp_path.glob("pipeline_sim-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    shipped = [p.relative_to(root).as_posix() for pattern in ("pipeline_sim/data/*.toml", "workloads/**/*.toml",
                                                              "workloads/meshes/*.*") for p in root.glob(pattern)]
    assert shipped and not [s for s in shipped if s not in names]
