"""An albedo defined everywhere around a site without a raster of the site: two periodic textures, summed.

A raster albedo at 0.5 m (:func:`~lunarmap.simulate.synthetic_albedo`) over the ~58 km x 6 km that
eight full-size NAC-like images cover would hold 1.4 G nodes. :class:`TiledAlbedo` instead sums two
periodic, band-limited textures (each a square tile of ``n x n`` nodes, generated once from the seed
by FFT filtering of white noise, so it wraps without a seam), laid over the ground in the site's
local east/north metres at two different angles and of two different periods. The sum has the
tiles' spectrum (``k^-1`` between ``feature_size`` and the tile size, Gaussian low-pass of
``blur`` metres), is the same at the same ground point in every image, and does not repeat: the two
tiles' lattices are rotated against each other by an irrational-looking angle and their periods
differ, so no translation maps the sum onto itself within any lunar site.

The albedo is ``mean * (1 + contrast * (T1 + T2) / sqrt(2))``, clipped to [0.02, 0.98], with each
tile ``T`` of zero mean and unit variance. No non-linearity other than the (rarely active, 3.8
sigma) clip is applied, so the albedo keeps the tiles' band limit: with the defaults (features down
to 1.5 m, blur 0.25 m) 29 % of the amplitude is left at the 1 m Nyquist wavelength of 0.5 m pixels,
as for :mod:`lunarmap.simulate.mission`'s 1 m-pixel scene, whose docstring explains the choice.

``TiledAlbedo(lon, lat)`` evaluates it in numpy (what :func:`~lunarmap.simulate.render_image` and
the tests use); :mod:`lunarmap.simulate.raycast` evaluates the same arithmetic compiled.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import xarray as xr
from numpy.typing import ArrayLike, NDArray
from scipy.ndimage import gaussian_filter

from ..camera.shape import MOON_RADIUS
from ..errors import InvalidInputError
from .terrain import _power_law_noise

__all__ = ["TiledAlbedo", "tiled_albedo", "ALBEDO_CLIP"]

Array = NDArray[np.float64]

#: Albedo limits after the clip.
ALBEDO_CLIP = (0.02, 0.98)
#: Angles (degrees, from east) of the two tiles' axes: far from each other and from 0/45/90.
_ANGLES_DEG = (17.3, 61.7)


@dataclass(frozen=True)
class TiledAlbedo:
    """Albedo (dimensionless) around a site from two periodic textures; see the module docstring.

    Attributes
    ----------
    lon0, lat0 : float
        Site centre, degrees: the origin of the local east/north metres.
    radius : float
        Reference sphere radius, m.
    mean, contrast : float
        Mean albedo and relative standard deviation before the clip.
    tiles : tuple of ndarray
        The textures, each ``(n, n)`` float32 of zero mean and unit variance, periodic.
    spacing : float
        Node spacing of the tiles on the ground, m.
    angles_deg : tuple of float
        Orientation of each tile's first axis, degrees counter-clockwise from east.
    offsets_m : tuple of (float, float)
        Where the site centre falls in each tile, m (from the seed).
    """

    lon0: float
    lat0: float
    radius: float
    mean: float
    contrast: float
    tiles: tuple[NDArray[np.float32], ...]
    spacing: float
    angles_deg: tuple[float, ...]
    offsets_m: tuple[tuple[float, float], ...]

    @property
    def metres_per_degree(self) -> tuple[float, float]:
        """East and north metres per degree of longitude and latitude at the site (``local_grid``'s scale)."""
        north = self.radius * np.pi / 180.0
        return north * float(np.cos(np.radians(self.lat0))), north

    def kernel_arrays(self) -> tuple[NDArray[np.float32], NDArray[np.float32], Array]:
        """The two tiles and the parameters row the compiled renderer takes.

        The row is ``[lon0, lat0, m per deg east, m per deg north, mean, contrast, spacing,
        cos a1, sin a1, u1, v1, cos a2, sin a2, u2, v2]`` (``u, v``: the site centre in tile nodes).
        """
        me, mn = self.metres_per_degree
        row = [self.lon0, self.lat0, me, mn, self.mean, self.contrast, self.spacing]
        for a, (ou, ov) in zip(self.angles_deg, self.offsets_m):
            row += [np.cos(np.radians(a)), np.sin(np.radians(a)), ou / self.spacing, ov / self.spacing]
        return self.tiles[0], self.tiles[1], np.asarray(row, dtype=np.float64)

    def local(self, lon: ArrayLike, lat: ArrayLike) -> tuple[Array, Array]:
        """Local east and north metres of ``lon``, ``lat`` (degrees), as :func:`local_grid` spaces them."""
        me, mn = self.metres_per_degree
        lon = np.asarray(lon, dtype=float)
        dlon = np.mod(lon - self.lon0 + 180.0, 360.0) - 180.0
        return dlon * me, (np.asarray(lat, dtype=float) - self.lat0) * mn

    def texture(self, east: ArrayLike, north: ArrayLike) -> Array:
        """``(T1 + T2) / sqrt(2)`` at local east/north metres: zero mean, unit variance."""
        east = np.asarray(east, dtype=float)
        north = np.asarray(north, dtype=float)
        out = np.zeros(np.broadcast(east, north).shape)
        for tile, a, (ou, ov) in zip(self.tiles, self.angles_deg, self.offsets_m):
            ca, sa = np.cos(np.radians(a)), np.sin(np.radians(a))
            u = (ca * east + sa * north) / self.spacing + ou / self.spacing
            v = (-sa * east + ca * north) / self.spacing + ov / self.spacing
            out += _periodic_bilinear(tile, u, v)
        return out / np.sqrt(2.0)

    def __call__(self, lon: ArrayLike, lat: ArrayLike) -> Array:
        """Albedo at ``lon``, ``lat`` (degrees); NaN where they are NaN."""
        e, n = self.local(lon, lat)
        a = self.mean * (1.0 + self.contrast * self.texture(e, n))
        return np.clip(a, *ALBEDO_CLIP)

    def raster(self, lat: ArrayLike, lon: ArrayLike) -> xr.DataArray:
        """The albedo sampled on a ``lat`` x ``lon`` grid (degrees), e.g. for a quick look at a window."""
        lat = np.asarray(lat, dtype=float)
        lon = np.asarray(lon, dtype=float)
        values = self(lon[None, :], lat[:, None])
        return xr.DataArray(values, dims=("lat", "lon"), coords={"lat": lat, "lon": lon}, name="albedo",
                            attrs={"units": "1", "description": "lunarmap.simulate TiledAlbedo, sampled"})

    @property
    def nbytes(self) -> int:
        """Memory of the tiles, bytes."""
        return int(sum(t.nbytes for t in self.tiles))


def _periodic_bilinear(tile: NDArray, u: Array, v: Array) -> Array:
    """Bilinear interpolation of a periodic tile at node coordinates ``u`` (axis 1) and ``v`` (axis 0)."""
    n0, n1 = tile.shape
    fu, fv = np.floor(u), np.floor(v)
    a, b = u - fu, v - fv
    j = np.mod(fu, n1).astype(np.intp)
    i = np.mod(fv, n0).astype(np.intp)
    j1 = np.where(j + 1 == n1, 0, j + 1)
    i1 = np.where(i + 1 == n0, 0, i + 1)
    t = tile.astype(np.float64, copy=False)
    return ((1.0 - b) * ((1.0 - a) * t[i, j] + a * t[i, j1])
            + b * ((1.0 - a) * t[i1, j] + a * t[i1, j1]))


def _tile(n: int, spacing: float, feature_size: float, blur: float, rng: np.random.Generator) -> NDArray[np.float32]:
    """A periodic texture: FFT-filtered white noise (periodic by construction), low-passed, unit variance."""
    tex = _power_law_noise((n, n), spacing, 1.0, feature_size / np.pi, n * spacing, rng)
    tex = gaussian_filter(tex, blur / spacing, mode="wrap")   # wrap: the tile stays periodic
    tex -= tex.mean()
    return (tex / tex.std()).astype(np.float32)


def tiled_albedo(lon0: float, lat0: float, seed: int, *, feature_size: float = 1.5, blur: float = 0.25,
                 spacing: float = 0.25, tile_nodes: tuple[int, int] = (4096, 3840), contrast: float = 0.25,
                 mean: float = 0.5, radius: float = MOON_RADIUS) -> TiledAlbedo:
    """The albedo of a site for images of ~0.5 m pixels (the defaults; scale all lengths for others).

    Parameters
    ----------
    lon0, lat0 : float
        Site centre, degrees.
    seed : int
        Seed of both textures and of their placement.
    feature_size : float
        Shortest wavelength of the texture, m (Gaussian roll-off below, as ``synthetic_albedo``).
    blur : float
        Sigma of the Gaussian low-pass, m.
    spacing : float
        Node spacing of the tiles, m (at most ``blur``).
    tile_nodes : (int, int)
        Nodes along each side of the two tiles: their periods are ``n * spacing`` (1024 m and 960 m).
    contrast, mean : float
        Relative standard deviation and mean of the albedo (before the clip).
    radius : float
        Reference sphere radius, m.

    Returns
    -------
    TiledAlbedo
        Memory: ``4 * sum(n^2)`` bytes (123 MB with the defaults).
    """
    if not (spacing > 0 and blur >= spacing and feature_size >= 2.0 * spacing):
        raise InvalidInputError(f"tiled albedo: need 0 < spacing ({spacing} m) <= blur ({blur} m) and "
                                f"feature_size ({feature_size} m) >= 2 spacing")
    if len(tile_nodes) != 2 or min(tile_nodes) < 64 or tile_nodes[0] == tile_nodes[1]:
        raise InvalidInputError(f"tile_nodes must be two different sizes >= 64, got {tile_nodes!r}")
    if not (0 < mean < 1 and 0 <= contrast < 1):
        raise InvalidInputError(f"albedo mean must be in (0, 1) and contrast in [0, 1), got {mean}, {contrast}")
    rng = np.random.default_rng([int(seed), 7171])
    tiles = tuple(_tile(int(n), float(spacing), float(feature_size), float(blur), rng) for n in tile_nodes)
    offsets = tuple((float(rng.uniform(0, n * spacing)), float(rng.uniform(0, n * spacing))) for n in tile_nodes)
    return TiledAlbedo(float(lon0), float(lat0), float(radius), float(mean), float(contrast), tiles,
                       float(spacing), _ANGLES_DEG, offsets)
