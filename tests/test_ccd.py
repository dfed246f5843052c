"""Continuous collision detection (pipeline.physics.ccd) against closed forms."""
from __future__ import annotations

import numpy as np
import pytest

from pipeline.physics.ccd import (cubic_roots, edge_edge_distance, edge_edge_impact,
                                  point_triangle_distance, point_triangle_impact)

TRI = ((0.0, 0.0, 0.0), (1.0, 0.0, 0.0), (0.0, 0.0, 1.0))  # in the plane y = 0
TOL = 1e-9


def pt(p0, p1, tri0=TRI, tri1=TRI):
    return point_triangle_impact(p0, *tri0, p1, *tri1, TOL, np.zeros(4))


def ee(e0, e1, f0, f1):
    return edge_edge_impact(e0[0], e0[1], f0[0], f0[1], e1[0], e1[1], f1[0], f1[1], TOL,
                            np.zeros(4))


def test_a_point_falling_through_a_triangle_hits_it_halfway():
    assert pt((0.2, 1.0, 0.2), (0.2, -1.0, 0.2)) == pytest.approx(0.5, abs=1e-12)
    assert pt((0.2, 1.0, 0.2), (0.2, 0.5, 0.2)) == -1.0  # stops short
    assert pt((0.8, 1.0, 0.8), (0.8, -1.0, 0.8)) == -1.0  # passes beside the hypotenuse


def test_a_triangle_rising_through_a_still_point():
    low = tuple((x, y - 1.0, z) for x, y, z in TRI)
    high = tuple((x, y + 3.0, z) for x, y, z in TRI)
    assert pt((0.1, 0.0, 0.1), (0.1, 0.0, 0.1), low, high) == pytest.approx(0.25, abs=1e-12)


def test_a_tilting_triangle_meets_a_point_at_the_root_of_its_cubic():
    """b rises from (1, 0, 0) to (1, 1, 0): the plane's normal is (t, -1, 0), so the still
    point (0.25, 0.1, 0.25) is on it when 0.25 t = 0.1, at t = 0.4, inside the triangle."""
    tilted = (TRI[0], (1.0, 1.0, 0.0), TRI[2])
    t = pt((0.25, 0.1, 0.25), (0.25, 0.1, 0.25), TRI, tilted)
    assert t == pytest.approx(0.4, abs=1e-9)


def test_the_first_of_several_coplanar_instants_is_the_impact():
    """A point going down through the plane and back up: two crossings, the first wins."""
    # the triangle moves up by 2 while the point moves up by 1 after starting 0.5 above
    up = tuple((x, y + 2.0, z) for x, y, z in TRI)
    t = pt((0.2, 0.5, 0.2), (0.2, 1.5, 0.2), TRI, up)
    assert t == pytest.approx(0.5, abs=1e-12)  # 0.5 + t = 2 t


def test_crossing_edges_meet_when_coplanar():
    e = ((-1.0, 0.0, 0.0), (1.0, 0.0, 0.0))
    f0 = ((0.0, 1.0, -1.0), (0.0, 1.0, 1.0))
    f1 = ((0.0, -1.0, -1.0), (0.0, -1.0, 1.0))
    assert ee(e, e, f0, f1) == pytest.approx(0.5, abs=1e-12)
    beside0 = ((2.0, 1.0, -1.0), (2.0, 1.0, 1.0))  # passes beyond the end of e
    beside1 = ((2.0, -1.0, -1.0), (2.0, -1.0, 1.0))
    assert ee(e, e, beside0, beside1) == -1.0


def test_parallel_edges_meet_only_where_they_overlap():
    e = ((0.0, 0.0, 0.0), (1.0, 0.0, 0.0))
    over0, over1 = ((0.5, 1.0, 0.0), (1.5, 1.0, 0.0)), ((0.5, -1.0, 0.0), (1.5, -1.0, 0.0))
    assert ee(e, e, over0, over1) == pytest.approx(0.5, abs=1e-9)
    apart0, apart1 = ((0.0, 1.0, 0.5), (1.0, 1.0, 0.5)), ((0.0, -1.0, 0.5), (1.0, -1.0, 0.5))
    assert ee(e, e, apart0, apart1) == -1.0  # always 0.5 apart in z


def test_grazing_and_coplanar_starts():
    # sliding in the triangle's plane, outside it all along: no impact; inside at the start
    assert pt((1.0, 0.0, 1.0), (2.0, 0.0, 2.0)) == -1.0
    assert pt((0.1, 0.0, 0.1), (0.3, 0.0, 0.1)) == 0.0
    # touching the plane at one instant from above and leaving: a double root, inside
    touch0, touch1 = (0.2, 1.0, 0.2), (0.2, 1.0, 0.2)
    down = tuple((x, y + 2.0, z) for x, y, z in TRI)  # the triangle rises to the point...
    assert pt(touch0, touch1, TRI, down) == pytest.approx(0.5, abs=1e-12)


def test_cubic_roots_of_a_known_cubic():
    out = np.zeros(4)
    # (t - 0.1)(t - 0.5)(t - 0.9) = t^3 - 1.5 t^2 + 0.59 t - 0.045
    count = cubic_roots((-0.045, 0.59, -1.5, 1.0), out)
    assert count == 3 and np.allclose(out[:3], [0.1, 0.5, 0.9], atol=1e-12)
    count = cubic_roots((-0.25, 1.0, -1.0, 0.0), out)  # -(t - 0.5)^2: a double root
    assert count == 1 and out[0] == pytest.approx(0.5, abs=1e-7)
    assert cubic_roots((1.0, 0.0, 0.0, 0.0), out) == 0


def test_distances_against_closed_forms():
    d, u, v, w = point_triangle_distance((0.25, 0.3, 0.25), *TRI)
    assert d == pytest.approx(0.3) and (u, v, w) == pytest.approx((0.5, 0.25, 0.25))
    d, *_ = point_triangle_distance((2.0, 0.0, 0.0), *TRI)
    assert d == pytest.approx(1.0)
    d, s, t = edge_edge_distance((-1.0, 0.0, 0.0), (1.0, 0.0, 0.0), (0.0, 0.7, -1.0),
                                 (0.0, 0.7, 1.0))
    assert d == pytest.approx(0.7) and (s, t) == pytest.approx((0.5, 0.5))
