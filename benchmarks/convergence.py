"""Section 11 ("convergence"): image error against samples per pixel, per sample pattern.

Three scenes, each at a reduced image size: motion.toml (object motion only),
defocus.toml (depth of field only) and default.toml with the camera panning
as in camera_motion.toml ("both": object motion, defocus and camera motion).
Each pattern renders each scene at spp = 16 .. 1024; the error is the RMSE
over the RGB channels of the linear image against a reference, the mean of
two renders at ``ref_spp`` (patterns ``net5`` and ``sobol``, with seeds none
of the measured renders uses; half the RMS difference of the two estimates
the reference's own error and is printed). The log-log slope of RMSE
against spp is fitted with ``numpy.polyfit`` (-0.5 is plain Monte Carlo;
steeper is better), and the error at 256 spp is reported. Renders are
deterministic, so the figures do not depend on the machine's load; only the
wall time printed beside them does.
"""

from __future__ import annotations

import dataclasses
import time
import tomllib

import numpy as np

PATTERNS = ("net", "net5", "sobol", "stratified", "random")
REF_PATTERNS = (("net5", 1_000_001), ("sobol", 1_000_002))
PEER_SCENE = "both"
PEER_PATTERNS = ("net", "net5")
PEER_SPP = (64, 256)
PEER_SEED, PEER_REF_SEED = 5, 1_000_003


def scenes(width: int, height: int) -> dict:
    """name -> Scene: the shipped motion-only and defocus-only scenes, and the
    default scene with camera_motion.toml's camera pan, all at width x height."""
    from benchmarks.workloads import ROOT
    from pipeline_sim.scene import parse_scene

    folder = ROOT / "workloads" / "scenes"

    def read(name: str) -> dict:
        with open(folder / name, "rb") as f:
            return tomllib.load(f)

    both = read("default.toml")
    pan = read("camera_motion.toml")["camera"]
    both["camera"].update({k: pan[k] for k in ("eye", "look_at", "eye_close", "look_at_close")})
    docs = {"motion": read("motion.toml"), "defocus": read("defocus.toml"), "both": both}
    out = {}
    for name, data in docs.items():
        data["image"].update(width=width, height=height)
        out[name] = parse_scene(data, where=f"convergence scene {name}", base_dir=folder)
    return out


def _render(base, pattern: str, spp: int, seed: int) -> tuple[np.ndarray, float]:
    from pipeline_sim.render import run_pass

    p = dataclasses.replace(base, spp=spp, seed=seed, state=base.state.replace(sample_pattern=pattern))
    start = time.perf_counter()
    img = run_pass(p).image[..., :3].astype(np.float64)
    return img, time.perf_counter() - start


def rmse(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean((a - b) ** 2)))


def bench(cfg: dict, log) -> dict:
    from pipeline_sim.config import load_arch
    from pipeline_sim.render import scene_pass

    cc = cfg["convergence"]
    spps = cc["spp"]
    arch = load_arch()
    out: dict = {"width": cc["width"], "height": cc["height"], "spp": spps, "ref_spp": cc["ref_spp"], "scenes": {}}
    for name, scene in scenes(cc["width"], cc["height"]).items():
        base = scene_pass(scene, arch)
        refs = []
        for pattern, seed in REF_PATTERNS:
            log(f"convergence: {name} reference, {pattern} at {cc['ref_spp']} spp")
            refs.append(_render(base, pattern, cc["ref_spp"], seed)[0])
        ref = 0.5 * (refs[0] + refs[1])
        sc = {"motion": base.draw.has_motion, "lens": base.draw.has_lens,
              "reference_error": 0.5 * rmse(refs[0], refs[1]), "patterns": {}}
        for pattern in PATTERNS:
            errs, walls = [], []
            for spp in spps:
                log(f"convergence: {name}, {pattern} at {spp} spp")
                img, wall = _render(base, pattern, spp, scene.image.seed)
                errs.append(rmse(img, ref))
                walls.append(wall)
            sc["patterns"][pattern] = {
                "rmse": errs, "wall_s": walls,
                "slope": float(np.polyfit(np.log(spps), np.log(errs), 1)[0]),
                "rmse_256": errs[spps.index(256)] if 256 in spps else None}
        out["scenes"][name] = sc
        if name == PEER_SCENE:
            out["peer"] = bench_peer(base, ref, sc, cc, log)
    return out


def bench_peer(base, ref: np.ndarray, sc: dict, cc: dict, log) -> dict:
    """llvmpipe's accumulation buffer on the same scene: passes and time to reach the
    project's error at each of ``PEER_SPP`` for the patterns ``PEER_PATTERNS``, the
    two timed alternately (median of ``peer_rounds`` rounds)."""
    from benchmarks import peer as pm

    gl, why = pm.open_peer(base)
    if gl is None:
        log(f"convergence: peer skipped: {why}")
        return {"skipped": why}
    try:
        log(f"convergence: peer reference, {cc['ref_spp']} passes")
        gl_ref, _ = gl.render(pm.sobol_points(cc["ref_spp"], PEER_REF_SEED))
        targets = {(pat, spp): sc["patterns"][pat]["rmse"][cc["spp"].index(spp)]
                   for pat in PEER_PATTERNS for spp in PEER_SPP}
        reach = pm.time_to_equal_error(gl, gl_ref, {f"{pat}/{spp}": e for (pat, spp), e in targets.items()},
                                       cc["peer_max_passes"], PEER_SEED)
        rows = []
        for (pat, spp), target in targets.items():
            n = reach["passes_to_reach"][f"{pat}/{spp}"]
            walls, gl_walls = [], []
            for i in range(cc["peer_rounds"]):
                log(f"convergence: peer round {i + 1}, {pat} at {spp} spp against {n} passes")
                order = (0, 1) if i % 2 == 0 else (1, 0)
                for k in order:
                    if k == 0:
                        walls.append(_render(base, pat, spp, base.seed)[1])
                    elif n is not None:
                        gl_walls.append(pm.timed(gl, n, PEER_SEED))
            row = {"pattern": pat, "spp": spp, "rmse": target, "passes": n, "project_s": float(np.median(walls)),
                   "peer_s": float(np.median(gl_walls)) if gl_walls else None}
            row["project_over_peer"] = row["project_s"] / row["peer_s"] if row["peer_s"] else None
            rows.append(row)
        return {"renderer": gl.renderer, "reference_vs_project": rmse(gl_ref, ref),
                "rmse_at": reach["rmse_at"], "rows": rows}
    finally:
        gl.release()


def report(b: dict, table, add) -> list[str]:
    spps = b["spp"]
    out = [f"11. Error against samples per pixel ({b['width']}x{b['height']}; RMSE of linear RGB against the mean "
           f"of a net5 and a sobol render at {b['ref_spp']} spp; log-log slope over {spps[0]}..{spps[-1]} spp, "
           f"-0.5 = plain Monte Carlo)"]
    for name, sc in b["scenes"].items():
        dims = "xy" + ("uv" if sc["lens"] else "") + ("t" if sc["motion"] else "")
        out.append(f"  {name} ({dims}; reference error about {sc['reference_error']:.6f})")
        rows = []
        for pattern, r in sc["patterns"].items():
            rows.append((pattern, f"{r['slope']:.3f}", "" if r["rmse_256"] is None else f"{r['rmse_256']:.6f}",
                         *(f"{e:.6f}" for e in r["rmse"])))
            add("convergence", f"slope@{name}/{pattern}", r["slope"], "log-log")
            if r["rmse_256"] is not None:
                add("convergence", f"rmse_256@{name}/{pattern}", r["rmse_256"], "RMSE")
        out.append(table(rows, ("pattern", "slope", "RMSE 256", *(f"{s} spp" for s in spps))))
    pr = b.get("peer")
    if pr is None:
        return out
    if "skipped" in pr:
        out.append(f"  peer (llvmpipe accumulation buffer): skipped, {pr['skipped']}")
        return out
    out.append(f"  peer: {pr['renderer']} as an accumulation buffer over scrambled Sobol (x, y, t, u, v), "
               f"on '{PEER_SCENE}'; error against its own {b['ref_spp']}-pass image (which is "
               f"{pr['reference_vs_project']:.6f} RMSE from the project's reference: per-fragment shading); "
               "RMSE at " + ", ".join(f"{n}: {e:.6f}" for n, e in pr["rmse_at"].items()))
    rows = []
    for r in pr["rows"]:
        ratio = r["project_over_peer"]
        rows.append((r["pattern"], r["spp"], f"{r['rmse']:.6f}", r["passes"] or "not reached",
                     f"{r['project_s']:.3f} s", "" if r["peer_s"] is None else f"{r['peer_s']:.3f} s",
                     "" if ratio is None else f"{ratio:.2f}"))
        if ratio is not None:
            add("convergence", f"time_to_equal_error_project_over_peer@{r['pattern']}/{r['spp']}", ratio, "ratio")
    out.append(table(rows, ("pattern", "spp", "project RMSE", "peer passes to reach it", "project time",
                            "peer time", "project / peer (goal < 1)")))
    return out


def csv_rows(b: dict) -> list[dict]:
    """One row per (scene, pattern, spp) for convergence.csv."""
    return [{"scene": name, "pattern": pattern, "spp": spp, "rmse": e, "wall_s": w, "slope": r["slope"],
             "reference_error": sc["reference_error"]}
            for name, sc in b["scenes"].items() for pattern, r in sc["patterns"].items()
            for spp, e, w in zip(b["spp"], r["rmse"], r["wall_s"])]
