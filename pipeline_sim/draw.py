"""From a scene to a draw: clip-space triangles at shutter open and close.

A ``Draw`` is the input of triangle setup, kept as structure of arrays. Each
vertex is given in homogeneous clip space at t=0 (``q``) and t=1 (``r``);
between them it moves linearly (docs/pipeline.md §1). With a thin lens the vertex
seen from lens position (u, v) in the unit disk moves by
(u * lens_x, v * lens_y) in clip x and y, where the circle of confusion is
linear in clip w (Wu13 §3.1): for a lens of radius R focused at distance F,
lens_x = P[0,0] * R * (w / F - 1) and lens_y = P[1,1] * R * (w / F - 1)
(shifting the pinhole by (uR, vR) and shearing the frustum so the focus plane
stays fixed).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline_sim.errors import UserError
from pipeline_sim.pass_state import ClipPlanes
from pipeline_sim.scene import MAX_COORDINATE

MATERIAL_IDS = {"flat": 0, "lambert": 1}
#: What a draw's occlusion query counts (docs/passes.md): "samples", its samples passing the depth test
#: (the draw renders as usual); "interval", whether z-cull's boxes can hide it (Nilsson12 §3: the draw's
#: tile records are compared with the boxes and render nothing).
QUERY_MODES = ("samples", "interval")


@dataclass
class Draw:
    """Clip-space triangles and their shading attributes (structure of arrays).

    Shapes: ``q``, ``r`` (N,3,4) float64 clip (x, y, z, w); ``lens_x``,
    ``lens_y`` (N,3,2) float64 clip shift per unit lens coordinate at t=0 and
    t=1; ``pos`` and ``nrm`` (2,N,3,3) float32 world position and normal at
    t=0 and t=1; ``color`` (N,3,3) float32; ``material`` (N,) int32;
    ``object_id`` (N,) int32. ``depth_w`` = (c1, c0) when every vertex's
    depth is z/w = c1 + c0 / w (a perspective projection, c0 < 0): it lets
    the tile test turn bounds on w into bounds on depth (Nilsson12 App. A).
    ``clip``: the draw's own user clip planes (None: its pass state's); ``query``: its occlusion
    query, one of ``QUERY_MODES``.
    """

    q: np.ndarray
    r: np.ndarray
    lens_x: np.ndarray
    lens_y: np.ndarray
    pos: np.ndarray
    nrm: np.ndarray
    color: np.ndarray
    material: np.ndarray
    object_id: np.ndarray
    width: int
    height: int
    depth_w: tuple[float, float] | None = None
    clip: ClipPlanes | None = None
    query: str = "samples"

    @property
    def n(self) -> int:
        return int(self.q.shape[0])

    @property
    def has_motion(self) -> bool:
        return bool(np.any(self.q != self.r))

    @property
    def has_lens(self) -> bool:
        return bool(np.any(self.lens_x != 0) or np.any(self.lens_y != 0))


def merge_draws(draws: list[Draw], where: str) -> tuple[Draw, np.ndarray]:
    """The draws of one pass as one draw, in submission order (draw 0's triangles first), and each
    triangle's draw index (int32). The draws share the frame size; ``depth_w`` is kept when they share
    it, and the clip planes are the caller's, per draw (``where``: the pass, for errors)."""
    if len(draws) == 1:
        return draws[0], np.zeros(draws[0].n, np.int32)
    if not draws or len({(d.width, d.height) for d in draws}) != 1:
        raise UserError(f"{where}: a pass needs at least one draw, and its draws one frame size")
    tri_draw = np.concatenate([np.full(d.n, i, np.int32) for i, d in enumerate(draws)])
    pos, nrm = (np.concatenate([getattr(d, k) for d in draws], axis=1) for k in ("pos", "nrm"))
    merged = {k: np.concatenate([getattr(d, k) for d in draws])
              for k in ("q", "r", "lens_x", "lens_y", "color", "material", "object_id")}
    depth_w = draws[0].depth_w if len({d.depth_w for d in draws}) == 1 else None
    return Draw(pos=pos, nrm=nrm, width=draws[0].width, height=draws[0].height, depth_w=depth_w, **merged), tri_draw


def lens_shift(proj: np.ndarray, w: np.ndarray, radius: float, focus: float) -> tuple[np.ndarray, np.ndarray]:
    """Clip-space x and y shift per unit lens coordinate for vertices at depth ``w``."""
    coc = radius * (w / focus - 1.0)
    return proj[0, 0] * coc, proj[1, 1] * coc


def _check_range(where: str, what: str, values: np.ndarray) -> None:
    """Refuse a value beyond +-MAX_COORDINATE (or not finite), naming it."""
    bad = np.flatnonzero(~(np.abs(values) <= MAX_COORDINATE))
    if len(bad):
        v = values.reshape(-1)[bad[0]]
        found = f"reaches {v:g}" if np.isfinite(v) else "overflows"
        raise UserError(f"{where}: {what} {found}, beyond +-{MAX_COORDINATE:g} (half the float32 range the "
                        "pipeline computes in)")


def build_draw(scene) -> Draw:
    """Transform every object of ``scene`` to clip space at t=0 and t=1.

    Every world position, clip coordinate and lens shift must lie within
    +-``MAX_COORDINATE`` (else a :class:`UserError` names the object)."""
    img = scene.image
    cam = scene.camera
    proj = cam.projection_matrix(img.width / img.height)
    views = [cam.view_matrix(0.0), cam.view_matrix(1.0)]
    where = scene.path or "scene"
    qs, rs, pos, nrm, col, mat, oid = [], [], [[], []], [[], []], [], [], []
    for index, obj in enumerate(scene.objects):
        faces = np.asarray(obj.faces, dtype=np.int64)
        for t in (0, 1):
            shutter = ("open", "close")[t]
            with np.errstate(over="ignore", invalid="ignore"):  # an overflow is refused just below
                world = obj.world_positions(t)
                hom = np.concatenate([world, np.ones((len(world), 1))], axis=1)
                clip = hom @ (proj @ views[t]).T
            _check_range(f"{where}: objects[{index}] ('{obj.name}')", f"a world coordinate at shutter {shutter}", world)
            _check_range(f"{where}: objects[{index}] ('{obj.name}')",
                         f"a clip coordinate (seen by the camera) at shutter {shutter}", clip)
            (qs if t == 0 else rs).append(clip[faces])
            pos[t].append(world[faces])
            nrm[t].append(obj.world_normals(t)[faces])
        col.append(np.asarray(obj.colors, dtype=np.float32)[faces])
        mat.append(np.full(len(faces), MATERIAL_IDS[obj.material], dtype=np.int32))
        oid.append(np.full(len(faces), index, dtype=np.int32))
    if not qs:
        raise UserError(f"{where}: the scene has no triangles")
    q = np.concatenate(qs)
    r = np.concatenate(rs)
    n = len(q)
    lens_x = np.zeros((n, 3, 2))
    lens_y = np.zeros((n, 3, 2))
    if cam.lens is not None and cam.lens.radius > 0:
        with np.errstate(over="ignore"):  # an overflow is refused just below
            for t, verts in enumerate((q, r)):
                lens_x[:, :, t], lens_y[:, :, t] = lens_shift(
                    proj, verts[:, :, 3], cam.lens.radius, cam.lens.focus_distance
                )
        _check_range(f"{where}: camera.lens", "a vertex's lens shift (radius * (w / focus_distance - 1), clip units)",
                     np.stack([lens_x, lens_y]))
    return Draw(
        q=q,
        r=r,
        lens_x=lens_x,
        lens_y=lens_y,
        pos=np.stack([np.concatenate(pos[0]), np.concatenate(pos[1])]).astype(np.float32),
        nrm=np.stack([np.concatenate(nrm[0]), np.concatenate(nrm[1])]).astype(np.float32),
        color=np.concatenate(col),
        material=np.concatenate(mat),
        object_id=np.concatenate(oid),
        width=img.width,
        height=img.height,
        depth_w=(float(-proj[2, 2]), float(proj[2, 3])) if cam.projection == "perspective" else None,
    )


def draw_from_world(world0: np.ndarray, world1: np.ndarray, proj: np.ndarray, view: np.ndarray | None = None, *,
                    width: int, height: int, lens_radius: float | tuple[float, float] = 0.0,
                    focus: float = np.inf, lens_point: tuple[float, float] | None = None, color=None) -> Draw:
    """A draw of world-space triangles (N, 3, 3) at shutter open and close, seen through the eye->clip
    ``proj`` after the world->eye ``view`` (None: the world is eye space), as ``build_draw`` makes a
    static camera's: clip coordinates, the thin lens's clip shifts (``lens_shift``; Wu13 §3.1) for a lens
    of ``lens_radius`` (or (x, y) half sizes of an oblong lens) focused at ``focus`` (inf: a constant
    shift, cameras translated parallel to the image plane), and ``depth_w`` of a perspective ``proj``.
    ``lens_point``: one fixed lens point (u, v), folded into the vertices (a 2D draw, no lens shift).
    Positions, normals and materials are ``draw_from_clip``'s; callers with world attributes replace them."""
    matrix = proj if view is None else proj @ view
    clip = [np.concatenate([w, np.ones(w.shape[:-1] + (1,))], axis=-1) @ matrix.T for w in (world0, world1)]
    n = len(world0)
    rx, ry = (lens_radius, lens_radius) if np.ndim(lens_radius) == 0 else lens_radius
    shift = np.zeros((2, n, 3, 2))
    for t in (0, 1):
        if rx > 0:
            shift[0, :, :, t] = lens_shift(proj, clip[t][..., 3], rx, focus)[0]
        if ry > 0:
            shift[1, :, :, t] = lens_shift(proj, clip[t][..., 3], ry, focus)[1]
    if lens_point is not None:
        for t in (0, 1):
            clip[t][..., 0] += lens_point[0] * shift[0, :, :, t]
            clip[t][..., 1] += lens_point[1] * shift[1, :, :, t]
        shift[:] = 0.0
    draw = draw_from_clip(clip[0], clip[1], shift[0], shift[1], color=color, width=width, height=height)
    draw.depth_w = (float(-proj[2, 2]), float(proj[2, 3])) if proj[3, 3] == 0 else None
    return draw


def draw_from_clip(q, r=None, lens_x=None, lens_y=None, color=None, width=64, height=64) -> Draw:
    """A draw made directly from clip-space triangles (tests, workloads)."""
    q = np.asarray(q, dtype=np.float64).reshape(-1, 3, 4)
    r = q.copy() if r is None else np.asarray(r, dtype=np.float64).reshape(-1, 3, 4)
    n = len(q)
    lx = np.zeros((n, 3, 2)) if lens_x is None else np.asarray(lens_x, dtype=np.float64).reshape(n, 3, 2)
    ly = np.zeros((n, 3, 2)) if lens_y is None else np.asarray(lens_y, dtype=np.float64).reshape(n, 3, 2)
    if color is None:
        color = np.ones((n, 3, 3), dtype=np.float32)
    color = np.broadcast_to(np.asarray(color, dtype=np.float32).reshape(-1, 3, 3) if np.ndim(color) == 3
                            else np.asarray(color, dtype=np.float32).reshape(n, 1, 3), (n, 3, 3)).copy()
    pos = np.stack([q[:, :, :3], r[:, :, :3]]).astype(np.float32)
    nrm = np.zeros_like(pos)
    nrm[..., 2] = 1.0
    return Draw(q=q, r=r, lens_x=lx, lens_y=ly, pos=pos, nrm=nrm, color=color,
                material=np.zeros(n, dtype=np.int32), object_id=np.zeros(n, dtype=np.int32),
                width=width, height=height)
