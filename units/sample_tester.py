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

from pipeline_sim.counters import N_OPS, OP_CMP, OP_MADD, OP_MUL, OP_RCP

EVENTS = ("samples_tested", "samples_covered", "samples_in_range", "pixels_visited",
          "tests_2d", "tests_3d_xyt", "tests_4d_xyuv", "tests_5d")
EV_TESTED, EV_COVERED, EV_INRANGE, EV_PIXELS, EV_2D, EV_3D, EV_4D, EV_5D = range(len(EVENTS))

# arithmetic of one exact 5D test (vertex lerp + lens, three edges, D) and of a covered sample
# arithmetic of one inside test by dimension (index: 0 = 2D, 1 = 3D xyt, 2 =
# 4D xyuv, 3 = 5D): vertex positions at the sample (none in 2D: the edges are
# set up once per tile; t: 3 madd for X, Y, W per vertex; lens: 2 madd per
# X, Y; both: 3 + 3 + 1 per vertex), the three edge normals (9 mul + 9 madd,
# none in 2D), the orientation D (1 mul + 2 madd) and three edge values
# (2 madd each)
TEST_OPS_MADD = (6, 9 + 9 + 2 + 6, 6 + 9 + 2 + 6, 21 + 9 + 2 + 6)
TEST_OPS_MUL = (0, 9 + 1, 9 + 1, 9 + 1)
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


@nb.njit(cache=True, inline="always")
def _f32_at_least(a):
    """The smallest float32 >= a: for float32 t, t >= a exactly when t >= this."""
    f = np.float32(a)
    if f < a:
        f = np.nextafter(f, np.float32(np.inf))
    return f


@nb.njit(cache=True, inline="always")
def _f32_at_most(a):
    """The largest float32 <= a."""
    f = np.float32(a)
    if f > a:
        f = np.nextafter(f, np.float32(-np.inf))
    return f


@nb.njit(cache=True, inline="always")
def _mark(j0, j1, general, extra, rt, ru, rv, rx, ry, rtup, colf, cand, fpx0, fy, iv, ln, mk, neps, tc):
    """Pass 1 over samples [j0, j1) of a tile row: interval test and float32
    edge functions, branch-free. Marks as candidates the samples in the
    intervals that no edge excludes by more than the float32 error bound.
    ``iv`` holds (t_lo, t_hi, u_lo, u_hi, v_lo, v_hi) and ``tc`` the
    triangle's constants. With ``extra`` (two-stage culling, Interleave UVT)
    a sample is in the intervals only if it also lies between the tile's time
    lines ``ln`` (t >= c + s u, t <= c + s u, then the same in v; 001 §3.4)
    and its tuple's bit is set in ``mk``. Returns (in the intervals, in t^,
    candidates) as int32 counts."""
    ta, tb, ua, ub, va, vb = iv[0], iv[1], iv[2], iv[3], iv[4], iv[5]
    X00, X01, X02, Y00, Y01, Y02, W00, W01, W02 = tc[0], tc[1], tc[2], tc[3], tc[4], tc[5], tc[6], tc[7], tc[8]
    dX0, dX1, dX2, dY0, dY1, dY2, dW0, dW1, dW2 = (tc[9], tc[10], tc[11], tc[12], tc[13], tc[14], tc[15],
                                                    tc[16], tc[17])
    LX0, LX1, LX2, LY0, LY1, LY2 = tc[18], tc[19], tc[20], tc[21], tc[22], tc[23]
    dLX0, dLX1, dLX2, dLY0, dLY1, dLY2 = tc[24], tc[25], tc[26], tc[27], tc[28], tc[29]
    sa0, sb0, sc0, sa1, sb1, sc1, sa2, sb2, sc2, ssg = (tc[30], tc[31], tc[32], tc[33], tc[34], tc[35], tc[36],
                                                        tc[37], tc[38], tc[39])
    one = np.float32(1.0)
    n_all = np.int32(0)
    n_t = np.int32(0)
    n_c = np.int32(0)
    # views from j0, looped from 0: no negative-index checks, so the loops vectorize
    rt = rt[j0:j1]
    ru = ru[j0:j1]
    rv = rv[j0:j1]
    rx = rx[j0:j1]
    ry = ry[j0:j1]
    colf = colf[j0:j1]
    cand = cand[j0:j1]
    lc, ls, hc, hs, mc, ms, kc, ks = ln[0], ln[1], ln[2], ln[3], ln[4], ln[5], ln[6], ln[7]
    if extra:
        rtup = rtup[j0:j1]
    if general:
        for j in range(j1 - j0):
            t = rt[j]
            u = ru[j]
            v = rv[j]
            in_t = (t >= ta) & (t <= tb)
            in_all = in_t & (u >= ua) & (u <= ub) & (v >= va) & (v <= vb)
            if extra:
                in_all = (in_all & (t >= lc + ls * u) & (t <= hc + hs * u) & (t >= mc + ms * v)
                          & (t <= kc + ks * v) & (((mk >> np.uint64(rtup[j])) & np.uint64(1)) != 0))
            x = (fpx0 + colf[j]) + rx[j]
            y = fy + ry[j]
            X0 = _at(X00, dX0, LX0, dLX0, t, u)
            Y0 = _at(Y00, dY0, LY0, dLY0, t, v)
            W0 = W00 + t * dW0
            X1 = _at(X01, dX1, LX1, dLX1, t, u)
            Y1 = _at(Y01, dY1, LY1, dLY1, t, v)
            W1 = W01 + t * dW1
            X2 = _at(X02, dX2, LX2, dLX2, t, u)
            Y2 = _at(Y02, dY2, LY2, dLY2, t, v)
            W2 = W02 + t * dW2
            a0, b0, c0, a1, b1, c1, a2, b2, c2, D = _edges(X0, Y0, W0, X1, Y1, W1, X2, Y2, W2)
            sg = one if D > 0 else -one
            e0 = (a0 * x + b0 * y + c0) * sg
            e1 = (a1 * x + b1 * y + c1) * sg
            e2 = (a2 * x + b2 * y + c2) * sg
            m = e0 if e0 < e1 else e1
            m = m if m < e2 else e2
            c = in_all & (m >= neps)
            cand[j] = c
            n_all += np.int32(in_all)
            n_t += np.int32(in_t)
            n_c += np.int32(c)
    else:
        for j in range(j1 - j0):
            t = rt[j]
            u = ru[j]
            v = rv[j]
            in_t = (t >= ta) & (t <= tb)
            in_all = in_t & (u >= ua) & (u <= ub) & (v >= va) & (v <= vb)
            x = (fpx0 + colf[j]) + rx[j]
            y = fy + ry[j]
            e0 = (sa0 * x + sb0 * y + sc0) * ssg
            e1 = (sa1 * x + sb1 * y + sc1) * ssg
            e2 = (sa2 * x + sb2 * y + sc2) * ssg
            m = e0 if e0 < e1 else e1
            m = m if m < e2 else e2
            c = in_all & (m >= neps)
            cand[j] = c
            n_all += np.int32(in_all)
            n_t += np.int32(in_t)
            n_c += np.int32(c)
    return n_all, n_t, n_c


@nb.njit(cache=True)
def sample_test_kernel(tri_ids, tile_x, tile_y, t_lo, t_hi, u_lo, u_hi, v_lo, v_hi, z_lo, z_hi, noread_in,
                       lines, masks, tile_size, width, height, spp, sx, sy, su, sv, st, stup,
                       p0, dp, l0, dl, edge_eps, backface_culling, specialize,
                       out_tri, out_pix, out_sidx, out_z, out_b0, out_b1, out_b2, out_noread, ops, events):
    """Interval lookup on the tile's samples and exact inside tests (002 §5; 004 eq. 3, 10-13).

    Per tile row, a branch-free first pass over the row's contiguous samples
    computes the interval test (t in t^, u in u^, v in v^) and the float32
    edge functions, and keeps as candidates the samples in the intervals that
    no edge excludes by more than the float32 error bound; numba vectorizes
    it. The second pass runs the full decision (``_decide``: float64 re-test
    near edges, top-left ties, depth) on the candidates only. A static,
    pinhole triangle gets its edge functions once per tile (a 2D test per
    sample); a moving or defocused one computes its vertices at each sample's
    (t, u, v). All paths compute bit-identical vertex values, so neighbours on
    different paths stay watertight. The modelled hardware looks the t-range
    up with a binary search on the t-ordered samples; its compares are
    counted as such.
    """
    n = 0
    tested = 0
    by_dims = np.zeros(4, np.int64)
    in_range = 0
    pixels = 0
    searches = 0
    row_len = tile_size * spp
    cand = np.zeros(row_len, np.uint8)
    colf = np.empty(row_len, np.float32)  # pixel column offset of each sample in a tile row
    for j in range(row_len):
        colf[j] = np.float32(j // spp)
    one = np.float32(1.0)
    tc = np.empty(40, np.float32)  # the current triangle's constants
    iv = np.empty(6, np.float32)  # the current tile's intervals
    ln = np.empty(8, np.float32)  # the current tile's time lines (two-stage culling)
    has_lines = lines.shape[0] == tri_ids.shape[0]
    has_masks = masks.shape[0] == tri_ids.shape[0]
    extra_tests = 0
    for i in range(tri_ids.shape[0]):
        tri = tri_ids[i]
        ta = _f32_at_least(t_lo[i])
        tb = _f32_at_most(t_hi[i])
        ua = _f32_at_least(u_lo[i])
        ub = _f32_at_most(u_hi[i])
        va = _f32_at_least(v_lo[i])
        vb = _f32_at_most(v_hi[i])
        za = np.float32(z_lo[i])
        zb = np.float32(z_hi[i])
        eps = edge_eps[tri]
        neps = -eps
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
        lens = LX0 != 0 or LX1 != 0 or LX2 != 0 or LY0 != 0 or LY1 != 0 or LY2 != 0
        # the dimensions this triangle uses: 0 = 2D, 1 = xyt, 2 = xyuv, 3 = xyuvt
        dims = (1 if moving else 0) + (2 if lens else 0)
        general = dims != 0 or not specialize
        # two-stage lines and tuple masks matter only where t, u or v do
        extra = (has_lines or has_masks) and general
        mk = masks[i] if has_masks else np.uint64(0xFFFFFFFFFFFFFFFF)
        if has_lines:
            for c_ in range(8):
                ln[c_] = lines[i, c_]
        else:
            ln[0], ln[1], ln[2], ln[3], ln[4], ln[5], ln[6], ln[7] = 0, 0, 1, 0, 0, 0, 1, 0
        # 2D path: vertices and edges once per tile (t, u, v do not matter)
        sa0, sb0, sc0, sa1, sb1, sc1, sa2, sb2, sc2, sD = _edges(X00, Y00, W00, X01, Y01, W01, X02, Y02, W02)
        for c_, val in enumerate((X00, X01, X02, Y00, Y01, Y02, W00, W01, W02, dX0, dX1, dX2, dY0, dY1, dY2,
                                  dW0, dW1, dW2, LX0, LX1, LX2, LY0, LY1, LY2, dLX0, dLX1, dLX2, dLY0, dLY1,
                                  dLY2, sa0, sb0, sc0, sa1, sb1, sc1, sa2, sb2, sc2)):
            tc[c_] = val
        tc[39] = one if sD > 0 else -one
        iv[0], iv[1], iv[2], iv[3], iv[4], iv[5] = ta, tb, ua, ub, va, vb
        full_t = t_lo[i] <= 0.0 and t_hi[i] >= 1.0
        px0 = tile_x[i] * tile_size
        px1 = min(px0 + tile_size, width)
        fpx0 = np.float32(px0)
        length = (px1 - px0) * spp
        for py in range(tile_y[i] * tile_size, min((tile_y[i] + 1) * tile_size, height)):
            start = (py * width + px0) * spp
            fy = np.float32(py)
            pixels += px1 - px0
            if not full_t:
                searches += px1 - px0
            row_tested = np.int32(0)  # int32: an int64 counter halves the vector width
            row_range = np.int32(0)
            row_cand = np.int32(0)
            # ---- pass 1: interval and float32 edge tests, marking candidates --
            rt = st[start:start + length]
            ru = su[start:start + length]
            rv = sv[start:start + length]
            rx = sx[start:start + length]
            ry = sy[start:start + length]
            # one branch-free loop over the whole row, which numba vectorizes: on a
            # CPU that beats a per-pixel range lookup even for narrow t^ (the
            # modelled hardware's lookups are still counted as such)
            rtup = stup[start:start + length] if has_masks else stup
            row_tested, row_range, row_cand = _mark(0, length, general, extra, rt, ru, rv, rx, ry, rtup, colf,
                                                    cand, fpx0, fy, iv, ln, mk, neps, tc)
            if extra:
                extra_tests += row_range
            tested += row_tested
            by_dims[dims if specialize else 3] += row_tested
            in_range += row_range
            if row_cand == 0:
                continue
            # ---- pass 2: the full decision on the candidates ----------------
            for j in range(length):
                if cand[j] == 0:
                    continue
                k = start + j
                t = st[k]
                u = su[k]
                v = sv[k]
                x = (fpx0 + colf[j]) + sx[k]
                y = fy + sy[k]
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
                                            W1, Z1, X2, Y2, W2, Z2, x, y, backface_culling, eps)
                if ok:
                    pix = py * width + px0 + j // spp
                    # the true depth lies in z^; clamping removes float32 rounding
                    # so z-cull decisions made on z^ agree with the ROP's
                    out_tri[n] = tri
                    out_pix[n] = pix
                    out_sidx[n] = j % spp
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
    # per sample in t^: four time lines (4 madd + 4 compares) or a mask bit (1 compare)
    ops[OP_MADD] += extra_tests * (4 if has_lines else 0)
    ops[OP_CMP] += extra_tests * (4 if has_lines else 1)
    events[EV_TESTED] += tested
    for d_ in range(4):
        events[EV_2D + d_] += by_dims[d_]
    events[EV_INRANGE] += in_range
    events[EV_PIXELS] += pixels
    events[EV_COVERED] += n
    return n


_NO_LINES = np.zeros((0, 8), np.float32)
_NO_MASKS = np.zeros(0, np.uint64)
_NO_TUPLES = np.zeros(1, np.int8)


class SampleTester:
    """Functional model of the sample tester unit."""

    name = "sample_tester"
    events = EVENTS

    def __init__(self, config, table, samples, tile_size: int, backface_culling: bool, specialize: bool = True):
        self.config = config
        self.specialize = specialize
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
                               tiles["z_hi"], tiles["noread"], tiles.get("lines", _NO_LINES),
                               tiles.get("mask", _NO_MASKS),
                               ts, s.width, s.height, s.spp, s.x, s.y, s.u, s.v, s.t,
                               s.tup if s.tup is not None else _NO_TUPLES,
                               t.p0_32, t.dp_32, t.l0_32, t.dl_32, t.edge_eps, self.backface_culling,
                               self.specialize,
                               out["tri"], out["pix"], out["sidx"], out["z"], out["b0"], out["b1"],
                               out["b2"], out["noread"], ops, events)
        tested = events[EV_TESTED]
        for d_ in range(4):
            ops[OP_MADD] += events[EV_2D + d_] * TEST_OPS_MADD[d_]
            ops[OP_MUL] += events[EV_2D + d_] * TEST_OPS_MUL[d_]
        ops[OP_CMP] += tested * 4
        ops[OP_RCP] += m * COVER_OPS_RCP
        ops[OP_MUL] += m * COVER_OPS_MUL
        ops[OP_MADD] += m * COVER_OPS_MADD
        return {k: v[:m].copy() for k, v in out.items()}, ops, events
