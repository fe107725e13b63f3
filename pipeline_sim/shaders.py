"""Shaders: numba-compiled Python functions run by the shading unit.

A shader shades a batch of shading points at once::

    @numba.njit(cache=True, nogil=True)
    def my_shader(inputs, params, textures, out, append):
        # inputs:   float32[N_INPUTS, K], one row per input named in INPUTS
        # params:   float32[:], the pass's shader parameters
        # textures: a tuple of float32[H, W, L] arrays, the pass's textures in the order it names them
        #           (an earlier pass's resolved image, L = its channels; its per-sample data or depth,
        #           one layer per sample index; any array); empty when it names none
        # out:      float32[K, C], the pass's shader outputs side by side (default one RGBA "color")
        # append:   the pass's append buffer, for append_record
        for i in range(inputs.shape[1]):
            out[i, 0] = inputs[IN_R, i]
            ...

Lookup helpers: ``sample_layer`` (bilinear on one layer), ``fetch`` (one
texel), ``sample_texture`` (bilinear RGBA), ``project`` (a point through a
4x4 matrix among the parameters, to texture coordinates: one matrix per
layer of a texture array gives a per-tuple projection), ``compare_layer``
(a depth comparison over a texel neighbourhood, percentage-closer);
``append_record`` appends a record to the append buffer.

A pass may run its shader on a thread of shading's own (``simulation.run_ahead``),
its batches in order and one at a time, as on the main thread: a shader must
compute from its arguments only (not numba's ``np.random``, whose state is
per thread, nor state kept between calls), and ``nogil=True`` lets it run
beside the other units.

Workloads bring their own shaders in the same form. In standard mode the
inputs describe the surface point (world position, normal, color at the
shading time) and the sample; in conservative mode (Nilsson12 §2) the shader runs
once per (triangle, pixel) and also receives the tile intervals
(u^, v^, t^, z^).
"""

from __future__ import annotations

import numba as nb
import numpy as np

# the input layout is the shading unit's; shaders, a workload's own too, take all of it from here
from pipeline_sim.definitions import (IN_B, IN_DEPTH, IN_G, IN_MATERIAL, IN_NX, IN_NY, IN_NZ, IN_OBJECT, IN_PX,
                                      IN_PY, IN_PZ, IN_R, IN_T, IN_T_HI, IN_T_LO, IN_TRIANGLE, IN_U, IN_U_HI,
                                      IN_U_LO, IN_V, IN_V_HI, IN_V_LO, IN_X, IN_Y, IN_Z_HI, IN_Z_LO, INPUTS,
                                      N_INPUTS, IN_SAMPLE, IN_TUPLE)

# parameters of the standard shader
LIGHT_DIRECTIONAL, LIGHT_POINT = 0.0, 1.0
STANDARD_PARAMS = ("light_kind", "light_x", "light_y", "light_z", "light_r", "light_g", "light_b", "ambient")


def standard_params(light) -> np.ndarray:
    """Parameters of ``standard_shader`` for a scene light."""
    kind = LIGHT_DIRECTIONAL if light.kind == "directional" else LIGHT_POINT
    vec = light.direction if light.kind == "directional" else light.position
    rgb = np.asarray(light.color, dtype=np.float64) * light.intensity
    return np.array([kind, *vec, *rgb, light.ambient], dtype=np.float32)


@nb.njit(cache=True, nogil=True)
def standard_shader(inputs, params, textures, out, append):
    """Flat (material 0: unlit color) or Lambert (material 1) with one light."""
    kind = params[0]
    for i in range(inputs.shape[1]):
        r = inputs[IN_R, i]
        g = inputs[IN_G, i]
        b = inputs[IN_B, i]
        if inputs[IN_MATERIAL, i] == 0.0:
            out[i, 0] = r
            out[i, 1] = g
            out[i, 2] = b
            out[i, 3] = 1.0
            continue
        if kind == LIGHT_DIRECTIONAL:
            lx, ly, lz = -params[1], -params[2], -params[3]
            atten = np.float32(1.0)
        else:
            lx = params[1] - inputs[IN_PX, i]
            ly = params[2] - inputs[IN_PY, i]
            lz = params[3] - inputs[IN_PZ, i]
            d2 = lx * lx + ly * ly + lz * lz
            atten = np.float32(1.0) / max(d2, np.float32(1e-12))  # <= 1e12: scene.MAX_RADIANCE's bound needs it
        ln = np.sqrt(lx * lx + ly * ly + lz * lz)
        if ln > 0:
            lx, ly, lz = lx / ln, ly / ln, lz / ln
        ndl = max(np.float32(0.0), inputs[IN_NX, i] * lx + inputs[IN_NY, i] * ly + inputs[IN_NZ, i] * lz)
        amb = params[7]
        out[i, 0] = r * (amb + params[4] * ndl * atten)
        out[i, 1] = g * (amb + params[5] * ndl * atten)
        out[i, 2] = b * (amb + params[6] * ndl * atten)
        out[i, 3] = 1.0


@nb.njit(cache=True, nogil=True)
def depth_shader(inputs, params, textures, out, append):
    """Writes the sample depth z/w to every channel (depth and shadow maps)."""
    for i in range(inputs.shape[1]):
        d = inputs[IN_DEPTH, i]
        out[i, 0] = d
        out[i, 1] = d
        out[i, 2] = d
        out[i, 3] = 1.0


@nb.njit(cache=True, nogil=True)
def interval_shader(inputs, params, textures, out, append):
    """Conservative mode: writes (t_lo, z_lo, t_hi, z_hi) of the pixel's tile test
    (the tz-box of Nilsson12 §3 continuous collision detection)."""
    for i in range(inputs.shape[1]):
        out[i, 0] = inputs[IN_T_LO, i]
        out[i, 1] = inputs[IN_Z_LO, i]
        out[i, 2] = inputs[IN_T_HI, i]
        out[i, 3] = inputs[IN_Z_HI, i]


@nb.njit(cache=True)
def sample_layer(texture, layer, s, t):
    """Bilinear lookup of layer ``layer`` of ``texture`` (H, W, L) at (s, t) in [0, 1]^2, t=0 at the top
    row, texel centres at half-integers; clamps at the border."""
    h = texture.shape[0]
    w = texture.shape[1]
    x = min(max(s * w - 0.5, 0.0), w - 1.0)
    y = min(max(t * h - 0.5, 0.0), h - 1.0)
    x0 = int(x)
    y0 = int(y)
    x1 = min(x0 + 1, w - 1)
    y1 = min(y0 + 1, h - 1)
    fx = x - x0
    fy = y - y0
    top = texture[y0, x0, layer] * (1 - fx) + texture[y0, x1, layer] * fx
    bot = texture[y1, x0, layer] * (1 - fx) + texture[y1, x1, layer] * fx
    return top * (1 - fy) + bot * fy


@nb.njit(cache=True)
def fetch(texture, x, y, layer):
    """Texel (column ``x``, row ``y``) of layer ``layer`` of ``texture`` (H, W, L), no filtering; the
    coordinates are clamped to the texture."""
    return texture[min(max(int(y), 0), texture.shape[0] - 1), min(max(int(x), 0), texture.shape[1] - 1), layer]


@nb.njit(cache=True)
def project(params, base, px, py, pz):
    """The point (px, py, pz) through the 4x4 matrix held row-major in ``params[base:base + 16]`` (clip
    space of a camera that rendered a texture): returns (s, t, z/w, w), (s, t) the texture coordinates of
    ``sample_layer`` (t=0 at the top row; [0, 1]^2 inside the frame). With one matrix per layer of a
    texture array at ``base = first + 16 * k``, layer k's own projection (Nilsson12 §7)."""
    x = params[base] * px + params[base + 1] * py + params[base + 2] * pz + params[base + 3]
    y = params[base + 4] * px + params[base + 5] * py + params[base + 6] * pz + params[base + 7]
    z = params[base + 8] * px + params[base + 9] * py + params[base + 10] * pz + params[base + 11]
    w = params[base + 12] * px + params[base + 13] * py + params[base + 14] * pz + params[base + 15]
    return 0.5 * (x / w + 1.0), 0.5 * (1.0 - y / w), z / w, w


@nb.njit(cache=True)
def compare_layer(texture, layer, s, t, ref, radius):
    """The share of the (2 radius + 1)^2 texels of layer ``layer`` around the one holding (s, t) (each
    clamped to the texture, as ``fetch``; (s, t) too, NaN as 0) whose value is at least ``ref``: a
    depth-map test, lit where ``ref`` is not behind the stored depth, percentage-closer filtered for
    ``radius`` > 0."""
    cx = int((min(s, 1.0) if s > 0.0 else 0.0) * texture.shape[1])
    cy = int((min(t, 1.0) if t > 0.0 else 0.0) * texture.shape[0])
    passed = 0
    for dy in range(-radius, radius + 1):
        for dx in range(-radius, radius + 1):
            if ref <= fetch(texture, cx + dx, cy + dy, layer):
                passed += 1
    return passed / (2 * radius + 1) ** 2


@nb.njit(cache=True)
def sample_texture(texture, s, t):
    """Bilinear RGBA lookup (``sample_layer`` of layers 0-3) at (s, t). Returns a 4-tuple."""
    return (sample_layer(texture, 0, s, t), sample_layer(texture, 1, s, t), sample_layer(texture, 2, s, t),
            sample_layer(texture, 3, s, t))


@nb.njit(cache=True)
def append_record(append, values):
    """Append one record (``values``: as many as the buffer has fields) to the pass's append buffer
    (Nilsson12 §5). Records are kept in the order they are appended; beyond the capacity an append is
    only counted (the overflow)."""
    records, count = append
    i = count[0]
    count[0] = i + 1
    if i < records.shape[0]:
        for f in range(records.shape[1]):
            records[i, f] = values[f]
