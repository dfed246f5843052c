"""An independent shadow checker: brute-force ray casting in numpy.

Written apart from the renderer (no shading.raster / renderer / shadow code): camera rays
come from the inverted view-projection matrix, hits from Moller-Trumbore on every
triangle. Pixels are classified for the hard shadows of a point light; a spherical
light's visibility is sampled at single points (to check the closed-form penumbra).

    classes = shadow_classes(meshes, camera, light_position)   # (H, W) int8
    v = area_light_visibility(point, meshes, light_position, radius)

Conventions shared with the renderer: pixel centres at half-integers, image row 0 at the
top, triangle ids index the meshes' triangles concatenated in list order, and meshes
named "plane" receive shadows but do not cast them.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

BACKGROUND, SHADOWED, LIT, FACES_AWAY = -1, 0, 1, 2
SHADOW_EPS = 1e-5  # metres: shadow rays start this far off the surface (two-sided normal)
EDGE_EPS = 1e-9  # barycentric slack: a ray through a shared edge hits at least one side
CLUSTER = 32  # triangles per bounding sphere
PAIRS = 1 << 15  # ray-triangle pairs per numpy chunk: its temporaries stay in cache


class Hits(NamedTuple):
    """First hits of the camera rays, flattened row-major (H*W): t = inf and tri = -1 on
    the background; points the hit points; normals the geometric normals of the hit
    triangles, turned toward the camera (two-sided); zero on the background."""

    t: np.ndarray
    tri: np.ndarray
    points: np.ndarray
    normals: np.ndarray


def scene_triangles(meshes) -> tuple[np.ndarray, np.ndarray]:
    """(tris (T,3,3) vertex positions, casts (T,) bool: not on a plane), meshes in order."""
    tris = np.concatenate([m.positions[m.triangles] for m in meshes])
    casts = np.concatenate([np.full(len(m.triangles), m.name != "plane") for m in meshes])
    return tris, casts


def camera_rays(camera) -> tuple[np.ndarray, np.ndarray]:
    """(origins, unit directions), each (H*W, 3) row-major, through the pixel centres;
    origins on the near plane (where the rasteriser clips)."""
    w, h = camera.width, camera.height
    x, y = np.meshgrid((np.arange(w) + 0.5) / w * 2 - 1, 1 - (np.arange(h) + 0.5) / h * 2)
    inv = np.linalg.inv(camera.view_projection())

    def unproject(z):
        c = np.stack([x.ravel(), y.ravel(), np.full(x.size, z), np.ones(x.size)], axis=1)
        c = c @ inv.T
        return c[:, :3] / c[:, 3:]

    near, far = unproject(-1.0), unproject(1.0)
    d = far - near
    return near, d / np.linalg.norm(d, axis=1, keepdims=True)


def _clusters(centroids: np.ndarray, idx: np.ndarray) -> list[np.ndarray]:
    """Triangle ids split at the median of the longest axis until CLUSTER or fewer."""
    if len(idx) <= CLUSTER:
        return [idx]
    c = centroids[idx]
    order = idx[np.argsort(c[:, np.argmax(np.ptp(c, axis=0))], kind="stable")]
    half = len(order) // 2
    return _clusters(centroids, order[:half]) + _clusters(centroids, order[half:])


def _moller_trumbore(o, d, v0, e1, e2):
    """t (R, K) of rays o, d (R,3) against triangles v0 + (e1, e2) (K,3); inf where
    missed. Component-wise on (R, K) arrays: no (R, K, 3) temporaries."""
    ox, oy, oz = (o[:, i:i + 1] for i in range(3))
    dx, dy, dz = (d[:, i:i + 1] for i in range(3))
    ax, ay, az = e1.T
    bx, by, bz = e2.T
    px, py, pz = dy * bz - dz * by, dz * bx - dx * bz, dx * by - dy * bx
    det = ax * px + ay * py + az * pz
    ok = np.abs(det) > 1e-14
    inv = 1.0 / np.where(ok, det, 1.0)
    sx, sy, sz = ox - v0[:, 0], oy - v0[:, 1], oz - v0[:, 2]
    u = (sx * px + sy * py + sz * pz) * inv
    qx, qy, qz = sy * az - sz * ay, sz * ax - sx * az, sx * ay - sy * ax
    v = (dx * qx + dy * qy + dz * qz) * inv
    t = (bx * qx + by * qy + bz * qz) * inv
    hit = ok & (u >= -EDGE_EPS) & (v >= -EDGE_EPS) & (u + v <= 1 + EDGE_EPS) & (t > 0)
    return np.where(hit, t, np.inf)


def first_hits(origins, dirs, tris, *, t_max=None, skip=None,
               ids=None) -> tuple[np.ndarray, np.ndarray]:
    """(t, triangle id) of the nearest hit with 0 < t < t_max (default inf) of each ray
    against every triangle of `tris` (T,3,3); t = inf and id = -1 on a miss.

    `ids` (T,) names the triangles (default 0..T-1); `skip` (R,) is a triangle id per ray
    that ray ignores. `dirs` must be unit vectors. Rays are tested only against clusters
    of triangles whose bounding sphere they meet: a conservative cull, so the result is
    that of testing every triangle."""
    o = np.asarray(origins, dtype=np.float64)
    d = np.asarray(dirs, dtype=np.float64)
    tris = np.asarray(tris, dtype=np.float64).reshape(-1, 3, 3)
    ids = np.arange(len(tris)) if ids is None else np.asarray(ids)
    best = np.full(len(o), np.inf) if t_max is None else np.array(t_max, dtype=np.float64)
    best_id = np.full(len(o), -1, np.int64)
    for k in _clusters(tris.mean(axis=1), np.arange(len(tris))):
        block = tris[k]
        v0, e1, e2 = block[:, 0], block[:, 1] - block[:, 0], block[:, 2] - block[:, 0]
        centre = block.reshape(-1, 3).mean(axis=0)
        radius = np.sqrt(np.max(np.sum((block.reshape(-1, 3) - centre) ** 2, axis=1))) + 1e-9
        oc = centre - o
        along = np.einsum("rj,rj->r", oc, d)
        miss2 = np.einsum("rj,rj->r", oc, oc) - along ** 2
        rays = np.nonzero((miss2 <= radius ** 2) & (along + radius > 0)
                          & (along - radius < best))[0]
        step = max(1, PAIRS // len(k))
        for r0 in range(0, len(rays), step):
            r = rays[r0:r0 + step]
            t = _moller_trumbore(o[r], d[r], v0, e1, e2)
            if skip is not None:
                t[skip[r][:, None] == ids[k][None]] = np.inf
            j = np.argmin(t, axis=1)
            tj = t[np.arange(len(r)), j]
            closer = tj < best[r]
            best[r[closer]] = tj[closer]
            best_id[r[closer]] = ids[k][j[closer]]
    best[best_id < 0] = np.inf
    return best, best_id


def trace_camera(meshes, camera) -> Hits:
    """The first hit of every pixel's camera ray among all the meshes' triangles."""
    tris, _ = scene_triangles(meshes)
    o, d = camera_rays(camera)
    t, tri = first_hits(o, d, tris)
    covered = tri >= 0
    points = np.where(covered[:, None], o + np.where(covered, t, 0.0)[:, None] * d, 0.0)
    n = np.zeros_like(points)
    f = tris[tri[covered]]
    n[covered] = np.cross(f[:, 1] - f[:, 0], f[:, 2] - f[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    n *= np.where(np.einsum("rj,rj->r", n, d) > 0, -1.0, 1.0)[:, None]
    return Hits(t, tri, points, n)


def shadow_classes(meshes, camera, light_position, hits: Hits | None = None) -> np.ndarray:
    """(H, W) int8: BACKGROUND (-1), SHADOWED (0), LIT (1) or FACES_AWAY (2: the hit
    triangle's two-sided geometric normal has n.l <= 0) for a point light.

    A point is shadowed by any triangle of a non-plane mesh, other than the one it lies
    on, crossed by the segment from it (moved SHADOW_EPS along the normal) to the light.
    `hits` (from trace_camera) saves tracing the camera rays again."""
    hits = trace_camera(meshes, camera) if hits is None else hits
    tris, casts = scene_triangles(meshes)
    lp = np.asarray(light_position, dtype=np.float64)
    out = np.full(len(hits.t), BACKGROUND, np.int8)
    covered = hits.tri >= 0
    to_light = lp - hits.points
    facing = covered & (np.einsum("rj,rj->r", hits.normals, to_light) > 0)
    out[covered & ~facing] = FACES_AWAY
    r = np.nonzero(facing)[0]
    o = hits.points[r] + SHADOW_EPS * hits.normals[r]
    seg = lp - o
    dist = np.linalg.norm(seg, axis=1)
    caster = np.nonzero(casts)[0]
    _, blocker = first_hits(o, seg / dist[:, None], tris[caster], t_max=dist,
                            skip=hits.tri[r], ids=caster)
    out[r] = np.where(blocker >= 0, SHADOWED, LIT)
    return out.reshape(camera.height, camera.width)


def smooth_normals(meshes, hits: Hits) -> np.ndarray:
    """(H*W, 3) interpolated vertex normals at the hit points (unnormalised, not made
    two-sided); zero on the background."""
    pos = np.concatenate([m.positions for m in meshes])
    nrm = np.concatenate([m.normals for m in meshes])
    base = np.cumsum([0] + [len(m.positions) for m in meshes[:-1]])
    corners = np.concatenate([m.triangles + b for m, b in zip(meshes, base)])
    out = np.zeros_like(hits.points)
    covered = hits.tri >= 0
    c = corners[hits.tri[covered]]
    a, e1, e2 = pos[c[:, 0]], pos[c[:, 1]] - pos[c[:, 0]], pos[c[:, 2]] - pos[c[:, 0]]
    # barycentrics of the hit point: least squares in the triangle's plane
    rel = hits.points[covered] - a
    g11, g12, g22 = (np.einsum("rj,rj->r", x, y) for x, y in ((e1, e1), (e1, e2), (e2, e2)))
    r1, r2 = np.einsum("rj,rj->r", rel, e1), np.einsum("rj,rj->r", rel, e2)
    det = g11 * g22 - g12 ** 2
    b1 = (g22 * r1 - g12 * r2) / det
    b2 = (g11 * r2 - g12 * r1) / det
    out[covered] = ((1 - b1 - b2)[:, None] * nrm[c[:, 0]] + b1[:, None] * nrm[c[:, 1]]
                    + b2[:, None] * nrm[c[:, 2]])
    return out


def area_light_visibility(point, meshes, light_position, radius: float, samples: int = 4000,
                          seed: int = 0) -> float:
    """Share of a spherical light (radius > 0) that `point` sees past the non-plane
    meshes: rays to random points of the light's disc facing the point (the sphere's
    outline, for a light small beside its distance), uniform in area."""
    rng = np.random.default_rng(seed)
    p = np.asarray(point, dtype=np.float64)
    lp = np.asarray(light_position, dtype=np.float64)
    axis = (lp - p) / np.linalg.norm(lp - p)
    e1 = np.cross(axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    ang = rng.uniform(0, 2 * np.pi, samples)
    rad = radius * np.sqrt(rng.uniform(0, 1, samples))
    seg = lp + rad[:, None] * (np.cos(ang)[:, None] * e1 + np.sin(ang)[:, None] * e2) - p
    dist = np.linalg.norm(seg, axis=1)
    tris, casts = scene_triangles(meshes)
    _, blocker = first_hits(np.broadcast_to(p, seg.shape), seg / dist[:, None], tris[casts],
                            t_max=dist)
    return float(np.mean(blocker < 0))
