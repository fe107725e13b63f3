"""A bare numba 5D inside-test micro-kernel: the speed limit of one test.

Structure-of-arrays float32 samples (x, y, u, v, t) in pixel units; one
moving, defocused triangle at a time against a block of samples:

* the three vertices lerped in t: X = X0 + t dX, Y = Y0 + t dY, W = W0 + t dW,
  then shifted by the lens: X += u LX, Y += v LY (pixel-space 2D homogeneous);
* three 2DH edge functions e_k = (p_j x p_i) . (x, y, 1) and the orientation
  D = p0 . (p2 x p1);
* inside when every e_k has the sign of D (no top-left tie rule, no depth).

It follows the shapes PERFORMANCE.md recommends: float32 throughout, an int32
accumulator (``cnt = np.int32(cnt + ...)``: numba types ``cnt += np.int32(...)``
as int64), loops that start at 0, no structured arrays. Single-threaded,
like the pipeline's sample tester kernel, and without fastmath (the pipeline's
kernel uses none either).
"""

from __future__ import annotations

import time

import numba as nb
import numpy as np

F32 = np.float32


@nb.njit(cache=True)
def count_inside(x, y, u, v, t, vx, vy, vw, dx, dy, dw, lx, ly):
    """For each triangle i (rows of the (T, 3) arrays), count the samples inside it.

    Returns an int32 array of T counts; every triangle is tested against every
    sample of the block (T * len(x) tests).
    """
    n_tri = vx.shape[0]
    n = x.shape[0]
    counts = np.zeros(n_tri, np.int32)
    zero = np.float32(0.0)
    for i in range(n_tri):
        x0, x1, x2 = vx[i, 0], vx[i, 1], vx[i, 2]
        y0, y1, y2 = vy[i, 0], vy[i, 1], vy[i, 2]
        w0, w1, w2 = vw[i, 0], vw[i, 1], vw[i, 2]
        dx0, dx1, dx2 = dx[i, 0], dx[i, 1], dx[i, 2]
        dy0, dy1, dy2 = dy[i, 0], dy[i, 1], dy[i, 2]
        dw0, dw1, dw2 = dw[i, 0], dw[i, 1], dw[i, 2]
        lx0, lx1, lx2 = lx[i, 0], lx[i, 1], lx[i, 2]
        ly0, ly1, ly2 = ly[i, 0], ly[i, 1], ly[i, 2]
        cnt = np.int32(0)
        for s in range(n):
            ts = t[s]
            us = u[s]
            vs = v[s]
            X0 = x0 + ts * dx0 + us * lx0
            Y0 = y0 + ts * dy0 + vs * ly0
            W0 = w0 + ts * dw0
            X1 = x1 + ts * dx1 + us * lx1
            Y1 = y1 + ts * dy1 + vs * ly1
            W1 = w1 + ts * dw1
            X2 = x2 + ts * dx2 + us * lx2
            Y2 = y2 + ts * dy2 + vs * ly2
            W2 = w2 + ts * dw2
            # edge k opposite vertex k: n_k = p_j x p_i, (i, j) = (k+1, k+2) mod 3
            a0 = Y2 * W1 - W2 * Y1
            b0 = W2 * X1 - X2 * W1
            c0 = X2 * Y1 - Y2 * X1
            a1 = Y0 * W2 - W0 * Y2
            b1 = W0 * X2 - X0 * W2
            c1 = X0 * Y2 - Y0 * X2
            a2 = Y1 * W0 - W1 * Y0
            b2 = W1 * X0 - X1 * W0
            c2 = X1 * Y0 - Y1 * X0
            xs = x[s]
            ys = y[s]
            e0 = a0 * xs + b0 * ys + c0
            e1 = a1 * xs + b1 * ys + c1
            e2 = a2 * xs + b2 * ys + c2
            d = X0 * a0 + Y0 * b0 + W0 * c0
            pos = (e0 >= zero) & (e1 >= zero) & (e2 >= zero) & (d > zero)
            neg = (e0 <= zero) & (e1 <= zero) & (e2 <= zero) & (d < zero)
            cnt = np.int32(cnt + np.int32(pos | neg))  # (cnt += ... would widen cnt to int64)
        counts[i] = cnt
    return counts


def make_block(n_samples: int = 4096, side: int = 16, seed: int = 0):
    """Samples spread over a ``side`` x ``side`` pixel square, lens in [-1,1]^2, t in [0,1)."""
    rng = np.random.default_rng(seed)
    x = rng.uniform(0, side, n_samples).astype(F32)
    y = rng.uniform(0, side, n_samples).astype(F32)
    u = rng.uniform(-1, 1, n_samples).astype(F32)
    v = rng.uniform(-1, 1, n_samples).astype(F32)
    t = np.sort(rng.uniform(0, 1, n_samples)).astype(F32)
    return x, y, u, v, t


def make_triangles(n_tri: int, side: int = 16, seed: int = 1):
    """Random moving, defocused triangles over the block, in pixel-space 2DH (X = x W)."""
    rng = np.random.default_rng(seed)
    sx = rng.uniform(-0.25 * side, 1.25 * side, (n_tri, 3))
    sy = rng.uniform(-0.25 * side, 1.25 * side, (n_tri, 3))
    w = rng.uniform(1.0, 3.0, (n_tri, 3))
    mx = rng.uniform(-0.3, 0.3, (n_tri, 1)) * side
    my = rng.uniform(-0.3, 0.3, (n_tri, 1)) * side
    w1 = w * rng.uniform(0.8, 1.25, (n_tri, 3))
    coc = rng.uniform(0.0, 0.2, (n_tri, 3)) * side
    vx, vy, vw = sx * w, sy * w, w
    dx, dy, dw = (sx + mx) * w1 - vx, (sy + my) * w1 - vy, w1 - w
    lx, ly = coc * w, coc * w
    return tuple(np.ascontiguousarray(a, dtype=F32) for a in (vx, vy, vw, dx, dy, dw, lx, ly))


def reference_count(block, tris, i: int) -> int:
    """numpy float64 version of the same test for triangle ``i`` (a correctness check)."""
    x, y, u, v, t = (a.astype(np.float64) for a in block)
    vx, vy, vw, dx, dy, dw, lx, ly = (a[i].astype(np.float64) for a in tris)
    X = vx[:, None] + t * dx[:, None] + u * lx[:, None]
    Y = vy[:, None] + t * dy[:, None] + v * ly[:, None]
    W = vw[:, None] + t * dw[:, None]
    e = []
    for k in range(3):
        i1, j = (k + 1) % 3, (k + 2) % 3
        a = Y[j] * W[i1] - W[j] * Y[i1]
        b = W[j] * X[i1] - X[j] * W[i1]
        c = X[j] * Y[i1] - Y[j] * X[i1]
        e.append((a * x + b * y + c, a, b, c))
    d = X[0] * e[0][1] + Y[0] * e[0][2] + W[0] * e[0][3]
    ee = np.stack([q[0] for q in e])
    pos = (ee >= 0).all(axis=0) & (d > 0)
    neg = (ee <= 0).all(axis=0) & (d < 0)
    return int((pos | neg).sum())


def measure(n_tests: int, n_samples: int = 4096, repeats: int = 5) -> dict:
    """Median rate of ``count_inside`` over about ``n_tests`` tests (one triangle vs n_samples each)."""
    block = make_block(n_samples)
    n_tri = max(1, -(-n_tests // n_samples))
    tris = make_triangles(n_tri)
    count_inside(*block, *(a[:1] for a in tris))  # compile or load from cache
    # correctness: the float32 kernel against float64 numpy on a few triangles (ties may differ by a few)
    small = count_inside(*block, *(a[:8] for a in tris))
    ref = [reference_count(block, tris, i) for i in range(min(8, n_tri))]
    mismatch = int(sum(abs(int(a) - b) for a, b in zip(small, ref)))
    times, cpu = [], []
    counts = None
    for _ in range(repeats):
        t0 = time.perf_counter()
        c0 = time.process_time()
        counts = count_inside(*block, *tris)
        cpu.append(time.process_time() - c0)
        times.append(time.perf_counter() - t0)
    tests = n_tri * n_samples
    med = float(np.median(times))
    cmed = float(np.median(cpu))
    return {
        "tests": tests, "triangles": n_tri, "samples_per_triangle": n_samples, "times_s": times,
        "median_s": med, "tests_per_s": tests / med, "cpu_times_s": cpu, "cpu_median_s": cmed,
        "tests_per_cpu_s": tests / cmed, "coverage": float(counts.sum()) / tests,
        "check_mismatch_vs_float64": mismatch, "check_tests": int(min(8, n_tri) * n_samples),
    }


# ---------------------------------------------------------------------------
# Bare kernels per dimension over (triangle, sample list) records
#
# The same inside test specialized like the pipeline's sample tester paths:
# 2D (edge functions once per record), xyt (vertices lerped in t), xyuv
# (vertices shifted by the lens) and xyuvt (both, with the lens shift itself
# lerped in t: X = X0 + t dX + u (LX + t dLX), as in the pipeline's 5D test).
# Record r tests triangle ``rec_tri[r]`` against the samples
# ``[rec_off[r], rec_off[r + 1])`` of the structure-of-arrays x, y (absolute
# pixel coordinates), u, v, t; ``p0, dp`` are (T, 3, 4) and ``l0, dl``
# (T, 3, 2) float32 pixel-space 2DH vertices, as in the triangle table.
# Returns the int32 count of inside samples per record.
# benchmarks/tester_speed.py feeds them exactly the samples the sample tester
# counts as tested.


@nb.njit(cache=True, inline="always")
def _inside(x, y, X0, Y0, W0, X1, Y1, W1, X2, Y2, W2):
    a0 = Y2 * W1 - W2 * Y1
    b0 = W2 * X1 - X2 * W1
    c0 = X2 * Y1 - Y2 * X1
    a1 = Y0 * W2 - W0 * Y2
    b1 = W0 * X2 - X0 * W2
    c1 = X0 * Y2 - Y0 * X2
    a2 = Y1 * W0 - W1 * Y0
    b2 = W1 * X0 - X1 * W0
    c2 = X1 * Y0 - Y1 * X0
    e0 = a0 * x + b0 * y + c0
    e1 = a1 * x + b1 * y + c1
    e2 = a2 * x + b2 * y + c2
    d = X0 * a0 + Y0 * b0 + W0 * c0
    zero = np.float32(0.0)
    pos = (e0 >= zero) & (e1 >= zero) & (e2 >= zero) & (d > zero)
    neg = (e0 <= zero) & (e1 <= zero) & (e2 <= zero) & (d < zero)
    return np.int32(pos | neg)


@nb.njit(cache=True)
def count_records_2d(rec_tri, rec_off, x, y, u, v, t, p0, dp, l0, dl):
    counts = np.zeros(rec_tri.shape[0], np.int32)
    zero = np.float32(0.0)
    for r in range(rec_tri.shape[0]):
        i = rec_tri[r]
        X0, Y0, W0 = p0[i, 0, 0], p0[i, 0, 1], p0[i, 0, 3]
        X1, Y1, W1 = p0[i, 1, 0], p0[i, 1, 1], p0[i, 1, 3]
        X2, Y2, W2 = p0[i, 2, 0], p0[i, 2, 1], p0[i, 2, 3]
        a0 = Y2 * W1 - W2 * Y1
        b0 = W2 * X1 - X2 * W1
        c0 = X2 * Y1 - Y2 * X1
        a1 = Y0 * W2 - W0 * Y2
        b1 = W0 * X2 - X0 * W2
        c1 = X0 * Y2 - Y0 * X2
        a2 = Y1 * W0 - W1 * Y0
        b2 = W1 * X0 - X1 * W0
        c2 = X1 * Y0 - Y1 * X0
        d = X0 * a0 + Y0 * b0 + W0 * c0
        dpos = d > zero
        dneg = d < zero
        o0, o1 = rec_off[r], rec_off[r + 1]
        xs = x[o0:o1]
        ys = y[o0:o1]
        cnt = np.int32(0)
        for s in range(o1 - o0):
            e0 = a0 * xs[s] + b0 * ys[s] + c0
            e1 = a1 * xs[s] + b1 * ys[s] + c1
            e2 = a2 * xs[s] + b2 * ys[s] + c2
            pos = (e0 >= zero) & (e1 >= zero) & (e2 >= zero) & dpos
            neg = (e0 <= zero) & (e1 <= zero) & (e2 <= zero) & dneg
            cnt = np.int32(cnt + np.int32(pos | neg))
        counts[r] = cnt
    return counts


@nb.njit(cache=True)
def count_records_xyt(rec_tri, rec_off, x, y, u, v, t, p0, dp, l0, dl):
    counts = np.zeros(rec_tri.shape[0], np.int32)
    for r in range(rec_tri.shape[0]):
        i = rec_tri[r]
        x0, y0, w0 = p0[i, 0, 0], p0[i, 0, 1], p0[i, 0, 3]
        x1, y1, w1 = p0[i, 1, 0], p0[i, 1, 1], p0[i, 1, 3]
        x2, y2, w2 = p0[i, 2, 0], p0[i, 2, 1], p0[i, 2, 3]
        dx0, dy0, dw0 = dp[i, 0, 0], dp[i, 0, 1], dp[i, 0, 3]
        dx1, dy1, dw1 = dp[i, 1, 0], dp[i, 1, 1], dp[i, 1, 3]
        dx2, dy2, dw2 = dp[i, 2, 0], dp[i, 2, 1], dp[i, 2, 3]
        o0, o1 = rec_off[r], rec_off[r + 1]
        xs = x[o0:o1]
        ys = y[o0:o1]
        ts = t[o0:o1]
        cnt = np.int32(0)
        for s in range(o1 - o0):
            tt = ts[s]
            cnt = np.int32(cnt + _inside(xs[s], ys[s], x0 + tt * dx0, y0 + tt * dy0, w0 + tt * dw0, x1 + tt * dx1,
                           y1 + tt * dy1, w1 + tt * dw1, x2 + tt * dx2, y2 + tt * dy2, w2 + tt * dw2))
        counts[r] = cnt
    return counts


@nb.njit(cache=True)
def count_records_xyuv(rec_tri, rec_off, x, y, u, v, t, p0, dp, l0, dl):
    counts = np.zeros(rec_tri.shape[0], np.int32)
    for r in range(rec_tri.shape[0]):
        i = rec_tri[r]
        x0, y0, w0 = p0[i, 0, 0], p0[i, 0, 1], p0[i, 0, 3]
        x1, y1, w1 = p0[i, 1, 0], p0[i, 1, 1], p0[i, 1, 3]
        x2, y2, w2 = p0[i, 2, 0], p0[i, 2, 1], p0[i, 2, 3]
        lx0, ly0 = l0[i, 0, 0], l0[i, 0, 1]
        lx1, ly1 = l0[i, 1, 0], l0[i, 1, 1]
        lx2, ly2 = l0[i, 2, 0], l0[i, 2, 1]
        o0, o1 = rec_off[r], rec_off[r + 1]
        xs = x[o0:o1]
        ys = y[o0:o1]
        us = u[o0:o1]
        vs = v[o0:o1]
        cnt = np.int32(0)
        for s in range(o1 - o0):
            uu = us[s]
            vv = vs[s]
            cnt = np.int32(cnt + _inside(xs[s], ys[s], x0 + uu * lx0, y0 + vv * ly0, w0, x1 + uu * lx1,
                                         y1 + vv * ly1, w1, x2 + uu * lx2, y2 + vv * ly2, w2))
        counts[r] = cnt
    return counts


@nb.njit(cache=True)
def count_records_xyuvt(rec_tri, rec_off, x, y, u, v, t, p0, dp, l0, dl):
    counts = np.zeros(rec_tri.shape[0], np.int32)
    for r in range(rec_tri.shape[0]):
        i = rec_tri[r]
        x0, y0, w0 = p0[i, 0, 0], p0[i, 0, 1], p0[i, 0, 3]
        x1, y1, w1 = p0[i, 1, 0], p0[i, 1, 1], p0[i, 1, 3]
        x2, y2, w2 = p0[i, 2, 0], p0[i, 2, 1], p0[i, 2, 3]
        dx0, dy0, dw0 = dp[i, 0, 0], dp[i, 0, 1], dp[i, 0, 3]
        dx1, dy1, dw1 = dp[i, 1, 0], dp[i, 1, 1], dp[i, 1, 3]
        dx2, dy2, dw2 = dp[i, 2, 0], dp[i, 2, 1], dp[i, 2, 3]
        lx0, ly0, dlx0, dly0 = l0[i, 0, 0], l0[i, 0, 1], dl[i, 0, 0], dl[i, 0, 1]
        lx1, ly1, dlx1, dly1 = l0[i, 1, 0], l0[i, 1, 1], dl[i, 1, 0], dl[i, 1, 1]
        lx2, ly2, dlx2, dly2 = l0[i, 2, 0], l0[i, 2, 1], dl[i, 2, 0], dl[i, 2, 1]
        o0, o1 = rec_off[r], rec_off[r + 1]
        xs = x[o0:o1]
        ys = y[o0:o1]
        us = u[o0:o1]
        vs = v[o0:o1]
        ts = t[o0:o1]
        cnt = np.int32(0)
        for s in range(o1 - o0):
            tt = ts[s]
            uu = us[s]
            vv = vs[s]
            cnt = np.int32(cnt + _inside(xs[s], ys[s], x0 + tt * dx0 + uu * (lx0 + tt * dlx0),
                                         y0 + tt * dy0 + vv * (ly0 + tt * dly0), w0 + tt * dw0,
                                         x1 + tt * dx1 + uu * (lx1 + tt * dlx1),
                                         y1 + tt * dy1 + vv * (ly1 + tt * dly1), w1 + tt * dw1,
                                         x2 + tt * dx2 + uu * (lx2 + tt * dlx2),
                                         y2 + tt * dy2 + vv * (ly2 + tt * dly2), w2 + tt * dw2))
        counts[r] = cnt
    return counts


RECORD_KERNELS = (count_records_2d, count_records_xyt, count_records_xyuv, count_records_xyuvt)
