"""Compiled ray casting of the renderer: ray ∩ DTM warm-started from the neighbouring ray, shading, albedo.

The arithmetic is that of the numpy path, operation for operation, so that a compiled pixel is what
the numpy renderer (:func:`~lunarmap.simulate.render_image`) and the camera's own
``image_to_ground(l, s, dtm=DtmSampler(dtm))`` say it is:

* heights: :class:`~lunarmap.camera.DtmSampler`'s bilinear lookup (the same cell search, longitude
  wrap and weights);
* the intersection: :func:`~lunarmap.camera.intersect_dtm`'s equation ``dtm(P(h)) = h`` with ``P(h)``
  the ray's nearest intersection with the sphere of radius ``R + h`` (the same quadratic, the same
  secant steps kept inside a bracket, bisection when a step leaves it or stalls), converged to
  ``tol`` (default 10 um, a hundredth of ``intersect_dtm``'s default) and started from the height
  of the previous ray of the same image line instead of the DTM's mid-range: neighbouring rays
  0.5 m apart differ by centimetres in height, so a ray costs two or three evaluations;
* shading: :func:`~lunarmap.simulate.surface_normals` (central differences over one DTM node
  spacing) and the Lambert law normalised by a flat surface's;
* albedo: a lat/lon raster sampled like the DTM, or :class:`~lunarmap.simulate.albedo.TiledAlbedo`.

Rays come from the caller: per image row (a line-scan line: position and rotation), per column or
per pixel look vectors in the sensor frame (undistorted ``(x, y, f)``); see
:mod:`lunarmap.simulate.compiled`.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numba import prange

__all__ = ["cast_rows", "add_noise_and_quantise"]

_NAN = np.nan
#: Image rows per parallel task and ray columns per block of the compiled loop (cache locality).
_BAND_ROWS = 8
_BLOCK_COLS = 256


@numba.njit(cache=True)
def _cell(grid, inv_step, x):
    """``clip(searchsorted(grid, x, 'right') - 1, 0, n - 2)``, or -1 outside ``[grid[0], grid[-1]]`` or NaN."""
    n = grid.shape[0]
    if not (x >= grid[0] and x <= grid[n - 1]):
        return -1
    i = int((x - grid[0]) * inv_step)   # a guess for a (nearly) regular grid, corrected below
    if i > n - 2:
        i = n - 2
    if i < 0:
        i = 0
    while i < n - 2 and grid[i + 1] <= x:
        i += 1
    while i > 0 and grid[i] > x:
        i -= 1
    return i


@numba.njit(cache=True)
def _wrap_lon(lon, lon360):
    """DtmSampler's ``np.mod(lon, 360)`` or ``np.mod(lon + 180, 360) - 180`` for ``|lon| < 540``."""
    if lon360:
        if lon < 0.0:
            return lon + 360.0
        return lon - 360.0 if lon >= 360.0 else lon
    a = lon + 180.0
    if a < 0.0:
        a += 360.0
    elif a >= 360.0:
        a -= 360.0
    return a - 180.0


@numba.njit(cache=True)
def _bilinear(lat_g, lon_g, z, inv_lat, inv_lon, lon, lat):
    """DtmSampler.__call__ at one point (``lon`` wrapped); NaN outside or next to NaN nodes.

    ``inv_lat``, ``inv_lon``: reciprocal node spacings, the last entry the reciprocal mean spacing.
    """
    nla = lat_g.shape[0]
    nlo = lon_g.shape[0]
    i = _cell(lat_g, inv_lat[nla - 1], lat)
    j = _cell(lon_g, inv_lon[nlo - 1], lon)
    if i < 0 or j < 0:
        return _NAN
    u = (lat - lat_g[i]) * inv_lat[i]
    v = (lon - lon_g[j]) * inv_lon[j]
    return ((1.0 - u) * ((1.0 - v) * z[i, j] + v * z[i, j + 1])
            + u * ((1.0 - v) * z[i + 1, j] + v * z[i + 1, j + 1]))


@numba.njit(cache=True)
def _lonlat(x, y, zz):
    lon = math.degrees(math.atan2(y, x))
    lat = math.degrees(math.atan2(zz, math.sqrt(x * x + y * y)))   # hypot's overflow guard is not needed here
    return lon, lat


@numba.njit(cache=True)
def _sphere_s(oo, od, dd, r):
    """Ray parameter of the nearest positive intersection with the sphere of radius ``r`` (NaN if none).

    ``intersect_sphere``'s quadratic ``a s^2 + 2 b s + c = 0`` in its cancellation-free form.
    """
    c = oo - r * r
    disc = od * od - dd * c
    if not disc >= 0.0:
        return _NAN
    q = -(od + math.copysign(math.sqrt(disc), od))
    if c > 0.0 and od < 0.0:
        return c / q          # outside, looking in: the near root (q > 0), the far one is q / dd
    s1 = q / dd
    s2 = c / q
    lo = min(s1, s2)
    hi = max(s1, s2)
    if lo > 0.0:
        return lo
    if hi > 0.0:
        return hi
    return _NAN


@numba.njit(cache=True)
def _meets_sphere(oo, od, dd, r):
    """Whether the ray has a positive intersection with the sphere of radius ``r`` (no root taken)."""
    c = oo - r * r
    return od * od - dd * c >= 0.0 and (c < 0.0 or od < 0.0)


#: Trial points within 3 m of the reference ground point (the previous ray's) take their latitude and
#: longitude from its first-order expansion: the neglected second order is ``|dp|^2 / R`` < 3e-6 m on
#: the ground, against the 1e-5 m height convergence. (Squared, m^2.)
_LINEAR_REACH_M2 = 9.0


@numba.njit(cache=True)
def _height_at(px, py, pz, lat_g, lon_g, z, inv_lat, inv_lon, lon360, ref):
    """DTM height under the point ``p`` (NaN off the DTM).

    ``ref = (x, y, z, lon, lat, dlon/dx, dlon/dy, dlat/dx, dlat/dy, dlat/dz)`` of a nearby ground point
    (``ref[0]`` NaN: none) linearises its latitude and longitude (degrees).
    """
    ex = px - ref[0]
    ey = py - ref[1]
    ez = pz - ref[2]
    if ex * ex + ey * ey + ez * ez < _LINEAR_REACH_M2:
        lon = ref[3] + ref[5] * ex + ref[6] * ey
        lat = ref[4] + ref[7] * ex + ref[8] * ey + ref[9] * ez
    else:   # also when ref[0] is NaN (the comparison is false)
        lon, lat = _lonlat(px, py, pz)
    return _bilinear(lat_g, lon_g, z, inv_lat, inv_lon, _wrap_lon(lon, lon360), lat)


@numba.njit(cache=True)
def _residual(ox, oy, oz, dx, dy, dz, oo, od, dd, radius, h, lat_g, lon_g, z, inv_lat, inv_lon, lon360, ref):
    """``f(h) = dtm(P(h)) - h`` of intersect_dtm (-1 where the ray misses the sphere R + h; NaN off the DTM)."""
    s = _sphere_s(oo, od, dd, radius + h)
    if s != s:
        return -1.0
    return _height_at(ox + s * dx, oy + s * dy, oz + s * dz, lat_g, lon_g, z, inv_lat, inv_lon, lon360, ref) - h


@numba.njit(cache=True)
def _reference(x, y, zz, lon, lat, inv_rho, inv_r):
    """The linearisation tuple of :func:`_height_at` at a ground point, its longitude, latitude (degrees) and
    ``1 / sqrt(x^2 + y^2)``, ``1 / |p|``."""
    k = 180.0 / math.pi
    a = k * inv_rho * inv_rho
    b = k * inv_r * inv_r * inv_rho
    return (x, y, zz, lon, lat, -y * a, x * a, -x * zz * b, -y * zz * b, (x * x + y * y) * b)


#: Trial heights within this distance (m) of the last exact sphere intersection move along the ray
#: by the second-order Taylor expansion of ``s(h)``: its third-order term is below 1e-9 m there.
_TAYLOR_REACH_M = 2.0


@numba.njit(cache=True)
def _intersect(ox, oy, oz, dx, dy, dz, radius, h_start, lo0, hi0, tol, max_iter,
               lat_g, lon_g, z, inv_lat, inv_lon, lon360, ref):
    """Height and ray parameter of the ray ∩ DTM (NaN: misses or leaves the DTM; +inf: did not converge).

    intersect_dtm's iteration for one ray, started from ``h_start`` when it is finite. The point
    ``P(h)`` of a trial height comes from the sphere's quadratic, or, near the last height where it
    did, from ``s(h) = s_a + s' dh + s'' dh^2 / 2`` (``|P|^2 = (R + h)^2`` differentiated twice).
    """
    oo = ox * ox + oy * oy + oz * oz
    od = ox * dx + oy * dy + oz * dz
    dd = dx * dx + dy * dy + dz * dz
    lo = lo0
    hi = hi0
    if not _meets_sphere(oo, od, dd, radius + lo):
        return _NAN, _NAN   # misses the lowest sphere: misses the terrain
    if h_start == h_start:
        h = min(max(h_start, lo), hi)
    else:
        mid = 0.5 * (lo + hi)
        h = mid + _residual(ox, oy, oz, dx, dy, dz, oo, od, dd, radius, mid, lat_g, lon_g, z, inv_lat, inv_lon,
                            lon360, ref)
        h = min(max(h, lo), hi) if h == h else mid
    h_prev = _NAN
    f_prev = _NAN
    ha = _NAN   # the Taylor anchor: height, ray parameter and its two derivatives there
    sa = s1 = s2 = 0.0
    for _ in range(max_iter):
        if abs(h - ha) < _TAYLOR_REACH_M:
            dh = h - ha
            s = sa + dh * (s1 + 0.5 * s2 * dh)
        else:
            s = _sphere_s(oo, od, dd, radius + h)
            if s == s:
                r = radius + h
                pd = od + s * dd      # P . d (< 0: the ray enters the sphere)
                ha = h
                sa = s
                s1 = r / pd
                s2 = (pd - r * dd * s1) / (pd * pd)
        if s == s:
            f = _height_at(ox + s * dx, oy + s * dy, oz + s * dz, lat_g, lon_g, z, inv_lat, inv_lon, lon360, ref) - h
        else:
            f = -1.0   # above the whole sphere R + h: the same side as f < 0
        if f != f:
            return _NAN, _NAN
        if f > 0.0:
            lo = h
        else:
            hi = h
        new = h + f
        if h_prev == h_prev:
            secant = h - f * (h - h_prev) / (f - f_prev)
            if math.isfinite(secant):
                new = secant
        stall = f_prev == f_prev and abs(f) > 0.5 * abs(f_prev)
        if not (new > lo and new < hi) or stall:
            new = 0.5 * (lo + hi)
        if f == 0.0:
            new = h
        step = abs(new - h)
        # Converged when the step is below tol (intersect_dtm's test), or when a secant step shrank so
        # fast (superlinear convergence: the next error ~ step^2 / previous step) that the error left
        # is below tol / 10: it saves the evaluation that would only confirm it.
        if step < tol or f == 0.0 or hi - lo < tol or (
                not stall and h_prev == h_prev and step * step < 0.1 * tol * abs(h - h_prev)):
            if abs(new - ha) < _TAYLOR_REACH_M:
                dh = new - ha
                return new, sa + dh * (s1 + 0.5 * s2 * dh)
            return new, _sphere_s(oo, od, dd, radius + new)
        h_prev = h
        f_prev = f
        h = new
    return np.inf, _NAN


@numba.njit(cache=True)
def _tile_value(tile, u, v):
    """Bilinear value of a periodic tile at node coordinates ``u`` (axis 1), ``v`` (axis 0)."""
    n0 = tile.shape[0]
    n1 = tile.shape[1]
    u = u - n1 * math.floor(u / n1)   # into [0, n1): a float floor, not an integer division
    v = v - n0 * math.floor(v / n0)
    fu = math.floor(u)
    fv = math.floor(v)
    a = u - fu
    b = v - fv
    j = min(int(fu), n1 - 1)
    i = min(int(fv), n0 - 1)
    j1 = j + 1 if j + 1 < n1 else 0
    i1 = i + 1 if i + 1 < n0 else 0
    return ((1.0 - b) * ((1.0 - a) * np.float64(tile[i, j]) + a * np.float64(tile[i, j1]))
            + b * ((1.0 - a) * np.float64(tile[i1, j]) + a * np.float64(tile[i1, j1])))


@numba.njit(cache=True)
def _tiled_albedo(t1, t2, p, lon, lat):
    """TiledAlbedo.__call__ at one point (p: its kernel_arrays() row)."""
    dlon = _wrap_lon(lon - p[0], False)
    e = dlon * p[2]
    nn = (lat - p[1]) * p[3]
    sp = p[6]
    tex = _tile_value(t1, (p[7] * e + p[8] * nn) / sp + p[9], (-p[8] * e + p[7] * nn) / sp + p[10])
    tex += _tile_value(t2, (p[11] * e + p[12] * nn) / sp + p[13], (-p[12] * e + p[11] * nn) / sp + p[14])
    a = p[4] * (1.0 + p[5] * (tex / math.sqrt(2.0)))
    return min(max(a, 0.02), 0.98)


@numba.njit(parallel=True, cache=True)
def cast_rows(pos, rot, look, k, radius, tol, max_iter, lat_g, lon_g, z, lon360, h_lo, h_hi,
              alb_mode, alb_lat, alb_lon, alb_z, alb_lon360, t1, t2, alb_p, sun, use_sun,
              out, xyz, want_xyz):
    """Mean grey value (albedo x shading) of ``k x k`` rays per pixel for ``out.shape`` pixels.

    Parameters
    ----------
    pos, rot : (m, 3), (m, 3, 3)
        Sensor position (m) and sensor-to-body rotation per ray row (``m = k * rows``) or one (``m = 1``).
    look : (m', k * cols, 3)
        Undistorted sensor-frame look vectors per ray row (``m' = k * rows``) or one row for all (``m' = 1``).
    k : int
        Rays per pixel along each axis; ray row ``r k + a`` of pixel row ``r``.
    lat_g, lon_g, z, lon360, h_lo, h_hi
        The DTM (DtmSampler's arrays) and its height range widened by 1 m.
    alb_mode : int
        0: the albedo is the raster ``alb_lat, alb_lon, alb_z``; 1: the tiles ``t1, t2`` (row ``alb_p``).
    sun : (3,)
        Unit vector to the Sun, body-fixed; ``use_sun`` false: no shading.
    out : (rows, cols) float64
        Filled with the mean value per pixel; NaN where a ray misses, +inf where it did not converge.
    xyz : (k rows, k cols, 3) or (1, 1, 3)
        Ground points of every ray when ``want_xyz``.
    """
    rows, cols = out.shape
    inv_lat = _reciprocal_steps(lat_g)
    inv_lon = _reciprocal_steps(lon_g)
    a_inv_lat = _reciprocal_steps(alb_lat)
    a_inv_lon = _reciprocal_steps(alb_lon)
    dlat = lat_g[1] - lat_g[0]
    dlon = lon_g[1] - lon_g[0]
    for i in range(1, lat_g.shape[0]):
        dlat = min(dlat, lat_g[i] - lat_g[i - 1])
    for j in range(1, lon_g.shape[0]):
        dlon = min(dlon, lon_g[j] - lon_g[j - 1])
    grad_e = 1.0 / (radius * math.radians(dlon))   # height difference over one node -> slope (x 1/cos lat)
    grad_n = 1.0 / (radius * math.radians(dlat))
    inv_k2 = 1.0 / (k * k)
    n_bands = (rows + _BAND_ROWS - 1) // _BAND_ROWS
    # Bands of image rows, each walked in blocks of columns: a block's rays land on a small patch of the
    # scene, so the DTM and albedo tile rows they read stay in cache (whole 5,064-ray rows do not); each
    # ray row keeps its warm start (the previous rays' heights, the linearisation point) from block to block.
    for band in prange(n_bands):
        r0 = band * _BAND_ROWS
        r1 = min(r0 + _BAND_ROWS, rows)
        n_rr = (r1 - r0) * k
        h1s = np.full(n_rr, _NAN)   # heights of the previous two rays of each ray row
        h2s = np.full(n_rr, _NAN)
        refs = np.full((n_rr, 10), _NAN)
        for r in range(r0, r1):
            for c in range(cols):
                out[r, c] = 0.0
        for c0 in range(0, cols * k, _BLOCK_COLS):
            c1 = min(c0 + _BLOCK_COLS, cols * k)
            for rr in range(n_rr):
                sr = r0 * k + rr
                r = sr // k
                pi = sr if pos.shape[0] > 1 else 0
                li = sr if look.shape[0] > 1 else 0
                ox, oy, oz = pos[pi, 0], pos[pi, 1], pos[pi, 2]
                h1 = h1s[rr]
                h2 = h2s[rr]
                q = refs[rr]
                ref = (q[0], q[1], q[2], q[3], q[4], q[5], q[6], q[7], q[8], q[9])
                for sc in range(c0, c1):
                    lx, ly, lz = look[li, sc, 0], look[li, sc, 1], look[li, sc, 2]
                    dx = rot[pi, 0, 0] * lx + rot[pi, 0, 1] * ly + rot[pi, 0, 2] * lz
                    dy = rot[pi, 1, 0] * lx + rot[pi, 1, 1] * ly + rot[pi, 1, 2] * lz
                    dz = rot[pi, 2, 0] * lx + rot[pi, 2, 1] * ly + rot[pi, 2, 2] * lz
                    inv = 1.0 / math.sqrt(dx * dx + dy * dy + dz * dz)
                    dx *= inv
                    dy *= inv
                    dz *= inv
                    # warm start: the previous rays' heights, extrapolated linearly
                    start = 2.0 * h1 - h2 if h2 == h2 else h1
                    h, s = _intersect(ox, oy, oz, dx, dy, dz, radius, start, h_lo, h_hi, tol, max_iter,
                                      lat_g, lon_g, z, inv_lat, inv_lon, lon360, ref)
                    pc = sc // k
                    if not math.isfinite(h):
                        out[r, pc] += h   # NaN (miss) or +inf (no convergence) marks the pixel
                        if want_xyz:
                            xyz[sr, sc, 0] = _NAN
                            xyz[sr, sc, 1] = _NAN
                            xyz[sr, sc, 2] = _NAN
                        h1 = _NAN
                        h2 = _NAN
                        ref = (_NAN, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
                        continue
                    h2 = h1
                    h1 = h
                    gx = ox + s * dx
                    gy = oy + s * dy
                    gz = oz + s * dz
                    if want_xyz:
                        xyz[sr, sc, 0] = gx
                        xyz[sr, sc, 1] = gy
                        xyz[sr, sc, 2] = gz
                    rho = math.sqrt(gx * gx + gy * gy)
                    inv_rho = 1.0 / rho
                    inv_r = 1.0 / math.sqrt(gx * gx + gy * gy + gz * gz)
                    lon = math.degrees(math.atan2(gy, gx))
                    lat = math.degrees(math.atan2(gz, rho))
                    ref = _reference(gx, gy, gz, lon, lat, inv_rho, inv_r)
                    if alb_mode == 1:
                        value = _tiled_albedo(t1, t2, alb_p, lon, lat)
                    else:
                        value = _bilinear(alb_lat, alb_lon, alb_z, a_inv_lat, a_inv_lon, _wrap_lon(lon, alb_lon360),
                                          lat)
                    if use_sun:
                        value *= _lambert(gx, gy, gz, rho, inv_rho, inv_r, lon, lat, lat_g, lon_g, z, inv_lat, inv_lon,
                                          lon360, dlat, dlon, grad_e, grad_n, sun)
                    out[r, pc] += value
                h1s[rr] = h1
                h2s[rr] = h2
                for m in range(10):
                    refs[rr, m] = ref[m]
        for r in range(r0, r1):
            for c in range(cols):
                out[r, c] *= inv_k2


@numba.njit(cache=True)
def _lambert(gx, gy, gz, rho, inv_rho, inv_r, lon, lat, lat_g, lon_g, z, inv_lat, inv_lon, lon360, dlat, dlon,
             grad_e, grad_n, sun):
    """``max(cos i, 0) / max(cos i_flat, 0.05)`` at a ground point: render_image's shading.

    The normal is surface_normals' (central differences over one DTM node spacing); the sines and
    cosines of latitude and longitude come from the point itself (``rho = sqrt(x^2 + y^2)``,
    ``inv_r = 1 / |p|``).
    """
    h_e = (_bilinear(lat_g, lon_g, z, inv_lat, inv_lon, _wrap_lon(lon + dlon / 2, lon360), lat)
           - _bilinear(lat_g, lon_g, z, inv_lat, inv_lon, _wrap_lon(lon - dlon / 2, lon360), lat))
    wl = _wrap_lon(lon, lon360)
    h_n = (_bilinear(lat_g, lon_g, z, inv_lat, inv_lon, wl, lat + dlat / 2)
           - _bilinear(lat_g, lon_g, z, inv_lat, inv_lon, wl, lat - dlat / 2))
    cphi, sphi, clam, slam = rho * inv_r, gz * inv_r, gx * inv_rho, gy * inv_rho
    dz_de = h_e * grad_e / cphi
    dz_dn = h_n * grad_n
    nx = cphi * clam + dz_de * slam + dz_dn * sphi * clam
    ny = cphi * slam - dz_de * clam + dz_dn * sphi * slam
    nz = sphi - dz_dn * cphi
    cos_i = (nx * sun[0] + ny * sun[1] + nz * sun[2]) / math.sqrt(nx * nx + ny * ny + nz * nz)
    cos_flat = max((gx * sun[0] + gy * sun[1] + gz * sun[2]) * inv_r, 0.05)
    return max(cos_i, 0.0) / cos_flat


@numba.njit(cache=True)
def _reciprocal_steps(grid):
    """``1 / diff(grid)``, and last the reciprocal mean step (the cell search's first guess)."""
    n = grid.shape[0]
    out = np.empty(max(n, 1))
    for i in range(n - 1):
        out[i] = 1.0 / (grid[i + 1] - grid[i])
    out[max(n, 1) - 1] = (n - 1) / (grid[n - 1] - grid[0]) if n > 1 else 1.0
    return out


@numba.njit(cache=True)
def _splitmix(x):
    x = (x + np.uint64(0x9E3779B97F4A7C15))
    x = (x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    x = (x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return x ^ (x >> np.uint64(31))


@numba.njit(parallel=True, cache=True)
def add_noise_and_quantise(values, line0, sample0, seed, gain, offset, sigma, lo, hi, null, out, quantise=True):
    """``out = clip(rint(offset + gain * values + noise), lo, hi)``, ``null`` where ``values`` is not finite.

    Without ``quantise`` the values are not rounded (Real cubes).

    The noise of pixel ``(line, sample)`` (absolute image indices) is a standard normal deviate drawn
    from a counter-based hash of ``(seed, line, sample)`` (SplitMix64, Box-Muller) times ``sigma``: the
    same whatever the stripe, window or thread that renders the pixel.
    """
    rows, cols = values.shape
    key = _splitmix(np.uint64(seed))
    for r in prange(rows):
        line = np.uint64(line0 + r)
        for c in range(cols):
            v = values[r, c]
            if not math.isfinite(v):
                out[r, c] = null
                continue
            g = offset + gain * v
            if sigma > 0.0:
                x = _splitmix(key ^ _splitmix((line << np.uint64(32)) | np.uint64(sample0 + c)))
                u1 = ((x >> np.uint64(11)) + np.uint64(1)) * (1.0 / 9007199254740993.0)   # (0, 1]
                u2 = (_splitmix(x) >> np.uint64(11)) * (1.0 / 9007199254740992.0)         # [0, 1)
                g += sigma * math.sqrt(-2.0 * math.log(u1)) * math.cos(2.0 * math.pi * u2)
            if quantise:
                g = np.rint(g)   # nearest integer, ties to even (as write_cube)
            out[r, c] = min(max(g, lo), hi)
