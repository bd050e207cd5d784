"""Render the synthetic imaging block and simulate check-point measurements.

For a block written by :func:`lunarmap.synthetic.write_block_mission`:

* :func:`block_scene` - a site's DTM and albedo (craters over rolling
  terrain, band-limited albedo), reproducible from the block's seed (one
  scene per site of a block of several sites);
* :func:`block_cameras` - the rigorous camera of every image from the TRUTH
  or the NAVIGATION kernels (labels + IKs through the generic driver);
* :func:`render_block` - every image rendered through its TRUTH camera with
  :func:`~lunarmap.simulate.render_image` (DTM intersection, supersampling,
  Lambert shading from the kernels' Sun direction, Gaussian noise) and
  written as netCDF, with the DTM;
* :func:`block_check_points` - ground points on the true DTM of a site inside
  every image of that site, with their true coordinates and noisy image
  measurements.

* :func:`render_block_cubes` - every image rendered by the compiled renderer
  (:func:`~lunarmap.simulate.compiled_render.render_cube`) into an ISIS cube, stripe by
  stripe: the way to the full-size layout's 52,224 x 5,064-pixel images.

Scene scales (chosen for the block's 1 m pixels): DTM spacing 2 m (the
renderer's normals are central differences over one spacing), rolling terrain
of 3 m RMS down to 40 m wavelength, craters 16 m to 200 m across
(bowls 20 % deep); albedo spacing 0.5 m with features down to 3 m, low-pass
filtered by a Gaussian of sigma 0.5 m (29 % of the amplitude left at 2 m, the
Nyquist wavelength of 1 m pixels). Without that filter the texture aliases
differently in images of different scale and orientation: windows at true
conjugates of a 40-degree pair correlated at 0.79 (1 ray per pixel) or 0.91
(2 x 2 rays); with it, at 0.96 either way.

The full-size layout's site (``write_block_mission(layout="full_size")``, ~6 km x 58 km under
~0.5 m pixels) cannot hold such rasters (a 0.5 m albedo would have 1.4 G nodes): its DTM has
4 m spacing (1,526 x 14,501 nodes, 177 MB as netCDF; rolling terrain of 3 m RMS down to 80 m
wavelength, craters 32 m to 400 m) and its albedo is a
:class:`~lunarmap.simulate.albedo.TiledAlbedo` at half the scales above (features down to 1.5 m,
low-pass sigma 0.25 m, for 0.5 m pixels), evaluated wherever a ray lands.
"""

from __future__ import annotations

import logging
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import dask
import numpy as np
import xarray as xr
from numpy.typing import NDArray
from scipy.ndimage import gaussian_filter

from ..atomic import atomic_write
from ..camera.factory import camera_from_isd
from ..camera.intersect import DtmSampler
from ..camera.shape import MOON_RADIUS
from ..errors import BlockMissionError, InvalidInputError
from ..orientation.drivers import image_support
from ..synthetic.block_writing import BlockMission, open_block_mission
from ..synthetic.labels import isis_label_groups
from .albedo import TiledAlbedo, tiled_albedo
from .compiled_render import RenderedCube, RenderScene, remove_stale_partials, render_cube
from .render import render_image
from .terrain import synthetic_albedo, synthetic_dtm

_log = logging.getLogger(__name__)

__all__ = ["block_scene", "block_cameras", "render_block", "RenderedBlock", "block_check_points", "block_dtm_file",
           "render_block_cubes", "image_seed", "DTM_SPACING_M", "ALBEDO_SPACING_M", "ALBEDO_FEATURE_M", "ALBEDO_BLUR_M",
           "DTM_FILE", "FULL_SIZE_DTM_SPACING_M"]

#: DTM node spacing, m.
DTM_SPACING_M = 2.0
#: Albedo node spacing and shortest feature, m.
ALBEDO_SPACING_M = 0.5
ALBEDO_FEATURE_M = 3.0
#: Sigma of the Gaussian anti-aliasing filter of the albedo, m.
ALBEDO_BLUR_M = 0.5
#: File name of the DTM written by :func:`render_block` (one site; see :func:`block_dtm_file`).
DTM_FILE = "dtm.nc"
#: DTM node spacing of the full-size layout's site, m.
FULL_SIZE_DTM_SPACING_M = 4.0

Array = NDArray[np.float64]


def _mission(mission: BlockMission | str | os.PathLike[str]) -> BlockMission:
    return open_block_mission(mission)


def _names(mission: BlockMission, names: Sequence[str] | None) -> list[str]:
    if names is None:
        return list(mission.image_names)
    if isinstance(names, str):
        names = [names]
    unknown = [n for n in names if n not in mission.image_names]
    if unknown or not names:
        raise InvalidInputError(f"unknown image(s) {unknown or 'none given'}; "
                                f"the block has {list(mission.image_names)}")
    return list(dict.fromkeys(names))


def _site(bm: BlockMission, site: Any) -> int:
    if isinstance(site, bool) or not isinstance(site, (int, np.integer)) or not 1 <= site <= bm.model.n_sites:
        raise InvalidInputError(f"site must be an integer from 1 to {bm.model.n_sites} (the block's sites), "
                                f"got {site!r}")
    return int(site)


def _site_seeds(seed: int, site: int) -> tuple[int, int]:
    """Seeds of a site's DTM and albedo: site 1 keeps the one-site block's ``(seed, seed + 1)``."""
    if site == 1:
        return seed, seed + 1
    a, b = np.random.SeedSequence([seed, site]).generate_state(2)
    return int(a), int(b)


def block_dtm_file(mission: BlockMission | str | os.PathLike[str], site: int = 1) -> str:
    """File name of a site's DTM written by :func:`render_block`: ``dtm.nc``, or ``dtm_s<site>.nc`` with several."""
    bm = _mission(mission)
    site = _site(bm, site)
    return DTM_FILE if bm.model.n_sites == 1 else f"dtm_s{site}.nc"


def _netcdf_writer(a: xr.DataArray) -> Callable[[Path], object]:
    """``write(tmp)`` for :func:`~lunarmap.atomic.atomic_write`: ``a`` as netCDF-4."""
    return lambda tmp: a.to_netcdf(tmp, engine="netcdf4")


def block_scene(mission: BlockMission | str | os.PathLike[str],
                site: int = 1) -> tuple[xr.DataArray, xr.DataArray | TiledAlbedo]:
    """A site's DTM (heights above the 1737.4 km sphere, m) on ``lat`` x ``lon`` (degrees) and its albedo.

    Both cover the square of side ``extent_m`` about the site (every
    footprint of its images with a 300 m border; ``manifest['site']`` for
    site 1, ``manifest['sites']`` for all) and depend only on the block (its
    seed) and the site. Different sites have different, independent scenes.
    The albedo is a raster on the DTM's square, or, for the full-size layout (whose DTM covers the
    site's rectangle ``extent_east_m`` x ``extent_north_m`` at 4 m), a :class:`TiledAlbedo`.

    Parameters
    ----------
    mission : BlockMission or path-like
    site : int
        1-based site.
    """
    bm = _mission(mission)
    s = bm.model.site(_site(bm, site))
    lon0, lat0, extent = s.longitude_deg, s.latitude_deg, s.extent_m
    seed_dtm, seed_albedo = _site_seeds(bm.model.seed, s.site)
    if bm.model.layout == "full_size":
        sp = FULL_SIZE_DTM_SPACING_M
        dtm = synthetic_dtm(lon0, lat0, s.extents, sp, relief=3.0, wavelength=20.0 * sp, crater_density=0.01,
                            d_min=8.0 * sp, d_max=400.0, seed=seed_dtm, radius=MOON_RADIUS)
        dtm.attrs["block_site"] = f"{lat0:.6f} N {lon0:.6f} E"
        return dtm, tiled_albedo(lon0, lat0, seed_albedo, radius=MOON_RADIUS)
    dtm = synthetic_dtm(lon0, lat0, extent, DTM_SPACING_M, relief=3.0, wavelength=20.0 * DTM_SPACING_M,
                        crater_density=0.01, d_min=8.0 * DTM_SPACING_M, d_max=200.0, seed=seed_dtm,
                        radius=MOON_RADIUS)
    albedo = synthetic_albedo(lon0, lat0, extent, ALBEDO_SPACING_M, feature_size=ALBEDO_FEATURE_M,
                              seed=seed_albedo, radius=MOON_RADIUS)
    albedo = albedo.copy(data=gaussian_filter(albedo.values, ALBEDO_BLUR_M / ALBEDO_SPACING_M, mode="nearest"))
    albedo.attrs["low_pass_sigma_m"] = ALBEDO_BLUR_M
    dtm.attrs["block_site"] = f"{lat0:.6f} N {lon0:.6f} E"
    if bm.model.n_sites > 1:
        dtm.attrs["site"] = albedo.attrs["site"] = s.site
    return dtm, albedo


def block_cameras(mission: BlockMission | str | os.PathLike[str], kernels: str = "truth",
                  names: Sequence[str] | None = None, distortion: bool = True) -> dict[str, Any]:
    """Rigorous cameras of the block's images from the TRUTH or NAVIGATION kernels.

    Parameters
    ----------
    mission : BlockMission or path-like
        The block (or its folder).
    kernels : {"truth", "navigation"}
    names : sequence of str, optional
        Images (default: all, in manifest order).
    distortion : bool
        ``False`` drops the lens distortion (to see what it does).

    Returns
    -------
    dict
        Image name -> :class:`~lunarmap.camera.FrameCamera` or :class:`~lunarmap.camera.LineScanCamera`.
    """
    bm = _mission(mission)
    mk = bm.metakernel(kernels)
    return {n: camera_from_isd(image_support(bm.label(n), mk), distortion=distortion) for n in _names(bm, names)}


@dataclass
class RenderedBlock:
    """The outcome of :func:`render_block`.

    Attributes
    ----------
    images : dict
        Image name -> float32 ``xarray.DataArray`` (``line``, ``sample``; CSM pixel centres), grey levels.
    dtm, albedo : xarray.DataArray
        The scene (of the first rendered image's site).
    paths : dict
        Image name -> written netCDF file, and the DTMs: ``"dtm"`` (one site) or ``"dtm_s<k>"`` per rendered
        site (several sites); empty when nothing was written.
    seconds : float
        Wall-clock time of the rendering alone, s.
    scenes : dict
        Site -> ``(dtm, albedo)`` of every rendered site.
    """

    images: dict[str, xr.DataArray]
    dtm: xr.DataArray
    albedo: xr.DataArray | TiledAlbedo
    paths: dict[str, Path] = field(default_factory=dict)
    seconds: float = 0.0
    scenes: dict[int, tuple[xr.DataArray, xr.DataArray | TiledAlbedo]] = field(default_factory=dict)


def _crop_window(cam: Any, crop: int | None) -> tuple[int, int, int, int] | None:
    if crop is None:
        return None
    nl, ns = int(cam.interior.n_lines), int(cam.interior.n_samples)
    hl, hs = min(crop, nl) // 2, min(crop, ns) // 2
    return nl // 2 - hl, nl // 2 + hl, ns // 2 - hs, ns // 2 + hs


def render_block(mission: BlockMission | str | os.PathLike[str], output: str | os.PathLike[str] | None = None, *,
                 names: Sequence[str] | None = None, supersample: int = 2, noise_sigma: float = 2.0,
                 crop: int | None = None, write: bool = True, scheduler: Any = "threads",
                 chunks: int = 128) -> RenderedBlock:
    """Render the block's images through their TRUTH cameras and write them as netCDF.

    Each image is :func:`~lunarmap.simulate.render_image` of its site's scene
    (:func:`block_scene`) with Lambert shading from the Sun direction in the
    kernels (``sun="eo"``), grey level ``255 * albedo * shading`` plus
    Gaussian noise of ``noise_sigma`` grey levels (seeded per image).

    Parameters
    ----------
    mission : BlockMission or path-like
    output : path-like, optional
        Folder for ``<image>.nc`` and the DTM of every rendered site (``dtm.nc``,
        or ``dtm_s<k>.nc`` with several sites: :func:`block_dtm_file`); the
        block's folder by default (it must exist).
    names : sequence of str, optional
        Images to render (default: all).
    supersample : int
        Rays per pixel along each axis. With 2, the whole block (12 images,
        2.5 M pixels) rendered in 13 s on the 2-core machine when lightly
        loaded and in up to 55 s while other jobs kept both cores busy.
    noise_sigma : float
        Grey levels.
    crop : int, optional
        Render only the central ``crop x crop`` pixels of each image (for
        quick looks and tests); coordinates stay those of the full image.
    write : bool
        Write the netCDF files (atomically).
    scheduler : str or distributed.Client
        Dask scheduler for the render tasks (``"threads"``, ``"sync"``...).
    chunks : int
        Render block size, pixels.

    Returns
    -------
    RenderedBlock
    """
    bm = _mission(mission)
    sel = _names(bm, names)
    if isinstance(supersample, bool) or not isinstance(supersample, (int, np.integer)) or not 1 <= supersample <= 8:
        raise InvalidInputError(f"supersample must be an integer from 1 to 8, got {supersample!r}")
    if crop is not None and (isinstance(crop, bool) or not isinstance(crop, (int, np.integer)) or crop < 16):
        raise InvalidInputError(f"crop must be an integer >= 16 pixels or None, got {crop!r}")
    out_dir = Path(output).expanduser() if output is not None else bm.folder
    if write and not out_dir.is_dir():
        raise BlockMissionError(f"output folder {out_dir} does not exist")
    site_of = {n: bm.model.image(n).site for n in sel}
    t_scene = time.perf_counter()
    scenes = {k: block_scene(bm, k) for k in dict.fromkeys(site_of.values())}
    _log.info("rendering: scene (DTM and albedo) of %d site(s) built in %.1f s", len(scenes), time.perf_counter() - t_scene)
    samplers = {k: DtmSampler(dtm) for k, (dtm, _) in scenes.items()}
    cams = block_cameras(bm, "truth", sel)
    lazy = {}
    for n in sel:
        seed = image_seed(bm, n)
        sampler, albedo = samplers[site_of[n]], scenes[site_of[n]][1]
        lazy[n] = render_image(cams[n], sampler, albedo, supersample=int(supersample), sun="eo", gain=255.0,
                               noise_sigma=float(noise_sigma), seed=seed, chunks=chunks,
                               window=_crop_window(cams[n], crop), name=n)
    t0 = time.perf_counter()
    if isinstance(scheduler, str):
        with _RenderProgress(len(sel)):
            computed = dask.compute(*lazy.values(), scheduler=scheduler)
    else:
        computed = dask.compute(*lazy.values(), scheduler=scheduler)
    seconds = time.perf_counter() - t0
    images = {}
    for n, img in zip(sel, computed):
        im = bm.manifest["images"][n]
        img.attrs.update({"image": n, "orbit": im["orbit"], "camera_name": im["camera"], "label": im["label"],
                          "kernels": "truth.tm", "block_seed": bm.model.seed})
        if bm.model.n_sites > 1:
            img.attrs["site"] = site_of[n]
        images[n] = img
    paths: dict[str, Path] = {}
    if write:
        for n, img in images.items():
            paths[n] = atomic_write(out_dir / f"{n}.nc", _netcdf_writer(img))
        for k, (dtm, _) in scenes.items():
            f = block_dtm_file(bm, k)
            paths[f[:-3]] = atomic_write(out_dir / f, _netcdf_writer(dtm))
    first = scenes[site_of[sel[0]]]
    return RenderedBlock(images, first[0], first[1], paths, seconds, scenes)


class _RenderProgress:
    """Logs the render's progress (blocks done / total) at most every ``every`` seconds (local schedulers)."""

    def __init__(self, n_images: int, every: float = 3.0) -> None:
        from dask.callbacks import Callback

        self.n_images, self.every = n_images, every
        self.done = self.total = 0
        self.last = self.start = time.perf_counter()
        self.cb = Callback(start_state=self._start, posttask=self._post)

    def _start(self, dsk: Any, state: Any) -> None:
        self.total = len(state.get("ready", [])) + len(state.get("waiting", {}))

    def _post(self, key: Any, result: Any, dsk: Any, state: Any, worker_id: Any) -> None:
        self.done += 1
        now = time.perf_counter()
        if now - self.last >= self.every:
            self.last = now
            _log.info("rendering %d image(s): %d of %d tasks done, %.0f s", self.n_images, self.done,
                      max(self.total, self.done), now - self.start)

    def __enter__(self) -> "_RenderProgress":
        self.cb.__enter__()
        return self

    def __exit__(self, *exc: Any) -> None:
        self.cb.__exit__(*exc)


def image_seed(mission: BlockMission | str | os.PathLike[str], name: str) -> int:
    """Noise seed of an image: depends on the block and the image, not on which others are rendered."""
    bm = _mission(mission)
    return bm.model.seed * 1000 + bm.image_names.index(name)


def _label_groups(bm: BlockMission, name: str) -> list[Any]:
    im = bm.manifest["images"][name]
    timing = {"line_time_ms": im["line_time_ms"]} if "line_time_ms" in im else {"exposure_ms": im["exposure_ms"]}
    return isis_label_groups(spacecraft_name=bm.manifest["spacecraft"]["name"], instrument_id=im["camera"],
                             start_time=im["start_time_utc"], stop_time=im["stop_time_utc"],
                             sclk_start=im["sclk_start"], naif_frame_code=im["instrument_id"], **timing)


def render_block_cubes(mission: BlockMission | str | os.PathLike[str], output: str | os.PathLike[str] | None = None,
                       *, names: Sequence[str] | None = None, supersample: int = 1, noise_sigma: float = 2.0,
                       gain: float = 160.0, threads: int = 2, stripe_lines: int = 512,
                       scene: tuple[xr.DataArray, Any] | None = None, write_dtm: bool = True,
                       log: Any = None) -> dict[str, RenderedCube]:
    """Render the block's images through their TRUTH cameras into ISIS cubes with the compiled renderer.

    Each image is :func:`~lunarmap.simulate.compiled_render.render_cube` of its site's scene
    (:func:`block_scene`; one site) with Lambert shading from the kernels' Sun direction, DN
    ``gain * albedo * shading`` plus Gaussian noise (seeded per image, :func:`image_seed`), as
    UnsignedByte cubes ``<image>.cub`` whose labels carry the image's ``Instrument`` and ``Kernels``
    groups. Memory is one stripe plus the scene, whatever the image size.

    Parameters
    ----------
    mission : BlockMission or path-like
    output : path-like, optional
        Folder for the cubes and ``dtm.nc`` (the block's folder by default; it must exist).
    names : sequence of str, optional
        Images to render (default: all).
    supersample : int
        Rays per pixel along each axis (1: the band-limited scene does not need more; see the module
        docstring of :mod:`lunarmap.simulate.albedo`).
    noise_sigma, gain : float
        DN.
    threads : int
        Numba threads per image.
    stripe_lines : int
        Lines per stripe.
    scene : (dtm, albedo), optional
        The site's scene (default :func:`block_scene`'s, built once here).
    write_dtm : bool
        Also write the DTM (``dtm.nc``, atomically).
    log : callable, optional
        Called with a message after each image (progress).

    Returns
    -------
    dict
        Image name -> :class:`~lunarmap.simulate.compiled_render.RenderedCube`, and ``"dtm"`` -> its path
        when written.
    """
    bm = _mission(mission)
    sel = _names(bm, names)
    if bm.model.n_sites != 1:
        raise InvalidInputError("render_block_cubes renders blocks of one site; use render_block for several")
    out_dir = Path(output).expanduser() if output is not None else bm.folder
    if not out_dir.is_dir():
        raise BlockMissionError(f"output folder {out_dir} does not exist")
    dtm, albedo = scene if scene is not None else block_scene(bm)
    rscene = RenderScene.of(dtm, albedo)
    cams = block_cameras(bm, "truth", sel)
    done: dict[str, Any] = {}
    for n in sel:
        path = out_dir / f"{n}.cub"
        remove_stale_partials(path)   # what a killed earlier render of this cube left
        done[n] = render_cube(cams[n], rscene, path, supersample=supersample, sun="eo", gain=gain,
                              noise_sigma=noise_sigma, seed=image_seed(bm, n), stripe_lines=stripe_lines,
                              threads=threads, groups=_label_groups(bm, n))
        if log is not None:
            log(f"rendered {n}: {done[n].lines} x {done[n].samples} pixels in {done[n].seconds:.1f} s")
    if write_dtm:
        done["dtm"] = atomic_write(out_dir / block_dtm_file(bm), lambda tmp: dtm.to_netcdf(tmp, engine="netcdf4"))
    return done


def block_check_points(mission: BlockMission | str | os.PathLike[str], n: int = 20, *, sigma_px: float = 0.3,
                       seed: int = 0, names: Sequence[str] | None = None, dtm: xr.DataArray | None = None,
                       margin_px: float = 20.0, cameras: dict[str, Any] | None = None,
                       site: int | None = None) -> xr.Dataset:
    """Check points: ground points on a site's true DTM seen by every image, with simulated measurements.

    Points are drawn uniformly over the site and kept when every image sees
    them at least ``margin_px`` inside its borders and not hidden by the
    terrain (the truth camera's ray through the projected pixel meets the DTM
    at the point itself, within 5 cm). Each image's measurement is the truth
    camera's ``ground_to_image`` plus Gaussian noise of ``sigma_px``.

    Parameters
    ----------
    mission : BlockMission or path-like
    n : int
        Number of points.
    sigma_px : float
        Standard deviation of the measurement noise, pixels.
    seed : int
        Seed of the point positions and the noise.
    names : sequence of str, optional
        The images that must all see each point, all of one site (default:
        every image of ``site``).
    dtm : xarray.DataArray, optional
        The site's true DTM (default: :func:`block_scene`'s).
    margin_px : float
        Minimum distance from the image borders, pixels.
    cameras : dict, optional
        Truth cameras by image name (default: :func:`block_cameras` ``"truth"``).
    site : int, optional
        1-based site (default: the site of ``names``, or site 1 of a one-site
        block; a block of several sites needs ``site`` or ``names``).

    Returns
    -------
    xarray.Dataset
        ``xyz`` (point, axis): true body-fixed coordinates, m; ``latitude``,
        ``longitude`` (degrees), ``height`` (m above the sphere) per point;
        one row per observation: ``point_id``, ``image_id`` (index into the
        ``image`` coordinate), ``line``, ``sample`` (measured, CSM pixels),
        ``line_true``, ``sample_true``, ``sigma_line``, ``sigma_sample``.

    Raises
    ------
    InvalidInputError
        Bad arguments (images of several sites, or of another site than ``site``), or the images have
        too small a common overlap for ``n`` points.
    """
    bm = _mission(mission)
    site = _check_site(bm, names, site)
    sel = _names(bm, names) if names is not None else list(bm.model.site_image_names(site))
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or not 1 <= n <= 100000:
        raise InvalidInputError(f"n must be an integer from 1 to 100000, got {n!r}")
    if not (isinstance(sigma_px, (int, float, np.floating)) and np.isfinite(sigma_px) and sigma_px >= 0):
        raise InvalidInputError(f"sigma_px must be a finite number >= 0 pixels, got {sigma_px!r}")
    if not (np.isfinite(margin_px) and margin_px >= 0):
        raise InvalidInputError(f"margin_px must be >= 0, got {margin_px!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise InvalidInputError(f"seed must be a non-negative integer, got {seed!r}")
    cams = cameras if cameras is not None else block_cameras(bm, "truth", sel)
    missing = [s for s in sel if s not in cams]
    if missing:
        raise InvalidInputError(f"no camera given for image(s) {missing}")
    dtm = dtm if dtm is not None else block_scene(bm, site)[0]
    sampler = DtmSampler(dtm)
    st = bm.model.site(site)
    rng = np.random.default_rng(int(seed))
    ext_e, ext_n = st.extents
    half = 0.5 * np.array([[ext_e], [ext_n]]) if ext_e != ext_n else 0.5 * st.extent_m
    lat0, lon0 = np.radians(st.latitude_deg), st.longitude_deg
    kept: list[Array] = []
    n_kept = 0
    t_log = time.perf_counter()
    for _ in range(200):
        if time.perf_counter() - t_log > 3.0:
            t_log = time.perf_counter()
            _log.info("points: %d of %d found visible in every image", n_kept, n)
        east, north = rng.uniform(-half, half, (2, max(64, 4 * n)))
        lat = st.latitude_deg + np.degrees(north / MOON_RADIUS)
        lon = lon0 + np.degrees(east / (MOON_RADIUS * np.cos(lat0)))
        h = sampler(lon, lat)
        ok = np.isfinite(h)
        r = MOON_RADIUS + np.where(ok, h, 0.0)
        la, lo = np.radians(lat), np.radians(lon)
        xyz = r[:, None] * np.stack([np.cos(la) * np.cos(lo), np.cos(la) * np.sin(lo), np.sin(la)], axis=-1)
        for name in sel:
            if time.perf_counter() - t_log > 3.0:
                t_log = time.perf_counter()
                _log.info("points: %d of %d found; testing visibility in %s", n_kept, n, name)
            cam = cams[name]
            ln, sm = cam.ground_to_image(xyz)
            nl, ns = cam.interior.n_lines, cam.interior.n_samples
            ok &= (ln >= margin_px) & (ln <= nl - margin_px) & (sm >= margin_px) & (sm <= ns - margin_px)
            if not ok.any():
                break
            idx = np.flatnonzero(ok)
            back = cam.image_to_ground(ln[idx], sm[idx], dtm=sampler, on_miss="nan")
            ok[idx] &= np.linalg.norm(back - xyz[idx], axis=-1) < 0.05
        kept.append(xyz[ok])
        n_kept += int(ok.sum())
        if n_kept >= n:
            break
    else:
        raise InvalidInputError(f"the common overlap of {sel} holds fewer than {n} visible points "
                                f"({n_kept} found); use fewer points, fewer images or a smaller margin")
    xyz = np.concatenate(kept)[:n]
    obs_pt, obs_img, lt, smt = [], [], [], []
    for k, name in enumerate(sel):
        ln, sm = cams[name].ground_to_image(xyz)
        obs_pt.append(np.arange(n))
        obs_img.append(np.full(n, k))
        lt.append(ln)
        smt.append(sm)
    line_true, sample_true = np.concatenate(lt), np.concatenate(smt)
    noise = rng.normal(0.0, 1.0, (2, line_true.size)) * float(sigma_px)
    rr = np.linalg.norm(xyz, axis=-1)
    sig = np.full(line_true.size, float(sigma_px))
    return xr.Dataset(
        {
            "xyz": (("point", "axis"), xyz, {"units": "m", "long_name": "true body-fixed coordinates"}),
            "latitude": ("point", np.degrees(np.arcsin(xyz[:, 2] / rr)), {"units": "degree"}),
            "longitude": ("point", np.degrees(np.arctan2(xyz[:, 1], xyz[:, 0])), {"units": "degree"}),
            "height": ("point", rr - MOON_RADIUS, {"units": "m", "long_name": "height above the reference sphere"}),
            "point_id": ("observation", np.concatenate(obs_pt).astype(np.int64)),
            "image_id": ("observation", np.concatenate(obs_img).astype(np.int32),
                         {"long_name": "index into the image coordinate"}),
            "line": ("observation", line_true + noise[0], {"units": "pixel"}),
            "sample": ("observation", sample_true + noise[1], {"units": "pixel"}),
            "line_true": ("observation", line_true, {"units": "pixel"}),
            "sample_true": ("observation", sample_true, {"units": "pixel"}),
            "sigma_line": ("observation", sig, {"units": "pixel"}),
            "sigma_sample": ("observation", sig.copy(), {"units": "pixel"}),
        },
        coords={"image": ("image", np.asarray(sel, dtype=str)), "axis": ["x", "y", "z"]},
        attrs={"pixel_convention": "CSM: centre of the first pixel at (0.5, 0.5)", "sigma_px": float(sigma_px),
               "seed": int(seed), "kernels": "truth", "source": "lunarmap.simulate.block_check_points",
               **({"site": site} if bm.model.n_sites > 1 else {})},
    )


def _check_site(bm: BlockMission, names: Sequence[str] | None, site: int | None) -> int:
    """The one site that ``names`` and ``site`` designate (named errors for mixtures and omissions)."""
    if site is not None:
        site = _site(bm, site)
    if names is None:
        if site is None:
            if bm.model.n_sites > 1:
                raise InvalidInputError(f"the block has {bm.model.n_sites} sites, whose images do not overlap: "
                                        f"give site= (1 to {bm.model.n_sites}) or names= of one site")
            return 1
        return site
    sites = {bm.model.image(nm).site for nm in _names(bm, names)}
    if len(sites) > 1 or (site is not None and sites != {site}):
        raise InvalidInputError(f"check points need images of one site: {list(names)} are of sites {sorted(sites)}"
                                + (f", not site {site}" if site is not None else ""))
    return sites.pop()
