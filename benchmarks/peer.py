"""The accumulation-buffer peer of section 11: Mesa's llvmpipe through moderngl on EGL.

The 2D rasterizer a user would reach for instead of 5D rasterization renders
the project's own draw (the same clip-space triangles, lens shifts, normals,
colours and light) once per 5D sample point (x, y, t, u, v) and averages the
passes (Haeberli and Akeley's accumulation buffer): each pass moves every
vertex to time t, shifts it by the lens position (u, v) exactly as the sample
tester does (X + u LX, docs/pipeline.md §2.5) and offsets the frame by the
sub-pixel position (x, y), so that OpenGL's pixel-centre sample lands where
the project's sample (col + x, row + y) lies. The points are scrambled 5D
Sobol points (scipy.stats.qmc), the lens mapped to the disk like the
project's. Shading is the project's standard shader (flat or Lambert with one
light) evaluated per fragment, so the converged image is close to, not the
same as, the project's (whose default shading is cached); each renderer's
error is therefore taken against its own converged image.

moderngl is an optional benchmark dependency (``pip install -e '.[bench]'``);
without it, or without an EGL display (Mesa's libEGL), the section reports
why and skips the peer.
"""

from __future__ import annotations

import time

import numpy as np

VERTEX = """
#version 330
in vec4 q; in vec4 dq; in vec2 l0; in vec2 dl;
in vec3 p0; in vec3 dp; in vec3 n0; in vec3 dn; in vec3 col; in float mat;
uniform float t; uniform vec2 lens; uniform vec2 offset;
out vec3 wpos; out vec3 wnrm; out vec3 vcol; flat out float vmat;
void main() {
    vec4 c = q + t * dq;
    c.xy += lens * (l0 + t * dl);
    c.xy += offset * c.w;
    gl_Position = c;
    wpos = p0 + t * dp; wnrm = n0 + t * dn; vcol = col; vmat = mat;
}
"""
FRAGMENT = """
#version 330
in vec3 wpos; in vec3 wnrm; in vec3 vcol; flat in float vmat;
uniform vec4 light; uniform vec3 rgb; uniform float ambient;
out vec4 colour;
void main() {
    if (vmat == 0.0) { colour = vec4(vcol, 1.0); return; }
    vec3 l = light.w == 0.0 ? -light.xyz : light.xyz - wpos;
    float atten = light.w == 0.0 ? 1.0 : 1.0 / max(dot(l, l), 1e-12);
    float ndl = max(0.0, dot(normalize(wnrm), normalize(l)));
    colour = vec4(vcol * (ambient + rgb * ndl * atten), 1.0);
}
"""


def sobol_points(n: int, seed: int) -> np.ndarray:
    """(n, 5) scrambled Sobol points, columns x, y, t, u, v with (u, v) on the unit disk."""
    import warnings

    from scipy.stats import qmc

    from pipeline_sim.sampling import concentric_disk

    with warnings.catch_warnings():  # a count that is not a power of two loses balance; allowed
        warnings.simplefilter("ignore", UserWarning)
        pts = qmc.Sobol(d=5, scramble=True, seed=seed).random(n)
    u, v = concentric_disk(pts[:, 3], pts[:, 4])
    return np.stack([pts[:, 0], pts[:, 1], pts[:, 2], u, v], axis=1)


class Peer:
    """An OpenGL context (``ctx``) rendering pass ``p``'s draw as an accumulation buffer."""

    def __init__(self, p, ctx) -> None:
        from pipeline_sim.shaders import LIGHT_DIRECTIONAL

        self.ctx = ctx
        self.renderer = self.ctx.info["GL_RENDERER"]
        d = p.draw
        self.w, self.h = d.width, d.height
        n3 = d.n * 3
        parts = {
            "q": d.q, "dq": d.r - d.q,
            "l0": np.stack([d.lens_x[..., 0], d.lens_y[..., 0]], axis=-1),
            "dl": np.stack([d.lens_x[..., 1] - d.lens_x[..., 0], d.lens_y[..., 1] - d.lens_y[..., 0]], axis=-1),
            "p0": d.pos[0], "dp": d.pos[1] - d.pos[0], "n0": d.nrm[0], "dn": d.nrm[1] - d.nrm[0],
            "col": d.color, "mat": np.repeat(d.material[:, None], 3, axis=1)[..., None],
        }
        data = np.concatenate([np.asarray(a, np.float64).reshape(n3, -1) for a in parts.values()], axis=1)
        fmt = " ".join(f"{np.asarray(a).reshape(n3, -1).shape[1]}f" for a in parts.values())
        self.prog = self.ctx.program(vertex_shader=VERTEX, fragment_shader=FRAGMENT)
        self.vbo = self.ctx.buffer(data.astype(np.float32).tobytes())
        self.vao = self.ctx.vertex_array(self.prog, [(self.vbo, fmt, *parts)])
        self.fbo = self.ctx.framebuffer(color_attachments=[self.ctx.renderbuffer((self.w, self.h), 4, dtype="f4")],
                                        depth_attachment=self.ctx.depth_renderbuffer((self.w, self.h)))
        prm = np.asarray(p.params, np.float64)
        self.prog["light"].value = (*prm[1:4], 0.0 if prm[0] == LIGHT_DIRECTIONAL else 1.0)
        self.prog["rgb"].value = tuple(prm[4:7])
        self.prog["ambient"].value = float(prm[7])
        self.clear = tuple(float(c) for c in p.clear_color)

    def render(self, points: np.ndarray, ref: np.ndarray | None = None) -> tuple[np.ndarray, list[float]]:
        """Average of one pass per point (rows x, y, t, u, v): (H, W, 3) float64, top row first;
        with ``ref``, also the RMSE of the running average against it after each pass."""
        self.fbo.use()
        self.ctx.enable(self.ctx.DEPTH_TEST)
        acc = np.zeros((self.h, self.w, 3))
        errs = []
        for i, (x, y, t, u, v) in enumerate(points):
            self.fbo.clear(*self.clear, depth=1.0)
            self.prog["t"].value = float(t)
            self.prog["lens"].value = (float(u), float(v))
            # GL samples a pixel at its centre; move the frame so that the centre sees (col + x, row + y)
            self.prog["offset"].value = (-(x - 0.5) * 2.0 / self.w, (y - 0.5) * 2.0 / self.h)
            self.vao.render()
            img = np.frombuffer(self.fbo.read(components=4, dtype="f4"), np.float32).reshape(self.h, self.w, 4)
            acc += img[::-1, :, :3]
            if ref is not None:
                errs.append(float(np.sqrt(np.mean((acc / (i + 1) - ref) ** 2))))
        return acc / max(1, len(points)), errs

    def release(self) -> None:
        self.ctx.release()


def open_peer(p) -> tuple[Peer | None, str]:
    """A peer for pass ``p``, or None and the reason none could be made (a shader or
    buffer error once a context exists is a bug, and raises)."""
    try:
        import moderngl
    except ImportError as exc:
        return None, f"moderngl is not installed ({exc}); pip install -e '.[bench]'"
    try:
        ctx = moderngl.create_standalone_context(backend="egl")
    except Exception as exc:  # no libEGL, no EGL display or no OpenGL 3.3 driver: report and skip
        return None, f"no EGL context: {type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
    return Peer(p, ctx), ""


def time_to_equal_error(peer: Peer, ref: np.ndarray, targets: dict[str, float], max_passes: int,
                        seed: int) -> dict:
    """For each target error: the fewest accumulation passes whose running average is
    within it of the peer's own converged image ``ref``; and the RMSE at every power of two."""
    _, errs = peer.render(sobol_points(max_passes, seed), ref)
    reach = {key: next((n + 1 for n, e in enumerate(errs) if e <= target), None) for key, target in targets.items()}
    return {"passes_to_reach": reach, "rmse_at": {n + 1: e for n, e in enumerate(errs) if (n + 1) & n == 0}}


def timed(peer: Peer, n: int, seed: int) -> float:
    pts = sobol_points(n, seed)
    start = time.perf_counter()
    peer.render(pts)
    return time.perf_counter() - start
