"""Render the image a camera model would take of a DTM and an orthoimage.

This is the simulation of the LROC multi-image study (seeds/001, section 3.4):
every pixel's ray is intersected with the DTM, iterating on height until it
converges (here :func:`lunarmap.camera.intersect_dtm`, called through the
camera's ``image_to_ground(dtm=...)``), and the grey value is read from the
orthoimage at the resulting latitude and longitude. Two additions matter for
sub-pixel truth:

* anti-aliasing: each pixel is the mean of ``supersample x supersample`` rays
  spread evenly over its footprint (a box filter), so the image is what an
  ideal detector of that pixel size integrates;
* optional Lambert shading from the Sun direction, using the DTM normal, and
  Gaussian noise (grey levels), drawn per dask block from a seed so renders
  are reproducible.

Images are ``xarray.DataArray`` (``line``, ``sample``) backed by dask, one
task per block; coordinates are CSM pixel centres (``i + 0.5``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

import dask
import dask.array as dska
import numpy as np
import xarray as xr
from numpy.typing import ArrayLike, NDArray

from ..camera.intersect import DtmSampler
from ..errors import InvalidInputError, SimulationWarning, warn
from .sampling import RasterSampler

__all__ = ["render_image", "surface_normals", "RenderSpec"]

Array = NDArray[np.float64]


def surface_normals(dtm: DtmSampler, lon: Array, lat: Array, radius: float) -> Array:
    """Unit outward normals (body-fixed) of the DTM surface at ``lon``, ``lat`` (degrees).

    Central differences over one DTM node spacing; NaN where the DTM is undefined.
    """
    dlat = float(np.min(np.diff(dtm.lat)))
    dlon = float(np.min(np.diff(dtm.lon)))
    h_e = dtm(lon + dlon / 2, lat) - dtm(lon - dlon / 2, lat)
    h_n = dtm(lon, lat + dlat / 2) - dtm(lon, lat - dlat / 2)
    phi, lam = np.radians(lat), np.radians(lon)
    dz_de = h_e / (radius * np.cos(phi) * np.radians(dlon))
    dz_dn = h_n / (radius * np.radians(dlat))
    east = np.stack([-np.sin(lam), np.cos(lam), np.zeros_like(lam)], axis=-1)
    north = np.stack([-np.sin(phi) * np.cos(lam), -np.sin(phi) * np.sin(lam), np.cos(phi)], axis=-1)
    up = np.stack([np.cos(phi) * np.cos(lam), np.cos(phi) * np.sin(lam), np.sin(phi)], axis=-1)
    n = up - dz_de[..., None] * east - dz_dn[..., None] * north
    return n / np.linalg.norm(n, axis=-1, keepdims=True)


@dataclass
class RenderSpec:
    """Everything a render task needs; pickled once into the dask graph."""

    camera: Any
    dtm: DtmSampler
    ortho: Any
    radius: float
    supersample: int
    sun: Array | None
    gain: float
    offset: float
    noise_sigma: float
    saturation: float | None
    seed: int

    def block(self, l0: int, l1: int, s0: int, s1: int, block_seed: tuple[int, ...]) -> Array:
        """Grey values of pixels ``[l0, l1) x [s0, s1)``; NaN where rays miss the DTM or orthoimage."""
        k = self.supersample
        sub = (np.arange(k) + 0.5) / k  # ray offsets inside a pixel (box filter)
        lines = (np.arange(l0, l1)[:, None] + sub[None, :]).ravel()
        samples = (np.arange(s0, s1)[:, None] + sub[None, :]).ravel()
        L, S = np.meshgrid(lines, samples, indexing="ij")
        g = self.camera.image_to_ground(L.ravel(), S.ravel(), dtm=self.dtm, on_miss="nan")
        lon = np.degrees(np.arctan2(g[:, 1], g[:, 0]))
        lat = np.degrees(np.arctan2(g[:, 2], np.hypot(g[:, 0], g[:, 1])))
        value = self.ortho(lon, lat)
        if self.sun is not None:
            n = surface_normals(self.dtm, lon, lat, self.radius)
            up = g / np.linalg.norm(g, axis=-1, keepdims=True)
            cos_i = np.einsum("ij,j->i", n, self.sun)
            cos_flat = np.maximum(up @ self.sun, 0.05)
            # Lambert: brightness proportional to cos(incidence); normalised by a
            # flat surface's so the mean level stays that of the orthoimage.
            value = value * np.maximum(cos_i, 0.0) / cos_flat
        img = value.reshape(l1 - l0, k, s1 - s0, k).mean(axis=(1, 3))
        img = self.offset + self.gain * img
        if self.noise_sigma > 0:
            rng = np.random.default_rng(block_seed)
            img = img + rng.normal(0.0, self.noise_sigma, img.shape)
        if self.saturation is not None:
            img = np.minimum(img, self.saturation)
        return img


def _sun_direction(camera: Any, sun: Any) -> Array | None:
    if sun is None or sun is False:
        return None
    if isinstance(sun, str):
        if sun != "eo":
            raise InvalidInputError(f"sun must be None, 'eo' or a 3-vector, got {sun!r}")
        eo = camera.eo
        t0, t1 = eo.time_range
        s = np.asarray(eo.sun_position_at(0.5 * (t0 + t1)), dtype=float).reshape(3)
    else:
        s = np.asarray(sun, dtype=float).reshape(-1)
        if s.shape != (3,) or not np.all(np.isfinite(s)) or not np.any(s):
            raise InvalidInputError(f"sun direction must be a finite non-zero 3-vector, got {sun!r}")
    # The Sun is ~1.5e11 m away: one direction serves the whole scene.
    return s / np.linalg.norm(s)


def render_image(camera: Any, dtm: xr.DataArray | DtmSampler, ortho: xr.DataArray | Callable[..., Any], *, supersample: int = 3,
                 sun: str | ArrayLike | None = None, gain: float = 255.0, offset: float = 0.0,
                 noise_sigma: float = 0.0, saturation: float | None = None, seed: int = 0,
                 chunks: int = 256, window: tuple[int, int, int, int] | None = None,
                 name: str = "image") -> xr.DataArray:
    """Simulate the image of a DTM and an orthoimage seen by a camera model.

    Parameters
    ----------
    camera : FrameCamera or LineScanCamera
        Any object with ``image_to_ground(line, sample, dtm=..., on_miss="nan")``,
        ``.interior.n_lines`` / ``.n_samples`` and, for ``sun="eo"``, ``.eo``.
    dtm : xarray.DataArray or DtmSampler
        Heights (metres above ``camera.shape.reference_radius``) on ``lat`` x ``lon`` (degrees).
    ortho : xarray.DataArray or callable
        Orthoimage or albedo, on (``lat``, ``lon``) or projected (``y``, ``x``) with
        ``attrs["crs"]`` (see :class:`RasterSampler`), or any ``ortho(lon, lat)`` -> values
        sampler such as a :class:`~lunarmap.simulate.albedo.TiledAlbedo`.
    supersample : int
        Rays per pixel along each axis (box-filter anti-aliasing).
    sun : None, "eo" or array_like (3,)
        No shading, the Sun position from ``camera.eo`` (mid-time), or a
        body-fixed direction towards the Sun.
    gain, offset : float
        Grey level = ``offset + gain * ortho * shading``.
    noise_sigma : float
        Standard deviation of the added Gaussian noise, grey levels.
    saturation : float, optional
        Grey values are clipped at this level (a saturated detector).
    seed : int
        Noise seed; each block draws from ``(seed, line block, sample block)``.
    chunks : int
        Block size (lines and samples) of the dask array; one task per block.
    window : (l0, l1, s0, s1), optional
        Render only pixels ``[l0, l1) x [s0, s1)`` (array indices) instead of the whole image.
    name : str
        Name of the returned array.

    Returns
    -------
    xarray.DataArray
        Lazy (dask) float32 image, dims (``line``, ``sample``), coordinates at
        pixel centres (CSM convention), grey levels. Pixels whose rays miss the
        DTM or orthoimage are NaN (a :class:`SimulationWarning` is issued when
        the image is computed).
    """
    if int(supersample) < 1:
        raise InvalidInputError(f"supersample must be >= 1, got {supersample}")
    if not (np.isfinite(noise_sigma) and noise_sigma >= 0):
        raise InvalidInputError(f"noise_sigma must be >= 0 grey levels, got {noise_sigma}")
    if int(chunks) < 8:
        raise InvalidInputError(f"chunks must be >= 8 pixels, got {chunks}")
    nl, ns = int(camera.interior.n_lines), int(camera.interior.n_samples)
    l0, l1, s0, s1 = window if window is not None else (0, nl, 0, ns)
    if not (0 <= l0 < l1 <= nl and 0 <= s0 < s1 <= ns):
        raise InvalidInputError(f"window {window} is empty or outside the {nl} x {ns} image")
    sampler = dtm if isinstance(dtm, DtmSampler) else DtmSampler(dtm)
    if not isinstance(ortho, xr.DataArray) and not callable(ortho):
        raise InvalidInputError(f"ortho must be an xarray.DataArray or a sampler ortho(lon, lat), got {type(ortho).__name__}")
    spec = RenderSpec(camera=camera, dtm=sampler, ortho=RasterSampler(ortho) if isinstance(ortho, xr.DataArray) else ortho,
                      radius=float(camera.shape.reference_radius), supersample=int(supersample),
                      sun=_sun_direction(camera, sun), gain=float(gain), offset=float(offset),
                      noise_sigma=float(noise_sigma), saturation=saturation, seed=int(seed))
    spec_d = dask.delayed(spec, traverse=False)
    rows = []
    for bi, a in enumerate(range(l0, l1, chunks)):
        b = min(a + chunks, l1)
        row = []
        for bj, c in enumerate(range(s0, s1, chunks)):
            d = min(c + chunks, s1)
            task = dask.delayed(_render_block)(spec_d, a, b, c, d, (int(seed), bi, bj))
            row.append(dska.from_delayed(task, shape=(b - a, d - c), dtype=np.float32))
        rows.append(row)
    data = dska.block(rows)
    return xr.DataArray(
        data, dims=("line", "sample"),
        coords={"line": np.arange(l0, l1) + 0.5, "sample": np.arange(s0, s1) + 0.5}, name=name,
        attrs={"units": "grey level", "camera": repr(camera), "supersample": int(supersample),
               "noise_sigma": float(noise_sigma), "gain": float(gain), "offset": float(offset),
               "shading": "lambert" if spec.sun is not None else "none",
               "pixel_convention": "CSM: centre of the first pixel at (0.5, 0.5)"})


def _render_block(spec: RenderSpec, l0: int, l1: int, s0: int, s1: int, block_seed: tuple[int, ...]
                  ) -> NDArray[np.float32]:
    img = spec.block(l0, l1, s0, s1, block_seed)
    n_bad = int(np.count_nonzero(~np.isfinite(img)))
    if n_bad:
        warn(f"{n_bad} of {img.size} pixels in block lines [{l0}, {l1}) samples [{s0}, {s1}) see no DTM "
             f"or orthoimage (outside their extent) and are NaN", SimulationWarning)
    return img.astype(np.float32)
