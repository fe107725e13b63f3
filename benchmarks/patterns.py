"""Sample-pattern quality: discrepancy of each pattern's per-pixel samples.

For every pattern of ``pipeline_sim.sampling`` (the t-ordered (0, m, 3)-net
of Munkberg11 §5, Sobol, stratified, random and Interleave UVT's tuple set), the
centered L2 discrepancy (scipy.stats.qmc.discrepancy, method "CD") of each
pixel's samples, averaged over pixels, in (x, y), (x, y, t) and all five
dimensions (lens on the square, mapped to [0, 1)^2), plus the generation
rate. Lower discrepancy is better; Interleave UVT shares a few (u, v, t)
tuples between pixels, which shows in its time and lens figures.
"""

from __future__ import annotations

import time

import numpy as np
from scipy.stats import qmc

from pipeline_sim.sampling import make_samples

PATTERNS = ("net", "sobol", "stratified", "random", "interleave")


def bench(cfg: dict, log) -> dict:
    pc = cfg["patterns"]
    w, h = pc["width"], pc["height"]
    rows = []
    for spp in pc["spp"]:
        for pattern in PATTERNS:
            log(f"patterns: {pattern} at {spp} spp")
            kw = {"interleave_tuples": 64} if pattern == "interleave" else {}
            make_samples(4, 4, spp, 7, lens=True, motion=True, pattern=pattern, lens_shape="square", **kw)  # compile
            start = time.perf_counter()
            s = make_samples(w, h, spp, 7, lens=True, motion=True, pattern=pattern, lens_shape="square", **kw)
            gen_s = time.perf_counter() - start
            pts = np.stack([s.x, s.y, 0.5 * (s.u + 1.0), 0.5 * (s.v + 1.0), s.t], axis=1).astype(np.float64)
            pts = np.clip(pts, 0.0, np.nextafter(1.0, 0.0)).reshape(w * h, spp, 5)
            pick = np.linspace(0, w * h - 1, min(pc["pixels"], w * h)).astype(int)
            d = {name: float(np.mean([qmc.discrepancy(pts[p][:, cols], method="CD") for p in pick]))
                 for name, cols in (("xy", [0, 1]), ("xyt", [0, 1, 4]), ("xyuvt", [0, 1, 2, 3, 4]))}
            rows.append({"pattern": pattern, "spp": spp, **{f"cd_{k}": v for k, v in d.items()},
                         "msamples_per_s": len(s) / gen_s / 1e6, "pixels": len(pick)})
    return {"rows": rows, "width": w, "height": h}


def report(b: dict, table, add) -> list[str]:
    out = [f"8. Sample patterns: centered L2 discrepancy per pixel (scipy.stats.qmc, mean over "
           f"{b['rows'][0]['pixels']} pixels of a {b['width']}x{b['height']} frame; lower is better)"]
    rows = []
    for r in b["rows"]:
        rows.append((r["pattern"], r["spp"], f"{r['cd_xy']:.5f}", f"{r['cd_xyt']:.5f}", f"{r['cd_xyuvt']:.5f}",
                     f"{r['msamples_per_s']:.0f} M/s"))
        for k in ("cd_xy", "cd_xyt", "cd_xyuvt"):
            add("patterns", f"{k}@{r['pattern']}/{r['spp']}", r[k], "discrepancy")
    out.append(table(rows, ("pattern", "spp", "CD (x, y)", "CD (x, y, t)", "CD (x, y, u, v, t)", "generated")))
    return out
