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
def _edges(X0, Y0, W0, X1, Y1, W1, X2, Y2, W2):
    """Edge k opposite vertex k: n_k = p_j x p_i, (i, j) = (k+1, k+2) mod 3, and
    the orientation D = p0 . (p2 x p1) (004 eq. 3 at fixed t; Olano and Greer)."""
    a0 = Y2 * W1 - W2 * Y1
    b0 = W2 * X1 - X2 * W1
    c0 = X2 * Y1 - Y2 * X1
    a1 = Y0 * W2 - W0 * Y2
    b1 = W0 * X2 - X0 * W2
    c1 = X0 * Y2 - Y0 * X2
    a2 = Y1 * W0 - W1 * Y0
    b2 = W1 * X0 - X1 * W0
    c2 = X1 * Y0 - Y1 * X0
    D = X0 * a0 + Y0 * b0 + W0 * c0
    return a0, b0, c0, a1, b1, c1, a2, b2, c2, D


MISS = (False, np.float32(0.0), np.float32(0.0), np.float32(0.0), np.float32(0.0))


@nb.njit(cache=True, inline="always")
def _decide(a0, b0, c0, a1, b1, c1, a2, b2, c2, D, X0, Y0, W0, Z0, X1, Y1, W1, Z1, X2, Y2, W2, Z2,
            x, y, backface_culling, eps):
    """Inside decision, barycentrics and depth of one sample at (x, y).

    Edge functions are evaluated in float32; a sample within the float32 error
    bound ``eps`` of an edge is re-evaluated in float64 from the same float32
    vertices (products of two float32 are exact), so the decision matches
    exact arithmetic: shared edges (exactly negated functions) and shared
    vertices are covered once. Ties follow the top-left rule (003 §3.4).
    """
    e0 = np.float64(a0 * x + b0 * y + c0)
    e1 = np.float64(a1 * x + b1 * y + c1)
    e2 = np.float64(a2 * x + b2 * y + c2)
    fa0, fb0, fa1, fb1, fa2, fb2 = (np.float64(a0), np.float64(b0), np.float64(a1), np.float64(b1),
                                    np.float64(a2), np.float64(b2))
    if abs(e0) <= eps or abs(e1) <= eps or abs(e2) <= eps:
        g = _edges(np.float64(X0), np.float64(Y0), np.float64(W0), np.float64(X1), np.float64(Y1),
                   np.float64(W1), np.float64(X2), np.float64(Y2), np.float64(W2))
        xd = np.float64(x)
        yd = np.float64(y)
        fa0, fb0, fa1, fb1, fa2, fb2 = g[0], g[1], g[3], g[4], g[6], g[7]
        e0 = g[0] * xd + g[1] * yd + g[2]
        e1 = g[3] * xd + g[4] * yd + g[5]
        e2 = g[6] * xd + g[7] * yd + g[8]
    if D == 0.0 or (backface_culling and D < 0.0):
        return MISS
    if D < 0.0:
        e0, e1, e2 = -e0, -e1, -e2
        fa0, fa1, fa2 = -fa0, -fa1, -fa2
        fb0, fb1, fb2 = -fb0, -fb1, -fb2
    if e0 < 0.0 or e1 < 0.0 or e2 < 0.0:
        return MISS
    if ((e0 == 0.0 and not _top_left(fa0, fb0)) or (e1 == 0.0 and not _top_left(fa1, fb1))
            or (e2 == 0.0 and not _top_left(fa2, fb2))):
        return MISS
    tot = e0 + e1 + e2
    # z/w = sum(e_k Z_k) / sum(e_k W_k) (the denominator is |D| in exact
    # arithmetic; summing non-negative e_k avoids D's cancellation)
    den = e0 * W0 + e1 * W1 + e2 * W2
    if tot == 0.0 or den == 0.0:
        return MISS
    z = np.float32((e0 * Z0 + e1 * Z1 + e2 * Z2) / den)
    if not (z >= -1.0 and z <= 1.0):
        return MISS
    inv = 1.0 / tot
    return True, np.float32(e0 * inv), np.float32(e1 * inv), np.float32(e2 * inv), z


@nb.njit(cache=True, inline="always")
def _at(p0, d, l0, dl, t, u):
    """A vertex coordinate at time t and lens coordinate u (001 §3.1)."""
    return p0 + t * d + u * (l0 + t * dl)


@nb.njit(cache=True)
def inside_test(p0, dp, l0, dl, tri, x, y, t, u, v, backface_culling, edge_eps):
    """Exact 5D test of one sample; returns (covered, b0, b1, b2, z_ndc).

    Vertices at (t, u, v) are computed in float32 and taken as exact inputs;
    see ``_decide`` for the decision itself.
    """
    X0 = _at(p0[tri, 0, 0], dp[tri, 0, 0], l0[tri, 0, 0], dl[tri, 0, 0], t, u)
    Y0 = _at(p0[tri, 0, 1], dp[tri, 0, 1], l0[tri, 0, 1], dl[tri, 0, 1], t, v)
    W0 = p0[tri, 0, 3] + t * dp[tri, 0, 3]
    Z0 = p0[tri, 0, 2] + t * dp[tri, 0, 2]
    X1 = _at(p0[tri, 1, 0], dp[tri, 1, 0], l0[tri, 1, 0], dl[tri, 1, 0], t, u)
    Y1 = _at(p0[tri, 1, 1], dp[tri, 1, 1], l0[tri, 1, 1], dl[tri, 1, 1], t, v)
    W1 = p0[tri, 1, 3] + t * dp[tri, 1, 3]
    Z1 = p0[tri, 1, 2] + t * dp[tri, 1, 2]
    X2 = _at(p0[tri, 2, 0], dp[tri, 2, 0], l0[tri, 2, 0], dl[tri, 2, 0], t, u)
    Y2 = _at(p0[tri, 2, 1], dp[tri, 2, 1], l0[tri, 2, 1], dl[tri, 2, 1], t, v)
    W2 = p0[tri, 2, 3] + t * dp[tri, 2, 3]
    Z2 = p0[tri, 2, 2] + t * dp[tri, 2, 2]
    a0, b0, c0, a1, b1, c1, a2, b2, c2, D = _edges(X0, Y0, W0, X1, Y1, W1, X2, Y2, W2)
    return _decide(a0, b0, c0, a1, b1, c1, a2, b2, c2, D, X0, Y0, W0, Z0, X1, Y1, W1, Z1, X2, Y2, W2, Z2,
                   x, y, backface_culling, edge_eps[tri])


@nb.njit(cache=True)
def sample_test_kernel(tri_ids, tile_x, tile_y, t_lo, t_hi, u_lo, u_hi, v_lo, v_hi, z_lo, z_hi, noread_in,
                       tile_size, width, height, spp, sx, sy, su, sv, st,
                       p0, dp, l0, dl, edge_eps, backface_culling,
                       out_tri, out_pix, out_sidx, out_z, out_b0, out_b1, out_b2, out_noread, ops, events):
    """Range lookup on t-ordered samples and exact inside tests (002 §5; 004 eq. 3, 10-13).

    Specialized per triangle: a static, pinhole triangle gets its edge
    functions once per tile (a 2D test per sample); a moving or defocused one
    recomputes its vertices at each sample's (t, u, v). Both paths compute
    bit-identical vertex values, so neighbours on different paths stay
    watertight.
    """
    n = 0
    tested = 0
    in_range = 0
    pixels = 0
    searches = 0
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
        eps = edge_eps[tri]
        # the triangle's constants, loaded once per tile
        X00, X01, X02 = p0[tri, 0, 0], p0[tri, 1, 0], p0[tri, 2, 0]
        Y00, Y01, Y02 = p0[tri, 0, 1], p0[tri, 1, 1], p0[tri, 2, 1]
        Z00, Z01, Z02 = p0[tri, 0, 2], p0[tri, 1, 2], p0[tri, 2, 2]
        W00, W01, W02 = p0[tri, 0, 3], p0[tri, 1, 3], p0[tri, 2, 3]
        dX0, dX1, dX2 = dp[tri, 0, 0], dp[tri, 1, 0], dp[tri, 2, 0]
        dY0, dY1, dY2 = dp[tri, 0, 1], dp[tri, 1, 1], dp[tri, 2, 1]
        dZ0, dZ1, dZ2 = dp[tri, 0, 2], dp[tri, 1, 2], dp[tri, 2, 2]
        dW0, dW1, dW2 = dp[tri, 0, 3], dp[tri, 1, 3], dp[tri, 2, 3]
        LX0, LX1, LX2 = l0[tri, 0, 0], l0[tri, 1, 0], l0[tri, 2, 0]
        LY0, LY1, LY2 = l0[tri, 0, 1], l0[tri, 1, 1], l0[tri, 2, 1]
        dLX0, dLX1, dLX2 = dl[tri, 0, 0], dl[tri, 1, 0], dl[tri, 2, 0]
        dLY0, dLY1, dLY2 = dl[tri, 0, 1], dl[tri, 1, 1], dl[tri, 2, 1]
        moving = (dX0 != 0 or dX1 != 0 or dX2 != 0 or dY0 != 0 or dY1 != 0 or dY2 != 0 or dZ0 != 0
                  or dZ1 != 0 or dZ2 != 0 or dW0 != 0 or dW1 != 0 or dW2 != 0 or dLX0 != 0 or dLX1 != 0
                  or dLX2 != 0 or dLY0 != 0 or dLY1 != 0 or dLY2 != 0)
        lens = LX0 != 0 or LX1 != 0 or LX2 != 0 or LY0 != 0 or LY1 != 0 or LY2 != 0 or moving
        # 2D path: vertices and edges once per tile (t, u, v do not matter)
        X0, Y0, W0, Z0 = X00, Y00, W00, Z00
        X1, Y1, W1, Z1 = X01, Y01, W01, Z01
        X2, Y2, W2, Z2 = X02, Y02, W02, Z02
        a0, b0, c0, a1, b1, c1, a2, b2, c2, D = _edges(X0, Y0, W0, X1, Y1, W1, X2, Y2, W2)
        full_t = ta <= 0.0 and tb >= 1.0
        for py in range(tile_y[i] * tile_size, min((tile_y[i] + 1) * tile_size, height)):
            for px in range(tile_x[i] * tile_size, min((tile_x[i] + 1) * tile_size, width)):
                base = (py * width + px) * spp
                pixels += 1
                first = 0
                last = spp
                if not full_t:
                    searches += 1
                    lo = 0
                    hi = spp
                    while lo < hi:  # first t >= ta
                        mid = (lo + hi) >> 1
                        if st[base + mid] < ta:
                            lo = mid + 1
                        else:
                            hi = mid
                    first = lo
                    hi = spp
                    while lo < hi:  # first t > tb
                        mid = (lo + hi) >> 1
                        if st[base + mid] <= tb:
                            lo = mid + 1
                        else:
                            hi = mid
                    last = lo
                in_range += last - first
                fx = np.float32(px)
                fy = np.float32(py)
                for s in range(first, last):
                    k = base + s
                    u = su[k]
                    v = sv[k]
                    if u < ua or u > ub or v < va or v > vb:
                        continue
                    tested += 1
                    if lens:
                        t = st[k]
                        X0 = _at(X00, dX0, LX0, dLX0, t, u)
                        Y0 = _at(Y00, dY0, LY0, dLY0, t, v)
                        W0 = W00 + t * dW0
                        Z0 = Z00 + t * dZ0
                        X1 = _at(X01, dX1, LX1, dLX1, t, u)
                        Y1 = _at(Y01, dY1, LY1, dLY1, t, v)
                        W1 = W01 + t * dW1
                        Z1 = Z01 + t * dZ1
                        X2 = _at(X02, dX2, LX2, dLX2, t, u)
                        Y2 = _at(Y02, dY2, LY2, dLY2, t, v)
                        W2 = W02 + t * dW2
                        Z2 = Z02 + t * dZ2
                        a0, b0, c0, a1, b1, c1, a2, b2, c2, D = _edges(X0, Y0, W0, X1, Y1, W1, X2, Y2, W2)
                    ok, r0, r1, r2, z = _decide(a0, b0, c0, a1, b1, c1, a2, b2, c2, D, X0, Y0, W0, Z0, X1, Y1,
                                                W1, Z1, X2, Y2, W2, Z2, fx + sx[k], fy + sy[k],
                                                backface_culling, eps)
                    if ok:
                        # the true depth lies in z^; clamping removes float32 rounding
                        # so z-cull decisions made on z^ agree with the ROP's
                        out_tri[n] = tri
                        out_pix[n] = py * width + px
                        out_sidx[n] = s
                        out_z[n] = min(max(z, za), zb)
                        out_b0[n] = r0
                        out_b1[n] = r1
                        out_b2[n] = r2
                        out_noread[n] = noread_in[i]
                        n += 1
    log_spp = 1
    while (1 << log_spp) <= spp:
        log_spp += 1
    ops[OP_CMP] += 2 * searches * log_spp
    events[EV_TESTED] += tested
    events[EV_INRANGE] += in_range
    events[EV_PIXELS] += pixels
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
