"""Shading cache (units/shading_cache.py): keys, replacement, reuse, colors.

The cache key of every sample is computed here independently in float64
(project sum_k b_k ref[tri, k] to (X/W, Y/W), cell = floor(. / rate)); the
cache itself is compared with a pure-Python LRU/FIFO model. The set mapping
(a hash) is an implementation detail, so exact comparisons use a fully
associative configuration (ways == entries), or a set mapping *observed* by
probing an empty cache with one key at a time.
"""

from __future__ import annotations

from collections import OrderedDict
from types import SimpleNamespace

import numba as nb
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from pipeline_sim.config import ShadingConfig, load_arch, pass_settings
from pipeline_sim.counters import N_OPS
from pipeline_sim.draw import draw_from_clip
from pipeline_sim.render import RenderPass, run_pass
from pipeline_sim.pass_state import PassState
from pipeline_sim.shaders import (IN_B, IN_G, IN_PX, IN_PY, IN_R, IN_T, IN_TRIANGLE, IN_U, IN_V, IN_X, IN_Y,
                                  N_INPUTS, standard_shader)
from units.shading_cache import (EVENTS, REPL_FIFO, REPL_LRU, Shading, cache_kernel, cache_scratch, cell_keys,
                                 deliver_colors, request_points, run_end, store_requests)

EV = {name: i for i, name in enumerate(EVENTS)}


# --------------------------------------------------------------------------- #
# stream generation and independent keys
# --------------------------------------------------------------------------- #
def make_ref(rng, ntri, width, height, size):
    """Reference-camera 2DH vertices (X, Y, W), W > 0, projecting inside the screen."""
    ref = np.zeros((ntri, 3, 3), np.float64)
    for t in range(ntri):
        cx = rng.uniform(0, width - size)
        cy = rng.uniform(0, height - size)
        sx = cx + rng.uniform(0, size, 3)
        sy = cy + rng.uniform(0, size, 3)
        w = rng.uniform(0.5, 2.0, 3)
        ref[t, :, 0] = sx * w
        ref[t, :, 1] = sy * w
        ref[t, :, 2] = w
    return ref.astype(np.float32)


def key_of(ref, tri, b, rate):
    """(tri, cx, cy) in float64, and the distance (in cells) to the nearest cell border."""
    p = b.astype(np.float64) @ ref[tri].astype(np.float64)
    fx, fy = p[0] / p[2] / rate, p[1] / p[2] / rate
    margin = min(abs(fx - round(fx)), abs(fy - round(fy)))
    return (int(tri), int(np.floor(fx)), int(np.floor(fy))), margin


def centre_inside(ref, key, rate, eps=1e-4):
    """Is the centre of the key's cell strictly inside the reference triangle?"""
    tri, cx, cy = key
    m = ref[tri].astype(np.float64).T  # columns: vertices (X, Y, W)
    c = np.linalg.solve(m, np.array([(cx + 0.5) * rate, (cy + 0.5) * rate, 1.0]))
    lam = c / c.sum()
    return bool(np.all(lam > eps))


def make_stream(rng, ref, n, rate, locality=0.85, require_centre=False):
    """Samples (tri, b0, b1, b2) with temporal locality in the triangle, with
    their keys. Samples within 1e-3 cells of a cell border are skipped so the
    float32 kernel and this float64 model agree on the cell."""
    ntri = ref.shape[0]
    tris, bs, keys = [], [], []
    cur = int(rng.integers(ntri))
    while len(tris) < n:
        if rng.random() > locality:
            cur = int(rng.integers(ntri))
        b = rng.dirichlet([1.0, 1.0, 1.0]).astype(np.float32)
        key, margin = key_of(ref, cur, b, rate)
        if margin < 1e-3:
            continue
        if require_centre and not centre_inside(ref, key, rate):
            continue
        tris.append(cur)
        bs.append(b)
        keys.append(key)
    b = np.array(bs, np.float32).reshape(-1, 3)
    return np.array(tris, np.int32), b[:, 0].copy(), b[:, 1].copy(), b[:, 2].copy(), keys


# --------------------------------------------------------------------------- #
# pure-Python reference caches
# --------------------------------------------------------------------------- #
class RefCache:
    """Set-associative cache; ``set_of`` maps a key to its set (default: one set)."""

    def __init__(self, entries, ways, policy, set_of=None):
        self.ways = ways
        self.policy = policy
        self.sets = [OrderedDict() for _ in range(entries // ways)]
        self.set_of = set_of or (lambda key: 0)
        self.hits = self.misses = self.evictions = 0

    def access(self, key) -> bool:
        s = self.sets[self.set_of(key)]
        if key in s:
            self.hits += 1
            if self.policy == "lru":
                s.move_to_end(key)
            return True
        self.misses += 1
        if len(s) == self.ways:
            s.popitem(last=False)
            self.evictions += 1
        s[key] = True
        return False


def encode(key):
    return np.array([key[0], key[1], key[2], 7.0], np.float32)


class KernelCache:
    """Drives ``cache_kernel`` batch by batch the way ``Shading.run`` does:
    after each batch every entry filled in the batch gets the color of its last
    request (here: the request's key, encoded) and its request link is cleared."""

    def __init__(self, entries, ways, policy, ref, rate):
        nsets = entries // ways
        self.tags = np.full((nsets, ways), -1, np.int64)
        self.stamps = np.zeros((nsets, ways), np.int64)
        self.entry_req = np.full(entries, -1, np.int32)
        self.entry_color = np.zeros((entries, 4), np.float32)
        self.clock = 0
        self.repl = REPL_LRU if policy == "lru" else REPL_FIFO
        self.ref, self.rate = ref, rate
        self.events = np.zeros(len(EVENTS), np.int64)

    def run(self, tri, b0, b1, b2, keys):
        n = len(tri)
        entries = len(self.entry_req)
        # scratch longer than the batch, as Shading keeps it: the kernel must use only its first rows
        keys_buf, sample_src, req_entry, req_tri, req_l, req_sample = cache_scratch(n + 5)
        ops = np.zeros(N_OPS, np.int64)
        ev = np.zeros(len(EVENTS), np.int64)
        nreq, self.clock = cache_kernel(tri, b0, b1, b2, self.ref, self.rate,
                                        self.tags, self.stamps, self.entry_req, self.clock, self.repl, keys_buf,
                                        sample_src, req_entry, req_tri, req_l, req_sample, ops, ev)
        self.events += ev
        # classify samples: a miss opens the next request; a hit points at an
        # earlier request of this batch, or at an entry's stored color
        hit = np.zeros(n, bool)
        first_of_req = []
        for i in range(n):
            src = int(sample_src[i])
            if src == entries + len(first_of_req):
                r = len(first_of_req)
                first_of_req.append(i)
                assert req_tri[r] == tri[i] and req_sample[r] == i
            else:
                hit[i] = True
                if src >= entries:
                    r = src - entries
                    assert r < len(first_of_req)
                    assert keys[first_of_req[r]] == keys[i], "within-batch hit on another key"
                else:
                    np.testing.assert_array_equal(self.entry_color[src], encode(keys[i]),
                                                  err_msg="hit on another key's color")
        assert nreq == len(first_of_req) == ev[EV["misses"]] == ev[EV["shader_executions"]]
        for r in range(nreq):  # emulate Shading.run: last request of an entry wins
            self.entry_color[req_entry[r]] = encode(keys[first_of_req[r]])
        self.entry_req[req_entry[:nreq]] = -1
        return hit, req_l[:, :nreq].copy(), [keys[i] for i in first_of_req], req_tri[:nreq].copy()


def _setup(seed, ntri=8, size=7.0, rate=1.0, width=32, height=24):
    rng = np.random.default_rng(seed)
    ref = make_ref(rng, ntri, width, height, size)
    return rng, ref


# --------------------------------------------------------------------------- #
# kernel against the reference
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize("policy", ["lru", "fifo"])
@pytest.mark.parametrize("entries", [1, 3, 8, 32])
@pytest.mark.parametrize("rate", [1.0, 2.0])
def test_fully_associative_matches_reference(policy, entries, rate):
    rng, ref = _setup(entries * 7 + int(rate), rate=rate)
    kc = KernelCache(entries, entries, policy, ref, rate)
    rc = RefCache(entries, entries, policy)
    for batch in range(5):
        tri, b0, b1, b2, keys = make_stream(rng, ref, int(rng.integers(1, 150)), rate)
        hit, _, _, _ = kc.run(tri, b0, b1, b2, keys)
        expect = np.array([rc.access(k) for k in keys])
        np.testing.assert_array_equal(hit, expect, err_msg=f"batch {batch}")
    ev = kc.events
    assert ev[EV["hits"]] == rc.hits and ev[EV["misses"]] == rc.misses
    assert ev[EV["evictions"]] == rc.evictions
    assert ev[EV["lookups"]] == rc.hits + rc.misses
    assert rc.hits > 0 and (entries > 8 or rc.evictions > 0)  # the stream exercises both paths


@pytest.mark.parametrize("policy", ["lru", "fifo"])
@pytest.mark.parametrize("entries,ways", [(8, 2), (16, 4), (12, 3)])
def test_set_associative_matches_reference_with_observed_sets(policy, entries, ways):
    """The set of a key is observed by looking it up alone in an empty cache;
    with that mapping, each set must behave as an independent LRU/FIFO cache."""
    rate = 1.0
    rng, ref = _setup(entries + ways, rate=rate)
    streams = [make_stream(rng, ref, 120, rate) for _ in range(4)]
    probe_set = {}
    for tri, b0, b1, b2, keys in streams:
        for i, key in enumerate(keys):
            if key in probe_set:
                continue
            probe = KernelCache(entries, ways, policy, ref, rate)
            probe.run(tri[i:i + 1], b0[i:i + 1], b1[i:i + 1], b2[i:i + 1], [key])
            rows = np.nonzero((probe.tags != -1).any(axis=1))[0]
            assert len(rows) == 1
            probe_set[key] = int(rows[0])
    assert len(set(probe_set.values())) > 1
    kc = KernelCache(entries, ways, policy, ref, rate)
    rc = RefCache(entries, ways, policy, set_of=probe_set.__getitem__)
    for tri, b0, b1, b2, keys in streams:
        hit, _, _, _ = kc.run(tri, b0, b1, b2, keys)
        np.testing.assert_array_equal(hit, [rc.access(k) for k in keys])
    assert kc.events[EV["evictions"]] == rc.evictions


@given(st.lists(st.tuples(st.integers(0, 3), st.integers(1, 200)), min_size=1, max_size=12))
def test_run_end_finds_each_run_of_equal_values(runs):
    """``run_end`` against runs written out here: from every index, the end of the run of equal values
    holding it (runs shorter and longer than its 64-value blocks, ending on a block's edge or inside)."""
    values = np.concatenate([np.full(n, v, np.int32) for v, n in runs])
    ends = np.r_[np.flatnonzero(np.diff(values)) + 1, len(values)]
    for i in range(len(values)):
        assert run_end(values, i) == ends[np.searchsorted(ends, i, side="right")]


def test_cell_keys_in_long_runs_against_float64_keys():
    """Runs of one triangle longer than ``run_end``'s blocks, ending on a block edge and inside one: each
    sample's key is its (triangle, cell) computed here in float64 (``key_of``)."""
    rng, ref = _setup(37, ntri=6, size=9.0, rate=1.0)
    tri = np.repeat(np.arange(6, dtype=np.int32), [65, 64, 1, 200, 129, 241])
    bs, expect = [], []
    for t in tri:
        while True:  # away from cell borders, where float32 and float64 may disagree
            b = rng.dirichlet([1.0, 1.0, 1.0]).astype(np.float32)
            (_, cx, cy), margin = key_of(ref, t, b, 1.0)
            if margin >= 1e-3:
                break
        bs.append(b)
        expect.append((int(t) << 42) + ((cy + 2**20) << 21) + cx + 2**20)
    b0, b1, b2 = np.array(bs).T.copy()
    got = np.empty(len(tri), np.int64)
    n_in_front = cell_keys(tri, b0, b1, b2, ref, 1.0, got)
    np.testing.assert_array_equal(got, expect)
    assert n_in_front == len(tri) and len(set(expect)) > 50


@pytest.mark.parametrize("rate", [1.0, 2.0, 0.75])
def test_cell_keys_against_float64_keys(rate):
    """Each sample's key is its (triangle, cell) computed here in float64, packed as documented
    (triangle << 42 | (cy + 2^20) << 21 | (cx + 2^20)); a sample behind the reference camera has none (-1)."""
    rng, ref = _setup(31, ntri=10, size=9.0, rate=rate)
    ref[::2, :, :2] -= 30 * ref[::2, :, 2:]  # half of them 30 pixels left of and above the screen: negative cells
    far = ref[:1].copy()
    far[:, :, :2] += 2.0**22 * far[:, :, 2:]  # in front, but 2^22 pixels off screen: beyond the grid's cells
    ref = np.concatenate([ref, -ref[:2], far])  # two triangles behind the reference camera (W < 0)
    tri, b0, b1, b2, keys = make_stream(rng, ref[:10], 400, rate)
    order = np.argsort(tri, kind="stable")[: len(tri) // 2]  # half the stream in runs of one triangle
    tri, b0, b1, b2 = (np.concatenate([a[order], a]) for a in (tri, b0, b1, b2))
    keys = [keys[i] for i in order] + list(keys)
    behind = rng.random(len(tri)) < 0.1
    tri[behind] = 10 + rng.integers(0, 2, behind.sum())
    off = ~behind & (rng.random(len(tri)) < 0.05)
    tri[off] = 12
    got = np.full(len(tri) + 2, -7, np.int64)
    n_in_front = cell_keys(tri, b0, b1, b2, ref, rate, got)
    expect = [-1 if h or o else (t << 42) + ((cy + 2 ** 20) << 21) + cx + 2 ** 20
              for h, o, (t, cx, cy) in zip(behind, off, keys)]
    np.testing.assert_array_equal(got[:len(tri)], expect)
    assert np.all(got[len(tri):] == -7)  # only the batch's rows are written
    assert n_in_front == len(tri) - behind.sum() and 0 < behind.sum() < len(tri) and off.sum() > 0
    assert len({k for k in expect if k >= 0}) > 20 and min(k[1] for k in keys) < 0 and min(k[2] for k in keys) < 0


class DictOfSetsCache:
    """A set-associative cache in plain Python: ``sets[s]`` maps each resident key to its stamp (its last
    use under LRU, its fill under FIFO); a full set evicts its smallest stamp. ``fresh`` maps the keys
    filled in the current batch to their request number."""

    def __init__(self, nsets, ways, policy, set_of):
        self.sets = {s: {} for s in range(nsets)}
        self.ways, self.policy, self.set_of = ways, policy, set_of
        self.time = 0
        self.hits = self.misses = self.evictions = 0

    def batch(self, stream):
        """``stream``: keys, None for a sample with no cell. Returns each sample's color source,
        ("request", r) or ("stored", key), and the batch's requests (their keys, None: uncached)."""
        sources, requests, fresh = [], [], {}
        for key in stream:
            self.time += 1
            if key is None:
                self.misses += 1
                sources.append(("request", len(requests)))
                requests.append(None)
                continue
            resident = self.sets[self.set_of(key)]
            if key in resident:
                self.hits += 1
                if self.policy == "lru":
                    resident[key] = self.time
                sources.append(("request", fresh[key]) if key in fresh else ("stored", key))
                continue
            self.misses += 1
            if len(resident) == self.ways:
                victim = min(resident, key=resident.get)
                del resident[victim]
                fresh.pop(victim, None)
                self.evictions += 1
            resident[key] = self.time
            fresh[key] = len(requests)
            sources.append(("request", len(requests)))
            requests.append(key)
        return sources, requests


def vertex_cell_scene(rng, ntri, rate, spread):
    """Degenerate reference triangles whose vertices sit at cell centres, so a sample with barycentrics
    (1, 0, 0), (0, 1, 0) or (0, 0, 1) sees its vertex exactly and its key (triangle, cx, cy) is known
    without rounding; one more triangle lies behind the reference camera (no cell: key None)."""
    cells = rng.integers(-spread, spread, (ntri, 3, 2))
    ref = np.ones((ntri + 1, 3, 3), np.float32)
    ref[:ntri, :, :2] = (cells + 0.5) * rate
    ref[ntri, :, 2] = -1.0
    keys = {(t, k): (t, int(cells[t, k, 0]), int(cells[t, k, 1])) for t in range(ntri) for k in range(3)}
    keys.update({(ntri, k): None for k in range(3)})
    return ref, keys


def run_stream(rng, choices, n):
    """``n`` samples as (triangle, vertex): runs of one choice, of length 1 to about 60."""
    out = []
    while len(out) < n:
        pick = choices[int(rng.integers(len(choices)))]
        length = int(rng.choice([1, 1, 2, int(rng.geometric(0.2)), int(rng.integers(20, 60))]))
        out.extend([pick] * length)
    return out[:n]


@pytest.mark.parametrize("policy", ["lru", "fifo"])
@pytest.mark.parametrize("entries,ways,rate,seed", [(8, 2, 1.0, 1), (16, 4, 2.0, 2), (12, 3, 0.5, 3), (32, 8, 1.0, 4),
                                                    (4, 4, 1.0, 5)])
def test_kernel_matches_a_dict_of_sets_cache_on_runs_and_conflicts(policy, entries, ways, rate, seed):
    """Key streams with long runs of one key, set conflicts (more keys than entries) and samples with no
    cell, cut into batches at random points (inside runs too): the kernel, its colors delivered and
    stored as Shading.run does, against DictOfSetsCache: the same hits, misses and evictions, each
    sample's color source (a request of its batch, or a stored color and whose), the same requests in
    the same order, and each sample's delivered color that of its own key."""
    rng = np.random.default_rng(seed)
    ref, keys = vertex_cell_scene(rng, entries, rate, spread=40)  # three keys per triangle: conflicts
    nsets = entries // ways
    empty = lambda: (np.full((nsets, ways), -1, np.int64), np.zeros((nsets, ways), np.int64),  # noqa: E731
                     np.full(entries, -1, np.int32))
    repl = REPL_LRU if policy == "lru" else REPL_FIFO
    unit = np.eye(3, dtype=np.float32)

    def lookup(tags, stamps, entry_req, clock, picks):
        tri = np.array([t for t, _ in picks], np.int32)
        b = unit[[k for _, k in picks]].reshape(-1, 3)
        scratch = cache_scratch(len(picks) + 3)
        ops, ev = np.zeros(N_OPS, np.int64), np.zeros(len(EVENTS), np.int64)
        nreq, clock = cache_kernel(tri, b[:, 0].copy(), b[:, 1].copy(), b[:, 2].copy(), ref, rate, tags,
                                   stamps, entry_req, clock, repl, *scratch, ops, ev)
        return nreq, clock, scratch, ev

    def set_of(key, seen={}):  # observed: the row a key fills when looked up alone in an empty cache
        if key not in seen:
            tags = empty()[0]
            pick = next(p for p, k in keys.items() if k == key)
            lookup(tags, np.zeros_like(tags), np.full(entries, -1, np.int32), 0, [pick])
            seen[key] = int(np.nonzero((tags != -1).any(axis=1))[0][0])
        return seen[key]

    def encode(key):
        return np.array([-1, -1, -1, -1] if key is None else [key[0], key[1], key[2], 1], np.float32)

    model = DictOfSetsCache(nsets, ways, policy, set_of)
    tags, stamps, entry_req = empty()
    entry_color = np.zeros((entries, 4), np.float32)
    clock = 0
    events = np.zeros(len(EVENTS), np.int64)
    stored = 0
    stream = run_stream(rng, list(keys), 3000)
    cuts = np.unique(np.r_[0, rng.integers(0, len(stream), 25), len(stream)])
    for a, b in zip(cuts[:-1], cuts[1:]):
        picks = stream[a:b]
        sources, requests = model.batch([keys[p] for p in picks])
        nreq, clock, (_, src, req_entry, _, _, req_sample), ev = lookup(tags, stamps, entry_req, clock, picks)
        events += ev
        n = len(picks)
        assert nreq == len(requests)
        assert [keys[picks[i]] for i in req_sample[:nreq]] == requests
        got = [("request", int(s) - entries) if s >= entries else ("stored", tuple(int(v) for v in entry_color[s, :3]))
               for s in src[:n]]
        assert got == sources
        stored += sum(kind == "stored" for kind, _ in sources)
        shaded = np.array([encode(k) for k in requests], np.float32).reshape(-1, 4)
        color = np.empty((n, 4), np.float32)
        deliver_colors(src[:n], np.concatenate((entry_color, shaded)), color)
        store_requests(req_entry[:nreq], shaded, entry_color, entry_req)
        np.testing.assert_array_equal(color, [encode(keys[p]) for p in picks])
    assert events[EV["lookups"]] == len(stream) and events[EV["hits"]] == model.hits
    assert events[EV["misses"]] == events[EV["shader_executions"]] == model.misses
    assert events[EV["evictions"]] == model.evictions
    # the stream exercised what it is for: reuse, evictions, uncached samples, conflicts in a set
    assert model.hits > 1000 and model.evictions > 50 and 100 < stored < model.hits
    assert any(keys[p] is None for p in stream)
    assert len({set_of(k) for k in keys.values() if k is not None}) == nsets


def test_request_barycentrics_are_the_cell_centre():
    """A miss's barycentrics (req_l) project, through the reference camera, to
    the centre of the sample's shading cell (when that centre is inside)."""
    rate = 2.0
    rng, ref = _setup(21, size=14.0, rate=rate)
    kc = KernelCache(16, 16, "lru", ref, rate)
    tri, b0, b1, b2, keys = make_stream(rng, ref, 300, rate, require_centre=True)
    _, req_l, req_keys, req_tri = kc.run(tri, b0, b1, b2, keys)
    assert len(req_keys) > 10
    for r, key in enumerate(req_keys):
        assert req_tri[r] == key[0]
        lam = req_l[:, r]
        assert np.all(lam >= 0) and abs(lam.sum() - 1) < 1e-9
        p = lam @ ref[key[0]].astype(np.float64)
        np.testing.assert_allclose([p[0] / p[2], p[1] / p[2]],
                                   [(key[1] + 0.5) * rate, (key[2] + 0.5) * rate], atol=1e-3)


def test_hit_rate_rises_with_cache_size():
    """LRU is a stack algorithm: for a fully associative cache the hits can only
    grow with the size; on a stream with reuse they must strictly grow overall."""
    rng, ref = _setup(5)
    stream = [make_stream(rng, ref, 200, 1.0) for _ in range(3)]
    hits = []
    for entries in (1, 2, 4, 8, 16, 32, 64, 128):
        kc = KernelCache(entries, entries, "lru", ref, 1.0)
        for s in stream:
            kc.run(*s)
        hits.append(int(kc.events[EV["hits"]]))
    assert all(a <= b for a, b in zip(hits, hits[1:])), hits
    assert hits[-1] > hits[0]
    distinct = len({k for s in stream for k in s[4]})
    assert distinct <= 128
    assert hits[-1] == 600 - distinct  # the largest cache only takes compulsory misses


def test_reference_w_nonpositive_never_hits_across_batches():
    ref = np.zeros((2, 3, 3), np.float32)
    ref[:, :, 0] = 1.0
    ref[:, :, 1] = 1.0
    ref[:, :, 2] = -1.0  # surface point behind the reference camera
    kc = KernelCache(4, 4, "lru", ref, 1.0)
    third = np.array([1 / 3], np.float32)
    for tr in (0, 1):
        kc.run(np.array([tr], np.int32), third, third, third, [(tr, 999, 999)])
    assert kc.events[EV["hits"]] == 0  # documented: "unique: never hits"


# --------------------------------------------------------------------------- #
# the Shading unit: shaded colors and 1:1 mode
# --------------------------------------------------------------------------- #
@nb.njit
def cell_shader(inputs, params, textures, out, append):
    """Returns (triangle, cell x, cell y): the interpolated 'color' is the
    reference-camera (X, Y, W) of the shading point (see below)."""
    rate = params[0]
    for i in range(inputs.shape[1]):
        w = inputs[IN_B, i]
        out[i, 0] = inputs[IN_TRIANGLE, i]
        out[i, 1] = np.floor(inputs[IN_R, i] / w / rate)
        out[i, 2] = np.floor(inputs[IN_G, i] / w / rate)
        out[i, 3] = 1.0


def _shading_unit(cfg, mode, rate, ref, width, height, spp, shader, rng):
    ntri = ref.shape[0]
    draw = draw_from_clip(rng.uniform(-1, 1, (ntri, 3, 4)), width=width, height=height)
    # vertex "color" = reference-camera (X, Y, W): interpolating it with the
    # request's barycentrics gives the homogeneous shading point
    draw.color = ref.astype(np.float32).copy()
    npix = width * height
    samples = SimpleNamespace(spp=spp, width=width, height=height, row0=0,
                              x=rng.random(npix * spp).astype(np.float32),
                              y=rng.random(npix * spp).astype(np.float32),
                              u=rng.uniform(-1, 1, npix * spp).astype(np.float32),
                              v=rng.uniform(-1, 1, npix * spp).astype(np.float32),
                              t=rng.random(npix * spp).astype(np.float32), tup=None, table_rows=False)
    table = SimpleNamespace(ref=ref)
    return Shading(cfg, mode, rate, draw, table, samples, shader, np.array([rate], np.float32), None, False)


def _batch(rng, tri, b0, b1, b2, npix, spp):
    n = len(tri)
    return dict(tri=tri, pix=rng.integers(0, npix, n).astype(np.int32),
                sidx=rng.integers(0, spp, n).astype(np.int32), z=rng.random(n).astype(np.float32),
                b0=b0, b1=b1, b2=b2, noread=np.zeros(n, bool))


@pytest.mark.parametrize("entries,ways,policy", [(4, 4, "lru"), (8, 2, "fifo"), (64, 8, "lru")])
def test_cache_mode_color_is_shader_at_the_samples_request(entries, ways, policy):
    width, height, spp, rate = 32, 24, 4, 2.0
    rng, ref = _setup(entries + ways, ntri=6, size=14.0, rate=rate, width=width, height=height)
    cfg = ShadingConfig(cache_entries=entries, cache_ways=ways, replacement=policy)
    unit = _shading_unit(cfg, "cache", rate, ref, width, height, spp, cell_shader, rng)
    execs = 0
    for _ in range(5):
        tri, b0, b1, b2, keys = make_stream(rng, ref, int(rng.integers(1, 200)), rate, require_centre=True)
        out, _, ev = unit.run(_batch(rng, tri, b0, b1, b2, width * height, spp))
        expect = np.array([[k[0], k[1], k[2], 1.0] for k in keys], np.float32)
        np.testing.assert_array_equal(out["color"], expect)
        assert ev[EV["lookups"]] == len(tri)
        execs += ev[EV["shader_executions"]]
    assert execs < 5 * 200  # some reuse happened


def test_per_sample_mode_shades_every_sample_once_at_its_own_point():
    width, height, spp = 16, 8, 4
    rng, ref = _setup(9, ntri=5, size=6.0, width=width, height=height)
    calls = []

    def recording_shader(inputs, params, textures, out, append):
        calls.append(inputs.copy())
        out[:, 0] = inputs[IN_X]
        out[:, 1] = inputs[IN_Y]
        out[:, 2] = inputs[IN_T]
        out[:, 3] = inputs[IN_TRIANGLE]

    unit = _shading_unit(ShadingConfig(), "per_sample", 1.0, ref, width, height, spp, recording_shader, rng)
    s = unit.samples
    for n in (0, 1, 37, 120):
        tri, b0, b1, b2, _ = make_stream(rng, ref, n, 1.0)
        batch = _batch(rng, tri, b0, b1, b2, width * height, spp)
        calls.clear()
        out, _, ev = unit.run(batch)
        rows = sum(c.shape[1] for c in calls)
        assert rows == n and ev[EV["shader_executions"]] == n and ev[EV["lookups"]] == 0  # cache bypassed
        if n == 0:
            continue
        inp = np.concatenate(calls, axis=1)
        k = batch["pix"].astype(np.int64) * spp + batch["sidx"]
        py, px = np.divmod(batch["pix"], width)
        np.testing.assert_allclose(inp[IN_X], px + s.x[k], rtol=1e-6)
        np.testing.assert_allclose(inp[IN_Y], py + s.y[k], rtol=1e-6)
        np.testing.assert_array_equal(inp[IN_T], s.t[k])
        np.testing.assert_array_equal(inp[IN_U], s.u[k])
        np.testing.assert_array_equal(inp[IN_V], s.v[k])
        np.testing.assert_array_equal(inp[IN_TRIANGLE], tri)
        np.testing.assert_array_equal(out["color"], inp[[IN_X, IN_Y, IN_T, IN_TRIANGLE]].T)
        assert inp.shape[0] == N_INPUTS


def _moving_draw(seed, n=40, width=48, height=32):
    rng = np.random.default_rng(seed)
    c = rng.uniform(-0.9, 0.9, (n, 1, 2))
    q = np.zeros((n, 3, 4))
    q[:, :, :2] = c + rng.normal(0, 0.25, (n, 3, 2))
    q[:, :, 2] = rng.uniform(-0.5, 0.9, (n, 1))
    q[:, :, 3] = 1.0
    r = q.copy()
    r[:, :, :2] += rng.normal(0, 0.15, (n, 1, 2))
    lx = np.zeros((n, 3, 2))
    lx[:, :, :] = rng.uniform(0, 0.05, (n, 1, 1))
    return draw_from_clip(q, r, lx, lx.copy(), rng.uniform(0, 1, (n, 3)), width, height)


def test_per_sample_mode_in_the_pipeline_one_execution_per_covered_sample():
    draw = _moving_draw(3)
    rows = []

    def counting_shader(inputs, params, textures, out, append):
        rows.append(inputs[[IN_X, IN_Y, IN_T, IN_U, IN_V, IN_TRIANGLE]].T.copy())
        standard_shader(inputs, params, textures, out, append)

    settings = pass_settings(["pass.shading_mode=per_sample", "simulation.samples_per_batch=500"])
    res = run_pass(RenderPass(draw=draw, **settings, spp=4, shader=counting_shader))
    covered = res.counter("sample_tester", "samples_covered")
    allrows = np.concatenate(rows)
    assert covered > 1000
    assert len(allrows) == covered == res.counter("shading", "shader_executions")
    # every row is a distinct (sample (x, y, t, u, v), triangle): none shaded twice
    assert len(np.unique(allrows, axis=0)) == len(allrows)


def test_cache_mode_in_the_pipeline_executes_fewer_shaders_and_counts_add_up():
    draw = _moving_draw(4)
    res = run_pass(RenderPass(draw=draw, arch=load_arch(), spp=8))
    c = lambda name: res.counter("shading", name)  # noqa: E731
    assert c("lookups") == res.counter("sample_tester", "samples_covered")
    assert c("hits") + c("misses") == c("lookups")
    assert c("shader_executions") == c("misses") < c("lookups")


@pytest.mark.parametrize("overrides", [
    ["shading.cache_entries=16", "shading.cache_ways=4", "simulation.samples_per_batch=64"],
    ["shading.cache_entries=8", "shading.cache_ways=8", "shading.replacement=fifo",
     "pass.shading_rate=2", "simulation.samples_per_batch=33"],
    ["pass.shading_rate=3"],
])
def test_cache_mode_in_the_pipeline_colors_follow_keys(monkeypatch, overrides):
    """Through run_pass, with the cell shader: every sample reaching the ROP
    carries (its triangle, its shading cell) as color, the cell computed here
    from its barycentrics and the reference-camera vertices."""
    import pipeline_sim.render as render
    from units.rop import Rop
    from units.triangle_setup import TriangleSetup

    draw = _moving_draw(8, n=30)
    settings = pass_settings(overrides)
    arch, rate = settings["arch"], settings["state"].shading_rate
    setup = TriangleSetup(arch.triangle_setup, draw, arch.tile_traverser.tile_size)
    setup.run(np.arange(draw.n, dtype=np.int64))
    ref = setup.table.ref.copy()
    draw.color = ref.astype(np.float32).copy()  # see cell_shader
    batches = []

    class RecordingRop(Rop):
        def run(self, batch):
            batches.append({k: v.copy() for k, v in batch.items()})
            return super().run(batch)

    monkeypatch.setattr(render, "Rop", RecordingRop)
    res = run_pass(RenderPass(draw=draw, **settings, spp=4, shader=cell_shader,
                              params=np.array([rate], np.float32)))
    grid_w, grid_h = int(np.ceil(draw.width / rate)), int(np.ceil(draw.height / rate))
    checked = 0
    for b in batches:
        for i in range(len(b["tri"])):
            bc = np.array([b["b0"][i], b["b1"][i], b["b2"][i]], np.float32)
            key, margin = key_of(ref, int(b["tri"][i]), bc, rate)
            # only cells of the screen's shading grid are checked (a cell off it is
            # keyed alike, but its centre is off screen)
            if not (0 <= key[1] < grid_w and 0 <= key[2] < grid_h):
                continue
            if margin < 1e-3 or not centre_inside(ref, key, rate):
                continue
            np.testing.assert_array_equal(b["color"][i], [key[0], key[1], key[2], 1.0])
            checked += 1
    assert checked > 1000
    assert res.counter("shading", "hits") > 0
    if arch.shading.cache_entries <= 16:
        assert res.counter("shading", "evictions") > 0


def test_triangles_behind_reference_camera_keep_their_own_color():
    # two triangles moving from w=1 (t=0) to w=-3 (t=1): at the reference time
    # t=0.5 their surface is behind the camera (W=-1), early samples see them
    q = np.array([[[-0.9, -0.9, 0, 1], [-0.1, -0.9, 0, 1], [-0.5, 0.5, 0, 1]],
                  [[0.1, -0.9, 0, 1], [0.9, -0.9, 0, 1], [0.5, 0.5, 0, 1]]], float)
    r = q.copy()
    r[:, :, 3] = -3.0
    r[:, :, :2] *= -3.0
    draw = draw_from_clip(q, r, color=np.array([[1, 0, 0], [0, 1, 0]], np.float32), width=32, height=32)
    big = run_pass(RenderPass(draw=draw, arch=load_arch(), spp=16))
    # the right triangle is green, the left one red (flat material: color = vertex color)
    assert big.image[:, 16:, 1].sum() > 10 and big.image[:, 16:, 0].sum() == 0
    small = run_pass(RenderPass(draw=draw, **pass_settings(["simulation.samples_per_batch=1"]), spp=16))
    np.testing.assert_array_equal(small.image, big.image)


@given(st.lists(st.integers(-1, 5), min_size=0, max_size=40))
def test_store_requests_keeps_each_entrys_last_request(entries):
    req_entry = np.array(entries, np.int32)
    shaded = np.arange(4 * len(entries), dtype=np.float32).reshape(-1, 4)
    entry_color = np.full((6, 4), -7.0, np.float32)
    entry_req = np.full(6, 3, np.int32)
    store_requests(req_entry, shaded, entry_color, entry_req)
    for e in range(6):
        last = max((r for r, q in enumerate(entries) if q == e), default=None)
        if last is None:  # untouched
            assert np.all(entry_color[e] == -7.0) and entry_req[e] == 3
        else:
            np.testing.assert_array_equal(entry_color[e], shaded[last])
            assert entry_req[e] == -1


@given(st.lists(st.integers(0, 6), min_size=0, max_size=60), st.sampled_from([1, 3, 4, 7]))
def test_deliver_colors_against_fancy_indexing(refs, channels):
    """Four channels (the unrolled copy) and others, against numpy's fancy indexing."""
    sample_src = np.array(refs, np.int32)
    palette = np.arange(7 * channels, dtype=np.float32).reshape(7, channels) + 0.5
    color = np.full((len(refs), channels), -3.0, np.float32)
    deliver_colors(sample_src, palette, color)
    np.testing.assert_array_equal(color, palette[sample_src])


@nb.njit
def _surface_point_shader(inputs, params, textures, out, append):
    """Writes the shading point's world position (linear over a triangle) and its shading time."""
    for i in range(inputs.shape[1]):
        out[i, 0] = inputs[IN_PX, i]
        out[i, 1] = inputs[IN_PY, i]
        out[i, 2] = inputs[IN_T, i]
        out[i, 3] = 1.0


@pytest.mark.parametrize("view", [(0.8, -0.4, 0.9), (-0.6, 0.3, 0.1)])
def test_the_shading_view_keys_the_cache_and_places_the_shading(view):
    """Stereo's chosen view (Nilsson12 §8): with one sample per pixel at the pixel centre and at the view's
    (u, v, t), cache mode at one grid cell per pixel keys each covered sample to its own pixel as seen from
    that view and shades it there: its image equals per-sample shading's (the other code path, each sample
    at its own (t, u, v)); from the default view (lens centre, mid-shutter) the surface points differ."""
    u0, v0, t0 = view
    q = np.array([[[-0.7, -0.6, 0.2, 1.0], [0.5, -0.5, 0.3, 1.0], [-0.1, 0.7, 0.4, 1.0]]])
    r = q + np.array([0.4, 0.1, 0.0, 0.0])  # moves over the shutter
    lens = np.full((1, 3, 2), 0.15)  # and is defocused
    draw = draw_from_clip(q, r, lens, -lens, width=48, height=40)
    table = np.array([[0.5, 0.5, u0, v0, t0]])

    def image(state):
        return run_pass(RenderPass(draw=draw, arch=load_arch(), spp=1, sample_table=table, state=state,
                                   shader=_surface_point_shader, clear_color=(0.0, 0.0, 0.0, 0.0))).image

    per_sample = image(PassState(shading_mode="per_sample"))
    cached = image(PassState(shading_mode="cache", shading_rate=1.0, shading_u=u0, shading_v=v0, shading_t=t0))
    default_view = image(PassState(shading_mode="cache", shading_rate=1.0))
    covered = per_sample[..., 3] > 0
    assert covered.sum() > 200 and np.array_equal(covered, cached[..., 3] > 0)
    np.testing.assert_allclose(cached[covered], per_sample[covered], atol=2e-5)
    assert np.abs(default_view[covered][:, :3] - per_sample[covered][:, :3]).max() > 0.05


def test_triangles_whose_key_has_the_top_bit_set_are_cached():
    """Triangle ids from 2^21 set a key's sign bit: still a grid cell (hit on the second look), not the
    'no cell' sentinel; a unit for more triangles than a key holds is refused."""
    from units.shading_cache import MAX_CACHED_TRIANGLES

    ref_row = np.array([[0.0, 0.0, 1.0], [4.0, 0.0, 1.0], [0.0, 4.0, 1.0]])
    ref = np.broadcast_to(ref_row, (MAX_CACHED_TRIANGLES + 1, 3, 3))
    tri = np.array([2**21, 2**21, MAX_CACHED_TRIANGLES - 1, MAX_CACHED_TRIANGLES - 1], np.int32)
    third = np.full(4, 1.0 / 3.0)
    tags = np.full((4, 2), -1, np.int64)
    stamps = np.zeros((4, 2), np.int64)
    ops, ev = np.zeros(N_OPS, np.int64), np.zeros(len(EVENTS), np.int64)
    cache_kernel(tri, third, third, third, ref, 1.0, tags, stamps, np.full(8, -1, np.int32), 0, REPL_LRU,
                 *cache_scratch(4), ops, ev)
    assert ev[EVENTS.index("hits")] == 2 and ev[EVENTS.index("misses")] == 2
    draw = SimpleNamespace(n=MAX_CACHED_TRIANGLES + 1, width=8, height=8)
    with pytest.raises(ValueError, match="at most"):
        Shading(load_arch().shading, "cache", 1.0, draw, None, None, None, np.zeros(0), None, False)


def test_a_pass_of_more_triangles_than_a_cache_key_holds_is_refused_in_one_line(monkeypatch):
    from pipeline_sim import render
    from pipeline_sim.errors import UserError

    draw = draw_from_clip(np.array([[[-0.5, -0.5, 0.2, 1.0], [0.5, -0.5, 0.2, 1.0], [0.0, 0.5, 0.2, 1.0]]] * 2),
                          width=8, height=8)
    monkeypatch.setattr(render, "MAX_CACHED_TRIANGLES", 1)
    with pytest.raises(UserError, match="keys at most 1 triangles and the pass draws 2.*per_sample"):
        run_pass(RenderPass(draw=draw, arch=load_arch(), spp=1))
    assert run_pass(RenderPass(draw=draw, arch=load_arch(), spp=1, state=PassState(shading_mode="per_sample")))


@given(st.integers(1, 5000), st.lists(st.integers(0, 10**6), min_size=1, max_size=40), st.randoms(use_true_random=False))
def test_request_points_are_numpys_pixel_centres(width, pix_list, rnd):
    """Each request's pixel centre and depth, against numpy's divmod of the first samples' pixels."""
    pix = np.array(pix_list, np.int32)
    z = np.array([rnd.uniform(-1, 1) for _ in pix_list], np.float32)
    first = np.array([rnd.randrange(len(pix_list)) for _ in range(rnd.randrange(1, 20))], np.int32)
    x, y, depth = (np.empty(len(first), np.float32) for _ in range(3))
    request_points(first, pix, z, width, x, y, depth)
    py, px = np.divmod(pix[first], width)
    np.testing.assert_array_equal(x, (px + 0.5).astype(np.float32))
    np.testing.assert_array_equal(y, (py + 0.5).astype(np.float32))
    np.testing.assert_array_equal(depth, z[first])
