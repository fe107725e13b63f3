"""pipeline_sim.memory: after ``keep_freed_memory`` a freed large array's pages are reused by the next
allocation instead of being faulted in again (counted as the process's minor page faults, in a fresh
interpreter, with numpy's huge pages off so that a fault is one 4 KiB page)."""

import json
import os
import subprocess
import sys

import pytest

from conftest import ROOT

SCRIPT = """
import json, resource, sys
import numpy as np
from pipeline_sim.memory import keep_freed_memory
kept = keep_freed_memory() if sys.argv[1] == "keep" else None
def touch():
    a = np.empty(64 << 18, np.float32)  # 64 MiB
    a.fill(1.0)
    return float(a[-1])
touch()
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
touch()
print(json.dumps({"kept": kept, "faults": resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before}))
"""


def _faults(mode: str) -> dict:
    env = {**os.environ, "NUMPY_MADVISE_HUGEPAGE": "0"}
    out = subprocess.run([sys.executable, "-c", SCRIPT, mode], capture_output=True, text=True, cwd=ROOT, env=env,
                         check=True)
    return json.loads(out.stdout)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc")
def test_a_freed_array_is_reused_without_faulting_its_pages_in_again():
    default = _faults("default")
    kept = _faults("keep")
    assert kept["kept"] is True
    pages = (64 << 20) // 4096
    assert default["faults"] > pages // 2  # unmapped on free, faulted in again: the cost being avoided
    assert kept["faults"] < pages // 20
