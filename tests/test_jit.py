"""warm_up on two cores (pipeline_sim.jit): the worker's group of kernels gets the argument types of a real
pass, a cached warm_up compiles nothing and starts no process, and a worker that cannot start, fails or
is interrupted changes nothing but the time taken.

Which kernels compile is counted with numba's "numba:compile" event, which fires on a real compile only
(a cache miss), in fresh processes with a private, empty NUMBA_CACHE_DIR.
"""

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numba
import pytest

from pipeline_sim import jit

ROOT = Path(__file__).resolve().parent.parent

# a child's prologue: import the pipeline first (sampling compiles its hash helpers at import, in every
# process), then record each compile as (phase, dispatcher), its callees' included
RECORDER = """
import json, sys
import pipeline_sim.render
from numba.core import event
from pipeline_sim import jit
phase = ["?"]
compiled = []
class Recorder(event.Listener):
    def on_start(self, ev):
        f = ev.data["dispatcher"].py_func
        compiled.append((phase[0], f"{f.__module__}.{f.__qualname__}"))
    def on_end(self, ev):
        pass
event.register("numba:compile", Recorder())
"""


def _child(code: str, cache: Path, **env: str) -> list[tuple[str, str]]:
    """Run ``code`` after ``RECORDER`` in a fresh interpreter with numba's cache in ``cache``; return the
    compiles it recorded (the child prints them last)."""
    full = RECORDER + textwrap.dedent(code) + "\nprint(json.dumps(compiled))\n"
    res = subprocess.run([sys.executable, "-c", full], capture_output=True, text=True, cwd=ROOT,
                         env={**os.environ, "NUMBA_CACHE_DIR": str(cache), "PYTHONPATH": str(ROOT), **env})
    assert res.returncode == 0, res.stderr
    return [tuple(c) for c in json.loads(res.stdout.splitlines()[-1])]


def _kernels(compiled: list[tuple[str, str]], phase: str) -> set[str]:
    """The project's dispatchers compiled in ``phase`` (numba's own overloads compile in every process)."""
    return {name for p, name in compiled if p == phase and not name.startswith("numba.")}


@pytest.fixture(scope="module")
def cold_groups(tmp_path_factory) -> tuple[list[tuple[str, str]], Path]:
    """On an empty cache: the worker's warmers, the parent's, the warm pass and the default scene's pass,
    one after the other in one process; and the cache they filled."""
    cache = tmp_path_factory.mktemp("numba-cache")
    compiled = _child("""
        from pipeline_sim.config import load_arch
        from pipeline_sim.render import render_scene
        from pipeline_sim.scene import load_scene
        phase[0] = "worker"
        jit.warm_units(jit.WORKER_UNITS)
        phase[0] = "parent"
        jit.warm_units(jit.PARENT_UNITS)
        phase[0] = "pass"
        jit.warm_pass()
        phase[0] = "default"
        render_scene(load_scene("workloads/scenes/default.toml"), load_arch())
    """, cache)
    return compiled, cache


def test_worker_group_compiles_what_the_pass_needs(cold_groups, tmp_path):
    compiled, _ = cold_groups
    worker = _kernels(compiled, "worker")
    assert {"units.sample_tester.sample_test_kernel", "units.zcull.refresh_kernel"} <= worker
    # together the two groups are every kernel of the warm pass with its argument types: the pass, in
    # particular, compiles none of the worker's again
    assert [c for c in compiled if c[0] == "pass"] == []
    # and they share no kernel: the parent's group alone, in a process and cache of its own as on a cold
    # cache (in one process the first group would have compiled a kernel the second also calls), compiles
    # none that the worker's compiles
    parent = _kernels(_child('phase[0] = "parent"\njit.warm_units(jit.PARENT_UNITS)', tmp_path), "parent")
    assert "units.triangle_setup.setup_kernel" in parent and not worker & parent


def test_default_pass_after_warm_up_compiles_nothing(cold_groups):
    compiled, _ = cold_groups
    assert [c for c in compiled if c[0] == "default"] == []


def test_cached_warm_up_compiles_nothing_and_starts_no_worker(cold_groups):
    _, cache = cold_groups
    compiled = _child("""
        import subprocess
        def refuse(*args, **kwargs):
            raise AssertionError("a cached warm_up started a process")
        subprocess.Popen = refuse
        phase[0] = "warm_up"
        jit.warm_up()
    """, cache)
    assert compiled == []


def _cut_down_warm_up(cache: Path, command: list[str] | None) -> subprocess.CompletedProcess:
    """warm_up on an empty cache, its parent's group cut down to the ROP (whose kernels start the worker)
    and its warm pass to the worker's group and the ROP, with ``command`` as the worker (None: the real one)."""
    code = RECORDER + textwrap.dedent(f"""
        jit.PARENT_UNITS = ("rop",)
        jit.warm_pass = lambda: jit.warm_units(jit.WORKER_UNITS + ("rop",))
        if {command!r} is not None:
            jit.worker_command = lambda: {command!r}
        started = []
        start = jit.Worker.start
        def recording_start(self):  # (called at every compile: it starts the worker at the first)
            first = not self._started
            start(self)
            if first:
                started.append(self.process is not None)
        jit.Worker.start = recording_start
        phase[0] = "warm_up"
        assert jit.warm_up() > 0
        print(json.dumps(started))
        print(json.dumps(compiled))
    """)
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT,
                          env={**os.environ, "NUMBA_CACHE_DIR": str(cache), "PYTHONPATH": str(ROOT)})


@pytest.mark.parametrize("command, starts", [([str(ROOT / "no-such-python")], False),
                                             ([sys.executable, "-c", "raise SystemExit('worker failed')"], True)])
def test_warm_up_compiles_itself_when_the_worker_cannot(tmp_path, command, starts):
    res = _cut_down_warm_up(tmp_path, command)
    assert res.returncode == 0 and res.stderr == ""
    started, compiled = (json.loads(line) for line in res.stdout.splitlines()[-2:])
    assert started == [starts]  # started once, at the first compile
    assert "units.zcull.refresh_kernel" in _kernels([tuple(c) for c in compiled], "warm_up")


def test_worker_fills_the_parents_cache(tmp_path):
    # the real worker: what it compiles, this process then loads (it compiles the ROP's kernels only)
    res = _cut_down_warm_up(tmp_path, None)
    assert res.returncode == 0 and res.stderr == ""
    started, compiled = (json.loads(line) for line in res.stdout.splitlines()[-2:])
    assert started == [True]
    assert _kernels([tuple(c) for c in compiled], "warm_up") == {"units.rop.rop_kernel", "units.rop.resolve_kernel"}


def test_interrupted_warm_up_kills_the_worker(monkeypatch):
    started = []

    def interrupt(w):
        # a compile (a new function, never cached) starts the worker; then the user interrupts
        numba.njit(lambda x: x + 1)(1)
        raise KeyboardInterrupt

    monkeypatch.setattr(jit, "_WARM", False)
    monkeypatch.setattr(jit, "PARENT_UNITS", ("interrupt",))
    monkeypatch.setitem(jit.WARMERS, "interrupt", interrupt)
    monkeypatch.setattr(jit, "worker_command", lambda: [sys.executable, "-c", "import time; time.sleep(600)"])
    start = jit.Worker.start
    monkeypatch.setattr(jit.Worker, "start", lambda self: (start(self), started.append(self)))
    with pytest.raises(KeyboardInterrupt):
        jit.warm_up()
    worker = started[0]
    assert worker.process is not None and worker.process.returncode is not None


def test_a_hung_worker_is_killed_after_the_timeout(monkeypatch):
    started = []

    def compile_something(w):
        numba.njit(lambda x: x + 2)(1)  # a real compile: starts the worker

    monkeypatch.setattr(jit, "_WARM", False)
    monkeypatch.setattr(jit, "PARENT_UNITS", ("compile",))
    monkeypatch.setitem(jit.WARMERS, "compile", compile_something)
    monkeypatch.setattr(jit, "WORKER_TIMEOUT_S", 0.5)
    monkeypatch.setattr(jit, "warm_pass", lambda: None)
    monkeypatch.setattr(jit, "worker_command", lambda: [sys.executable, "-c", "import time; time.sleep(600)"])
    start = jit.Worker.start
    monkeypatch.setattr(jit.Worker, "start", lambda self: (start(self), started.append(self)))
    assert jit.warm_up() < 60
    worker = started[0]
    assert worker.process is not None and worker.process.returncode is not None  # killed, not left running


def test_worker_exits_with_its_parent():
    # the worker's watch on its stdin: the parent's end closing (as when it dies) ends the worker
    child = subprocess.Popen([sys.executable, "-c", "import threading, time; from pipeline_sim.jit import "
                              "_exit_at_eof; threading.Thread(target=_exit_at_eof, daemon=True).start(); "
                              "time.sleep(600)"], stdin=subprocess.PIPE, cwd=ROOT,
                             env={**os.environ, "PYTHONPATH": str(ROOT)})
    child.stdin.close()
    assert child.wait(timeout=120) == 1


def test_worker_runs_this_package_with_this_cache(monkeypatch, tmp_path):
    # from another directory holding another pipeline_sim, the worker still imports this one
    (tmp_path / "pipeline_sim").mkdir()
    (tmp_path / "pipeline_sim" / "__init__.py").write_text("raise ImportError('the wrong package')")
    command = jit.worker_command()
    probe = command[2].replace("from pipeline_sim.jit import worker_main; worker_main()",
                               "import pipeline_sim; print(pipeline_sim.__file__)")
    res = subprocess.run([*command[:2], probe, *command[3:]], capture_output=True, text=True, cwd=tmp_path)
    assert Path(res.stdout.strip()) == ROOT / "pipeline_sim" / "__init__.py", res.stderr
    monkeypatch.setattr(numba.config, "CACHE_DIR", str(tmp_path))
    assert jit.worker_env()["NUMBA_CACHE_DIR"] == str(tmp_path)
