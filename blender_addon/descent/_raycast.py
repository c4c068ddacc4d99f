"""numba kernels of the descent renderer: height-field ray casting, bilinear sampling, cast shadows.

Arrays in, arrays out.  The terrain is a node grid ``h[iy, ix]`` at world ``(x0 + ix res, y0 + iy res)``
(x east, y north, metres; row 0 south), bilinear between nodes.  Empty-space skipping uses block
maxima ``bmax[by, bx]`` over the nodes ``by*B .. by*B+B`` x ``bx*B .. bx*B+B`` (inclusive, so no
bilinear sample inside the block can be higher).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from .brdf import eq9

_OPTS = dict(nogil=True, cache=True, fastmath=False, error_model="numpy")
_eq9 = njit(inline="always", **_OPTS)(eq9)
#: Regula-falsi (Illinois) iterations refining a bracketed crossing (the bracket is <= step_m horizontally,
#: where the bilinear surface is nearly planar: 2-3 iterations reach 1e-5 m).
_REFINE = 12


@njit(inline="always", **_OPTS)
def _height(h, x0, y0, res, x, y):
    """Bilinear height at (x, y); -inf outside the grid."""
    fx = (x - x0) / res
    fy = (y - y0) / res
    ny, nx = h.shape
    if fx < 0.0 or fy < 0.0 or fx > nx - 1 or fy > ny - 1:
        return -np.inf
    ix = min(int(fx), nx - 2)
    iy = min(int(fy), ny - 2)
    tx = fx - ix
    ty = fy - iy
    return ((1.0 - tx) * (1.0 - ty) * h[iy, ix] + tx * (1.0 - ty) * h[iy, ix + 1]
            + (1.0 - tx) * ty * h[iy + 1, ix] + tx * ty * h[iy + 1, ix + 1])


def block_max(h: np.ndarray, block: int) -> np.ndarray:
    """(ceil((ny-1)/B), ceil((nx-1)/B)) maxima over each block's nodes and the next row/column of nodes."""
    ny, nx = h.shape
    nby, nbx = -(-(ny - 1) // block), -(-(nx - 1) // block)
    out = np.empty((nby, nbx), np.float32)
    for by in range(nby):
        for bx in range(nbx):
            out[by, bx] = h[by * block:by * block + block + 1, bx * block:bx * block + block + 1].max()
    return out


@njit(inline="always", **_OPTS)
def _cast_one(h, bmax, block, x0, y0, res, zmin, zmax, ox, oy, oz, dx, dy, dz, step_m):
    """Distance (m) along the unit ray (d) from (o) to the terrain; NaN = miss (see :func:`cast_rays`)."""
    ny, nx = h.shape
    xmax = x0 + (nx - 1) * res
    ymax = y0 + (ny - 1) * res
    bsize = block * res
    if dz >= 0.0 and oz > zmax:
        return np.nan
    t = 0.0
    if oz > zmax:
        t = (zmax - oz) / dz
    t_end = 1e9 if dz >= 0.0 else (zmin - 1e-3 - oz) / dz
    hd = math.sqrt(dx * dx + dy * dy)
    dt_fine = step_m / hd if hd > 1e-12 else 1e9
    f_prev = oz + t * dz - _height(h, x0, y0, res, ox + t * dx, oy + t * dy)
    if f_prev <= 0.0:
        if f_prev != f_prev:
            return np.nan
        return t            # starts under the surface (camera inside the terrain)
    while t < t_end:
        px = ox + t * dx
        py = oy + t * dy
        if px < x0 or py < y0 or px > xmax or py > ymax:
            return np.nan
        bx = min(int((px - x0) / bsize), bmax.shape[1] - 1)
        by = min(int((py - y0) / bsize), bmax.shape[0] - 1)
        top = bmax[by, bx]
        pz = oz + t * dz
        t_prev = t
        if pz > top + 1e-4:
            # above everything in this block: jump to its exit or to where the ray drops to its top
            t_next = t_end
            if dz < 0.0:
                t_next = min(t_next, t + (top - pz) / dz)
            if dx > 0.0:
                t_next = min(t_next, t + (x0 + (bx + 1) * bsize - px) / dx)
            elif dx < 0.0:
                t_next = min(t_next, t + (x0 + bx * bsize - px) / dx)
            if dy > 0.0:
                t_next = min(t_next, t + (y0 + (by + 1) * bsize - py) / dy)
            elif dy < 0.0:
                t_next = min(t_next, t + (y0 + by * bsize - py) / dy)
            t = max(t_next, t + 1e-6) + 1e-5
        else:
            t = min(t + dt_fine, t_end)
        f = oz + t * dz - _height(h, x0, y0, res, ox + t * dx, oy + t * dy)
        if f > 0.0:          # still above (+inf outside the grid)
            f_prev = f
            continue
        # bracket [t_prev (f > 0), t (f <= 0)], at most step_m long horizontally: Illinois regula falsi
        a = t_prev
        b = t
        fa = f_prev
        fb = f
        if fa == np.inf:
            fa = 1.0
        side = 0
        for _ in range(_REFINE):
            m = a + (b - a) * fa / (fa - fb)
            fm = oz + m * dz - _height(h, x0, y0, res, ox + m * dx, oy + m * dy)
            if abs(fm) < 1e-5:
                return m
            if fm > 0.0:
                a = m
                fa = min(fm, 1e9)
                if side == 1:
                    fb *= 0.5
                side = 1
            else:
                b = m
                fb = fm
                if side == -1:
                    fa *= 0.5
                side = -1
        return a + (b - a) * fa / (fa - fb)
    return np.nan


@njit(**_OPTS)
def cast_rays(h, bmax, block, x0, y0, res, zmin, zmax, origin, dirs, step_m, t_hit):
    """Distance ``t_hit[i]`` (m) along unit world ray ``dirs[i]`` from ``origin`` to the terrain; NaN = miss.

    zmin, zmax : the grid's lowest and highest heights (m).  Sampling step ``step_m`` (horizontal
    metres) between empty-space skips; a sign change of ``ray z - h`` is refined by Illinois regula falsi to 1e-5 m.
    """
    for i in range(dirs.shape[0]):
        t_hit[i] = _cast_one(h, bmax, block, x0, y0, res, zmin, zmax, origin[0], origin[1], origin[2],
                             dirs[i, 0], dirs[i, 1], dirs[i, 2], step_m)


@njit(**_OPTS)
def render_eq9(h, bmax, block, x0, y0, res, zmin, zmax, origin, dirs, step_m, gnx, gny, gnz, galb, gtemp,
               lit, light_dirs, light_w, rho_s, k, ambient, out_t, out_vis, out_th, out_x, out_y):
    """Fused ray cast + eq. 9 shading + temperature lookup per pixel (the fast path of the tm BRDF).

    gnx, gny, gnz, galb, gtemp : node grids of the normal components, albedo, temperature (K);
    lit : (L, ny, nx) shadow maps, or (L, 1, 1) ones without cast shadows; light_dirs (L, 3) unit
    world vectors to the visible sources, light_w (L,) their irradiances over the Sun's.
    Outputs per ray: distance, brightness, K, hit x, y (NaN on a miss).
    """
    ny, nx = h.shape
    with_lit = lit.shape[1] == ny
    ox, oy, oz = origin[0], origin[1], origin[2]
    for i in range(dirs.shape[0]):
        dx, dy, dz = dirs[i, 0], dirs[i, 1], dirs[i, 2]
        t = _cast_one(h, bmax, block, x0, y0, res, zmin, zmax, ox, oy, oz, dx, dy, dz, step_m)
        out_t[i] = t
        if t != t:
            out_vis[i] = np.nan
            out_th[i] = np.nan
            out_x[i] = np.nan
            out_y[i] = np.nan
            continue
        px = ox + t * dx
        py = oy + t * dy
        out_x[i] = px
        out_y[i] = py
        fx = min(max((px - x0) / res, 0.0), nx - 1.0)
        fy = min(max((py - y0) / res, 0.0), ny - 1.0)
        ix = min(int(fx), nx - 2)
        iy = min(int(fy), ny - 2)
        tx = fx - ix
        ty = fy - iy
        w00 = (1.0 - tx) * (1.0 - ty)
        w10 = tx * (1.0 - ty)
        w01 = (1.0 - tx) * ty
        w11 = tx * ty
        nnx = w00 * gnx[iy, ix] + w10 * gnx[iy, ix + 1] + w01 * gnx[iy + 1, ix] + w11 * gnx[iy + 1, ix + 1]
        nny = w00 * gny[iy, ix] + w10 * gny[iy, ix + 1] + w01 * gny[iy + 1, ix] + w11 * gny[iy + 1, ix + 1]
        nnz = w00 * gnz[iy, ix] + w10 * gnz[iy, ix + 1] + w01 * gnz[iy + 1, ix] + w11 * gnz[iy + 1, ix + 1]
        nn = math.sqrt(nnx * nnx + nny * nny + nnz * nnz)
        nnx /= nn
        nny /= nn
        nnz /= nn
        alb = w00 * galb[iy, ix] + w10 * galb[iy, ix + 1] + w01 * galb[iy + 1, ix] + w11 * galb[iy + 1, ix + 1]
        out_th[i] = (w00 * gtemp[iy, ix] + w10 * gtemp[iy, ix + 1] + w01 * gtemp[iy + 1, ix]
                     + w11 * gtemp[iy + 1, ix + 1])
        ndv = -(nnx * dx + nny * dy + nnz * dz)
        e = ambient * alb
        for s in range(light_dirs.shape[0]):
            lx, ly, lz = light_dirs[s, 0], light_dirs[s, 1], light_dirs[s, 2]
            shade = 1.0
            if with_lit:
                shade = (w00 * lit[s, iy, ix] + w10 * lit[s, iy, ix + 1] + w01 * lit[s, iy + 1, ix]
                         + w11 * lit[s, iy + 1, ix + 1])
            ndl = nnx * lx + nny * ly + nnz * lz
            cos_g = -(lx * dx + ly * dy + lz * dz)
            e += light_w[s] * _eq9(ndl, ndv, cos_g, 0.0, alb, rho_s, k, shade)
        out_vis[i] = e


@njit(**_OPTS)
def sample_bilinear(grid, x0, y0, res, xs, ys, out):
    """``out[i]`` = bilinear value of ``grid`` (node grid) at world ``(xs[i], ys[i])``; NaN outside or at NaN."""
    ny, nx = grid.shape
    for i in range(xs.shape[0]):
        x = xs[i]
        y = ys[i]
        fx = (x - x0) / res
        fy = (y - y0) / res
        if not (fx >= 0.0 and fy >= 0.0 and fx <= nx - 1 and fy <= ny - 1):
            out[i] = np.nan
            continue
        ix = min(int(fx), nx - 2)
        iy = min(int(fy), ny - 2)
        tx = fx - ix
        ty = fy - iy
        out[i] = ((1.0 - tx) * (1.0 - ty) * grid[iy, ix] + tx * (1.0 - ty) * grid[iy, ix + 1]
                  + (1.0 - tx) * ty * grid[iy + 1, ix] + tx * ty * grid[iy + 1, ix + 1])


@njit(**_OPTS)
def shadow_map(h, x0, y0, res, light_dir, step_m, lift_m, out):
    """``out[iy, ix]`` = 1 where the node sees the light direction over the terrain, 0 where it is shadowed.

    The ray starts ``lift_m`` above the node and is sampled every ``step_m`` horizontal metres until it
    rises above the highest node or leaves the grid (then lit).  Below the horizon: 0.
    """
    ny, nx = h.shape
    zmax = -np.inf
    for iy in range(ny):
        for ix in range(nx):
            zmax = max(zmax, h[iy, ix])
    lx, ly, lz = light_dir[0], light_dir[1], light_dir[2]
    hd = math.sqrt(lx * lx + ly * ly)
    for iy in range(ny):
        for ix in range(nx):
            if lz <= 0.0:
                out[iy, ix] = 0.0
                continue
            if hd < 1e-9:
                out[iy, ix] = 1.0
                continue
            dt = step_m / hd
            px = x0 + ix * res
            py = y0 + iy * res
            pz = h[iy, ix] + lift_m
            lit = 1.0
            t = dt
            while True:
                z = pz + t * lz
                if z > zmax:
                    break
                hh = _height(h, x0, y0, res, px + t * lx, py + t * ly)
                if hh == -np.inf:
                    break
                if hh > z:
                    lit = 0.0
                    break
                t += dt
            out[iy, ix] = lit
