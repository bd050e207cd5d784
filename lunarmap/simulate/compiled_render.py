"""The compiled, tiled renderer: full-size images rendered stripe by stripe into ISIS cubes.

:func:`~lunarmap.simulate.render_image` (numpy, dask blocks) needs about 2 us per ray: a
52,224 x 5,064 NAC image would take hours. Here the same image model (see
:mod:`lunarmap.simulate.raycast` for the arithmetic, which is the numpy path's) runs compiled with
numba over image rows in parallel:

* a line-scan camera's exterior orientation is evaluated once per ray row (the camera's own EO:
  position and rotation at the exposure time of the line), a frame camera's once;
* the undistorted look vectors (the camera's interior orientation and distortion) once per image
  column for a line-scan camera, per pixel of the stripe for a frame camera;
* each ray's DTM intersection starts from the height of the previous ray of its row.

:func:`render_cube` renders ``stripe_lines`` lines at a time, adds the noise (a counter-based hash
of the pixel's line and sample, so a pixel's noise does not depend on the stripe or the thread),
quantises, and writes the stripe through :class:`~lunarmap.io.cube.CubeWriter`: memory is bounded
by one stripe plus the scene, whatever the image size, and a failed or killed render leaves no
cube under the final name. :func:`render_window` returns a window's float grey values and,
for tests, every ray's ground point.

Pixel type: ``UnsignedByte`` by default, as LRO NAC EDRs store their (companded) 8-bit samples:
DN = nearest integer of ``offset + gain * albedo * shading + noise``, clipped to the valid range
1..254 (0 is Null, 255 His/Hrs in ISIS); quantisation adds 1/sqrt(12) = 0.29 DN RMS, far below the
default 2 DN noise. ``SignedWord`` or ``Real`` cubes are written the same way.
"""

from __future__ import annotations

import glob
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numba
import numpy as np
import xarray as xr
from numpy.typing import NDArray

from ..camera.frame import FrameCamera, image_to_focal
from ..camera.intersect import DtmSampler
from ..camera.linescan import LineScanCamera
from ..errors import ConvergenceError, InvalidInputError, SimulationWarning, warn
from ..io.cube import CubeWriter
from ..io.special import PIXEL_TYPES, special_values
from .albedo import TiledAlbedo
from .raycast import add_noise_and_quantise, cast_rows
from .render import _sun_direction

__all__ = ["RenderScene", "render_window", "render_cube", "RenderedCube", "remove_stale_partials"]

Array = NDArray[np.float64]

#: Height convergence of the compiled DTM intersection, m (intersect_dtm's default: 1 mm).
RAY_TOL_M = 1e-5
_MAX_ITER = 100


@dataclass(frozen=True)
class RenderScene:
    """A DTM and an albedo prepared for the compiled renderer.

    Parameters
    ----------
    dtm : xarray.DataArray or DtmSampler
        Heights above the camera's reference sphere, m, on ``lat`` x ``lon`` (degrees).
    albedo : xarray.DataArray or TiledAlbedo
        A ``lat`` x ``lon`` raster (sampled as the DTM) or a tiled albedo.
    """

    dtm: DtmSampler
    albedo: Any

    @classmethod
    def of(cls, dtm: xr.DataArray | DtmSampler, albedo: xr.DataArray | TiledAlbedo) -> "RenderScene":
        """The scene of a DTM and an albedo (a ``lat`` x ``lon`` raster or a :class:`TiledAlbedo`)."""
        sampler = dtm if isinstance(dtm, DtmSampler) else DtmSampler(dtm)
        source: DtmSampler | TiledAlbedo
        if isinstance(albedo, xr.DataArray):
            if set(albedo.dims) != {"lat", "lon"}:
                raise InvalidInputError("the compiled renderer takes a lat/lon albedo raster or a TiledAlbedo; "
                                        f"got dims {albedo.dims} (use render_image for projected rasters)")
            source = DtmSampler(albedo)
        elif isinstance(albedo, TiledAlbedo):
            source = albedo
        else:
            raise InvalidInputError(f"albedo must be an xarray.DataArray (lat, lon) or a TiledAlbedo, "
                                    f"got {type(albedo).__name__}")
        return cls(sampler, source)

    def _albedo_args(self) -> tuple[Any, ...]:
        empty1 = np.zeros(1)
        empty2 = np.zeros((1, 1), dtype=np.float32)
        if isinstance(self.albedo, TiledAlbedo):
            t1, t2, row = self.albedo.kernel_arrays()
            return 1, empty1, empty1, np.zeros((1, 1)), False, t1, t2, row
        a = self.albedo
        return 0, a.lat, a.lon, a.z, a._lon360, empty2, empty2, np.zeros(15)


def _sensor_look(camera: Any, line: Array, sample: Array) -> Array:
    """Undistorted sensor-frame look vectors ``(x, y, f)`` of image coordinates (the camera's ``_sensor_look``)."""
    x, y = image_to_focal(camera.interior, line, sample)
    ux, uy = camera.distortion.undistort(x, y)
    return np.stack([ux, uy, np.full_like(ux, camera.interior.focal_length)], axis=-1)


def _rays(camera: Any, l0: int, l1: int, s0: int, s1: int, k: int) -> tuple[Array, Array, Array]:
    """Positions ``(m, 3)``, rotations ``(m, 3, 3)`` and look vectors of the ``k x k`` rays of a window."""
    sub = (np.arange(k) + 0.5) / k
    lines = (np.arange(l0, l1)[:, None] + sub[None, :]).ravel()
    samples = (np.arange(s0, s1)[:, None] + sub[None, :]).ravel()
    if isinstance(camera, LineScanCamera):
        t = camera.image_time(lines)
        pos = camera.eo.position_at(t)
        rot = camera.eo.rotation_at(t)
        look = _sensor_look(camera, np.zeros_like(samples), samples)[None]
    elif isinstance(camera, FrameCamera):
        pos = camera.eo.position_at(camera.time).reshape(1, 3)
        rot = camera.eo.rotation_at(camera.time).reshape(1, 3, 3)
        L, S = np.meshgrid(lines, samples, indexing="ij")
        look = _sensor_look(camera, L, S)
    else:
        raise InvalidInputError(f"the compiled renderer takes a FrameCamera or a LineScanCamera, "
                                f"got {type(camera).__name__}")
    return (np.ascontiguousarray(pos, dtype=np.float64), np.ascontiguousarray(rot, dtype=np.float64),
            np.ascontiguousarray(look, dtype=np.float64))


def _check_window(camera: Any, window: tuple[int, int, int, int] | None) -> tuple[int, int, int, int]:
    nl, ns = int(camera.interior.n_lines), int(camera.interior.n_samples)
    l0, l1, s0, s1 = window if window is not None else (0, nl, 0, ns)
    if not (0 <= l0 < l1 <= nl and 0 <= s0 < s1 <= ns):
        raise InvalidInputError(f"window {window} is empty or outside the {nl} x {ns} image")
    return int(l0), int(l1), int(s0), int(s1)


def render_window(camera: Any, scene: RenderScene, window: tuple[int, int, int, int] | None = None, *,
                  supersample: int = 1, sun: Any = "eo", ground: bool = False,
                  threads: int | None = None) -> tuple[Array, Array | None]:
    """Mean albedo x shading of the pixels of a window (before gain, noise and quantisation).

    Parameters
    ----------
    camera : FrameCamera or LineScanCamera
    scene : RenderScene
    window : (l0, l1, s0, s1), optional
        Pixels ``[l0, l1) x [s0, s1)`` (array indices); the whole image by default.
    supersample : int
        Rays per pixel along each axis (box filter), at ``i + (a + 0.5) / k``.
    sun : None, "eo" or array_like (3,)
        As for :func:`~lunarmap.simulate.render_image`.
    ground : bool
        Also return every ray's ground point.
    threads : int, optional
        Numba threads (default: numba's current setting).

    Returns
    -------
    values : ndarray, shape (l1 - l0, s1 - s0)
        NaN where a ray misses the DTM or the albedo.
    xyz : ndarray, shape (k (l1 - l0), k (s1 - s0), 3) or None
        Body-fixed ground points (m) of the rays, row ``k i + a`` for line ``l0 + i + (a + 0.5) / k``.

    Raises
    ------
    ConvergenceError
        A ray's DTM intersection did not converge.
    """
    l0, l1, s0, s1 = _check_window(camera, window)
    k = int(supersample)
    if isinstance(supersample, bool) or k < 1:
        raise InvalidInputError(f"supersample must be an integer >= 1, got {supersample!r}")
    pos, rot, look = _rays(camera, l0, l1, s0, s1, k)
    s = _sun_direction(camera, sun)
    out = np.empty((l1 - l0, s1 - s0))
    xyz = np.empty((k * (l1 - l0), k * (s1 - s0), 3)) if ground else np.empty((1, 1, 3))
    d = scene.dtm
    before = numba.get_num_threads()
    if threads is not None:
        numba.set_num_threads(max(1, min(int(threads), numba.config.NUMBA_NUM_THREADS)))
    try:
        cast_rows(pos, rot, look, k, float(camera.shape.reference_radius), RAY_TOL_M, _MAX_ITER, d.lat, d.lon, d.z,
                  d._lon360, d.min_height - 1.0, d.max_height + 1.0, *scene._albedo_args(),
                  np.zeros(3) if s is None else np.ascontiguousarray(s, dtype=np.float64), s is not None,
                  out, xyz, bool(ground))
    finally:
        numba.set_num_threads(before)
    if np.isinf(out).any():
        raise ConvergenceError(f"DTM intersection did not converge in {_MAX_ITER} iterations for "
                               f"{int(np.isinf(out).sum())} pixel(s) of window {(l0, l1, s0, s1)}")
    return out, (xyz if ground else None)


@dataclass
class RenderedCube:
    """What :func:`render_cube` wrote.

    Attributes
    ----------
    path : pathlib.Path
    lines, samples : int
    seconds : float
        Wall time of the rendering and writing, s.
    n_null, n_clipped : int
        Pixels without DTM or albedo (Null), and pixels clipped at the pixel type's range.
    nbytes : int
        File size, bytes.
    """

    path: Path
    lines: int
    samples: int
    seconds: float
    n_null: int
    n_clipped: int
    nbytes: int


def _dn_range(pixel_type: str) -> tuple[float, float, float]:
    """Lowest and highest valid stored value and the Null value of an integer pixel type."""
    code = PIXEL_TYPES[pixel_type]
    if code == "f4":
        return -np.inf, np.inf, np.nan
    info = {"u1": (1, 254), "i2": (-32752, 32767), "u2": (3, 65522)}.get(code)
    if info is None:
        raise InvalidInputError(f"render_cube writes UnsignedByte, SignedWord, UnsignedWord or Real, not {pixel_type}")
    return float(info[0]), float(info[1]), float(special_values(code)["Null"])


def remove_stale_partials(path: str | os.PathLike[str]) -> int:
    """Remove the hidden temporary files a killed :class:`CubeWriter` of ``path`` left; returns how many."""
    p = Path(path)
    n = 0
    for f in glob.glob(os.path.join(glob.escape(str(p.parent)), f".{glob.escape(p.name)}.*.tmp")):
        try:
            os.unlink(f)
            n += 1
        except OSError:
            pass
    return n


def render_cube(camera: Any, scene: RenderScene, path: str | os.PathLike[str], *, supersample: int = 1,
                sun: Any = "eo", gain: float = 160.0, offset: float = 0.0, noise_sigma: float = 2.0, seed: int = 0,
                pixel_type: str = "UnsignedByte", stripe_lines: int = 512, tile: tuple[int, int] = (128, 128),
                threads: int = 2, groups: list[Any] | None = None) -> RenderedCube:
    """Render a camera's whole image into an ISIS cube (Tile format), stripe by stripe.

    Parameters
    ----------
    camera : FrameCamera or LineScanCamera
    scene : RenderScene
    path : path-like
        The cube; its folder must exist.
    supersample : int
        Rays per pixel along each axis.
    sun : None, "eo" or array_like (3,)
        Lambert shading (see :func:`~lunarmap.simulate.render_image`).
    gain, offset : float
        DN = ``offset + gain * albedo * shading`` before noise and quantisation.
    noise_sigma : float
        Gaussian noise, DN, drawn per pixel from ``(seed, line, sample)``.
    seed : int
        Noise seed (non-negative).
    pixel_type : str
        ``"UnsignedByte"`` (default), ``"SignedWord"``, ``"UnsignedWord"`` or ``"Real"``; integer DN are
        clipped to the type's valid range (counted in ``n_clipped``).
    stripe_lines : int
        Lines rendered and written at a time (a multiple of the tile lines).
    tile : (int, int)
        Cube tile size.
    threads : int
        Numba threads.
    groups : list, optional
        Further PVL groups of the cube label (e.g. ``Instrument``).

    Returns
    -------
    RenderedCube

    Raises
    ------
    CubeWriteError
        The folder is missing or read-only, or the disk is full (nothing is left under ``path``).
    ConvergenceError
        A ray's DTM intersection did not converge (nothing is left under ``path``).
    """
    if not (np.isfinite(noise_sigma) and noise_sigma >= 0):
        raise InvalidInputError(f"noise_sigma must be >= 0 DN, got {noise_sigma}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise InvalidInputError(f"seed must be a non-negative integer, got {seed!r}")
    if pixel_type not in PIXEL_TYPES:
        raise InvalidInputError(f"unknown pixel type {pixel_type!r}; known: {sorted(PIXEL_TYPES)}")
    lo, hi, null = _dn_range(pixel_type)
    nl, ns = int(camera.interior.n_lines), int(camera.interior.n_samples)
    tl = min(int(tile[0]), nl)
    stripe = max(tl, (int(stripe_lines) // tl) * tl)
    out_dtype = np.dtype(PIXEL_TYPES[pixel_type]).newbyteorder("<")
    t0 = time.perf_counter()
    n_null = n_clipped = 0
    with CubeWriter(path, nl, ns, pixel_type=pixel_type, tile=(tl, int(tile[1])), groups=groups) as cube:
        dn = np.empty((stripe, ns), dtype=np.float64)
        for a in range(0, nl, stripe):
            b = min(a + stripe, nl)
            values, _ = render_window(camera, scene, (a, b, 0, ns), supersample=supersample, sun=sun,
                                      threads=threads)
            d = dn[: b - a]
            add_noise_and_quantise(values, a, 0, int(seed), float(gain), float(offset), float(noise_sigma), lo, hi,
                                   null, d, out_dtype.kind != "f")
            bad = ~np.isfinite(values)
            n_null += int(bad.sum())
            n_clipped += int(np.count_nonzero(((d == lo) | (d == hi)) & ~bad))
            if out_dtype.kind == "f":
                cube.write(np.where(bad, np.nan, d), a)
            else:
                cube.write(d.astype(out_dtype), a)   # already stored values (Null where bad)
    if n_null:
        warn(f"{n_null} of {nl * ns} pixels of {path} see no DTM or albedo (outside their extent) and are Null",
             SimulationWarning)
    seconds = time.perf_counter() - t0
    return RenderedCube(Path(path), nl, ns, seconds, n_null, n_clipped, os.path.getsize(path))
