"""The independent self-intersection checker of issue 43 (benchmarks/crossings.py) on meshes
with known crossings and distances worked out by hand, and against brute force."""
from __future__ import annotations

import importlib.util
import itertools
import sys
from pathlib import Path

import numpy as np
import pytest

def _load_checker():
    """benchmarks/crossings.py by its path: benchmarks/ on sys.path would shadow packages
    (its distributed.py the Dask one)."""
    spec = importlib.util.spec_from_file_location(
        "crossings", Path(__file__).resolve().parents[1] / "benchmarks" / "crossings.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules["crossings"] = module
    spec.loader.exec_module(module)
    return module


C = _load_checker()
from crossings import (  # noqa: E402
    edge_triangle_contacts,
    edge_triangle_crossing_pairs,
    edge_triangle_crossings,
    min_separation,
    separation_pairs,
)

# --- meshes ----------------------------------------------------------------------------------
#: a square in z = 0, x and y in [-1, 1]: triangles (v0 v1 v2) below the diagonal y = x and
#: (v0 v2 v3) above it
SQUARE = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], float)
SQUARE_TRIS = np.array([[0, 1, 2], [0, 2, 3]])


def two_squares_x():
    """Square A (above) and square B upright in the plane x = 0.3, y in [-2, 2], z in [-1, 1],
    diagonal w0-w2 (z = y / 2 in its plane): the two cut each other along x = 0.3, z = 0,
    y in [-1, 1] (A's extent), like an X seen along y.

    A's edges crossing B's plane inside B: the bottom v0-v1 at (0.3, -1, 0) (above B's diagonal:
    z = 0 > y/2 = -0.5, so B's triangle 3), the top v2-v3 at (0.3, 1, 0) (below it: triangle 2)
    and A's diagonal v0-v2 at (0.3, 0.3, 0) (0 < 0.15: triangle 2); A's sides x = -1, 1 do
    not reach x = 0.3. B's edges crossing z = 0 inside A: only B's diagonal w0-w2, at
    (0.3, 0, 0), below A's diagonal (y = 0 < x = 0.3: A's triangle 0); B's sides y = +-2 cross
    z = 0 outside A and its top and bottom lie in z = +-1. 3 + 1 = 4 crossings."""
    b = np.array([[0.3, -2, -1], [0.3, 2, -1], [0.3, 2, 1], [0.3, -2, 1]], float)
    return np.vstack([SQUARE, b]), np.vstack([SQUARE_TRIS, SQUARE_TRIS + 4])


X_CROSSINGS = [[0, 1, 3], [0, 2, 2], [2, 3, 2], [4, 6, 0]]


def square_and_sliver():
    """Square A and a sliver triangle in the plane y = -0.3, x in [0.2, 0.21], z in [-1, 1]:
    its two long edges pass through A below A's diagonal (triangle 0) at x = 0.2 and 0.205;
    its short edge lies in z = 1. A's edges meet the plane y = -0.3 only at x = -1, 1 (the
    sides) and x = -0.3 (the diagonal), all outside the sliver: 2 crossings."""
    s = np.array([[0.2, -0.3, -1], [0.2, -0.3, 1], [0.21, -0.3, 1]])
    return np.vstack([SQUARE, s]), np.vstack([SQUARE_TRIS, [[4, 5, 6]]])


def grid(nw, nh, s=0.1):
    """A flat grid in z = 0 triangulated like the simulator's: per cell (A, C, B), (B, C, D)
    with A the corner at the lowest index, vertex index row * nw + column."""
    i, j = np.meshgrid(np.arange(nh), np.arange(nw), indexing="ij")
    pts = np.stack([j.ravel() * s, i.ravel() * s, np.zeros(nw * nh)], 1)
    a = (i[:-1, :-1] * nw + j[:-1, :-1]).ravel()
    tris = np.stack([np.stack([a, a + nw, a + 1], 1),
                     np.stack([a + 1, a + nw, a + nw + 1], 1)], 1).reshape(-1, 3)
    return pts, tris


M, ROWS, S, H = 6, 6, 0.125, 0.0625  # fold: 2M columns, ROWS rows, spacing, layer gap


def folded(h=H):
    """A 2M x ROWS grid folded in half about x = (M - 1) S: columns 0..M-1 lie in z = 0,
    columns M..2M-1 mirrored above them in z = h (column i at x = (2M - 1 - i) S), the cells
    between columns M-1 and M an upright band at the fold."""
    pts, tris = grid(2 * M, ROWS, S)
    col = np.arange(len(pts)) % (2 * M)
    up = col >= M
    pts[up, 0] = (2 * M - 1 - col[up]) * S
    pts[up, 2] = h
    return pts, tris


#: an upper-layer vertex well inside (row 2, column M + 2: above x = (M - 3) S, y = 2 S), and
#: the lower triangle (A, C, B) of the cell whose corner A lies under it
V = 2 * (2 * M) + M + 2
T0_CORNER = 2 * (2 * M) + (M - 3)


def t0_index(tris):
    a = T0_CORNER
    return int(np.nonzero((tris == [a, a + 2 * M, a + 1]).all(axis=1))[0][0])


def v_edges(tris):
    e = C.unique_edges(tris)
    return e[(e == V).any(axis=1)]


# --- crossings -------------------------------------------------------------------------------
def test_two_squares_in_an_x_cross_four_times():
    pts, tris = two_squares_x()
    assert edge_triangle_crossings(pts, tris) == 4
    assert edge_triangle_crossing_pairs(pts, tris).tolist() == X_CROSSINGS
    assert len(edge_triangle_contacts(pts, tris).touching) == 0


@pytest.mark.parametrize("seed", range(5))
def test_two_squares_moved_anywhere_still_cross_four_times(seed):
    """A rigid motion changes no count (the positions are generic: no exact zeros)."""
    rng = np.random.default_rng(seed)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    pts, tris = two_squares_x()
    moved = pts @ q.T + rng.normal(size=3) * 10
    c = edge_triangle_contacts(moved, tris)
    assert c.crossings.tolist() == X_CROSSINGS and len(c.touching) == 0


def test_square_pierced_by_a_sliver_crosses_twice():
    pts, tris = square_and_sliver()
    assert edge_triangle_crossing_pairs(pts, tris).tolist() == [[4, 5, 0], [4, 6, 0]]


def test_flat_grid_has_no_crossing_and_no_touching():
    pts, tris = grid(12, 9)
    c = edge_triangle_contacts(pts, tris)
    assert len(c.crossings) == 0 and len(c.touching) == 0
    wavy = pts.copy()
    wavy[:, 2] = 0.05 * np.sin(7 * pts[:, 0]) * np.cos(5 * pts[:, 1])
    assert edge_triangle_crossings(wavy, tris) == 0


def test_folded_strip_with_a_gap_neither_crosses_nor_touches():
    pts, tris = folded()
    c = edge_triangle_contacts(pts, tris)
    assert len(c.crossings) == 0 and len(c.touching) == 0


def test_folded_strip_touching_at_a_vertex_is_touching_not_crossing():
    """The upper vertex V put exactly on the lower layer, inside T0 (S/4 from its corner in
    x and y: exact in binary): V's 6 edges each end on T0 and nothing else meets."""
    pts, tris = folded()
    pts[V] = [(M - 3) * S + S / 4, 2 * S + S / 4, 0.0]
    c = edge_triangle_contacts(pts, tris)
    assert len(c.crossings) == 0
    assert c.touching[:, :2].tolist() == v_edges(tris).tolist()
    assert set(c.touching[:, 2]) == {t0_index(tris)}


def test_strip_folded_flat_onto_itself_touches_but_does_not_cross():
    """Both layers in z = 0 (the fold band collapsed onto a line): coplanar overlaps only."""
    pts, tris = folded(h=0.0)
    c = edge_triangle_contacts(pts, tris)
    assert len(c.crossings) == 0 and len(c.touching) > 0


def test_vertex_pushed_through_the_other_layer_crosses_six_times():
    """V moved to just under the lower layer (z = -H/20) above T0's centroid: each of its 6
    edges runs from there to a neighbour at z = H, crossing z = 0 at 1/21 of its length from V,
    within 0.09 S of the centroid and so inside T0 (0.23 S from T0's nearest side); the tent
    of V's triangles cuts z = 0 in that small hexagon, which no lower edge reaches: 6 crossings,
    all with T0."""
    pts, tris = folded()
    pts[V] = [(M - 3) * S + S / 3, 2 * S + S / 3, -H / 20]
    pairs = edge_triangle_crossing_pairs(pts, tris)
    assert len(pairs) == 6
    assert pairs[:, :2].tolist() == v_edges(tris).tolist()
    assert set(pairs[:, 2]) == {t0_index(tris)}
    assert len(edge_triangle_contacts(pts, tris).touching) == 0


def test_a_pass_through_exactly_at_a_triangle_edge_is_touching():
    """The square and a triangle (0,0,-1), (0,0,1), (5,3,-0.5): its edge 4-5 passes through
    the middle of the square's diagonal exactly, a zero orientation against both triangles:
    touching (twice), not crossing (module doc); so is the diagonal 0-2 against the triangle
    (through its edge). The triangle cuts z = 0 along (0,0,0)-(10/3,2,0), y = 0.6 x, which
    leaves the square through its side 1-2 at (1, 0.6, 0): that is a crossing. Its other
    edges stay below z = 0 or meet it at x = 10/3, outside the square."""
    pts = np.vstack([SQUARE, [[0.0, 0.0, -1.0], [0.0, 0.0, 1.0], [5, 3, -0.5]]])
    tris = np.vstack([SQUARE_TRIS, [[4, 5, 6]]])
    c = edge_triangle_contacts(pts, tris)
    assert c.crossings.tolist() == [[1, 2, 2]]
    assert c.touching.tolist() == [[0, 2, 2], [4, 5, 0], [4, 5, 1]]


# --- the exact predicate, the float filters, the pruning --------------------------------------
def _brute_contacts(pts, tris):
    """Every (edge, triangle) pair sharing no vertex, decided exactly, no pruning."""
    cross, touch = [], []
    for (u, v), t in itertools.product(C.unique_edges(tris).tolist(), range(len(tris))):
        if u in tris[t] or v in tris[t]:
            continue
        kind = C._classify_exact(pts[u], pts[v], *pts[tris[t]])
        (cross if kind == 1 else touch if kind == 2 else []).append([u, v, t])
    return cross, touch


def _float_crossing(p, q, a, b, c):
    """A plain float segment-triangle test (Moller-Trumbore style) for generic positions."""
    n = np.cross(b - a, c - a)
    dp, dq = np.dot(p - a, n), np.dot(q - a, n)
    if dp * dq >= 0:
        return False
    x = p + (q - p) * dp / (dp - dq)
    return all(np.dot(np.cross(v - u, x - u), n) > 0 for u, v in ((a, b), (b, c), (c, a)))


def crumpled(seed, nw=7, nh=6):
    """A grid whose points are thrown about a small box: many crossings, generic positions."""
    pts, tris = grid(nw, nh, 0.1)
    rng = np.random.default_rng(seed)
    return pts + rng.normal(scale=0.08, size=pts.shape), tris


@pytest.mark.parametrize("seed", range(4))
def test_pruned_count_matches_brute_force_and_a_float_test(seed):
    pts, tris = crumpled(seed)
    cross, touch = _brute_contacts(pts, tris)
    c = edge_triangle_contacts(pts, tris)
    assert c.crossings.tolist() == sorted(cross) and c.touching.tolist() == sorted(touch) == []
    floats = [[u, v, t] for (u, v), t in itertools.product(C.unique_edges(tris).tolist(),
                                                           range(len(tris)))
              if u not in tris[t] and v not in tris[t]
              and _float_crossing(pts[u], pts[v], *pts[tris[t]])]
    assert sorted(floats) == sorted(cross) and len(cross) > 10


def test_a_few_huge_elements_are_tested_against_everything():
    """One point flung far: its long edges and big triangles go round the k-d tree."""
    pts, tris = crumpled(7)
    pts[20] = [3.0, -2.0, 0.5]
    cross, _ = _brute_contacts(pts, tris)
    assert edge_triangle_crossing_pairs(pts, tris).tolist() == sorted(cross)
    assert any(20 in row[:2] for row in cross)


@pytest.mark.parametrize("seed", range(3))
def test_vectorised_decision_equals_the_exact_one_on_degenerate_configurations(seed):
    """Points on a coarse lattice (exact zeros everywhere: coplanar, through edges, ends on
    planes) and the same lattice in non-representable steps (0.1 k: near-zeros that floats get
    wrong): the filtered float signs decide as the rational arithmetic does."""
    rng = np.random.default_rng(seed)
    for step in (0.5, 0.1, 1 / 3):
        P, Q, A, B, Cc = (rng.integers(0, 4, size=(2000, 3)) * step for _ in range(5))
        A[::3, 2] = B[::3, 2] = Cc[::3, 2] = P[::3, 2]  # many coplanar and on-plane cases
        P[1::3] = (A[1::3] + B[1::3]) * 0.5  # ends on a triangle edge
        got = C._classify(P, Q, A, B, Cc, 1e-9)
        want = [C._classify_exact(*x) for x in zip(P, Q, A, B, Cc)]
        assert got.tolist() == want
        assert {0, 1, 2} <= set(want)


def test_diverged_positions_are_refused():
    pts, tris = grid(3, 3)
    pts[4, 0] = np.nan
    with pytest.raises(ValueError, match="finite"):
        edge_triangle_crossings(pts, tris)


# --- separation ------------------------------------------------------------------------------
@pytest.mark.parametrize("d", [0.1, 0.003])
def test_two_parallel_squares_are_their_distance_apart(d):
    """Unit-sided squares at z = 0 and z = d, the upper shifted in x and y: every point of the
    one above the other's plane at d; within a square the nearest non-sharing pair is a
    corner against the far triangle, at the diagonal's half 0.707 > d."""
    sq = SQUARE * 0.5
    pts = np.vstack([sq, sq + [0.2, 0.1, d]])
    tris = np.vstack([SQUARE_TRIS, SQUARE_TRIS + 4])
    assert min_separation(pts, tris, r=0.5) == pytest.approx(d, rel=1e-12)
    assert min_separation(pts, tris, r=0.5 * d) == np.inf


def test_point_above_a_triangle():
    tri = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    inside = np.vstack([tri, [[0.25, 0.25, 0.3]]])
    assert min_separation(inside, [[0, 1, 2]], r=1.0) == pytest.approx(0.3, rel=1e-12)
    # beyond the hypotenuse x + y = 1: to the edge, sqrt(((1.2 - 1) / sqrt 2)^2 + 0.3^2)
    outside = np.vstack([tri, [[0.6, 0.6, 0.3]]])
    want = np.hypot(0.2 / np.sqrt(2), 0.3)
    assert min_separation(outside, [[0, 1, 2]], r=1.0) == pytest.approx(want, rel=1e-12)


@pytest.mark.parametrize("seed", range(4))
def test_two_skew_edges(seed):
    """Edge (-1,0,0)-(1,0,0) of a triangle hanging below it in y = 0, edge (0.3,-1,d)-(0.3,1,d)
    of a triangle standing above it in x = 0.3: the common perpendicular (0.3,0,0)-(0.3,0,d)
    gives d; every vertex-triangle pair is further (at least sqrt(0.49 + d^2)), and so are the
    other edge pairs. Then turned and moved anywhere."""
    d = 0.05 * (seed + 1)
    pts = np.array([[-1, 0, 0], [1, 0, 0], [0, 0, -1],
                    [0.3, -1, d], [0.3, 1, d], [0.3, 0, d + 1]], float)
    tris = [[0, 1, 2], [3, 4, 5]]
    sep = separation_pairs(pts, tris, r=0.5)
    assert len(sep.vt) == 0 and sep.ee.tolist() == [[0, 1, 3, 4]]
    assert sep.min == pytest.approx(d, rel=1e-12)
    rng = np.random.default_rng(seed)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    moved = pts @ q.T + rng.normal(size=3)
    assert min_separation(moved, tris, r=0.5) == pytest.approx(d, rel=1e-9)
    # skew at an angle: closed form |(p2 - p1) . (u x v)| / |u x v|
    slanted = pts.copy()
    slanted[3:, 0] += np.array([-0.2, 0.2, 0.0])  # edge 3-4 now runs (0.5,-1,d)-(0.1,1,d)
    u, v = slanted[1] - slanted[0], slanted[4] - slanted[3]
    n = np.cross(u, v)
    want = abs(np.dot(slanted[3] - slanted[0], n)) / np.linalg.norm(n)
    assert min_separation(slanted, tris, r=0.5) == pytest.approx(want, rel=1e-12)


def test_rest_shape_leaves_out_pairs_that_were_close_at_rest():
    """A flat grid at rest: its closest non-sharing pairs are a vertex against the far
    triangle of its cell, across the diagonal, at S / sqrt 2; with rest_min above that they
    go and the next are parallel edges of a cell, at S."""
    pts, tris = grid(6, 5, S)
    assert min_separation(pts, tris, r=2 * S) == pytest.approx(S / np.sqrt(2), rel=1e-12)
    assert min_separation(pts, tris, r=2 * S, rest_points=pts,
                          rest_min=0.75 * S) == pytest.approx(S, rel=1e-12)


@pytest.mark.parametrize("seed", range(3))
def test_separation_matches_brute_force(seed):
    pts, tris = crumpled(seed)
    pts[11] = [2.0, 2.0, 2.0]  # a few big elements too
    r = 0.06
    sep = separation_pairs(pts, tris, r)
    sep_np = separation_pairs(pts, tris, r, compiled=False)
    want_vt, want_ee = [], []
    for v, t in itertools.product(range(len(pts)), range(len(tris))):
        if v not in tris[t]:
            dv = C.point_triangle_distance(pts[v], *pts[tris[t]])[0]
            if dv <= r:
                want_vt.append((v, t, dv))
    edges = C.unique_edges(tris)
    for a, b in itertools.combinations(range(len(edges)), 2):
        if not set(edges[a]) & set(edges[b]):
            de = C.segment_segment_distance(*pts[edges[a]], *pts[edges[b]])[0]
            if de <= r:
                want_ee.append((*edges[a], *edges[b], de))
    for got in (sep, sep_np):
        assert got.vt.tolist() == [[v, t] for v, t, _ in want_vt]
        np.testing.assert_allclose(got.vt_dist, [x[-1] for x in want_vt], rtol=1e-12)
        assert got.ee.tolist() == [list(x[:4]) for x in want_ee]
        np.testing.assert_allclose(got.ee_dist, [x[-1] for x in want_ee], rtol=1e-12)
    assert len(want_vt) > 5 and len(want_ee) > 5


def test_distances_against_closed_forms_and_brute_sampling():
    rng = np.random.default_rng(3)
    p1, q1, p2, q2 = (rng.normal(size=(200, 3)) for _ in range(4))
    d = C.segment_segment_distance(p1, q1, p2, q2)
    s = np.linspace(0, 1, 201)
    for k in range(0, 200, 20):  # dense sampling bounds it from above, closely
        x = p1[k] + s[:, None] * (q1[k] - p1[k])
        y = p2[k] + s[:, None] * (q2[k] - p2[k])
        sampled = np.linalg.norm(x[:, None] - y[None], axis=2).min()
        assert d[k] <= sampled + 1e-12 and sampled - d[k] < 0.02
    # parallel segments, overlapping and apart
    assert C.segment_segment_distance([0, 0, 0], [1, 0, 0], [0.5, 0.3, 0], [2, 0.3, 0])[0] == \
        pytest.approx(0.3)
    assert C.segment_segment_distance([0, 0, 0], [1, 0, 0], [2, 0.3, 0], [3, 0.3, 0])[0] == \
        pytest.approx(np.hypot(1, 0.3))
