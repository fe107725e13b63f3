"""Independent float64 reference renderer for pipeline-sim tests.

Deliberately simple and *independent* of the pipeline's algorithms:

* no 2D-homogeneous edge functions: each triangle is clipped as a polygon in
  clip space (Sutherland-Hodgman against the OpenGL near plane ``z >= -w`` and
  far plane ``z <= w``), perspective-divided, fan-triangulated, and every
  sample's barycentric coordinates are obtained by solving the 2x2 linear
  system in NDC with Cramer's rule;
* attributes are interpolated perspective-correctly (``attr/w`` and ``1/w``
  are interpolated linearly in screen space); depth ``z_ndc = z/w`` is
  interpolated linearly in screen space.

Conventions (shared with the pipeline):

* vertices are clip-space ``(x, y, z, w)``; motion is linear in clip space,
  ``p(t) = (1-t) q + t r``; the thin lens displaces clip-space x/y by
  ``u * lerp(lens_x, t)`` and ``v * lerp(lens_y, t)``;
* image has ``height`` rows x ``width`` cols, row 0 at the top; a sample of
  pixel (row i, col j) with offset (dx, dy) lies at ``x_pix = j + dx``,
  ``y_pix = i + dy`` (from the top), ``x_ndc = 2 x_pix / width - 1``,
  ``y_ndc = 1 - 2 y_pix / height``;
* depth test LESS on ``z_ndc``, triangles processed in index order so the
  earlier triangle wins ties;
* front-facing = counter-clockwise in NDC (y up), i.e. positive signed area of
  the clipped polygon in NDC.

Coverage of a sample lying *exactly* on a triangle edge is inclusive (closed
triangles; no top-left rule).  Tests comparing against a pipeline that uses a
fill rule should avoid samples exactly on edges (random offsets do so with
probability one).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    "clip_polygon",
    "render_static",
    "accumulation_render",
    "stratified_points",
    "positions_at",
    "exact_time_coverage",
    "point_coverage",
]


# --------------------------------------------------------------------------- #
# clipping
# --------------------------------------------------------------------------- #
def _plane_dist(v: np.ndarray, which: int) -> float:
    # which == 0: near plane z + w >= 0 ; which == 1: far plane w - z >= 0
    if which == 0:
        return float(v[2] + v[3])
    return float(v[3] - v[2])


def clip_polygon(verts: np.ndarray) -> np.ndarray:
    """Sutherland-Hodgman clip of a convex polygon against near/far planes.

    ``verts`` is (M, 4 + C): clip-space position followed by C attributes,
    all interpolated linearly in clip space along clipped edges (correct for
    perspective-correct attributes).  Returns (M', 4 + C), possibly empty.
    """
    poly = [np.asarray(v, dtype=np.float64) for v in verts]
    for which in (0, 1):
        if not poly:
            break
        out = []
        m = len(poly)
        for k in range(m):
            cur = poly[k]
            nxt = poly[(k + 1) % m]
            dc = _plane_dist(cur, which)
            dn = _plane_dist(nxt, which)
            if dc >= 0.0:
                out.append(cur)
            if (dc >= 0.0) != (dn >= 0.0):
                s = dc / (dc - dn)
                out.append(cur + s * (nxt - cur))
        poly = out
    if not poly:
        return np.zeros((0, verts.shape[1]))
    return np.array(poly)


# --------------------------------------------------------------------------- #
# static rendering
# --------------------------------------------------------------------------- #
def _sample_ndc(width: int, height: int, offsets):
    off = np.asarray(offsets, dtype=np.float64)
    jj, ii = np.meshgrid(np.arange(width, dtype=np.float64),
                         np.arange(height, dtype=np.float64))
    if off.shape == (2,):
        xp = jj + off[0]
        yp = ii + off[1]
    elif off.shape == (height, width, 2):
        xp = jj + off[..., 0]
        yp = ii + off[..., 1]
    else:
        raise ValueError(f"offsets must be (2,) or ({height},{width},2), got {off.shape}")
    X = 2.0 * xp / width - 1.0
    Y = 1.0 - 2.0 * yp / height
    return X, Y


def render_static(tris_clip, colors, width, height, offsets=(0.5, 0.5), *,
                  cull_backfaces=False, background=(0, 0, 0)):
    """Render clip-space triangles with one sample per pixel.

    tris_clip: (N,3,4) clip-space vertices; colors: (N,3,C) per-vertex
    attributes (C=3 for RGB, but any C works; None = no attributes); offsets:
    (dx,dy) for every pixel, or an (H,W,2) array.  Returns (image (H,W,C),
    triangle id (H,W) int64 with -1 = none, depth z_ndc (H,W) with +inf = none).
    """
    tris = np.asarray(tris_clip, dtype=np.float64).reshape(-1, 3, 4)
    n = tris.shape[0]
    if colors is None:
        cols = np.zeros((n, 3, 3))
    else:
        cols = np.asarray(colors, dtype=np.float64)
        if cols.ndim == 2:
            cols = cols[:, :, None]
        cols = cols.reshape(n, 3, -1)
    nc = cols.shape[2]

    X, Y = _sample_ndc(width, height, offsets)
    depth = np.full((height, width), np.inf)
    tid = np.full((height, width), -1, dtype=np.int64)
    img = np.zeros((height, width, nc))

    # ---- per-triangle setup, vectorized over triangles (no-clip fast path)
    wv = tris[..., 3]
    near = tris[..., 2] + wv          # >= 0 inside near plane
    far = wv - tris[..., 2]           # >= 0 inside far plane
    trivially_out = (near < 0).all(1) | (far < 0).all(1)
    fully_in = (near >= 0).all(1) & (far >= 0).all(1) & (wv > 0).all(1)
    with np.errstate(divide="ignore", invalid="ignore"):
        iw_all = 1.0 / wv
        px_all = (tris[..., 0] * iw_all).tolist()
        py_all = (tris[..., 1] * iw_all).tolist()
        pz_all = (tris[..., 2] * iw_all).tolist()
        pa_all = cols * iw_all[..., None]
    iw_list = iw_all.tolist()
    sx = 0.5 * width
    sy = 0.5 * height

    for k in range(n):
        if trivially_out[k]:
            continue
        if fully_in[k]:
            px, py, pz, iw = px_all[k], py_all[k], pz_all[k], iw_list[k]
            pa = pa_all[k]
        else:
            poly = clip_polygon(np.concatenate([tris[k], cols[k]], axis=1))
            if poly.shape[0] < 3:
                continue
            w = poly[:, 3]
            if not np.all(w > 0):
                continue  # polygon touches the eye point (w == 0): degenerate
            iwa = 1.0 / w
            px = (poly[:, 0] * iwa).tolist()
            py = (poly[:, 1] * iwa).tolist()
            pz = (poly[:, 2] * iwa).tolist()
            pa = poly[:, 4:] * iwa[:, None]
            iw = iwa.tolist()
        m_ = len(px)
        if not all(math.isfinite(c) for c in px + py):
            continue
        # signed area in NDC (shoelace); > 0 = CCW = front facing
        area2 = 0.0
        for e in range(m_):
            area2 += px[e] * py[(e + 1) % m_] - px[(e + 1) % m_] * py[e]
        if area2 == 0.0:
            continue
        if cull_backfaces and area2 < 0.0:
            continue

        # bounding box in pixel space -> candidate pixels (offsets in [0,1))
        xmin = (min(px) + 1.0) * sx
        xmax = (max(px) + 1.0) * sx
        ymin = (1.0 - max(py)) * sy
        ymax = (1.0 - min(py)) * sy
        j0 = min(max(math.floor(xmin) - 1, 0), width)
        j1 = min(max(math.floor(xmax) + 1, 0), width)
        i0 = min(max(math.floor(ymin) - 1, 0), height)
        i1 = min(max(math.floor(ymax) + 1, 0), height)
        if j0 >= j1 or i0 >= i1:
            continue
        Xs = X[i0:i1, j0:j1]
        Ys = Y[i0:i1, j0:j1]
        dslice = depth[i0:i1, j0:j1]

        # fan triangulation of the convex clipped polygon
        for f in range(1, m_ - 1):
            a, b, c = 0, f, f + 1
            e1x, e1y = px[b] - px[a], py[b] - py[a]
            e2x, e2y = px[c] - px[a], py[c] - py[a]
            det = e1x * e2y - e1y * e2x
            if det == 0.0:
                continue
            rx = Xs - px[a]
            ry = Ys - py[a]
            # Cramer's rule for  l1 * e1 + l2 * e2 = (rx, ry)
            l1 = (rx * e2y - ry * e2x) / det
            l2 = (e1x * ry - e1y * rx) / det
            l0 = 1.0 - l1 - l2
            inside = (l0 >= 0.0) & (l1 >= 0.0) & (l2 >= 0.0)
            z = l0 * pz[a] + l1 * pz[b] + l2 * pz[c]
            m = inside & (z < dslice)
            if not m.any():
                continue
            L0, L1, L2 = l0[m], l1[m], l2[m]
            inv_w = L0 * iw[a] + L1 * iw[b] + L2 * iw[c]
            attr = (L0[:, None] * pa[a] + L1[:, None] * pa[b]
                    + L2[:, None] * pa[c]) / inv_w[:, None]
            dslice[m] = z[m]
            tid[i0:i1, j0:j1][m] = k
            img[i0:i1, j0:j1][m] = attr

    bg = np.asarray(background, dtype=np.float64).ravel()
    if bg.size not in (1, nc):
        if np.all(bg == bg[0]):
            bg = bg[:1]  # e.g. default (0,0,0) with non-RGB attributes
        else:
            raise ValueError(f"background has {bg.size} channels, attributes have {nc}")
    bg = np.broadcast_to(bg, (nc,))
    img[tid < 0] = bg
    return img, tid, depth


# --------------------------------------------------------------------------- #
# 5D accumulation
# --------------------------------------------------------------------------- #
def positions_at(q, r, lens_x, lens_y, t, u, v):
    """Clip-space vertices (N,3,4) at time t and lens position (u, v)."""
    q = np.asarray(q, dtype=np.float64)
    r = np.asarray(r, dtype=np.float64)
    p = (1.0 - t) * q + t * r
    if lens_x is not None or lens_y is not None:
        p = p.copy()
    if lens_x is not None:
        lx = np.asarray(lens_x, dtype=np.float64)
        p[..., 0] += u * ((1.0 - t) * lx[..., 0] + t * lx[..., 1])
    if lens_y is not None:
        ly = np.asarray(lens_y, dtype=np.float64)
        p[..., 1] += v * ((1.0 - t) * ly[..., 0] + t * ly[..., 1])
    return p


def accumulation_render(q, r, lens_x, lens_y, colors, width, height, points, *,
                        cull_backfaces=False, background=(0, 0, 0)):
    """Average of one static render per 5D point (dx, dy, t, u, v)."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 5)
    acc = None
    for dx, dy, t, u, v in pts:
        tris = positions_at(q, r, lens_x, lens_y, t, u, v)
        img, _, _ = render_static(tris, colors, width, height, (dx, dy),
                                  cull_backfaces=cull_backfaces,
                                  background=background)
        acc = img if acc is None else acc + img
    return acc / len(pts)


def stratified_points(k: int, seed: int, *, motion: bool, lens: bool) -> np.ndarray:
    """K jointly low-discrepancy points (dx, dy, t, u, v).

    Scrambled 5D Sobol (use a power of two for K for the best balance);
    (u, v) are mapped to the unit disk with the polar sqrt map.  t = 0.5 when
    ``motion`` is False; u = v = 0 when ``lens`` is False.
    """
    import warnings
    from scipy.stats import qmc

    sob = qmc.Sobol(d=5, scramble=True, seed=seed)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # non power-of-two balance warning
        s = sob.random(k)
    out = np.empty((k, 5))
    out[:, 0:2] = s[:, 0:2]
    out[:, 2] = s[:, 2] if motion else 0.5
    if lens:
        rad = np.sqrt(s[:, 3])
        th = 2.0 * np.pi * s[:, 4]
        out[:, 3] = rad * np.cos(th)
        out[:, 4] = rad * np.sin(th)
    else:
        out[:, 3:5] = 0.0
    return out


# --------------------------------------------------------------------------- #
# helpers for checking analytic time intervals
# --------------------------------------------------------------------------- #
def point_coverage(tri_clip, px, py, width, height, *, cull_backfaces=False):
    """True if the pixel-space point (px, py) (from top) is covered by the
    single clip-space triangle ``tri_clip`` (3,4), using render_static on a
    1x1 'image' window.  (Image size fixes the NDC mapping.)"""
    # shift the NDC mapping so that the point lies in a 1x1 image
    j = np.floor(px)
    i = np.floor(py)
    tri = np.asarray(tri_clip, dtype=np.float64).reshape(1, 3, 4).copy()
    # map full-image NDC to the NDC of a 1x1 image whose pixel is (i, j):
    # x1 = 2*(x_pix - j) - 1 with x_pix = (x_ndc + 1) * width / 2
    w = tri[..., 3]
    xn = tri[..., 0]
    yn = tri[..., 1]
    tri[..., 0] = ((xn + w) * width / 2 - j * w) * 2 - w
    tri[..., 1] = w - 2 * ((w - yn) * height / 2 - i * w)
    _, tid, _ = render_static(tri, np.zeros((1, 3, 1)), 1, 1, (px - j, py - i),
                              cull_backfaces=cull_backfaces)
    return bool(tid[0, 0] == 0)


def exact_time_coverage(q, r, px, py, n=4096, *, width, height,
                        lens_x=None, lens_y=None, u=0.0, v=0.0,
                        cull_backfaces=False):
    """Fraction of the shutter [0,1] during which pixel point (px, py)
    (pixel coordinates from the top) is covered by one moving triangle
    (q, r: (3,4)), estimated by n midpoint samples in t."""
    q = np.asarray(q, dtype=np.float64).reshape(1, 3, 4)
    r = np.asarray(r, dtype=np.float64).reshape(1, 3, 4)
    lx = None if lens_x is None else np.asarray(lens_x, dtype=np.float64).reshape(1, 3, 2)
    ly = None if lens_y is None else np.asarray(lens_y, dtype=np.float64).reshape(1, 3, 2)
    ts = (np.arange(n) + 0.5) / n
    hits = 0
    for t in ts:
        tri = positions_at(q, r, lx, ly, t, u, v)[0]
        hits += point_coverage(tri, px, py, width, height,
                               cull_backfaces=cull_backfaces)
    return hits / n
