"""Layering: every module imports on its own, in a fresh interpreter, in any order.

An import cycle shows up only when a module of the cycle is the first one
imported, so each module is imported first, alone, in its own process.
"""

import subprocess
import sys

from conftest import ROOT

MODULES = sorted(
    ".".join(p.relative_to(ROOT).with_suffix("").parts)
    for package in ("pipeline_sim", "units", "reports")
    for p in (ROOT / package).rglob("*.py")
    if p.name not in ("__init__.py", "__main__.py") and "__pycache__" not in p.parts
)


def test_every_package_module_is_listed():
    assert "units.tile_test_dual" in MODULES and "pipeline_sim.cli" in MODULES and len(MODULES) > 30


def test_each_module_imports_first_and_alone():
    script = ("import importlib, sys\n"
              "name = sys.argv[1]\n"
              "importlib.import_module(name)\n")
    failed = {}
    for start in range(0, len(MODULES), 4):   # a few interpreters at a time
        procs = {name: subprocess.Popen([sys.executable, "-c", script, name], stdout=subprocess.DEVNULL,
                                        stderr=subprocess.PIPE, text=True, cwd=ROOT)
                 for name in MODULES[start:start + 4]}
        for name, proc in procs.items():
            _, err = proc.communicate()
            if proc.returncode != 0:
                failed[name] = err.strip().splitlines()[-1]
    assert not failed, failed
