"""Sample tester: the exact 5D inside test for the samples of each tile.

Implements PIPELINE.md §2.5. For each pixel of a surviving tile, the samples
whose t lies in t^ form a contiguous range of the pixel's t-ordered samples
(a binary-search range lookup, 002 §5); those whose (u, v) also lie in
(u^, v^) get the exact test at their own (x, y, u, v, t):

* vertices lerped to t and shifted by the lens: p_k = (X + u LX, Y + v LY, W)
  (001 §3.1);
* 2DH edge functions e_k = (p_j x p_i) . (x, y, 1) (Olano and Greer; 004 eq. 3
  at a fixed t) and the orientation D = p_0 . (p_2 x p_1);
* inside when every e_k has the sign of D; a zero e_k counts only on a
  top-left edge (normal (a, b) with a > 0, or a == 0 and b > 0, after
  orienting by D), so samples on a shared edge or vertex are covered exactly
  once (003 §3.4);
* perspective-correct barycentrics b_k = e_k / sum(e) and depth
  z/w = sum(e_k z_k) / D (004 eq. 10-13), clipped to [-1, 1] (near and far).

Arithmetic is float32, as in hardware; the computation is bit-for-bit the
same for the two triangles that share an edge, which makes it watertight.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from pipeline_sim.counters import N_OPS, OP_ADD, OP_CMP, OP_MADD, OP_MUL, OP_RCP

EVENTS = ("samples_tested", "samples_covered", "samples_in_range", "pixels_visited")
EV_TESTED, EV_COVERED, EV_INRANGE, EV_PIXELS = range(len(EVENTS))

# arithmetic of one exact 5D test (vertex lerp + lens, three edges, D) and of a covered sample
TEST_OPS_MADD = 9 + 6 + 9 + 6 + 2
TEST_OPS_MUL = 9 + 3
COVER_OPS_RCP = 1
COVER_OPS_MUL = 4
COVER_OPS_MADD = 3 + 3


@nb.njit(cache=True, inline="always")
def _top_left(a, b):
    return a > 0.0 or (a == 0.0 and b > 0.0)


@nb.njit(cache=True, inline="always")
def _edge(xj, yj, wj, xi, yi, wi, x, y):
    """n = p_j x p_i and its value at (x, y, 1)."""
    a = yj * wi - wj * yi
    b = wj * xi - xj * wi
    c = xj * yi - yj * xi
    return a, b, a * x + b * y + c


@nb.njit(cache=True, inline="always")
def _edge64(xj, yj, wj, xi, yi, wi, x, y):
    """The same edge in float64 from the same float32 inputs: the products of
    two float32 values are exact, so the sign is that of exact arithmetic
    unless the sample lies within about 1e-16 (relative) of the edge."""
    return _edge(np.float64(xj), np.float64(yj), np.float64(wj), np.float64(xi), np.float64(yi),
                 np.float64(wi), np.float64(x), np.float64(y))


@nb.njit(cache=True)
def inside_test(p0, dp, l0, dl, tri, x, y, t, u, v, backface_culling, edge_eps):
    """Exact 5D test of one sample; returns (covered, b0, b1, b2, z_ndc).

    Vertices at (t, u, v) are computed in float32 and taken as exact inputs.
    Edge functions are evaluated in float32; a sample within the float32
    error bound ``edge_eps[tri]`` of an edge is re-evaluated in float64, so
    the decision matches exact arithmetic on the vertex values: shared edges
    (exactly negated functions) and shared vertices are covered once.
    """
    X0 = p0[tri, 0, 0] + t * dp[tri, 0, 0] + u * (l0[tri, 0, 0] + t * dl[tri, 0, 0])
    Y0 = p0[tri, 0, 1] + t * dp[tri, 0, 1] + v * (l0[tri, 0, 1] + t * dl[tri, 0, 1])
    W0 = p0[tri, 0, 3] + t * dp[tri, 0, 3]
    X1 = p0[tri, 1, 0] + t * dp[tri, 1, 0] + u * (l0[tri, 1, 0] + t * dl[tri, 1, 0])
    Y1 = p0[tri, 1, 1] + t * dp[tri, 1, 1] + v * (l0[tri, 1, 1] + t * dl[tri, 1, 1])
    W1 = p0[tri, 1, 3] + t * dp[tri, 1, 3]
    X2 = p0[tri, 2, 0] + t * dp[tri, 2, 0] + u * (l0[tri, 2, 0] + t * dl[tri, 2, 0])
    Y2 = p0[tri, 2, 1] + t * dp[tri, 2, 1] + v * (l0[tri, 2, 1] + t * dl[tri, 2, 1])
    W2 = p0[tri, 2, 3] + t * dp[tri, 2, 3]
    # edge k opposite vertex k: n_k = p_j x p_i with (i, j) = (k+1, k+2) mod 3
    a0, b0, e0 = _edge(X2, Y2, W2, X1, Y1, W1, x, y)
    a1, b1, e1 = _edge(X0, Y0, W0, X2, Y2, W2, x, y)
    a2, b2, e2 = _edge(X1, Y1, W1, X0, Y0, W0, x, y)
    eps = edge_eps[tri]
    if abs(e0) <= eps or abs(e1) <= eps or abs(e2) <= eps:
        a0, b0, e0 = _edge64(X2, Y2, W2, X1, Y1, W1, x, y)
        a1, b1, e1 = _edge64(X0, Y0, W0, X2, Y2, W2, x, y)
        a2, b2, e2 = _edge64(X1, Y1, W1, X0, Y0, W0, x, y)
    c0 = X2 * Y1 - Y2 * X1
    D = X0 * (Y2 * W1 - W2 * Y1) + Y0 * (W2 * X1 - X2 * W1) + W0 * c0  # p0 . (p2 x p1)
    if D == 0.0 or (backface_culling and D < 0.0):
        return False, np.float32(0.0), np.float32(0.0), np.float32(0.0), np.float32(0.0)
    if D < 0.0:
        e0, e1, e2 = -e0, -e1, -e2
        a0, a1, a2 = -a0, -a1, -a2
        b0, b1, b2 = -b0, -b1, -b2
    if e0 < 0.0 or e1 < 0.0 or e2 < 0.0:
        return False, np.float32(0.0), np.float32(0.0), np.float32(0.0), np.float32(0.0)
    if ((e0 == 0.0 and not _top_left(a0, b0)) or (e1 == 0.0 and not _top_left(a1, b1))
            or (e2 == 0.0 and not _top_left(a2, b2))):
        return False, np.float32(0.0), np.float32(0.0), np.float32(0.0), np.float32(0.0)
    tot = e0 + e1 + e2
    if tot == 0.0:
        return False, np.float32(0.0), np.float32(0.0), np.float32(0.0), np.float32(0.0)
    Z0 = p0[tri, 0, 2] + t * dp[tri, 0, 2]
    Z1 = p0[tri, 1, 2] + t * dp[tri, 1, 2]
    Z2 = p0[tri, 2, 2] + t * dp[tri, 2, 2]
    # z/w = sum(e_k Z_k) / sum(e_k W_k) (the denominator is |D| in exact
    # arithmetic; summing non-negative e_k avoids D's cancellation)
    den = e0 * W0 + e1 * W1 + e2 * W2
    if den == 0.0:
        return False, np.float32(0.0), np.float32(0.0), np.float32(0.0), np.float32(0.0)
    z = np.float32((e0 * Z0 + e1 * Z1 + e2 * Z2) / den)
    if not (z >= -1.0 and z <= 1.0):
        return False, np.float32(0.0), np.float32(0.0), np.float32(0.0), np.float32(0.0)
    inv = 1.0 / tot
    return True, np.float32(e0 * inv), np.float32(e1 * inv), np.float32(e2 * inv), z


@nb.njit(cache=True)
def sample_test_kernel(tri_ids, tile_x, tile_y, t_lo, t_hi, u_lo, u_hi, v_lo, v_hi, z_lo, z_hi, noread_in,
                       tile_size, width, height, spp, sx, sy, su, sv, st,
                       p0, dp, l0, dl, edge_eps, backface_culling,
                       out_tri, out_pix, out_sidx, out_z, out_b0, out_b1, out_b2, out_noread, ops, events):
    """Range lookup on t-ordered samples and exact 5D inside tests (002 §5; 004 eq. 3, 10-13)."""
    n = 0
    for i in range(tri_ids.shape[0]):
        tri = tri_ids[i]
        ta = t_lo[i]
        tb = t_hi[i]
        ua = u_lo[i]
        ub = u_hi[i]
        va = v_lo[i]
        vb = v_hi[i]
        za = np.float32(z_lo[i])
        zb = np.float32(z_hi[i])
        for py in range(tile_y[i] * tile_size, min((tile_y[i] + 1) * tile_size, height)):
            for px in range(tile_x[i] * tile_size, min((tile_x[i] + 1) * tile_size, width)):
                base = (py * width + px) * spp
                events[EV_PIXELS] += 1
                # binary searches for the first t >= ta and the first t > tb
                lo = 0
                hi = spp
                while lo < hi:
                    mid = (lo + hi) >> 1
                    if st[base + mid] < ta:
                        lo = mid + 1
                    else:
                        hi = mid
                first = lo
                hi = spp
                while lo < hi:
                    mid = (lo + hi) >> 1
                    if st[base + mid] <= tb:
                        lo = mid + 1
                    else:
                        hi = mid
                last = lo
                ops[OP_CMP] += 2 * (1 + int(np.log2(spp + 1)))
                events[EV_INRANGE] += last - first
                for s in range(first, last):
                    k = base + s
                    u = su[k]
                    v = sv[k]
                    if u < ua or u > ub or v < va or v > vb:
                        continue
                    events[EV_TESTED] += 1
                    ok, b0, b1, b2, z = inside_test(p0, dp, l0, dl, tri, np.float32(px + sx[k]),
                                                     np.float32(py + sy[k]), st[k], u, v, backface_culling,
                                                     edge_eps)
                    if ok:
                        # the true depth lies in z^; clamping removes float32 rounding
                        # so z-cull decisions made on z^ agree with the ROP's
                        z = min(max(z, za), zb)
                        out_tri[n] = tri
                        out_pix[n] = py * width + px
                        out_sidx[n] = s
                        out_z[n] = z
                        out_b0[n] = b0
                        out_b1[n] = b1
                        out_b2[n] = b2
                        out_noread[n] = noread_in[i]
                        n += 1
    events[EV_COVERED] += n
    return n


class SampleTester:
    """Functional model of the sample tester unit."""

    name = "sample_tester"
    events = EVENTS

    def __init__(self, config, table, samples, tile_size: int, backface_culling: bool):
        self.config = config
        self.table = table
        self.samples = samples
        self.tile_size = tile_size
        self.backface_culling = backface_culling

    def run(self, tiles: dict[str, np.ndarray]) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray]:
        s = self.samples
        ts = self.tile_size
        n = len(tiles["tri"])
        cap = n * ts * ts * s.spp
        out = {
            "tri": np.empty(cap, np.int32), "pix": np.empty(cap, np.int32), "sidx": np.empty(cap, np.int32),
            "z": np.empty(cap, np.float32), "b0": np.empty(cap, np.float32), "b1": np.empty(cap, np.float32),
            "b2": np.empty(cap, np.float32), "noread": np.empty(cap, np.bool_),
        }
        ops = np.zeros(N_OPS, np.int64)
        events = np.zeros(len(EVENTS), np.int64)
        t = self.table
        m = sample_test_kernel(tiles["tri"], tiles["tx"], tiles["ty"], tiles["t_lo"], tiles["t_hi"],
                               tiles["u_lo"], tiles["u_hi"], tiles["v_lo"], tiles["v_hi"], tiles["z_lo"],
                               tiles["z_hi"], tiles["noread"],
                               ts, s.width, s.height, s.spp, s.x, s.y, s.u, s.v, s.t,
                               t.p0_32, t.dp_32, t.l0_32, t.dl_32, t.edge_eps, self.backface_culling,
                               out["tri"], out["pix"], out["sidx"], out["z"], out["b0"], out["b1"],
                               out["b2"], out["noread"], ops, events)
        tested = events[EV_TESTED]
        ops[OP_MADD] += tested * TEST_OPS_MADD
        ops[OP_MUL] += tested * TEST_OPS_MUL
        ops[OP_CMP] += tested * 4
        ops[OP_RCP] += m * COVER_OPS_RCP
        ops[OP_MUL] += m * COVER_OPS_MUL
        ops[OP_MADD] += m * COVER_OPS_MADD
        return {k: v[:m].copy() for k, v in out.items()}, ops, events
