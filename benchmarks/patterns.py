"""Sample-pattern quality: discrepancy of each pattern's per-pixel samples.

For every pattern of ``pipeline_sim.sampling`` (the t-ordered (0, m, 3)-net
of Munkberg11 §5, the t-ordered (t, m, 5)-net ``net5``, Sobol, stratified,
random and Interleave UVT's tuple set), the
centered L2 discrepancy (scipy.stats.qmc.discrepancy, method "CD") of each
pixel's samples, averaged over pixels, in (x, y), (x, y, t) and all five
dimensions (lens on the square, mapped to [0, 1)^2), plus the generation
rate. Lower discrepancy is better; Interleave UVT shares a few (u, v, t)
tuples between pixels, which shows in its time and lens figures.

Also the t-value of the digital nets behind ``net5`` and ``sobol`` (in all
five dimensions and in the projections (x, y, t), (u, v, t) and
(x, y, u, v)) for each spp, by the rank criterion: a digital net with
generator matrices C_1..C_s is a (t, m, s)-net iff, for every choice of
d_1 + ... + d_s = m - t, the first d_i rows of the C_i are linearly
independent over F2. The per-pixel scrambles keep these values. (``net``'s
lens is paired with its (x, y, t) net at random, so it has no 5D t-value;
its (x, y, t) projection is a (0, m, 3)-net.)
"""

from __future__ import annotations

import time

import numpy as np
from scipy.stats import qmc

from pipeline_sim.sampling import make_samples, net5_columns, sobol_points

PATTERNS = ("net", "net5", "sobol", "stratified", "random", "interleave")
#: projections whose t-value is reported, as indices into (x, y, u, v, t)
PROJECTIONS = {"xyuvt": (0, 1, 2, 3, 4), "xyt": (0, 1, 4), "uvt": (2, 3, 4), "xyuv": (0, 1, 2, 3)}


def _rows(columns: np.ndarray, m: int) -> list[int]:
    """Rows of one m x m generator matrix (row k: digit of weight 2^-(k+1)) as bit masks over its columns."""
    return [sum(1 << l for l in range(m) if (int(columns[l]) >> (m - 1 - k)) & 1) for k in range(m)]


def _independent(vectors: list[int]) -> bool:
    basis: list[int] = []
    for v in vectors:
        for b in basis:
            v = min(v, v ^ b)
        if not v:
            return False
        basis.append(v)
    return True


def _splits(n: int, s: int):
    if s == 1:
        yield (n,)
        return
    for i in range(n + 1):
        for rest in _splits(n - i, s - 1):
            yield (i, *rest)


def t_value(columns: np.ndarray, m: int) -> int:
    """Smallest t for which the digital net with these (s, m) generator columns is a (t, m, s)-net."""
    mats = [_rows(c, m) for c in columns]
    for t in range(m + 1):
        if all(_independent([r for mat, d in zip(mats, split) for r in mat[:d]]) for split in _splits(m - t, len(mats))):
            return t
    return m


def net_columns(pattern: str, m: int) -> np.ndarray:
    """(5, m) generator columns in the order (x, y, u, v, t) of ``net5`` or ``sobol``."""
    if pattern == "net5":
        return net5_columns(m)
    pts = sobol_points(m)  # dimensions x, y, t, a, b; Gray-code order: point 2^(l+1) - 1 is column l
    return np.stack([pts[[0, 1, 3, 4, 2], (1 << (l + 1)) - 1] for l in range(m)], axis=1)


def t_values(ms: list[int]) -> list[dict]:
    return [{"pattern": pattern, "m": m, **{name: t_value(net_columns(pattern, m)[list(dims)], m)
                                              for name, dims in PROJECTIONS.items()}}
            for pattern in ("net5", "sobol") for m in ms]


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
    log("patterns: t-values")
    return {"rows": rows, "width": w, "height": h, "t_values": t_values(pc["t_value_m"])}


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
    out.append("  t-value of the digital nets (rank criterion; lower is better, 0 is the best a base-2 net can be "
               "in up to 3 dimensions)")
    rows = []
    for r in b["t_values"]:
        rows.append((r["pattern"], 1 << r["m"], *(r[k] for k in PROJECTIONS)))
        add("patterns", f"t_value@{r['pattern']}/{1 << r['m']}", r["xyuvt"], "t")
    out.append(table(rows, ("pattern", "spp", *(f"t ({', '.join(k)})" for k in PROJECTIONS))))
    return out
