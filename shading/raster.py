"""The numba rasteriser (SPEC section 4). It knows nothing of lighting.

Pipeline per frame, all on flat arrays:
  1. `transform`: world positions -> clip coordinates (parallel over vertices).
  2. `setup_triangles` / `setup_lines`: trivial reject, clipping in homogeneous space
     against the near plane and a guard band (only for the rare primitives that need
     it), projection to window coordinates snapped to 1/256 pixel (fixed point, as GPUs
     do: edge functions are exact int64, so shared edges are neither missed nor drawn
     twice), orientation normalised (no culling), bounding boxes.
  3. `bin_prims`: primitives binned into horizontal bands of rows, in draw order.
  4. `raster`: parallel over bands; each band is owned by one thread, which clears its
     rows and draws its primitives in draw order, so the result is deterministic and
     the depth buffer has no races. Depth test "less" on window z (linear in screen
     space, as OpenGL), fragments outside z in [0, 1] dropped (far plane), top-left
     fill rule, pixel centres at half-integers.
The output is a visibility buffer per sample: depth, primitive id (-1 = background) and
the perspective-correct barycentric weights (b1, b2) of vertices 1 and 2 of the source
primitive (b0 = 1 - b1 - b2). Lines are stored as primitives (a, b, b) with b1 = the
perspective-correct parameter along the line, so one shading kernel serves both.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

SUB = 256  # sub-pixel precision (8 bits)
HALF = SUB // 2
GUARD = 8.0  # guard band, in NDC units: |x|, |y| <= GUARD * w after clipping
BAND = 8  # rows per band


@njit(cache=True)
def transform(pos, m, clip):
    """clip[i] = m @ (pos[i], 1). (Sequential: cheaper than a parallel region here.)"""
    for i in range(pos.shape[0]):
        x = pos[i, 0]
        y = pos[i, 1]
        z = pos[i, 2]
        for r in range(4):
            clip[i, r] = m[r, 0] * x + m[r, 1] * y + m[r, 2] * z + m[r, 3]


@njit(cache=True, inline="always")
def _plane_dist(c, k):
    """Signed distance (>= 0 inside) of clip point c to clip plane k:
    0 near (z >= -w), 1..4 guard band x, y."""
    if k == 0:
        return c[2] + c[3]
    if k == 1:
        return GUARD * c[3] - c[0]
    if k == 2:
        return GUARD * c[3] + c[0]
    if k == 3:
        return GUARD * c[3] - c[1]
    return GUARD * c[3] + c[1]


@njit(cache=True, inline="always")
def _outcode(x, y, z, w):
    """Bits 0-4: outside near / guard planes; bits 5-10: outside the real frustum."""
    code = 0
    if z + w < 0.0:
        code |= 1
    if x > GUARD * w:
        code |= 2
    if x < -GUARD * w:
        code |= 4
    if y > GUARD * w:
        code |= 8
    if y < -GUARD * w:
        code |= 16
    if x > w:
        code |= 32
    if x < -w:
        code |= 64
    if y > w:
        code |= 128
    if y < -w:
        code |= 256
    if z > w:
        code |= 512
    if z + w < 0.0:
        code |= 1024
    return code


@njit(cache=True)
def _emit_tri(W, H, c, bar, src, m, px, py, pz, piw, pb, psrc, pbox, xs, ys):
    """Project clip triangle c (3,4) and store it as raster primitive m.
    Returns 1 if stored, 0 if it covers no sample (degenerate or off screen)."""
    cap = px.shape[0]
    for k in range(3):
        iw = 1.0 / c[k, 3]
        sx = (c[k, 0] * iw + 1.0) * 0.5 * W
        sy = (1.0 - c[k, 1] * iw) * 0.5 * H
        xs[k] = np.int64(round(sx * SUB))
        ys[k] = np.int64(round(sy * SUB))
    area = (xs[1] - xs[0]) * (ys[2] - ys[0]) - (ys[1] - ys[0]) * (xs[2] - xs[0])
    if area == 0:
        return 0
    order = (0, 1, 2) if area > 0 else (0, 2, 1)
    xmin = min(xs[0], min(xs[1], xs[2]))
    xmax = max(xs[0], max(xs[1], xs[2]))
    ymin = min(ys[0], min(ys[1], ys[2]))
    ymax = max(ys[0], max(ys[1], ys[2]))
    # sample columns / rows whose centre (i*SUB + HALF) lies in [min, max]
    x0 = max(0, -((HALF - xmin) // SUB))
    x1 = min(W - 1, (xmax - HALF) // SUB)
    y0 = max(0, -((HALF - ymin) // SUB))
    y1 = min(H - 1, (ymax - HALF) // SUB)
    if x0 > x1 or y0 > y1:
        return 0
    if m < cap:
        for k in range(3):
            o = order[k]
            px[m, k] = xs[o]
            py[m, k] = ys[o]
            iw = 1.0 / c[o, 3]
            pz[m, k] = (c[o, 2] * iw + 1.0) * 0.5
            piw[m, k] = iw
            for q in range(3):
                pb[m, k, q] = bar[o, q]
        psrc[m] = src
        pbox[m, 0] = x0
        pbox[m, 1] = x1
        pbox[m, 2] = y0
        pbox[m, 3] = y1
    return 1


@njit(cache=True)
def setup_triangles(clip, tris, W, H, px, py, pz, piw, pb, psrc, pbox):
    """Triangles -> raster primitives. Returns the number needed (may exceed capacity:
    then the caller grows the arrays and calls again)."""
    m = 0
    c = np.empty((3, 4))
    bar = np.zeros((3, 3))
    poly = np.empty((16, 4))
    pbar = np.empty((16, 3))
    npoly = np.empty((16, 4))
    nbar = np.empty((16, 3))
    tc = np.empty((3, 4))
    tb = np.empty((3, 3))
    xs = np.empty(3, np.int64)
    ys = np.empty(3, np.int64)
    for t in range(tris.shape[0]):
        codes_and = 0xFFFF
        codes_or = 0
        for k in range(3):
            v = tris[t, k]
            for r in range(4):
                c[k, r] = clip[v, r]
            oc = _outcode(c[k, 0], c[k, 1], c[k, 2], c[k, 3])
            codes_and &= oc
            codes_or |= oc
        if codes_and & (32 | 64 | 128 | 256 | 512 | 1024):
            continue  # entirely outside one frustum plane
        if (codes_or & 31) == 0:
            for k in range(3):
                for q in range(3):
                    bar[k, q] = 1.0 if k == q else 0.0
            m += _emit_tri(W, H, c, bar, t, m, px, py, pz, piw, pb, psrc, pbox, xs, ys)
            continue
        # Sutherland-Hodgman against the near plane and the guard band
        n = 3
        for k in range(3):
            for r in range(4):
                poly[k, r] = c[k, r]
            for q in range(3):
                pbar[k, q] = 1.0 if k == q else 0.0
        for plane in range(5):
            if n == 0:
                break
            nn = 0
            for k in range(n):
                k2 = (k + 1) % n
                da = _plane_dist(poly[k], plane)
                db = _plane_dist(poly[k2], plane)
                if da >= 0.0:
                    for r in range(4):
                        npoly[nn, r] = poly[k, r]
                    for q in range(3):
                        nbar[nn, q] = pbar[k, q]
                    nn += 1
                if (da >= 0.0) != (db >= 0.0):
                    s = da / (da - db)
                    for r in range(4):
                        npoly[nn, r] = poly[k, r] + s * (poly[k2, r] - poly[k, r])
                    for q in range(3):
                        nbar[nn, q] = pbar[k, q] + s * (pbar[k2, q] - pbar[k, q])
                    nn += 1
            n = nn
            for k in range(n):
                for r in range(4):
                    poly[k, r] = npoly[k, r]
                for q in range(3):
                    pbar[k, q] = nbar[k, q]
        for k in range(1, n - 1):  # fan
            for r in range(4):
                tc[0, r] = poly[0, r]
                tc[1, r] = poly[k, r]
                tc[2, r] = poly[k + 1, r]
            for q in range(3):
                tb[0, q] = pbar[0, q]
                tb[1, q] = pbar[k, q]
                tb[2, q] = pbar[k + 1, q]
            m += _emit_tri(W, H, tc, tb, t, m, px, py, pz, piw, pb, psrc, pbox, xs, ys)
    return m


@njit(cache=True)
def setup_lines(clip, lines, W, H, thick, px, py, pz, piw, pb, psrc, pbox):
    """Line segments -> raster primitives (parametric clipping, near + guard band).
    pb[m, k, 0] holds the parameter of end k along the source segment."""
    m = 0
    cap = px.shape[0]
    a = np.empty(4)
    b = np.empty(4)
    xs = np.empty(2, np.int64)
    ys = np.empty(2, np.int64)
    for t in range(lines.shape[0]):
        ia = lines[t, 0]
        ib = lines[t, 1]
        for r in range(4):
            a[r] = clip[ia, r]
            b[r] = clip[ib, r]
        oa = _outcode(a[0], a[1], a[2], a[3])
        ob = _outcode(b[0], b[1], b[2], b[3])
        if oa & ob & (32 | 64 | 128 | 256 | 512 | 1024):
            continue
        s0 = 0.0
        s1 = 1.0
        ok = True
        if (oa | ob) & 31:
            for plane in range(5):
                da = _plane_dist(a, plane)
                db = _plane_dist(b, plane)
                if da < 0.0 and db < 0.0:
                    ok = False
                    break
                if da < 0.0:
                    s0 = max(s0, da / (da - db))
                elif db < 0.0:
                    s1 = min(s1, da / (da - db))
            if not ok or s0 >= s1:
                continue
        for k in range(2):
            s = s0 if k == 0 else s1
            cx = a[0] + s * (b[0] - a[0])
            cy = a[1] + s * (b[1] - a[1])
            cz = a[2] + s * (b[2] - a[2])
            cw = a[3] + s * (b[3] - a[3])
            iw = 1.0 / cw
            xs[k] = np.int64(round((cx * iw + 1.0) * 0.5 * W * SUB))
            ys[k] = np.int64(round((1.0 - cy * iw) * 0.5 * H * SUB))
            if m < cap:
                px[m, k] = xs[k]
                py[m, k] = ys[k]
                pz[m, k] = (cz * iw + 1.0) * 0.5
                piw[m, k] = iw
                pb[m, k, 0] = s
        if xs[0] == xs[1] and ys[0] == ys[1]:
            continue
        ext = (thick + 1) * SUB
        y0 = max(0, (min(ys[0], ys[1]) - ext) // SUB)
        y1 = min(H - 1, (max(ys[0], ys[1]) + ext) // SUB)
        x0 = max(0, (min(xs[0], xs[1]) - ext) // SUB)
        x1 = min(W - 1, (max(xs[0], xs[1]) + ext) // SUB)
        if x0 > x1 or y0 > y1:
            continue
        if m < cap:
            psrc[m] = t
            pbox[m, 0] = x0
            pbox[m, 1] = x1
            pbox[m, 2] = y0
            pbox[m, 3] = y1
        m += 1
    return m


@njit(cache=True)
def bin_prims(pbox, n, band_h, nb, band_start, items):
    """Bin primitives 0..n-1 by their row range into nb bands (draw order kept).
    Returns the number of entries needed (caller grows `items` if larger)."""
    for b in range(nb + 1):
        band_start[b] = 0
    for m in range(n):
        for b in range(pbox[m, 2] // band_h, pbox[m, 3] // band_h + 1):
            band_start[b + 1] += 1
    for b in range(nb):
        band_start[b + 1] += band_start[b]
    total = band_start[nb]
    if total > items.shape[0]:
        return total
    cur = band_start[:nb].copy()
    for m in range(n):
        for b in range(pbox[m, 2] // band_h, pbox[m, 3] // band_h + 1):
            items[cur[b]] = m
            cur[b] += 1
    return total


@njit(cache=True, inline="always")
def _edge_tl(ax, ay, bx, by):
    """Bias for the top-left rule (y down, clockwise-on-screen order): 0 if the edge
    a->b is a top edge (horizontal, going right) or a left edge (going up), else -1."""
    dy = by - ay
    if dy < 0 or (dy == 0 and bx > ax):
        return 0
    return -1


@njit(cache=True)
def _raster_tri(m, r0, r1, W, px, py, pz, piw, pb, psrc, pbox,
                depth, prim, bary, count, count_on):
    x0, y0, y1 = pbox[m, 0], max(pbox[m, 2], r0), min(pbox[m, 3], r1 - 1)
    x1 = pbox[m, 1]
    if y0 > y1:
        return
    ax, ay = px[m, 0], py[m, 0]
    bx, by = px[m, 1], py[m, 1]
    cx, cy = px[m, 2], py[m, 2]
    area = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
    inv_area = 1.0 / area
    bias0 = _edge_tl(bx, by, cx, cy)  # edge b->c, weight of a
    bias1 = _edge_tl(cx, cy, ax, ay)  # edge c->a, weight of b
    bias2 = _edge_tl(ax, ay, bx, by)  # edge a->b, weight of c
    za, zb, zc = pz[m, 0], pz[m, 1], pz[m, 2]
    wa, wb, wc = piw[m, 0], piw[m, 1], piw[m, 2]
    src = psrc[m]
    # edge functions at the first sample centre and their steps
    sx = x0 * SUB + HALF
    for yy in range(y0, y1 + 1):
        sy = yy * SUB + HALF
        e0 = (cx - bx) * (sy - by) - (cy - by) * (sx - bx)
        e1 = (ax - cx) * (sy - cy) - (ay - cy) * (sx - cx)
        e2 = (bx - ax) * (sy - ay) - (by - ay) * (sx - ax)
        d0 = -(cy - by) * SUB
        d1 = -(ay - cy) * SUB
        d2 = -(by - ay) * SUB
        row = yy * W
        for xx in range(x0, x1 + 1):
            if e0 + bias0 >= 0 and e1 + bias1 >= 0 and e2 + bias2 >= 0:
                s = row + xx
                if count_on:
                    count[s] += 1
                l0 = e0 * inv_area
                l1 = e1 * inv_area
                l2 = e2 * inv_area
                z = l0 * za + l1 * zb + l2 * zc
                if z < depth[s] and z >= 0.0 and z <= 1.0:
                    depth[s] = z
                    q0 = l0 * wa
                    q1 = l1 * wb
                    q2 = l2 * wc
                    iq = 1.0 / (q0 + q1 + q2)
                    q0 *= iq
                    q1 *= iq
                    q2 *= iq
                    prim[s] = src
                    bary[s, 0] = q0 * pb[m, 0, 1] + q1 * pb[m, 1, 1] + q2 * pb[m, 2, 1]
                    bary[s, 1] = q0 * pb[m, 0, 2] + q1 * pb[m, 1, 2] + q2 * pb[m, 2, 2]
            e0 += d0
            e1 += d1
            e2 += d2


@njit(cache=True)
def _raster_line(m, r0, r1, W, thick, px, py, pz, piw, pb, psrc, pbox,
                 depth, prim, bary, count, count_on):
    """DDA along the major axis: one sample per major-axis step whose centre lies in
    [start, end), `thick` samples across (centred)."""
    ax = px[m, 0] / SUB
    ay = py[m, 0] / SUB
    bx = px[m, 1] / SUB
    by = py[m, 1] / SUB
    dx = bx - ax
    dy = by - ay
    xmajor = abs(dx) >= abs(dy)
    if xmajor:
        lo = min(ax, bx)
        hi = max(ax, bx)
    else:
        lo = min(ay, by)
        hi = max(ay, by)
    i0 = int(math.ceil(lo - 0.5))
    i1 = int(math.ceil(hi - 0.5))  # exclusive
    xlo, xhi = pbox[m, 0], pbox[m, 1]
    ylo, yhi = max(pbox[m, 2], r0), min(pbox[m, 3], r1 - 1)
    if xmajor:
        i0 = max(i0, xlo)
        i1 = min(i1, xhi + 1)
    else:
        i0 = max(i0, ylo - thick)
        i1 = min(i1, yhi + 1 + thick)
    za, zb = pz[m, 0], pz[m, 1]
    wa, wb = piw[m, 0], piw[m, 1]
    sa, sb = pb[m, 0, 0], pb[m, 1, 0]
    src = psrc[m]
    half = (thick - 1) // 2
    for i in range(i0, i1):
        if xmajor:
            t = (i + 0.5 - ax) / dx
            minor = ay + t * dy
        else:
            t = (i + 0.5 - ay) / dy
            minor = ax + t * dx
        if t < 0.0 or t > 1.0:
            continue
        j0 = int(math.floor(minor)) - half
        z = za + t * (zb - za)
        if not (z >= 0.0 and z <= 1.0):
            continue
        qa = (1.0 - t) * wa
        qb = t * wb
        s = (qa * sa + qb * sb) / (qa + qb)
        for j in range(j0, j0 + thick):
            if xmajor:
                xx = i
                yy = j
            else:
                xx = j
                yy = i
            if yy < ylo or yy > yhi or xx < xlo or xx > xhi:
                continue
            k = yy * W + xx
            if count_on:
                count[k] += 1
            if z < depth[k]:
                depth[k] = z
                prim[k] = src
                bary[k, 0] = s
                bary[k, 1] = 0.0


@njit(cache=True, parallel=True)
def raster(lines_mode, thick, nb, band_h, W, H, band_start, items,
           px, py, pz, piw, pb, psrc, pbox, depth, prim, bary, count, count_on):
    """Clear and draw every band; one thread owns a band (no races, deterministic)."""
    for b in prange(nb):
        r0 = b * band_h
        r1 = min(H, r0 + band_h)
        for s in range(r0 * W, r1 * W):
            depth[s] = np.inf
            prim[s] = -1
            if count_on:
                count[s] = 0
        for k in range(band_start[b], band_start[b + 1]):
            m = items[k]
            if lines_mode:
                _raster_line(m, r0, r1, W, thick, px, py, pz, piw, pb, psrc, pbox,
                             depth, prim, bary, count, count_on)
            else:
                _raster_tri(m, r0, r1, W, px, py, pz, piw, pb, psrc, pbox,
                            depth, prim, bary, count, count_on)
