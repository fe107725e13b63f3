"""Layering: every module imports on its own, in a fresh interpreter, in any order;
and the units depend on the framework only through ``pipeline_sim.definitions`` and
``pipeline_sim.records``.

An import cycle shows up only when a module of the cycle is the first one
imported, so each module is imported first, alone, in its own process.
"""

import ast
import subprocess
import sys
from pathlib import Path

import pytest

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


DEFINITIONS = "pipeline_sim.definitions"
RECORDS = "pipeline_sim.records"
SHARED = (DEFINITIONS, RECORDS)  # what units may import of the framework
UNIT_FILES = sorted(p for p in (ROOT / "units").glob("*.py") if p.name != "__init__.py")


def imports_of(source: str, module: str) -> set[str]:
    """The dotted names ``source`` (the text of ``module``) imports, anywhere in it:
    ``import a.b`` gives ``a.b``; ``from a import b`` gives ``a.b`` (b a module or
    not); relative imports are resolved against ``module``'s package."""
    names = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:  # level 1: the module's own package, 2: its parent, ...
                base = ".".join(module.split(".")[: -node.level] + ([base] if base else []))
            names.update(f"{base}.{alias.name}" for alias in node.names)
    return names


def unit_may_import(name: str) -> bool:
    """A unit imports the standard library, numpy, numba, other units, the definitions and the records only."""
    top = name.split(".")[0]
    return (top in sys.stdlib_module_names or top in ("numpy", "numba", "units")
            or any(name == m or name.startswith(m + ".") for m in SHARED))


def test_imports_of_reads_every_form():
    source = ("from __future__ import annotations\nimport numpy as np, simpy\nfrom . import zcull\n"
              "from .rounding import F32_REL\nfrom pipeline_sim import config\n"
              "def f():\n    from pipeline_sim.definitions import N_OPS\n    import pipeline_sim.render\n")
    assert imports_of(source, "units.rop") == {
        "__future__.annotations", "numpy", "simpy", "units.zcull", "units.rounding.F32_REL", "pipeline_sim.config",
        "pipeline_sim.definitions.N_OPS", "pipeline_sim.render"}
    assert [n for n in sorted(imports_of(source, "units.rop")) if not unit_may_import(n)] == [
        "pipeline_sim.config", "pipeline_sim.render", "simpy"]


def test_units_import_only_the_definitions_of_the_framework():
    """Units depend on the framework's counter and shared definitions only; what
    else they need (a region's samples, its rows) the pipeline hands them."""
    assert {p.stem for p in UNIT_FILES} >= {"rop", "sample_tester", "shading_cache", "tile_test", "zcull"}
    wrong = {f"units/{p.name}": sorted(n for n in imports_of(p.read_text(), f"units.{p.stem}")
                                       if not unit_may_import(n))
             for p in UNIT_FILES}
    assert not {k: v for k, v in wrong.items() if v}, wrong


@pytest.mark.parametrize("module", SHARED)
def test_definitions_import_nothing_of_the_project(module):
    """The framework imports its shared definitions and records, never the other way: they
    import the standard library (and numpy) only, no unit and no framework module."""
    path = ROOT / Path(*module.split(".")).with_suffix(".py")
    names = imports_of(path.read_text(), module)
    assert not [n for n in names if n.split(".")[0] not in sys.stdlib_module_names and n.split(".")[0] != "numpy"]


def test_importing_the_units_loads_no_other_framework_module():
    """At run time too: the package itself is lazy, so importing every unit
    loads ``pipeline_sim.definitions`` and ``pipeline_sim.records`` and nothing
    else of the framework, nor SimPy or pandas."""
    script = ("import importlib, sys\n"
              "for name in sys.argv[1:]:\n"
              "    importlib.import_module(name)\n"
              "watched = ('pipeline_sim', 'simpy', 'pandas')\n"
              "print(' '.join(sorted(m for m in sys.modules if m.split('.')[0] in watched)))\n")
    out = subprocess.run([sys.executable, "-c", script, *(f"units.{p.stem}" for p in UNIT_FILES)], cwd=ROOT,
                         capture_output=True, text=True, check=True).stdout.split()
    assert out == ["pipeline_sim", *SHARED]
