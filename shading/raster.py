"""The numba rasteriser (SPEC section 4). It knows nothing of lighting.

Pipeline per frame, all on flat arrays (every kernel cached on disk):
  1. `project`: world positions -> clip coordinates and outcodes; vertices inside the
     near plane and the guard band also get their window coordinates, snapped to 1/256
     pixel (fixed point, as GPUs do: edge functions are exact int64, so shared edges
     are neither missed nor drawn twice), window z and 1/w. Done once per vertex.
  2. `setup_triangles` / `setup_lines`: trivial reject, clipping in homogeneous space
     against the near plane and the guard band (only for the rare primitives that need
     it: their new vertices are appended after the mesh vertices), orientation
     normalised (no culling), bounding boxes, and the per-band primitive counts.
  3. `bin_prims`: primitives binned into horizontal bands of rows, in draw order.
  4. `raster_triangles` / `raster_lines`: parallel over bands of 8 rows (the renderer
     runs interleaved groups of bands on threads, GIL released); each band is owned by
     one thread, which clears the part of its rows written by the previous frame and
     draws its primitives in draw order, so the result is deterministic (the same for
     any number of threads) and the depth buffer has no races. For each
     row of a triangle the covered span of samples is computed exactly from the integer
     edge functions (top-left fill rule, pixel centres at half-integers); only the span
     is visited. Depth test "less" on window z (linear in screen space, as OpenGL),
     fragments outside z in [0, 1] dropped (far plane).
The output is a visibility buffer per sample: depth (float64), primitive id (int32,
-1 = background) and the perspective-correct barycentric weights (b1, b2) (float32) of
vertices 1 and 2 of the source primitive (b0 = 1 - b1 - b2), plus per sample row the
span [rowlo, rowhi] of samples written (rowlo > rowhi: none), which lets the shading
stage fill the background without reading the buffer and the next frame clear only what
was written. Lines are stored as primitives (a, b, b) with b1 = the perspective-correct
parameter along the line, so the shading helpers serve both.
"""
from __future__ import annotations

import math

import numpy as np
from clothjit import njit

SUB = 256  # sub-pixel precision (8 bits)
HALF = SUB // 2
GUARD = 8.0  # guard band, in NDC units: |x|, |y| <= GUARD * w after clipping
BAND = 8  # rows per band
# rows per band of a shadow map's groups (raster_depth): a triangle across two groups'
# bands is set up by both, a third of a dense cloth's with bands of 8, a tenth with 32
DEPTH_BAND = 4 * BAND
FRUSTUM = 32 | 64 | 128 | 256 | 512 | 1024
# pflag values: how a primitive's perspective-correct weights map to its source's
AS_IS, SWAPPED, CLIPPED = 0, 1, 2


@njit(cache=True, inline="always")
def _outcode(x, y, z, w):
    """Bits 0-4: outside near / guard planes; bits 5-10: outside the real frustum."""
    code = 0
    if z + w < 0.0:
        code |= 1 | 1024
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
    return code


# The setup's helpers below are kernels of their own, called (LLVM inlines them), not
# inlined by numba, which types an inlined callee again at every call site: setup_triangles
# compiles 0.3-0.7 s sooner, at the same speed (2026-11-27). The raster loop's stay inlined.
@njit(cache=True, error_model="numpy", no_cpython_wrapper=True)
def _plane_dist(x, y, z, w, k):
    """Signed distance (>= 0 inside) of clip point (x, y, z, w) to clip plane k:
    0 near (z >= -w), 1..4 guard band x, y."""
    if k == 0:
        return z + w
    if k == 1:
        return GUARD * w - x
    if k == 2:
        return GUARD * w + x
    if k == 3:
        return GUARD * w - y
    return GUARD * w + y


@njit(cache=True, error_model="numpy", no_cpython_wrapper=True)
def _window(c0, c1, c2, c3, W, H, vx, vy, vz, viw, i):
    """Window coordinates of clip point c into vertex slot i."""
    iw = 1.0 / c3
    sx = (c0 * iw + 1.0) * 0.5 * W
    sy = (1.0 - c1 * iw) * 0.5 * H
    vx[i] = np.int64(round(sx * SUB))
    vy[i] = np.int64(round(sy * SUB))
    vz[i] = (c2 * iw + 1.0) * 0.5
    viw[i] = iw


@njit(cache=True, error_model="numpy")
def project(pos, m, W, H, clip, vcode, vx, vy, vz, viw):
    """clip[i] = m @ (pos[i], 1); outcodes; window coordinates of the vertices that need
    no clipping (the others are projected after clipping, by the setup). Returns the
    outcodes or-ed together (no bit of 31: no primitive needs clipping)."""
    codes = 0
    for i in range(pos.shape[0]):
        x = pos[i, 0]
        y = pos[i, 1]
        z = pos[i, 2]
        c0 = m[0, 0] * x + m[0, 1] * y + m[0, 2] * z + m[0, 3]
        c1 = m[1, 0] * x + m[1, 1] * y + m[1, 2] * z + m[1, 3]
        c2 = m[2, 0] * x + m[2, 1] * y + m[2, 2] * z + m[2, 3]
        c3 = m[3, 0] * x + m[3, 1] * y + m[3, 2] * z + m[3, 3]
        clip[i, 0] = c0
        clip[i, 1] = c1
        clip[i, 2] = c2
        clip[i, 3] = c3
        code = _outcode(c0, c1, c2, c3)
        vcode[i] = code
        codes |= code
        if (code & 31) == 0:
            _window(c0, c1, c2, c3, W, H, vx, vy, vz, viw, i)
    return codes


@njit(cache=True, inline="always")
def _sample_range(n, a, b, c):
    """The first and last of samples 0 .. n - 1 along one axis whose centre (i*SUB + HALF)
    lies between the least and the greatest of a, b, c (first > last: none)."""
    return (max(0, -((HALF - min(a, min(b, c))) // SUB)),
            min(n - 1, (max(a, max(b, c)) - HALF) // SUB))


@njit(cache=True, error_model="numpy", no_cpython_wrapper=True)
def _tri_box(W, H, ax, ay, bx, by, cx, cy):
    """(twice the signed area, x0, x1, y0, y1): the sample columns / rows whose centre
    (i*SUB + HALF) lies in the triangle's bounding box, clipped to the image; x0 > x1
    when it covers no sample (or is degenerate)."""
    area = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
    x0, x1 = _sample_range(W, ax, bx, cx)
    y0, y1 = _sample_range(H, ay, by, cy)
    if area == 0 or y0 > y1:
        x1 = x0 - 1
    return area, x0, x1, y0, y1


@njit(cache=True, error_model="numpy", no_cpython_wrapper=True)
def _put_tri(m, a, b, c, flag, src, area, x0, x1, y0, y1, pv, pflag, psrc, pbox, band_start):
    """Store triangle (a, b, c) (vertex slots) as primitive m, clockwise on screen, and
    count it in its bands."""
    pv[m, 0] = a
    pv[m, 1] = b if area > 0 else c
    pv[m, 2] = c if area > 0 else b
    pflag[m] = SWAPPED if flag == AS_IS and area < 0 else flag
    psrc[m] = src
    pbox[m, 0] = x0
    pbox[m, 1] = x1
    pbox[m, 2] = y0
    pbox[m, 3] = y1
    for k in range(y0 // BAND, y1 // BAND + 1):
        band_start[k + 1] += 1


@njit(cache=True, error_model="numpy", no_cpython_wrapper=True)
def _clip_tri(t, tris, clip, nv, m, e, W, H, vx, vy, vz, viw, wb, pv, pflag, psrc, pbox,
              band_start):
    """Triangle t clipped (Sutherland-Hodgman) against the near plane and the guard band;
    the polygon's vertices become extra vertex slots nv + e, ...; a fan of primitives
    from m on. Returns (primitives, extra vertices) added or needed."""
    poly = np.empty((16, 4))
    pbar = np.empty((16, 3))
    npoly = np.empty((16, 4))
    nbar = np.empty((16, 3))
    n = 3
    for k in range(3):
        v = tris[t, k]
        for r in range(4):
            poly[k, r] = clip[v, r]
        for q in range(3):
            pbar[k, q] = 1.0 if k == q else 0.0
    for plane in range(5):
        if n == 0:
            break
        nn = 0
        for k in range(n):
            k2 = (k + 1) % n
            da = _plane_dist(poly[k, 0], poly[k, 1], poly[k, 2], poly[k, 3], plane)
            db = _plane_dist(poly[k2, 0], poly[k2, 1], poly[k2, 2], poly[k2, 3], plane)
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
    if n < 3:
        return 0, 0
    if nv + e + n > vx.shape[0] or e + n > wb.shape[0]:  # no room: count only
        return n - 2, n
    for k in range(n):
        i = nv + e + k
        _window(poly[k, 0], poly[k, 1], poly[k, 2], poly[k, 3], W, H, vx, vy, vz, viw, i)
        for q in range(3):
            wb[e + k, q] = pbar[k, q]
    dm = 0
    for k in range(1, n - 1):  # fan
        a, b, c = nv + e, nv + e + k, nv + e + k + 1
        area, x0, x1, y0, y1 = _tri_box(W, H, vx[a], vy[a], vx[b], vy[b], vx[c], vy[c])
        if x0 <= x1:
            if m + dm < pv.shape[0]:
                _put_tri(m + dm, a, b, c, CLIPPED, t, area, x0, x1, y0, y1, pv, pflag, psrc,
                         pbox, band_start)
            dm += 1
    return dm, n


@njit(cache=True, error_model="numpy")
def setup_triangles(tris, clip, vcode, nv, W, H, vx, vy, vz, viw, wb, pv, pflag, psrc, pbox,
                    band_start):
    """Triangles -> raster primitives, counted per band into band_start[1:].
    Returns (primitives, extra vertices) needed; if either exceeds the capacity (pv rows,
    vx rows - nv) the caller grows the arrays and calls again."""
    band_start[:] = 0
    cap = pv.shape[0]
    m = e = np.int64(0)  # not the literal 0: _clip_tri would compile for both
    for t in range(tris.shape[0]):
        a = tris[t, 0]
        b = tris[t, 1]
        c = tris[t, 2]
        ca = vcode[a]
        cb = vcode[b]
        cc = vcode[c]
        if ca & cb & cc & FRUSTUM:
            continue  # entirely outside one frustum plane
        if ((ca | cb | cc) & 31) == 0:
            area, x0, x1, y0, y1 = _tri_box(W, H, vx[a], vy[a], vx[b], vy[b], vx[c], vy[c])
            if x0 <= x1:
                if m < cap:
                    _put_tri(m, a, b, c, AS_IS, t, area, x0, x1, y0, y1, pv, pflag, psrc,
                             pbox, band_start)
                m += 1
        else:
            dm, de = _clip_tri(t, tris, clip, nv, m, e, W, H, vx, vy, vz, viw, wb, pv,
                               pflag, psrc, pbox, band_start)
            m += dm
            e += de
    return m, e


@njit(cache=True, error_model="numpy", no_cpython_wrapper=True)
def _line_end(a0, a1, a2, a3, b0, b1, b2, b3, s, W, H):
    """Window (x, y) fixed point, z and 1/w of the point at parameter s on clip a->b."""
    cx = a0 + s * (b0 - a0)
    cy = a1 + s * (b1 - a1)
    cz = a2 + s * (b2 - a2)
    cw = a3 + s * (b3 - a3)
    iw = 1.0 / cw
    return (np.int64(round((cx * iw + 1.0) * 0.5 * W * SUB)),
            np.int64(round((1.0 - cy * iw) * 0.5 * H * SUB)), (cz * iw + 1.0) * 0.5, iw)


@njit(cache=True, error_model="numpy")
def setup_lines(lines, clip, vcode, nv, W, H, thick, vx, vy, vz, viw, wb, pv, pflag, psrc,
                pbox, band_start):
    """Line segments -> raster primitives (parametric clipping, near + guard band).
    Each line gets two extra vertex slots (its clipped ends); wb[slot - nv, 0] holds the
    parameter of that end along the source segment. Returns (primitives, extra vertices)
    as setup_triangles."""
    band_start[:] = 0
    m = 0
    e = 0
    cap = pv.shape[0]
    vcap = vx.shape[0]
    for t in range(lines.shape[0]):
        ia = lines[t, 0]
        ib = lines[t, 1]
        oa = vcode[ia]
        ob = vcode[ib]
        if oa & ob & FRUSTUM:
            continue
        a0, a1, a2, a3 = clip[ia, 0], clip[ia, 1], clip[ia, 2], clip[ia, 3]
        b0, b1, b2, b3 = clip[ib, 0], clip[ib, 1], clip[ib, 2], clip[ib, 3]
        s0 = 0.0
        s1 = 1.0
        ok = True
        if (oa | ob) & 31:
            for plane in range(5):
                da = _plane_dist(a0, a1, a2, a3, plane)
                db = _plane_dist(b0, b1, b2, b3, plane)
                if da < 0.0 and db < 0.0:
                    ok = False
                    break
                if da < 0.0:
                    s0 = max(s0, da / (da - db))
                elif db < 0.0:
                    s1 = min(s1, da / (da - db))
            if not ok or s0 >= s1:
                continue
        xa, ya, za, wa = _line_end(a0, a1, a2, a3, b0, b1, b2, b3, s0, W, H)
        xb, yb, zb, wb_ = _line_end(a0, a1, a2, a3, b0, b1, b2, b3, s1, W, H)
        vroom = nv + e + 2 <= vcap and e + 2 <= wb.shape[0]
        if vroom:
            vx[nv + e] = xa
            vy[nv + e] = ya
            vz[nv + e] = za
            viw[nv + e] = wa
            wb[e, 0] = s0
            vx[nv + e + 1] = xb
            vy[nv + e + 1] = yb
            vz[nv + e + 1] = zb
            viw[nv + e + 1] = wb_
            wb[e + 1, 0] = s1
        room = m < cap and vroom
        if xa == xb and ya == yb:
            continue
        xs0, xs1, ys0, ys1 = xa, xb, ya, yb
        ext = (thick + 1) * SUB
        y0 = max(0, (min(ys0, ys1) - ext) // SUB)
        y1 = min(H - 1, (max(ys0, ys1) + ext) // SUB)
        x0 = max(0, (min(xs0, xs1) - ext) // SUB)
        x1 = min(W - 1, (max(xs0, xs1) + ext) // SUB)
        if x0 > x1 or y0 > y1:
            continue
        if room:
            pv[m, 0] = nv + e
            pv[m, 1] = nv + e + 1
            pv[m, 2] = nv + e + 1
            pflag[m] = CLIPPED
            psrc[m] = t
            pbox[m, 0] = x0
            pbox[m, 1] = x1
            pbox[m, 2] = y0
            pbox[m, 3] = y1
            for k in range(y0 // BAND, y1 // BAND + 1):
                band_start[k + 1] += 1
        m += 1
        e += 2
    return m, e


@njit(cache=True, error_model="numpy")
def bin_prims(pbox, n, nb, band_start, items):
    """Bin primitives 0..n-1 by their row range into nb bands (draw order kept);
    band_start[1:] holds the per-band counts from the setup. Returns the number of
    entries needed; if larger than `items`, nothing is changed (grow it and call again)."""
    total = 0
    for b in range(nb):
        total += band_start[b + 1]
    if total > items.shape[0]:
        return total
    for b in range(nb):
        band_start[b + 1] += band_start[b]
    cur = band_start[:nb].copy()
    for m in range(n):
        for b in range(pbox[m, 2] // BAND, pbox[m, 3] // BAND + 1):
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


@njit(cache=True, inline="always")
def _clip_span(f, d, lo, hi):
    """Narrow [lo, hi] to the k with f + d * k >= 0 (exact integer arithmetic)."""
    if d > 0:
        if f < 0:
            lo = max(lo, (-f + d - 1) // d)
    elif d < 0:
        if f < 0:
            return 1, 0
        hi = min(hi, f // -d)
    elif f < 0:
        return 1, 0
    return lo, hi


# _edges, _span and _begin_band are kernels of their own, called (LLVM inlines them) from
# both triangle kernels: numba types an inlined callee again at every call site.
@njit(cache=True, error_model="numpy", no_cpython_wrapper=True)
def _edges(ax, ay, bx, by, cx, cy, x0, y0):
    """Triangle a, b, c (clockwise on screen): its edge functions at the centre of sample
    (x0, y0) (weights of a, b, c), their steps along x and along y, and the top-left
    rule's biases."""
    sx = x0 * SUB + HALF
    sy = y0 * SUB + HALF
    return ((cx - bx) * (sy - by) - (cy - by) * (sx - bx),
            (ax - cx) * (sy - cy) - (ay - cy) * (sx - cx),
            (bx - ax) * (sy - ay) - (by - ay) * (sx - ax),
            -(cy - by) * SUB, -(ay - cy) * SUB, -(by - ay) * SUB,
            (cx - bx) * SUB, (ax - cx) * SUB, (bx - ax) * SUB,
            _edge_tl(bx, by, cx, cy), _edge_tl(cx, cy, ax, ay), _edge_tl(ax, ay, bx, by))


@njit(cache=True, error_model="numpy", no_cpython_wrapper=True)
def _span(e0, e1, e2, d0, d1, d2, bias0, bias1, bias2, n):
    """The covered samples [lo, hi] of columns 0..n of a row whose first sample has edge
    functions e0, e1, e2 (lo > hi: none). One or two columns (most triangles of a dense
    mesh): their centres tested, without _clip_span's divisions (the same span)."""
    if n <= 1:
        lo = 0 if (e0 + bias0 >= 0) & (e1 + bias1 >= 0) & (e2 + bias2 >= 0) else 1
        hi = 1 if (n == 1) & (e0 + d0 + bias0 >= 0) & (e1 + d1 + bias1 >= 0) & (
            e2 + d2 + bias2 >= 0) else 0
        return lo, hi
    lo, hi = _clip_span(e0 + bias0, d0, 0, n)
    lo, hi = _clip_span(e1 + bias1, d1, lo, hi)
    return _clip_span(e2 + bias2, d2, lo, hi)


@njit(cache=True, error_model="numpy", no_cpython_wrapper=True)
def _begin_band(b, W, H, depth, prim, rowlo, rowhi, count, count_on):
    """Rows [r0, r1) of band b, after clearing what the previous frame wrote there."""
    r0 = b * BAND
    r1 = min(H, r0 + BAND)
    for y in range(r0, r1):
        if rowlo[y] <= rowhi[y]:
            depth[y * W + rowlo[y]:y * W + rowhi[y] + 1] = np.inf
            prim[y * W + rowlo[y]:y * W + rowhi[y] + 1] = -1
        rowlo[y] = W
        rowhi[y] = -1
    if count_on:
        count[r0 * W:r1 * W] = 0
    return r0, r1


# The two raster kernels draw the bands of group g: b = g, g + groups, ... The renderer
# runs the groups on as many threads (the GIL is released): one owner per band, so no
# races and the same result for any number of threads; interleaved bands balance the
# load. (The per-primitive code is written out in the loop, not in a helper taking the
# arrays: numba would count references to them for every primitive.)


@njit(cache=True, nogil=True, error_model="numpy")
def raster_triangles(g, groups, nb, W, H, nv, band_start, items, pv, pflag, psrc, pbox, vx,
                     vy, vz, viw, wb, depth, prim, bary, rowlo, rowhi, count, count_on):
    """Triangles: per row the covered span from the exact integer edge functions."""
    for b in range(g, nb, groups):
        r0, r1 = _begin_band(b, W, H, depth, prim, rowlo, rowhi, count, count_on)
        for it in range(band_start[b], band_start[b + 1]):
            m = items[it]
            y0 = max(pbox[m, 2], r0)
            y1 = min(pbox[m, 3], r1 - 1)
            if y0 > y1:
                continue
            x0 = pbox[m, 0]
            n = pbox[m, 1] - x0
            ia = pv[m, 0]
            ib = pv[m, 1]
            ic = pv[m, 2]
            ax, ay = vx[ia], vy[ia]
            bx, by = vx[ib], vy[ib]
            cx, cy = vx[ic], vy[ic]
            area = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
            inv_area = 1.0 / area
            za, zb, zc = vz[ia], vz[ib], vz[ic]
            wa, wb_, wc = viw[ia], viw[ib], viw[ic]
            flag = pflag[m]
            src = psrc[m]
            # weights of the source's vertices 1 and 2 per primitive vertex
            g01 = g02 = g11 = g12 = g21 = g22 = 0.0
            if flag == CLIPPED:
                g01, g02 = wb[ia - nv, 1], wb[ia - nv, 2]
                g11, g12 = wb[ib - nv, 1], wb[ib - nv, 2]
                g21, g22 = wb[ic - nv, 1], wb[ic - nv, 2]
            # edge functions at the first sample centre of row y0, steps along x and y
            e0r, e1r, e2r, d0, d1, d2, s0, s1, s2, bias0, bias1, bias2 = _edges(
                ax, ay, bx, by, cx, cy, x0, y0)
            for yy in range(y0, y1 + 1):
                lo, hi = _span(e0r, e1r, e2r, d0, d1, d2, bias0, bias1, bias2, n)
                if lo <= hi:
                    xa = x0 + lo
                    if xa < rowlo[yy]:
                        rowlo[yy] = xa
                    if x0 + hi > rowhi[yy]:
                        rowhi[yy] = x0 + hi
                    e0 = e0r + d0 * lo
                    e1 = e1r + d1 * lo
                    e2 = e2r + d2 * lo
                    base = yy * W + x0
                    for s in range(base + lo, base + hi + 1):
                        if count_on:
                            count[s] += 1
                        l0 = e0 * inv_area
                        l1 = e1 * inv_area
                        l2 = e2 * inv_area
                        z = l0 * za + l1 * zb + l2 * zc
                        if z < depth[s] and z >= 0.0 and z <= 1.0:
                            depth[s] = z
                            q0 = l0 * wa
                            q1 = l1 * wb_
                            q2 = l2 * wc
                            iq = 1.0 / (q0 + q1 + q2)
                            q0 *= iq
                            q1 *= iq
                            q2 *= iq
                            prim[s] = src
                            if flag == AS_IS:
                                bary[s, 0] = q1
                                bary[s, 1] = q2
                            elif flag == SWAPPED:
                                bary[s, 0] = q2
                                bary[s, 1] = q1
                            else:
                                bary[s, 0] = q0 * g01 + q1 * g11 + q2 * g21
                                bary[s, 1] = q0 * g02 + q1 * g12 + q2 * g22
                        e0 += d0
                        e1 += d1
                        e2 += d2
                e0r += s0
                e1r += s1
                e2r += s2


@njit(cache=True, nogil=True, error_model="numpy")
def raster_depth(g, groups, tris, W, H, vcode, vx, vy, vz, depth, prim, rowlo, rowhi,
                 count):
    """Only the depth (a shadow map's) of triangles tris that need no clipping (`project`
    found no outcode bit of 31), set up and drawn one after the other: no primitive
    arrays, no bins (a dense mesh's triangles cover about a sample each: storing and
    binning them cost as much as drawing them). The same depths and spans as
    setup_triangles + raster_triangles (the least z is the same in any order); the rows
    of group g's bands of DEPTH_BAND rows, each group reading every triangle and setting
    up those that reach its bands."""
    for b in range((H + BAND - 1) // BAND):
        if (b * BAND // DEPTH_BAND) % groups == g:
            _begin_band(b, W, H, depth, prim, rowlo, rowhi, count, False)
    for t in range(tris.shape[0]):
        ia = tris[t, 0]
        ib = tris[t, 1]
        ic = tris[t, 2]
        if vcode[ia] & vcode[ib] & vcode[ic] & FRUSTUM:
            continue  # entirely outside one frustum plane
        if groups > 1:  # within one band of another group's: skipped before any set-up
            y0, y1 = _sample_range(H, vy[ia], vy[ib], vy[ic])
            if (y0 // DEPTH_BAND) % groups != g and y0 // DEPTH_BAND == y1 // DEPTH_BAND:
                continue
        area, x0, x1, y0, y1 = _tri_box(W, H, vx[ia], vy[ia], vx[ib], vy[ib], vx[ic],
                                        vy[ic])
        if x0 > x1:
            continue  # off the map
        if area < 0:  # clockwise on screen, as _put_tri stores it
            ib, ic = ic, ib
            area = -area
        n = x1 - x0
        ax, ay = vx[ia], vy[ia]
        bx, by = vx[ib], vy[ib]
        cx, cy = vx[ic], vy[ic]
        inv_area = 1.0 / area
        za, zb, zc = vz[ia], vz[ib], vz[ic]
        e0r, e1r, e2r, d0, d1, d2, s0, s1, s2, bias0, bias1, bias2 = _edges(
            ax, ay, bx, by, cx, cy, x0, y0)
        for yy in range(y0, y1 + 1):
            if groups == 1 or (yy // DEPTH_BAND) % groups == g:
                lo, hi = _span(e0r, e1r, e2r, d0, d1, d2, bias0, bias1, bias2, n)
                if lo <= hi:
                    if x0 + lo < rowlo[yy]:
                        rowlo[yy] = x0 + lo
                    if x0 + hi > rowhi[yy]:
                        rowhi[yy] = x0 + hi
                    e0 = e0r + d0 * lo
                    e1 = e1r + d1 * lo
                    e2 = e2r + d2 * lo
                    for s in range(yy * W + x0 + lo, yy * W + x0 + hi + 1):
                        z = (e0 * inv_area) * za + (e1 * inv_area) * zb + (e2 * inv_area) * zc
                        if z < depth[s] and z >= 0.0 and z <= 1.0:
                            depth[s] = z
                        e0 += d0
                        e1 += d1
                        e2 += d2
            e0r += s0
            e1r += s1
            e2r += s2


@njit(cache=True, nogil=True, error_model="numpy")
def raster_lines(g, groups, thick, nb, W, H, nv, band_start, items, pv, pflag, psrc, pbox,
                 vx, vy, vz, viw, wb, depth, prim, bary, rowlo, rowhi, count, count_on):
    """Lines: DDA along the major axis, one sample per major-axis step whose centre lies
    in [start, end), `thick` samples across (centred)."""
    for b in range(g, nb, groups):
        r0, r1 = _begin_band(b, W, H, depth, prim, rowlo, rowhi, count, count_on)
        for it in range(band_start[b], band_start[b + 1]):
            m = items[it]
            ia = pv[m, 0]
            ib = pv[m, 1]
            ax = vx[ia] / SUB
            ay = vy[ia] / SUB
            bx = vx[ib] / SUB
            by = vy[ib] / SUB
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
            za, zb = vz[ia], vz[ib]
            wa, wb_ = viw[ia], viw[ib]
            sa, sb = wb[ia - nv, 0], wb[ib - nv, 0]
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
                qb = t * wb_
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
                    if xx < rowlo[yy]:
                        rowlo[yy] = xx
                    if xx > rowhi[yy]:
                        rowhi[yy] = xx
                    if count_on:
                        count[k] += 1
                    if z < depth[k]:
                        depth[k] = z
                        prim[k] = src
                        bary[k, 0] = s
                        bary[k, 1] = 0.0
