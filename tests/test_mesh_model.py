"""The mesh cloth's model and kernels (pipeline.physics.mesh_model, mesh_forces), checked
against independent implementations: the grid FEM's kernels on the grid's triangles, a
spring-by-spring sum in numpy, finite differences of the energy, closed-form areas."""
from __future__ import annotations

import numpy as np
import pytest

from pipeline.physics import fem
from pipeline.physics.mesh_forces import (mesh_fem_energy, mesh_fem_forces, mesh_spring_forces,
                                          with_rest_angles)
from pipeline.physics.mesh_model import lumped_masses, mesh_fem, mesh_springs, topology


def grid_mesh(nw: int, nh: int, width: float, height: float):
    """The course grid's points in the z = 0 plane, its triangles (A, C, B), (B, C, D) and
    uvs (j / (nw - 1), i / (nh - 1)) per corner."""
    i, j = np.divmod(np.arange(nw * nh), nw)
    uv = np.stack([j / (nw - 1), i / (nh - 1)], axis=1)
    points = np.stack([width * j / (nw - 1), height * i / (nh - 1), np.zeros(nw * nh)], axis=1)
    ci, cj = np.meshgrid(np.arange(nh - 1), np.arange(nw - 1), indexing="ij")
    a = (ci * nw + cj).ravel()
    tris = np.concatenate([np.stack([a, a + nw, a + 1], 1), np.stack([a + 1, a + nw, a + nw + 1], 1)])
    return points, tris, uv[tris]


def cylinder_patch(rows: int = 9, cols: int = 12, radius: float = 0.3):
    """A curved mesh: a quarter of a cylinder (axis y), uvs along the arc and the axis."""
    theta = np.linspace(0.0, 0.5 * np.pi, cols)
    y = np.linspace(0.0, 0.4, rows)
    tt, yy = np.meshgrid(theta, y)
    points = np.stack([radius * np.cos(tt).ravel(), yy.ravel(), radius * np.sin(tt).ravel()], 1)
    uv = np.stack([(tt / theta[-1]).ravel(), (yy / y[-1]).ravel()], 1)
    ci, cj = np.meshgrid(np.arange(rows - 1), np.arange(cols - 1), indexing="ij")
    a = (ci * cols + cj).ravel()
    tris = np.concatenate([np.stack([a, a + 1, a + cols], 1),
                           np.stack([a + 1, a + cols + 1, a + cols], 1)])
    return points, tris, uv[tris]


def fem_of(points, tris, corner_uv, stretch=300.0, shear=30.0, bend=1e-3):
    # read-only triangles, as a loaded mesh's: numba types a writeable array apart, and the
    # FEM's kernels would compile again for these tests alone
    tris = np.array(tris, dtype=np.int64)
    tris.flags.writeable = False
    topo = topology(points, tris, corner_uv, True)
    params = mesh_fem(points, topo, stretch, shear, bend)
    return topo, with_rest_angles(params, np.ascontiguousarray(points.T))


def forces(x, params, mass=None):
    f = np.zeros_like(x)
    mass = np.ones(x.shape[1]) if mass is None else mass
    mesh_fem_forces(x, params, mass, np.zeros(3), f)
    return f


def test_fem_on_the_grids_triangles_has_the_grid_fems_forces(rng):
    """A flat mesh of the course grid's triangles: the mesh FEM's forces at random positions
    are the grid FEM's (pipeline.physics.fem, its own element layout and passes)."""
    nw, nh, width, height = 7, 5, 0.9, 0.6
    points, tris, corner_uv = grid_mesh(nw, nh, width, height)
    _, params = fem_of(points, tris, corner_uv)
    grid = fem.build_fem(nw, nh, width, height, 300.0, 30.0, 1e-3, 0.15)
    x = np.ascontiguousarray(points.T + rng.normal(0.0, 0.02, points.T.shape))
    expected = np.zeros_like(x)
    fem.add_fem_forces(x, grid, expected)
    got = forces(x, params)
    assert np.abs(got - expected).max() <= 1e-12 * np.abs(expected).max()
    assert mesh_fem_energy(x, params) == pytest.approx(fem.fem_energy(x, grid), rel=1e-12)


def test_fem_forces_are_minus_the_energy_gradient(rng):
    """Central differences of mesh_fem_energy on a curved mesh away from rest."""
    points, tris, corner_uv = cylinder_patch()
    _, params = fem_of(points, tris, corner_uv)
    x = np.ascontiguousarray(points.T + rng.normal(0.0, 0.01, points.T.shape))
    f = forces(x, params)
    h = 1e-6
    for p in rng.choice(x.shape[1], 12, replace=False):
        for a in range(3):
            xp, xm = x.copy(), x.copy()
            xp[a, p] += h
            xm[a, p] -= h
            grad = (mesh_fem_energy(xp, params) - mesh_fem_energy(xm, params)) / (2 * h)
            assert f[a, p] == pytest.approx(-grad, rel=1e-5, abs=1e-7)


def test_a_curved_mesh_rests_in_its_own_shape():
    """At the file's positions every force vanishes without gravity (FEM and springs)."""
    points, tris, corner_uv = cylinder_patch()
    topo, params = fem_of(points, tris, corner_uv, bend=1e-2)
    x = np.ascontiguousarray(points.T)
    assert np.abs(forces(x, params)).max() < 1e-9
    springs = mesh_springs(points, topo, 5000.0, True, True)
    f = np.zeros_like(x)
    mesh_spring_forces(x, springs, np.ones(x.shape[1]), np.zeros(3), np.zeros((3, len(springs.a))), f)
    assert np.abs(f).max() < 1e-9


def test_springs_forces_are_the_sum_over_the_spring_list(rng):
    points, tris, corner_uv = cylinder_patch()
    topo = topology(points, tris, corner_uv, True)
    springs = mesh_springs(points, topo, 5000.0, True, True)
    x = np.ascontiguousarray(points.T + rng.normal(0.0, 0.01, points.T.shape))
    mass = rng.uniform(0.5, 2.0, x.shape[1])
    g = np.array([0.0, -9.8, 0.0])
    expected = mass * g[:, None]
    for a, b, rest, k in zip(springs.a, springs.b, springs.rest, springs.stiffness):
        d = x[:, b] - x[:, a]
        length = np.linalg.norm(d)
        expected[:, a] += k * (length - rest) * d / length
        expected[:, b] -= k * (length - rest) * d / length
    got = np.zeros_like(x)
    mesh_spring_forces(x, springs, mass, g, np.zeros((3, len(springs.a))), got)
    assert np.allclose(got, expected, rtol=1e-12, atol=1e-9)


def test_springs_are_the_edges_and_one_bending_spring_per_interior_edge():
    """Structural springs on the 23 edges of a 4 x 3 grid's triangles, first, by (later
    point, earlier point); then one bending spring per pair of vertices opposite an interior
    edge (found here by comparing every two triangles)."""
    points, tris, corner_uv = grid_mesh(4, 3, 1.0, 1.0)
    topo = topology(points, tris, corner_uv, True)
    s = mesh_springs(points, topo, 100.0, True, True)
    tri_pairs = {tuple(sorted(e)) for t in tris.tolist()
                 for e in ((t[0], t[1]), (t[1], t[2]), (t[0], t[2]))}
    opposite = set()
    for i, t in enumerate(tris.tolist()):
        for u in tris[i + 1:].tolist():
            if len(set(t) & set(u)) == 2:
                opposite.add(tuple(sorted(set(t) ^ set(u))))
    assert s.structural == len(tri_pairs) == 23
    assert np.all(s.a > s.b)
    pairs = [(int(a), int(b)) for a, b in zip(s.a, s.b)]
    assert pairs[:23] == sorted(pairs[:23]) and pairs[23:] == sorted(pairs[23:])
    assert {(b, a) for a, b in pairs[:23]} == tri_pairs
    assert {(b, a) for a, b in pairs[23:]} == opposite and len(pairs) == 23 + len(opposite)
    assert np.all(s.stiffness[:23] == 100.0) and np.all(s.stiffness[23:] == 20.0)


def test_lumped_masses_sum_to_area_times_density():
    points, tris, _ = cylinder_patch(radius=0.3)
    m = lumped_masses(points, tris, 0.2)
    # the inscribed polyhedral surface's area: the quarter cylinder's chords times the height
    chord = 2 * 0.3 * np.sin(0.5 * (0.5 * np.pi) / 11)
    assert m.sum() == pytest.approx(0.2 * 11 * chord * 0.4, rel=1e-12)


def test_fem_jacobian_products_are_the_grid_fems(rng):
    """K_f y and the diagonal of -K_f of the mesh FEM on the grid's triangles against the
    grid FEM's own (pipeline.physics.fem), away from rest."""
    from pipeline.physics.mesh_forces import mesh_fem_product

    nw, nh, width, height = 7, 5, 0.9, 0.6
    points, tris, corner_uv = grid_mesh(nw, nh, width, height)
    _, params = fem_of(points, tris, corner_uv)
    grid = fem.build_fem(nw, nh, width, height, 300.0, 30.0, 1e-3, 0.15)
    x = np.ascontiguousarray(points.T + rng.normal(0.0, 0.03, points.T.shape))
    y = np.ascontiguousarray(rng.normal(0.0, 1.0, x.shape))
    expected, got = np.zeros_like(x), np.zeros_like(x)
    fem.fem_filtered_jacobian_product(x, grid, y, expected)
    mesh_fem_product(x, y, params, got, False)
    assert np.abs(got - expected).max() <= 1e-11 * np.abs(expected).max()
    fem.fem_jacobian_diagonal(x, grid, expected)
    mesh_fem_product(x, x, params, got, True)
    assert np.abs(got - expected).max() <= 1e-11 * np.abs(expected).max()


def test_spring_jacobian_is_the_derivative_of_the_forces_where_stretched(rng):
    """Every spring stretched (the filter drops nothing): K y against central differences
    of mesh_spring_forces, and the diagonal of -K against K assembled densely here."""
    from pipeline.physics.mesh_forces import (mesh_spring_diagonal_of, mesh_spring_jacobian,
                                              mesh_spring_product)

    points, tris, corner_uv = cylinder_patch(rows=5, cols=6)
    topo = topology(points, tris, corner_uv, True)
    springs = mesh_springs(points, topo, 700.0, True, True)
    n, count = len(points), len(springs.a)
    x = np.ascontiguousarray(1.3 * points.T + rng.normal(0.0, 0.002, points.T.shape))
    unit, alpha = np.zeros((1, 3, count)), np.zeros((1, count))
    mesh_spring_jacobian(x, springs, unit, alpha)
    assert (alpha >= 0.0).all() and (alpha > 0.0).any()
    y = np.ascontiguousarray(rng.normal(0.0, 1.0, x.shape))
    ky = np.zeros_like(x)
    mesh_spring_product(y, springs, unit, alpha, np.zeros((3, count)), ky)
    h, plus, minus = 1e-6, np.zeros_like(x), np.zeros_like(x)
    buffer, ones, g = np.zeros((3, count)), np.ones(n), np.zeros(3)
    mesh_spring_forces(x + h * y, springs, ones, g, buffer, plus)
    mesh_spring_forces(x - h * y, springs, ones, g, buffer, minus)
    assert np.allclose(ky, (plus - minus) / (2 * h), rtol=1e-6, atol=1e-5)
    k = np.zeros((3 * n, 3 * n))
    for a, b, stiffness in zip(springs.a, springs.b, springs.stiffness):
        d = x[:, b] - x[:, a]
        length = np.linalg.norm(d)
        u = d / length
        rest = np.linalg.norm(points[b] - points[a])
        block = stiffness * np.outer(u, u) + stiffness * (1 - rest / length) * (np.eye(3) - np.outer(u, u))
        for p, q, s in ((a, a, 1), (b, b, 1), (a, b, -1), (b, a, -1)):
            k[3 * p:3 * p + 3, 3 * q:3 * q + 3] += s * block
    diagonal = np.zeros_like(x)
    mesh_spring_diagonal_of(springs, unit, alpha, diagonal)
    assert np.allclose(diagonal.T.ravel(), np.diag(k), rtol=1e-12)
