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

_OPTS = dict(nogil=True, cache=True, fastmath=False, error_model="numpy")


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


@njit(**_OPTS)
def cast_rays(h, bmax, block, x0, y0, res, origin, dirs, step_m, t_hit):
    """Distance ``t_hit[i]`` (m) along unit world ray ``dirs[i]`` from ``origin`` to the terrain; NaN = miss.

    Sampling step ``step_m`` (horizontal metres) between empty-space skips; a sign change of
    ``ray z - h`` is refined by 30 bisections.
    """
    ny, nx = h.shape
    zmax = -np.inf
    zmin = np.inf
    for by in range(bmax.shape[0]):
        for bx in range(bmax.shape[1]):
            zmax = max(zmax, bmax[by, bx])
    for iy in range(ny):
        for ix in range(nx):
            zmin = min(zmin, h[iy, ix])
    xmax = x0 + (nx - 1) * res
    ymax = y0 + (ny - 1) * res
    bsize = block * res
    ox, oy, oz = origin[0], origin[1], origin[2]
    for i in range(dirs.shape[0]):
        dx, dy, dz = dirs[i, 0], dirs[i, 1], dirs[i, 2]
        t_hit[i] = np.nan
        if dz >= 0.0 and oz > zmax:
            continue
        t = 0.0
        if oz > zmax:
            t = (zmax - oz) / dz
        t_end = 1e9 if dz >= 0.0 else (zmin - 1e-3 - oz) / dz
        hd = math.sqrt(dx * dx + dy * dy)
        dt_fine = step_m / hd if hd > 1e-12 else 1e9
        t_prev = t
        f_prev = oz + t * dz - _height(h, x0, y0, res, ox + t * dx, oy + t * dy)
        if f_prev <= 0.0:
            if f_prev == -np.inf or f_prev != f_prev:
                continue
            t_hit[i] = t        # starts under the surface (camera inside the terrain)
            continue
        while t < t_end:
            px = ox + t * dx
            py = oy + t * dy
            if px < x0 or py < y0 or px > xmax or py > ymax:
                break
            bx = min(int((px - x0) / bsize), bmax.shape[1] - 1)
            by = min(int((py - y0) / bsize), bmax.shape[0] - 1)
            top = bmax[by, bx]
            pz = oz + t * dz
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
                t_next = max(t_next, t + 1e-6) + 1e-5
                t_prev = t
                t = t_next
                f_prev = oz + t * dz - _height(h, x0, y0, res, ox + t * dx, oy + t * dy)
                if f_prev <= 0.0 and f_prev != -np.inf:
                    # crossed the surface right at the jump: refine back over the jump
                    pass
                else:
                    continue
            else:
                t_prev = t
                t = min(t + dt_fine, t_end)
                f_prev = oz + t * dz - _height(h, x0, y0, res, ox + t * dx, oy + t * dy)
                if not (f_prev <= 0.0 and f_prev != -np.inf):
                    continue
            # bracket [t_prev (above), t (below)]: bisection
            a = t_prev
            b = t
            for _ in range(30):
                m = 0.5 * (a + b)
                fm = oz + m * dz - _height(h, x0, y0, res, ox + m * dx, oy + m * dy)
                if fm > 0.0 or fm == -np.inf:
                    a = m
                else:
                    b = m
            t_hit[i] = 0.5 * (a + b)
            break


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
