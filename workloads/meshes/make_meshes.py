"""Regenerate the small example meshes in this directory (one per format).

Run: python workloads/meshes/make_meshes.py
Loaded by workloads/scenes/meshes.toml and tests/test_scene.py.
"""

from pathlib import Path

import numpy as np
import trimesh

HERE = Path(__file__).resolve().parent


def main() -> None:
    # OBJ with vertex normals (the loader uses the file's normals).
    sphere = trimesh.creation.icosphere(subdivisions=1, radius=0.5)
    sphere.vertex_normals  # noqa: B018  (computes and caches normals so they are exported)
    (HERE / "icosphere.obj").write_text(
        trimesh.exchange.obj.export_obj(sphere, include_normals=True, digits=6)
    )

    # Binary PLY with per-vertex colours, no normals (smooth normals computed on load).
    torus = trimesh.creation.torus(major_radius=0.45, minor_radius=0.18, major_sections=16, minor_sections=8)
    v = torus.vertices
    rgb = np.stack([0.5 + v[:, 0], 0.5 + v[:, 1], 0.5 + 2.0 * v[:, 2]], axis=1).clip(0.0, 1.0)
    torus.visual.vertex_colors = np.column_stack([rgb * 255.0, np.full(len(v), 255.0)]).round().astype(np.uint8)
    (HERE / "torus_colors.ply").write_bytes(trimesh.exchange.ply.export_ply(torus, encoding="binary"))

    # Binary STL: unshared vertices per triangle, no normals per vertex.
    cylinder = trimesh.creation.cylinder(radius=0.35, height=1.0, sections=24)
    (HERE / "cylinder.stl").write_bytes(trimesh.exchange.stl.export_stl(cylinder))

    # GLB scene with two nodes whose transforms must be applied when flattening:
    # a cone (axis +z) turned to point up +y and lifted, and a capsule beside it.
    scene = trimesh.Scene()
    cone_tf = trimesh.transformations.rotation_matrix(-np.pi / 2.0, [1.0, 0.0, 0.0])
    cone_tf[:3, 3] = [-0.35, 0.0, 0.0]
    scene.add_geometry(
        trimesh.creation.cone(radius=0.3, height=0.8, sections=20), node_name="cone", geom_name="cone", transform=cone_tf
    )
    capsule_tf = np.eye(4)
    capsule_tf[:3, 3] = [0.4, 0.5, 0.0]
    scene.add_geometry(
        trimesh.creation.capsule(height=0.5, radius=0.2, count=[10, 6]),
        node_name="capsule",
        geom_name="capsule",
        transform=capsule_tf,
    )
    (HERE / "cone_capsule.glb").write_bytes(scene.export(file_type="glb"))


if __name__ == "__main__":
    main()
