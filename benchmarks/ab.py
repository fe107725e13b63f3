"""What the pass layer costs, and what the cost-per-sample work saved: the default pass A/B against earlier
revisions, in one run.

Each revision of ``REVISIONS`` (and the working tree) is extracted with
``git archive`` into a temporary folder and runs the default workload
(workloads/scenes/default.toml, the shipped architecture) in fresh
subprocesses, each tree's numba cache its own. A first child per tree
compiles (untimed); then ``rounds`` rounds run one child per tree in a
rotating order, each timing ``runs`` calls of ``run_pass`` on one pass
built once (wall and process CPU time). The figures are the medians over
all timed runs, and each tree's ratio to the working tree. The children
also hash the image and the counters, so the table says whether a
revision renders the same image (it must, since issue 12 changed no
image) and the same counters (the z-cull refresh became a costed path in
c222a40, which moved some ROP counters and the frame cycles by design).

Only calls that every revision has are used: ``load_scene``,
``load_arch``, ``scene_pass`` and ``run_pass``.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent

#: (label, revision): before issue 12 began, before its pass layer (targets, draws, shader interface), and
#: before issue 19's cost-per-sample work
REVISIONS = (("before issue 12 (d6313f9)", "d6313f9"), ("before the pass layer (6d2ecd5)", "6d2ecd5"),
             ("before the cost-per-sample work (f07c12f)", "f07c12f"))
CURRENT = "working tree"

CHILD = """
import hashlib, json, sys, time
import numpy as np
from pipeline_sim.config import load_arch
from pipeline_sim.render import run_pass, scene_pass
from pipeline_sim.scene import load_scene
runs = int(sys.argv[1])
p = scene_pass(load_scene("workloads/scenes/default.toml"), load_arch())
wall, cpu = [], []
for _ in range(runs):
    w0, c0 = time.perf_counter(), time.process_time()
    r = run_pass(p)
    wall.append(time.perf_counter() - w0)
    cpu.append(time.process_time() - c0)
counters = sorted((u, c, int(v)) for u, c, v in zip(r.counters.unit, r.counters.counter, r.counters.value))
print(json.dumps({"wall": wall, "cpu": cpu, "frame_cycles": float(r.timing.frame_cycles),
                  "image": hashlib.sha256(np.ascontiguousarray(r.image).tobytes()).hexdigest(),
                  "counters": hashlib.sha256(json.dumps(counters).encode()).hexdigest()}))
"""


def _extract(rev: str, into: Path) -> Path:
    into.mkdir(parents=True)
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", rev], check=True, capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(into)], input=archive, check=True)
    return into


def _child(tree: Path, runs: int) -> dict:
    res = subprocess.run([sys.executable, "-c", CHILD, str(runs)], cwd=tree, capture_output=True, text=True,
                         env={**_env(), "PYTHONPATH": str(tree)}, timeout=900)
    if res.returncode != 0:
        raise RuntimeError(f"{tree}: {res.stderr.strip().splitlines()[-1] if res.stderr.strip() else res.returncode}")
    return json.loads(res.stdout.strip().splitlines()[-1])


def _env() -> dict:
    import os

    env = dict(os.environ)
    env.pop("NUMBA_CACHE_DIR", None)  # each tree caches its kernels beside its own sources
    return env


def bench(cfg: dict, log) -> dict:
    """The default pass's wall and CPU time in the working tree and in each of ``REVISIONS``."""
    rounds, runs = cfg["ab_rounds"], cfg["ab_runs"]
    with tempfile.TemporaryDirectory(prefix="pipeline-sim-ab-") as tmp:
        trees = {CURRENT: ROOT}
        missing = {}
        for label, rev in REVISIONS:
            try:
                trees[label] = _extract(rev, Path(tmp) / rev)
            except subprocess.CalledProcessError as exc:  # a shallow clone without the revision
                missing[label] = (exc.stderr or b"").decode(errors="replace").strip() or "git archive failed"
        for label, tree in trees.items():
            log(f"pass layer A/B: compiling in {label}")
            _child(tree, 1)
        times = {label: {"wall": [], "cpu": []} for label in trees}
        last = {}
        labels = list(trees)
        for i in range(rounds):
            log(f"pass layer A/B: round {i + 1} of {rounds}")
            for label in labels[i % len(labels):] + labels[:i % len(labels)]:
                out = _child(trees[label], runs)
                times[label]["wall"] += out["wall"]
                times[label]["cpu"] += out["cpu"]
                last[label] = out
    base = {k: float(np.median(times[CURRENT][k])) for k in ("wall", "cpu")}
    rows = []
    for label in trees:
        wall, cpu = float(np.median(times[label]["wall"])), float(np.median(times[label]["cpu"]))
        rows.append({"tree": label, "wall_median_s": wall, "cpu_median_s": cpu,
                     "current_over_this_wall": base["wall"] / wall, "current_over_this_cpu": base["cpu"] / cpu,
                     "runs": len(times[label]["wall"]), "frame_cycles": last[label]["frame_cycles"],
                     "same_image": last[label]["image"] == last[CURRENT]["image"],
                     "same_counters": last[label]["counters"] == last[CURRENT]["counters"]})
    return {"rows": rows, "missing": missing, "rounds": rounds, "runs_per_child": runs}


def report(b: dict, table, add) -> list[str]:
    out = [f"10. What the pass layer costs: the default pass A/B against earlier revisions (benchmarks/ab.py; "
           f"{b['rounds']} rounds of one child per tree, {b['runs_per_child']} passes each; issue 12 asks for the "
           "working tree to be no more than 5% slower)"]
    rows = []
    for r in b["rows"]:
        rows.append((r["tree"], f"{r['wall_median_s']:.3f} s", f"{r['cpu_median_s']:.3f} s",
                     f"{r['current_over_this_wall']:.3f}", f"{r['current_over_this_cpu']:.3f}",
                     f"{r['frame_cycles']:,.0f}", "yes" if r["same_image"] else "NO",
                     "yes" if r["same_counters"] else "no"))
        add("ab", f"current_over@{r['tree']}", r["current_over_this_cpu"], "ratio",
            f"CPU time of the default pass, working tree / this tree (wall: {r['current_over_this_wall']:.3f})")
    out.extend("  " + line for line in table(rows, ("tree", "wall", "CPU", "current/this wall", "current/this CPU",
                                                    "frame cycles", "same image", "same counters")).splitlines())
    for label, why in b["missing"].items():
        out.append(f"  {label}: not measured ({why})")
    return out
