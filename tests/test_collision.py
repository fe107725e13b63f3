"""The collision workload (Nilsson12 §3) against python-fcl's exact discrete collision test at dense
times (the meshes' vertices interpolated linearly, as the workload moves them): never a missed
collision, on the shipped scenes and on random small scenes; every union tz-box holds the (t, z) of
densely sampled points of its object; the toaster and ball are told apart by time only; bad input is
one line, exit 2."""

import dataclasses
import json

import fcl
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pipeline_sim.cli import main
from pipeline_sim.config import load_arch
from pipeline_sim.render import run_pass
from pipeline_sim.workload import load_workload
from workloads.apps import collision as C
from runs import ran_file, refused_file

APP = "workloads/apps/collision"
TIMES = np.linspace(0.0, 1.0, 201)


def fcl_object(verts: np.ndarray, faces: np.ndarray) -> fcl.CollisionObject:
    model = fcl.BVHModel()
    model.beginModel(len(verts), len(faces))
    model.addSubModel(verts, faces)
    model.endModel()
    return fcl.CollisionObject(model, fcl.Transform())


def fcl_colliding(a: C.Body, b: C.Body, times=TIMES) -> bool:
    """Whether fcl finds the two meshes in contact at any of ``times``."""
    for t in times:
        contacts = fcl.collide(fcl_object(a.at(t), a.faces), fcl_object(b.at(t), b.faces),
                               fcl.CollisionRequest(), fcl.CollisionResult())
        if contacts:
            return True
    return False


def coplanar_times(p: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Times in [0, 1] at which the four points ``p + t d`` ((4, 3) each) are coplanar: the real roots
    of the cubic det[p1 - p0, p2 - p0, p3 - p0](t), fitted exactly through four times."""
    ts = np.array([0.0, 1 / 3, 2 / 3, 1.0])
    det = [np.linalg.det((p[1:] + t * d[1:]) - (p[0] + t * d[0])) for t in ts]
    coef = np.polyfit(ts, det, 3)
    if np.all(np.abs(coef) < 1e-14):
        return np.zeros(0)   # coplanar throughout: left to the discrete test
    roots = np.roots(np.trim_zeros(np.where(np.abs(coef) < 1e-14, 0.0, coef), "f"))
    real = roots[np.abs(roots.imag) < 1e-9].real
    return real[(real >= -1e-9) & (real <= 1 + 1e-9)]


def point_in_triangle(q: np.ndarray, tri: np.ndarray, eps: float = 1e-7) -> bool:
    e0, e1, v = tri[1] - tri[0], tri[2] - tri[0], q - tri[0]
    g = np.array([[e0 @ e0, e0 @ e1], [e0 @ e1, e1 @ e1]])
    if abs(np.linalg.det(g)) < 1e-18:
        return False
    s, u = np.linalg.solve(g, [v @ e0, v @ e1])
    return s >= -eps and u >= -eps and s + u <= 1 + eps and np.linalg.norm(tri[0] + s * e0 + u * e1 - q) < 1e-6


def segments_meet(a0, a1, b0, b1, eps: float = 1e-7) -> bool:
    da, db, r = a1 - a0, b1 - b0, a0 - b0
    g = np.array([[da @ da, -(da @ db)], [-(da @ db), db @ db]])
    if abs(np.linalg.det(g)) < 1e-18:
        return False
    s, u = np.linalg.solve(g, [-(r @ da), r @ db])
    return -eps <= s <= 1 + eps and -eps <= u <= 1 + eps and np.linalg.norm(a0 + s * da - b0 - u * db) < 1e-6


def exact_contact(a: C.Body, b: C.Body) -> bool:
    """Whether the moving meshes ever touch: a vertex of one meets a triangle of the other, or an edge
    of one an edge of the other, at a root of their coplanarity cubic (linear vertex paths), or they
    intersect at t=0."""
    if fcl_colliding(a, b, [0.0]):
        return True
    def edges(body):
        return {tuple(sorted(e)) for f in body.faces for e in ((f[0], f[1]), (f[1], f[2]), (f[2], f[0]))}
    for m, n in ((a, b), (b, a)):
        dv, dn = m.v1 - m.v0, n.v1 - n.v0
        for v in range(len(m.v0)):
            for f in n.faces:
                p, d = np.vstack([m.v0[v], n.v0[f]]), np.vstack([dv[v], dn[f]])
                if any(point_in_triangle(p[0] + t * d[0], p[1:] + t * d[1:]) for t in coplanar_times(p, d)):
                    return True
    da, db = a.v1 - a.v0, b.v1 - b.v0
    for ea in edges(a):
        for eb in edges(b):
            p, d = np.vstack([a.v0[list(ea)], b.v0[list(eb)]]), np.vstack([da[list(ea)], db[list(eb)]])
            if any(segments_meet(*(p + t * d)) for t in coplanar_times(p, d)):
                return True
    return False


def pcs(results: dict) -> dict[str, set[tuple[str, str]]]:
    return {m: {tuple(p) for p in v["pcs"]} for m, v in results["methods"].items()}


def run_file(root, name: str, tmp_path) -> tuple[C.Collision, dict]:
    path = tmp_path / name
    path.write_text((root / APP / name).read_text())
    w = load_workload(path, load_arch())
    return w, w.run().results


def assert_no_missed_collision(w: C.Collision, results: dict) -> int:
    """Every pair fcl finds colliding is in every method's PCS; returns how many collide."""
    found = pcs(results)
    colliding = 0
    for a, b in zip(*np.triu_indices(len(w.bodies), 1)):
        ba, bb = w.bodies[a], w.bodies[b]
        if C.swept_boxes_meet(ba, bb) and fcl_colliding(ba, bb):
            colliding += 1
            for m, pairs in found.items():
                assert (ba.name, bb.name) in pairs, (m, ba.name, bb.name)
    return colliding


def test_colliding_pair_is_in_every_pcs(root, tmp_path):
    w, results = run_file(root, "collide.toml", tmp_path)
    assert assert_no_missed_collision(w, results) == 1
    assert results["methods"]["tz_union"]["passes"] == 3 and results["methods"]["cullide"]["passes"] == 6


def test_toaster_dodges_the_ball_in_time_only(root, tmp_path):
    w, results = run_file(root, "toaster.toml", tmp_path)
    toaster, ball = w.bodies
    # never in contact (fcl's distance stays positive at every dense time) ...
    gaps = [fcl.distance(fcl_object(toaster.at(t), toaster.faces), fcl_object(ball.at(t), ball.faces),
                         fcl.DistanceRequest(), fcl.DistanceResult()) for t in TIMES]
    assert min(gaps) > 0.1
    # it has two slots: a thin rod put down into each, through the top's plane, touches it only
    # without them
    plain = C.make_body(C.ObjectSpec(shape="rounded_box", size=[0.8, 0.5, 0.6], subdivisions=3,
                                     start=[-1.5, 0.0, 0.0]), 0, "plain")
    for x0, x1, z0, z1 in C.slot_rects(np.array([0.8, 0.5, 0.6]), 2):
        rod = fcl.CollisionObject(fcl.Box(0.02, 0.6, 0.02), fcl.Transform([(x0 + x1) / 2 - 1.5, 0.3, (z0 + z1) / 2]))
        touches = [fcl.collide(rod, fcl_object(body.v0, body.faces), fcl.CollisionRequest(), fcl.CollisionResult())
                   for body in (toaster, plain)]
        assert touches == [0, 1], touches
    # ... while the swept volumes overlap: a point of the ball at t=0 is inside the toaster at t=1
    assert np.all(np.abs(ball.at(0.0).mean(axis=0) - toaster.at(1.0).mean(axis=0)) < [0.8, 0.5, 0.6])
    found = pcs(results)
    assert found["depth_only"] == found["cullide"] == {("toaster", "ball")}
    assert found["tz_union"] == found["tz_fragment"] == set()
    methods = results["methods"]
    assert methods["depth_only"]["passes"] == 3 and methods["cullide"]["passes"] == 6  # z meets in every view
    assert methods["tz_union"]["passes"] < 3 and methods["tz_fragment"]["passes"] < 6


@pytest.mark.parametrize("views", ["pair", "scene"])
def test_many_objects_no_missed_collision(tmp_path, views):
    path = tmp_path / "many.toml"
    path.write_text(f'kind = "collision"\nresolution = {12 if views == "pair" else 48}\nviews = "{views}"\n'
                    '[random]\ncount = 24\nseed = 3\nextent = 3.0\nradius = 0.5\ntravel = 1.5\nsubdivisions = 0\n')
    w = load_workload(path, load_arch())
    results = w.run().results
    assert assert_no_missed_collision(w, results) >= 3
    # a pair a looser test separates, a tighter one separates too: a fragment's tz-box lies inside its
    # object's union box; no pixel has overlapping depths when one object lies wholly in front
    found = pcs(results)
    assert found["tz_fragment"] <= found["tz_union"] <= found["depth_only"] <= found["cullide"]
    assert len(found["cullide"]) <= results["swept_box_pairs"]


vec = st.lists(st.floats(-1.0, 1.0), min_size=3, max_size=3)
speed = st.lists(st.floats(-6.0, 6.0), min_size=3, max_size=3)


@st.composite
def scenes(draw):
    """Two objects near each other, moving little (long contacts), or each passing a point near the
    origin at its own time in [0.2, 0.8], fast (brief contacts, if any)."""
    crossing = draw(st.booleans())
    specs = []
    for i in range(2):
        if crossing:
            middle, velocity, when = np.array(draw(vec)) * 0.5, np.array(draw(speed)), draw(st.floats(0.2, 0.8))
            start, end = list(middle - when * velocity), list(middle + (1 - when) * velocity)
        else:
            start, end = draw(vec), draw(vec)
        specs.append(C.ObjectSpec(shape=draw(st.sampled_from(["icosphere", "rounded_box"])),
                                  size=draw(st.lists(st.floats(0.2, 0.7), min_size=3, max_size=3)),
                                  subdivisions=1, start=start, end=end,
                                  turn=draw(st.lists(st.floats(-90, 90), min_size=3, max_size=3))))
    return specs


@settings(max_examples=60, deadline=None)
@given(specs=scenes())
def test_the_swept_box_cull_keeps_every_pair_in_contact(specs):
    """The pairs the run never draws (swept bounding boxes apart) are never in contact: every vertex at 201
    times lies in its object's swept box, and fcl finds no contact between pairs whose boxes are apart."""
    a, b = (C.make_body(spec, i, "random") for i, spec in enumerate(specs))
    for body in (a, b):
        lo, hi = body.swept_box()
        for t in TIMES:
            assert np.all(body.at(t) >= lo) and np.all(body.at(t) <= hi)
    if not C.swept_boxes_meet(a, b):
        assert not fcl_colliding(a, b)


@settings(max_examples=60, deadline=None)
@given(specs=scenes(), resolution=st.integers(2, 24))
def test_random_pairs_never_miss_a_collision(specs, resolution):
    w = C.Collision("random.toml", load_arch())
    w.resolution = resolution
    w.bodies = [C.make_body(spec, i, "random") for i, spec in enumerate(specs)]
    assert_no_missed_collision(w, w.run().results)


@settings(max_examples=25, deadline=None)
@given(specs=scenes(), resolution=st.integers(2, 24))
def test_scene_views_of_a_pair_decide_as_its_pair_views(specs, resolution):
    """With two objects a scene view is the pair's view (the same box, the same triangles): its tests
    from the appended fragments (per-pixel object lists, numpy) keep exactly the pairs the pair views'
    blended union targets and second fragment pass keep, for every method."""
    found = {}
    for views in ("pair", "scene"):
        w = C.Collision("random.toml", load_arch())
        w.resolution, w.views = resolution, views
        w.bodies = [C.make_body(spec, i, "random") for i, spec in enumerate(specs)]
        found[views] = pcs(w.run().results)
    assert found["pair"] == found["scene"]


@st.composite
def crowds(draw):
    """Five to nine small objects in a 3-unit cube, each moving up to 1.5 units and turning."""
    specs = []
    for i in range(draw(st.integers(5, 9))):
        start = np.array(draw(st.lists(st.floats(0.0, 3.0), min_size=3, max_size=3)))
        step = np.array(draw(st.lists(st.floats(-1.5, 1.5), min_size=3, max_size=3)))
        specs.append(C.ObjectSpec(shape=draw(st.sampled_from(["icosphere", "rounded_box"])), name=f"o{i}",
                                  size=draw(st.lists(st.floats(0.2, 0.6), min_size=3, max_size=3)),
                                  subdivisions=0, start=list(start), end=list(start + step),
                                  turn=draw(st.lists(st.floats(-60, 60), min_size=3, max_size=3))))
    return specs


@settings(max_examples=15, deadline=None)
@given(specs=crowds(), resolution=st.integers(4, 48))
def test_scene_views_never_miss_a_collision(specs, resolution):
    """Many objects, one view per axis over all of them: every pair fcl finds in contact at one of 201
    times is in every method's PCS, and the PCS inclusion order holds."""
    w = C.Collision("crowd.toml", load_arch())
    w.resolution, w.views = resolution, "scene"
    w.bodies = [C.make_body(spec, i, "crowd") for i, spec in enumerate(specs)]
    results = w.run().results
    assert_no_missed_collision(w, results)
    found = pcs(results)
    assert found["tz_fragment"] <= found["tz_union"] <= found["depth_only"] <= found["cullide"]
    assert results["methods"]["tz_union"]["passes"] <= 3


def test_exact_contact_between_dense_times_is_in_every_pcs():
    """A ball crossing 1000 units during the shutter hits a small box between two of the 201 times:
    fcl's dense test misses it, the exact coplanarity-cubic test finds it, and every method keeps it."""
    ball = C.ObjectSpec(shape="icosphere", name="ball", subdivisions=0, size=[1.0, 1.0, 1.0],
                        start=[-501.3, 0.0, 0.0], end=[498.7, 0.0, 0.0])
    box = C.ObjectSpec(shape="rounded_box", name="box", subdivisions=0, size=[0.5, 0.5, 0.5],
                       start=[0.0, 0.3, 0.0], end=[0.0, 0.3, 0.2], turn=[10.0, 20.0, 30.0])
    w = C.Collision("fast.toml", load_arch())
    w.resolution = 16
    w.bodies = [C.make_body(spec, i, "fast") for i, spec in enumerate((ball, box))]
    assert exact_contact(*w.bodies) and not fcl_colliding(*w.bodies)
    found = pcs(w.run().results)
    assert all(("ball", "box") in pairs for pairs in found.values()), found


@settings(max_examples=30, deadline=None)
@given(specs=scenes(), resolution=st.integers(2, 24))
def test_random_small_pairs_never_miss_an_exact_contact(specs, resolution):
    """Small meshes (an icosahedron, a rounded box of one cell per face) against the exact continuous
    test: vertex-triangle and edge-edge contacts at the roots of their coplanarity cubics."""
    w = C.Collision("random.toml", load_arch())
    w.resolution = resolution
    w.bodies = [C.make_body(dataclasses.replace(spec, subdivisions=0), i, "random") for i, spec in enumerate(specs)]
    if exact_contact(*w.bodies):  # the swept-box cull too must keep the pair (a pair never drawn is in no PCS)
        found = pcs(w.run().results)
        assert all((w.bodies[0].name, w.bodies[1].name) in pairs for pairs in found.values()), found


SQUARE = [[-1.0, 0.0, -1.0], [1.0, 0.0, -1.0], [1.0, 0.0, 1.0], [-1.0, 0.0, 1.0]]


def test_flat_sheets_seen_edge_on_collide_in_every_pcs():
    """Two square sheets of two triangles each: one lies still in the plane y = 0, the other stands in
    a plane x = const and sweeps along x through it (they cross for t in [1/3, 2/3]). The first is
    edge-on in the x and z views, the second in the y and z views: a segment of zero area, which still
    touches pixels. Every method keeps the pair (triangle setup drops zero-area triangles only in
    standard mode; it used to drop them in conservative mode too, separating the pair in the x view)."""
    lying = C.ObjectSpec(shape="mesh", name="lying", vertices=SQUARE, faces=[[0, 1, 2], [0, 2, 3]])
    standing = C.ObjectSpec(shape="mesh", name="standing", vertices=[[y, x, z] for x, y, z in SQUARE],
                            faces=[[0, 1, 2], [0, 2, 3]], start=[-3.0, 0.0, 0.0], end=[3.0, 0.0, 0.0])
    w = C.Collision("sheets.toml", load_arch())
    w.resolution = 16
    w.bodies = [C.make_body(spec, i, "sheets") for i, spec in enumerate((lying, standing))]
    assert fcl_colliding(*w.bodies) and not fcl_colliding(*w.bodies, times=[0.0, 0.3, 0.7, 1.0])
    found = pcs(w.run().results)
    assert all(("lying", "standing") in pairs for pairs in found.values()), found


def box_mesh(lo, hi) -> tuple[list, list]:
    """The 12 triangles of the axis-aligned box [lo, hi] (trimesh)."""
    import trimesh

    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    box = trimesh.creation.box(extents=hi - lo)
    return (np.asarray(box.vertices) + (lo + hi) / 2).tolist(), np.asarray(box.faces).tolist()


def presence(x0: float, x1: float, left0: float, width: float, speed: float) -> tuple[float, float]:
    """The times in [0, 1] at which the x extent [left0 + speed t, left0 + width + speed t] meets the
    pixel's [x0, x1] (empty when the first exceeds the second)."""
    lo, hi = (x0 - left0 - width) / speed, (x1 - left0) / speed
    return max(lo, 0.0), min(hi, 1.0)


def test_overlap_image_colours_agree_with_a_closed_form(tmp_path):
    """Nilsson12 Fig. 6 on a small case worked out by hand. Seen along z, box A (z in [0, 0.4]) slides
    from x in [-1, 1] by 1 along x; box B, two parts (upper: y in [0.2, 1], z in [0.2, 0.6], depth
    overlapping A; lower: y in [-1, -0.2], z in [0.8, 1.2], in front of it), follows from x in [-5, -4]
    by 6. Per pixel centre the times each box covers it are intervals in closed form, and its depths
    its part's: the image is red (time), blue (depth), purple (both) or black where they say, on
    every pixel whose decision is clear by more than the conservative rasterizer's slack (pixels
    within 1.5 pixels of a y edge and times within 0.15 of a decision are left out)."""
    va, fa = box_mesh([-1.0, -1.0, 0.0], [1.0, 1.0, 0.4])
    vu, fu = box_mesh([-5.0, 0.2, 0.2], [-4.0, 1.0, 0.6])
    vl, fl = box_mesh([-5.0, -1.0, 0.8], [-4.0, -0.2, 1.2])
    text = ('kind = "collision"\nresolution = 64\n[[objects]]\nname = "A"\nshape = "mesh"\n'
            f'vertices = {va}\nfaces = {fa}\nend = [1.0, 0.0, 0.0]\n'
            '[[objects]]\nname = "B"\nshape = "mesh"\n'
            f'vertices = {vu + vl}\nfaces = {fu + [[i + len(vu) for i in f] for f in fl]}\n'
            'end = [6.0, 0.0, 0.0]\n')
    path = tmp_path / "fig6.toml"
    path.write_text(text)
    w = load_workload(path, load_arch())
    image = w.run().images["A-B.z"]
    lo, hi = C.view_box(*w.bodies)
    n = 64
    checked = {}
    for row in range(n):
        y = hi[1] - (row + 0.5) / n * (hi[1] - lo[1])
        part = "upper" if 0.2 < y < 1.0 else "lower" if -1.0 < y < -0.2 else None
        if min(abs(y - e) for e in (-1.0, -0.2, 0.2, 1.0)) < 1.5 * (hi[1] - lo[1]) / n:
            continue
        for col in range(n):
            x0, x1 = lo[0] + col / n * (hi[0] - lo[0]), lo[0] + (col + 1) / n * (hi[0] - lo[0])
            a0, a1 = presence(x0, x1, -1.0, 2.0, 1.0) if -1.0 < y < 1.0 else (1.0, -1.0)
            b0, b1 = presence(x0, x1, -5.0, 1.0, 6.0) if part else (1.0, -1.0)
            if abs(a1 - a0) < 0.15 or abs(b1 - b0) < 0.15:
                continue  # a box that touches the pixel for a moment, or nearly does
            both = a0 <= a1 and b0 <= b1
            gap = max(a0, b0) - min(a1, b1)  # < 0: the times overlap by -gap
            if both and abs(gap) < 0.15:
                continue  # a decision too close to call at this resolution
            time = both and gap < 0
            depth = both and part == "upper"
            colour = {(True, True): "purple", (True, False): "red", (False, True): "blue", (False, False): "black"}
            want = colour[(time, depth)]
            assert tuple(image[row, col]) == (float(time), 0.0, float(depth)), (row, col, want)
            checked[want] = checked.get(want, 0) + 1
    assert all(checked.get(c, 0) >= 5 for c in ("purple", "red", "blue", "black")), checked


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_union_box_holds_every_point_of_the_object(root, tmp_path, axis):
    """Dense (t, barycentric) samples of each triangle of both objects, projected by hand: the pixel
    each falls in holds its (t, z) in its object's union box."""
    w = load_workload(root / APP / "collide.toml", load_arch())
    a, b = w.bodies
    res = run_pass(C.box_pass(a, b, axis, 24, load_arch(), "p"))
    lo, hi = C.view_box(a, b)
    i, j = (axis + 1) % 3, (axis + 2) % 3
    n = 24
    u, v = np.meshgrid(np.linspace(0, 1, 9), np.linspace(0, 1, 9))
    keep = u + v <= 1
    bary = np.stack([1 - u[keep] - v[keep], u[keep], v[keep]], axis=1)
    checked = 0
    for body, target in ((a, "a"), (b, "b")):
        box = res.images[target][0]
        for t in np.linspace(0, 1, 41):
            pts = np.einsum("kc,fcd->fkd", bary, body.at(t)[body.faces]).reshape(-1, 3)
            px = np.floor((pts[:, i] - lo[i]) / (hi[i] - lo[i]) * n).astype(int)
            py = np.floor((hi[j] - pts[:, j]) / (hi[j] - lo[j]) * n).astype(int)   # row 0 at the top
            z = (pts[:, axis] - lo[axis]) / (hi[axis] - lo[axis]) * 2 - 1
            cell = box[py, px]
            eps = 1e-5
            assert np.all(cell[:, 0] <= t + eps) and np.all(t - eps <= cell[:, 2]), (target, t)
            assert np.all(cell[:, 1] <= z + eps) and np.all(z - eps <= cell[:, 3]), (target, t)
            checked += len(pts)
    assert checked > 100_000


@pytest.mark.parametrize("text, message", [
    ('resolution = 0\n[[objects]]\nshape = "icosphere"\n[[objects]]\nshape = "icosphere"\n', "resolution"),
    ('[[objects]]\nshape = "icosphere"\n[[objects]]\nname = "empty"\nshape = "mesh"\n',
     "objects[1] ('empty'): the object has no triangles"),
    ('[[objects]]\nshape = "icosphere"\n[[objects]]\nshape = "icosphere"\nend = [nan, 0.0, 0.0]\n',
     "objects[1].end"),
    ('[[objects]]\nshape = "icosphere"\n', "at least two objects"),
    ('[[objects]]\nshape = "icosphere"\nname = "a"\n[[objects]]\nshape = "icosphere"\nname = "a"\n',
     "names must be distinct, 'a' is given twice"),
    ('[[objects]]\nshape = "icosphere"\nname = "a/b"\n[[objects]]\nshape = "icosphere"\n',
     "objects[0] ('a/b'): name: use letters"),
    ('[[objects]]\nshape = "icosphere"\n[[objects]]\nshape = "icosphere"\nstart = [1e300, 0.0, 0.0]\n',
     "objects[1] ('object1'): a vertex reaches beyond"),
])
def test_bad_input_is_one_line_exit_2(tmp_path, capsys, text, message):
    err = refused_file(tmp_path, capsys, "collision", text)
    assert message in err and "bad.toml" in err, err
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("views", ["pair", "scene"])
def test_objects_whose_swept_boxes_never_meet_give_empty_sets(tmp_path, views):
    """No pair to test: the run still has one view (of every object), and every PCS is empty."""
    out, results = ran_file(tmp_path, f'kind = "collision"\nresolution = 8\nviews = "{views}"\n[[objects]]\n'
                                    'shape = "icosphere"\n[[objects]]\nshape = "icosphere"\nstart = [5.0, 0.0, 0.0]\n')
    assert results["swept_box_pairs"] == 0
    assert all(row["pcs_size"] == 0 and row["passes"] == 0 for row in results["methods"].values())
    assert (out / "passes" / "scene.x").is_dir()


def test_results_json_is_strict_and_lists_every_method(root, tmp_path):
    out = tmp_path / "run"
    assert main(["run", str(root / APP / "toaster.toml"), "--out", str(out), "--quiet"]) == 0
    results = json.loads((out / "results.json").read_text(), parse_constant=lambda c: pytest.fail(c))
    for m in C.METHODS:
        row = results["methods"][m]
        assert row["pcs_size"] == len(row["pcs"]) and row["passes"] >= 1 and row["pixels_shaded"] > 0
        assert row["cycles"] > 0
    # each union view's overlap image (Nilsson12 Fig. 6), as .npy and .png
    views = sorted(p.stem for p in (out / "images").glob("*.npy"))
    assert views == ["toaster-ball.x", "toaster-ball.y", "toaster-ball.z"]  # depth only never separates them
    assert all((out / "images" / f"{v}.png").exists() for v in views)


def test_cost_sweep_runs_a_tiny_version(root, tmp_path):
    """workloads/sweeps/collision_cost.toml on 6 objects at two resolutions: every point runs, each
    method's PCS size is a column, and the PCS inclusion order holds at each point."""
    import pandas as pd

    from pipeline_sim.sweep import load_sweep, run_sweep

    shipped = (root / "workloads/sweeps/collision_cost.toml").read_text()
    text = shipped.replace('"../apps/collision/many.toml"', '"many.toml"').replace("[16, 32, 64, 128, 256, 512]",
                                                                                  "[8, 32]")
    assert text.count("../apps") == 0 and "[8, 32]" in text
    (tmp_path / "many.toml").write_text('kind = "collision"\nviews = "scene"\n[random]\ncount = 6\nseed = 2\n'
                                        'extent = 1.0\nsubdivisions = 0\n')
    (tmp_path / "sweep.toml").write_text(text)
    frame = run_sweep(load_sweep(tmp_path / "sweep.toml"), tmp_path / "out", executor="serial", progress=False)
    assert (frame.status == "ok").all() and len(frame) == 2
    points = pd.read_csv(tmp_path / "out" / "points.csv").sort_values("workload.resolution")
    size = {m: points[f"result.methods.{m}.pcs_size"].to_numpy() for m in C.METHODS}
    assert np.all(size["tz_fragment"] <= size["tz_union"]) and np.all(size["tz_union"] <= size["depth_only"])
    assert np.all(size["depth_only"] <= size["cullide"]) and np.all(points["result.swept_box_pairs"] >= size["cullide"])
    assert points.frame_cycles.iloc[0] < points.frame_cycles.iloc[1]  # finer views shade more pixels
