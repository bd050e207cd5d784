"""Frame (framing) camera model, and the pixel <-> focal-plane arithmetic of all cameras.

Image to ground
---------------
``(line, sample)`` (CSM pixel convention, centre of the first pixel at
(0.5, 0.5)) -> detector coordinates (starting detector line/sample and
summing) -> distorted focal plane (inverse of ALE's ``focal2pixel`` affine
about the detector centre) -> undistorted focal plane (the distortion model)
-> look vector ``(x, y, f)`` in the sensor frame -> rotated to body-fixed by
the exterior orientation -> intersected with the body shape (at a height) or
a DTM.

:func:`image_to_focal` and :func:`focal_to_image` repeat usgscsm's
``computeDistortedFocalPlaneCoordinates`` and ``computePixel``
(``src/Utilities.cpp``) operation for operation, with ALE's
``focal2pixel_lines`` / ``focal2pixel_samples`` in the role of usgscsm's
``iTransL`` / ``iTransS`` and ``detector_center_*`` in that of
``m_ccdCenter`` / ``m_detector*Origin``; so our pixel coordinates equal CSM's.
The look vector keeps the NAIF instrument-frame convention (boresight +z,
look ``(x, y, f)``) rather than usgscsm's ``(-x, -y, -f)`` camera frame,
because our quaternions rotate NAIF instrument-frame vectors.
"""

from __future__ import annotations

import threading
from typing import Any

import numpy as np
import xarray as xr
from numpy.typing import ArrayLike, NDArray

from ..errors import GeometryError, InvalidInputError
from ..orientation.exterior import ExteriorOrientation
from .corrections import FrameCorrections
from .distortion import Distortion, distortion_from_interior
from .interior import InteriorOrientation
from .intersect import DtmSampler, OnMiss, intersect_dtm, intersect_ellipsoid
from .shape import Shape

__all__ = ["FrameCamera", "image_to_focal", "focal_to_image"]

Array = NDArray[np.float64]

# Depth below the reference shape that no terrain reaches (the deepest lunar
# point is about 9.1 km below 1737.4 km): sight lines crossing the shape
# shrunk by this much are blocked by the body.
_OCCLUSION_DEPTH = 20_000.0


def image_to_focal(interior: InteriorOrientation, line: ArrayLike, sample: ArrayLike
                   ) -> tuple[Array, Array]:
    """Distorted focal-plane coordinates of image coordinates (usgscsm ``computeDistortedFocalPlaneCoordinates``).

    Parameters
    ----------
    interior : InteriorOrientation
        Camera constants.
    line, sample : array_like
        Image coordinates, pixels, CSM convention. Line-scan cameras pass
        ``line = 0`` (the image line is time, not a detector position).

    Returns
    -------
    (ndarray, ndarray)
        Distorted focal-plane ``x, y``, millimetres.
    """
    io = interior
    line, sample = np.broadcast_arrays(np.asarray(line, dtype=float), np.asarray(sample, dtype=float))
    det_sample = sample * io.sample_summing + io.starting_detector_sample
    det_line = line * io.line_summing + io.starting_detector_line
    il, is_ = io.focal2pixel_lines, io.focal2pixel_samples
    t1 = det_line - io.detector_center_line - il[0]
    t2 = det_sample - io.detector_center_sample - is_[0]
    det = il[1] * is_[2] - il[2] * is_[1]
    x = (is_[2] * t1 - il[2] * t2) / det
    y = (-is_[1] * t1 + il[1] * t2) / det
    return x, y


def focal_to_image(interior: InteriorOrientation, x: ArrayLike, y: ArrayLike) -> tuple[Array, Array]:
    """Image coordinates of distorted focal-plane coordinates (usgscsm ``computePixel``).

    Parameters
    ----------
    interior : InteriorOrientation
        Camera constants.
    x, y : array_like
        Distorted focal-plane coordinates, millimetres.

    Returns
    -------
    (ndarray, ndarray)
        ``line, sample``, pixels, CSM convention.
    """
    io = interior
    x, y = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
    il, is_ = io.focal2pixel_lines, io.focal2pixel_samples
    centered_sample = is_[0] + is_[1] * x + is_[2] * y
    centered_line = il[0] + il[1] * x + il[2] * y
    sample = (centered_sample + io.detector_center_sample - io.starting_detector_sample) / io.sample_summing
    line = (centered_line + io.detector_center_line - io.starting_detector_line) / io.line_summing
    return line, sample


def _finite_pixels(line: ArrayLike, sample: ArrayLike) -> tuple[Array, Array]:
    line, sample = np.broadcast_arrays(np.asarray(line, dtype=float), np.asarray(sample, dtype=float))
    if not (np.all(np.isfinite(line)) and np.all(np.isfinite(sample))):
        n = int(np.count_nonzero(~(np.isfinite(line) & np.isfinite(sample))))
        raise InvalidInputError(f"{n} image coordinate(s) are NaN or infinite")
    return line, sample


def _finite_xyz(xyz: ArrayLike) -> Array:
    xyz = np.asarray(xyz, dtype=float)
    if xyz.shape[-1:] != (3,):
        raise InvalidInputError(f"ground points must have shape (..., 3), got {xyz.shape}")
    if not np.all(np.isfinite(xyz)):
        n = int(np.count_nonzero(~np.all(np.isfinite(xyz), axis=-1)))
        raise InvalidInputError(f"{n} ground point(s) hold NaN or infinite coordinates")
    return xyz


def _check_ground_on_miss(on_miss: str) -> None:
    if on_miss not in ("raise", "nan"):
        raise InvalidInputError(f"on_miss must be 'raise' or 'nan', got {on_miss!r}")


class _CameraModel:
    """What frame and line-scan cameras share: rays, intersections, bookkeeping."""

    interior: InteriorOrientation
    eo: ExteriorOrientation
    shape: Shape
    distortion: Distortion

    def __init__(self, interior: InteriorOrientation, eo: ExteriorOrientation, shape: Shape | None) -> None:
        if not isinstance(interior, InteriorOrientation):
            raise InvalidInputError(f"interior must be an InteriorOrientation, got {type(interior).__name__}")
        if not isinstance(eo, ExteriorOrientation):
            raise InvalidInputError(f"eo must be an ExteriorOrientation, got {type(eo).__name__}")
        self.interior = interior
        self.eo = eo
        self.shape = Shape.moon() if shape is None else shape
        self.distortion = distortion_from_interior(interior)
        self._dtm_cache: tuple[Any, DtmSampler] | None = None
        # Guards the lazy caches: each is built by one thread while the others wait, and is never
        # changed after it is published (threads share cameras, e.g. dask's threaded scheduler).
        self._cache_lock = threading.RLock()

    #: Attributes that are caches, rebuilt on demand from the rest of the state.
    _CACHES = ("_table", "_dtm_cache")

    def __getstate__(self) -> dict[str, Any]:
        # Cameras travel to dask workers: a line-scan camera's per-line EO table is ~99 % of
        # its pickle (16 MB for a 52,224-line NAC image) and rebuilds in ~0.05 s, so it stays home.
        state = self.__dict__.copy()
        for k in self._CACHES:
            if k in state:
                state[k] = None
        state.pop("_cache_lock", None)   # a lock cannot be pickled; each copy gets its own
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._cache_lock = threading.RLock()

    # -- to be provided by subclasses -----------------------------------
    def _rays(self, line: Array, sample: Array) -> tuple[Array, Array]:
        """Origins (m) and unit directions, body-fixed, of finite pixel arrays."""
        raise NotImplementedError

    def corrections(self, degree: int | None = None) -> Any:
        """The correction parameters of this camera (see :mod:`lunarmap.camera.corrections`)."""
        raise NotImplementedError

    # -- the SensorModel protocol (lunarmap.camera.sensor) ----------------
    @property
    def n_lines(self) -> int:
        """Image lines."""
        return int(self.interior.n_lines)

    @property
    def n_samples(self) -> int:
        """Image samples."""
        return int(self.interior.n_samples)

    @property
    def reference_radius(self) -> float:
        """Radius of the height reference sphere, metres."""
        return float(self.shape.reference_radius)

    def rays(self, line: ArrayLike, sample: ArrayLike) -> tuple[Array, Array]:
        """Sensor positions (metres) and unit look vectors (body-fixed) of image coordinates, shapes ``(..., 3)``."""
        line, sample = _finite_pixels(line, sample)
        return self._rays(line, sample)

    def ground_partials(self, xyz: ArrayLike) -> tuple[Array, Array, Array]:
        """Image coordinates of ground points and their partials with respect to the points.

        Parameters
        ----------
        xyz : array_like, shape (..., 3)
            Body-fixed points, metres.

        Returns
        -------
        line, sample : ndarray, shape (...)
            Pixels (CSM convention), not limited to the image; NaN behind the sensor.
        jac : ndarray, shape (..., 2, 3)
            ``d(line, sample) / d(x, y, z)``, pixels per metre.
        """
        xyz = _finite_xyz(xyz)
        corr = self.corrections(degree=0)
        pix, _, jac = corr.partials(np.zeros(corr.n_params), xyz.reshape(-1, 3))
        shape = xyz.shape[:-1]
        return pix[:, 0].reshape(shape), pix[:, 1].reshape(shape), jac.reshape(shape + (2, 3))

    # -- shared -----------------------------------------------------------
    def _sensor_look(self, line: Array, sample: Array) -> Array:
        """Undistorted look vectors ``(x, y, f)`` in the sensor frame, mm."""
        x, y = image_to_focal(self.interior, line, sample)
        ux, uy = self.distortion.undistort(x, y)
        return np.stack([ux, uy, np.full_like(ux, self.interior.focal_length)], axis=-1)

    def look_vector(self, line: ArrayLike, sample: ArrayLike) -> Array:
        """Unit look vectors, body-fixed, of image coordinates.

        Parameters
        ----------
        line, sample : array_like
            Image coordinates, pixels (CSM convention).

        Returns
        -------
        ndarray, shape (..., 3)
            Unit vectors from the sensor towards the scene, body-fixed.
        """
        line, sample = _finite_pixels(line, sample)
        return self._rays(line, sample)[1]

    def _sampler(self, dtm: xr.DataArray | DtmSampler) -> DtmSampler:
        if isinstance(dtm, DtmSampler):
            return dtm
        # Building the sampler copies the grid; cache it for repeated calls on one DTM. The cache is
        # read once into a local: another thread may replace it (another DTM) between two reads.
        cached = self._dtm_cache
        if cached is not None and cached[0] is dtm:
            return cached[1]
        with self._cache_lock:
            cached = self._dtm_cache
            if cached is not None and cached[0] is dtm:
                return cached[1]
            sampler = DtmSampler(dtm)
            self._dtm_cache = (dtm, sampler)
        return sampler

    def image_to_ground(self, line: ArrayLike, sample: ArrayLike, height: ArrayLike = 0.0,
                        dtm: xr.DataArray | DtmSampler | None = None, on_miss: OnMiss = "raise",
                        tol: float = 1e-3) -> Array:
        """Ground points seen at image coordinates.

        Parameters
        ----------
        line, sample : array_like
            Image coordinates, pixels (CSM convention); broadcast together.
        height : array_like
            Height above the shape, metres: the ray is intersected with the
            ellipsoid enlarged by ``height`` (sphere of radius ``R + height``).
            Ignored when ``dtm`` is given.
        dtm : xarray.DataArray or DtmSampler, optional
            Heights (metres above ``shape.reference_radius``) on a ``lat`` x
            ``lon`` grid, degrees.
        on_miss : {"raise", "nan"}
            Rays missing the body (or DTM): raise
            :class:`~lunarmap.errors.NoIntersectionError`, or return NaN rows.
        tol : float
            DTM convergence threshold on height, metres.

        Returns
        -------
        ndarray, shape (..., 3)
            Body-fixed ground points, metres.

        Raises
        ------
        InvalidInputError
            NaN or infinite image coordinates or heights.
        NoIntersectionError
            A ray misses and ``on_miss="raise"``.
        ConvergenceError
            The DTM intersection does not converge.
        """
        line, sample = _finite_pixels(line, sample)
        origins, dirs = self._rays(line, sample)
        if dtm is not None:
            return intersect_dtm(origins, dirs, self._sampler(dtm), self.shape.reference_radius,
                                 tol=tol, on_miss=on_miss)
        h = np.asarray(height, dtype=float)
        if not np.all(np.isfinite(h)):
            raise InvalidInputError("heights hold NaN or infinite values")
        h = np.broadcast_to(h, line.shape)
        return intersect_ellipsoid(origins, dirs, self.shape.axes_at_height(h), on_miss=on_miss)

    def _project(self, v: Array) -> tuple[Array, Array, NDArray[np.bool_]]:
        """Image coordinates of sensor-frame vectors; also the validity mask (in front)."""
        f = self.interior.focal_length
        in_front = v[..., 2] * f > 0.0   # a negative focal length looks along -z (ISIS z direction -1)
        with np.errstate(divide="ignore", invalid="ignore"):
            ux = np.where(in_front, f * v[..., 0] / v[..., 2], np.nan)
            uy = np.where(in_front, f * v[..., 1] / v[..., 2], np.nan)
        dx, dy = self.distortion.distort(ux, uy)
        line, sample = focal_to_image(self.interior, dx, dy)
        return line, sample, in_front & np.isfinite(line) & np.isfinite(sample)

    def _occluded(self, sensor: Array, ground: Array) -> NDArray[np.bool_]:
        return occluded_by_body(self.shape, sensor, ground)

    def _finish_ground_to_image(self, line: Array, sample: Array, ok: NDArray[np.bool_], within_image: bool,
                                on_miss: str) -> tuple[Array, Array]:
        return finish_ground_to_image(line, sample, ok, self.n_lines, self.n_samples, within_image, on_miss,
                                      self.interior.name)


def occluded_by_body(shape: Shape, sensor: Array, ground: Array) -> NDArray[np.bool_]:
    """True where the segment sensor -> ground crosses the body's deep interior.

    The body is the shape shrunk by ``_OCCLUSION_DEPTH`` (deeper than any
    lunar terrain), so points on or below the surface on the visible
    hemisphere are never flagged while points on the far side are.
    """
    axes = np.maximum(shape.axes - _OCCLUSION_DEPTH, 0.5 * shape.axes)
    o = sensor / axes
    d = (ground - sensor) / axes
    a = np.einsum("...i,...i->...", d, d)
    b = np.einsum("...i,...i->...", o, d)
    c = np.einsum("...i,...i->...", o, o) - 1.0
    disc = b * b - a * c
    with np.errstate(invalid="ignore", divide="ignore"):
        s_near = (-b - np.sqrt(disc)) / a
    return (disc > 0.0) & (c > 0.0) & (s_near > 0.0) & (s_near < 1.0)


def finish_ground_to_image(line: Array, sample: Array, ok: NDArray[np.bool_], n_lines: int, n_samples: int,
                           within_image: bool, on_miss: str, name: str = "") -> tuple[Array, Array]:
    """NaN for points not seen (and outside the image when ``within_image``), or GeometryError for ``"raise"``."""
    if within_image:
        # a hair of tolerance so that points on the image edge survive round-off
        tol = 1e-6
        ok = ok & (line >= -tol) & (line <= n_lines + tol) & (sample >= -tol) & (sample <= n_samples + tol)
    if on_miss == "raise" and not np.all(ok):
        n = int(np.count_nonzero(~ok))
        raise GeometryError(f"{n} of {ok.size} ground point(s) are not seen by "
                            f"{name or 'the image'} (behind the sensor or the body"
                            f"{' or outside the image' if within_image else ''})")
    return np.where(ok, line, np.nan), np.where(ok, sample, np.nan)


class FrameCamera(_CameraModel):
    """A framing camera: one exposure time for the whole image.

    Parameters
    ----------
    interior : InteriorOrientation
        Camera constants and distortion.
    eo : ExteriorOrientation
        Sensor position and attitude; evaluated once at ``time``.
    shape : Shape, optional
        Body shape; the 1737.4 km Moon sphere by default.
    time : float, optional
        Exposure time, seconds relative to ``eo.epoch``; defaults to
        ``eo.times[0]`` (a framing image's EO normally holds one sample).
    """

    def __init__(self, interior: InteriorOrientation, eo: ExteriorOrientation, shape: Shape | None = None,
                 time: float | None = None) -> None:
        super().__init__(interior, eo, shape)
        self.time = float(eo.times[0] if time is None else time)
        if not np.isfinite(self.time):
            raise InvalidInputError("frame camera exposure time must be finite")
        self._position = eo.position_at(self.time)
        self._rotation = eo.rotation_at(self.time)

    def __repr__(self) -> str:
        return f"FrameCamera({self.interior.name or 'unnamed'}, t={self.time:.6f} s, {self.distortion!r})"

    @property
    def center_time(self) -> float:
        """Exposure time, ephemeris seconds (TDB past J2000)."""
        return float(self.eo.epoch + self.time)

    def corrections(self, degree: int | None = None) -> Any:
        """Six exterior-orientation corrections (:class:`~lunarmap.camera.corrections.FrameCorrections`).

        ``degree`` is accepted for the :class:`~lunarmap.camera.sensor.SensorModel` protocol and ignored
        (one exposure has no time dependence).
        """
        return FrameCorrections(self)

    def sensor_position(self, line: ArrayLike, sample: ArrayLike) -> Array:
        """Sensor position (metres, body-fixed) for image coordinates; shape ``(..., 3)``."""
        line, sample = _finite_pixels(line, sample)
        return np.broadcast_to(self._position, line.shape + (3,)).copy()

    def _rays(self, line: Array, sample: Array) -> tuple[Array, Array]:
        look = self._sensor_look(line, sample) @ self._rotation.T
        look /= np.linalg.norm(look, axis=-1, keepdims=True)
        return np.broadcast_to(self._position, look.shape).copy(), look

    def ground_to_image(self, xyz: ArrayLike, on_miss: OnMiss = "nan",
                        within_image: bool = True) -> tuple[Array, Array]:
        """Image coordinates of body-fixed ground points.

        Parameters
        ----------
        xyz : array_like, shape (..., 3)
            Ground points, metres, body-fixed.
        on_miss : {"nan", "raise"}
            Points not seen (behind the sensor, hidden by the body, outside
            the image when ``within_image``, or beyond the distortion model's
            domain): NaN coordinates, or :class:`~lunarmap.errors.GeometryError`.
        within_image : bool
            Treat coordinates outside ``[0, n_lines] x [0, n_samples]`` as not seen.

        Returns
        -------
        line, sample : ndarray, shape (...)
            Image coordinates, pixels (CSM convention).

        Notes
        -----
        A point counts as hidden by the body when the sight line crosses the
        shape shrunk by 20 km; occlusion by terrain is not tested.
        """
        _check_ground_on_miss(on_miss)
        xyz = _finite_xyz(xyz)
        v = (xyz - self._position) @ self._rotation  # R^T (G - P), sensor frame
        line, sample, ok = self._project(v)
        ok &= ~self._occluded(self._position, xyz)
        return self._finish_ground_to_image(line, sample, ok, within_image, on_miss)
