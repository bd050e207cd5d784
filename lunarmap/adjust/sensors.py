"""The adjustment's image model over lunarmap's sensor models: each image's own correction parameters.

:class:`SensorImageModel` wraps any :class:`~lunarmap.camera.sensor.SensorModel` (frame and
line-scan cameras with whatever distortion their IK gives, RFMs) and exposes to the solver the
correction parameters each sensor offers (:meth:`~lunarmap.camera.sensor.SensorModel.corrections`):
6 exterior-orientation corrections for a frame camera, ``6 (degree + 1)`` polynomial coefficients
for a line-scan camera, 6 affine parameters for an RFM. The sensors' own orientation is the
reference (for cameras from SPICE: the navigation orientation), so zero parameters reproduce the
sensors and navigation observations are observations of zero.

Images with fewer parameters than the block's widest are padded with columns that do not exist
(:attr:`SensorImageModel.param_mask`) and never move. Frame cameras are evaluated together in one
vectorised pass (:class:`~lunarmap.camera.corrections.FrameStack`); other sensors image by image.
Image coordinates are ``(line, sample)``, pixels, CSM convention; points are body-fixed metres.
"""

from __future__ import annotations

import contextlib
import contextvars
import os
from concurrent.futures import ThreadPoolExecutor
from typing import Iterator, Sequence

import numpy as np
from numpy.typing import NDArray

from ..camera.corrections import FrameCorrections, FrameStack
from ..camera.linescan import LineScanCamera
from ..camera.sensor import Corrections, SensorModel
from ..errors import AdjustmentInputError, DistortionPartialsError
from .intersection import midpoint_intersection

__all__ = ["SensorImageModel", "image_threads"]

# threads for the image-by-image evaluation, per calling thread (a context variable: a step that runs alone
# sets it, steps running side by side on other threads keep one)
_IMAGE_THREADS: contextvars.ContextVar[int] = contextvars.ContextVar("lunarmap_image_threads", default=1)


@contextlib.contextmanager
def image_threads(n: int) -> Iterator[None]:
    """Context in which :class:`SensorImageModel` evaluates its non-frame images on ``n`` threads.

    Each image's projections and partials are computed exactly as on one thread, into its own rows, so the
    results do not depend on ``n``. Only what releases the GIL (numpy, scipy's interpolation) runs side
    by side: see ``docs/SCALING.md`` for what it gains.
    """
    token = _IMAGE_THREADS.set(max(1, int(n)))
    try:
        yield
    finally:
        _IMAGE_THREADS.reset(token)


_pools: dict[tuple[int, int], ThreadPoolExecutor] = {}


def _pool(n: int) -> ThreadPoolExecutor:
    """A thread pool of ``n`` threads (one per ``n`` and process, started on first use: a forked child
    gets its own)."""
    key = (os.getpid(), n)
    pool = _pools.get(key)
    if pool is None:
        pool = _pools[key] = ThreadPoolExecutor(n, thread_name_prefix="lunarmap-images")
    return pool


class SensorImageModel:
    """Image model of a block of sensors (see the module docstring).

    Parameters
    ----------
    sensors : sequence of SensorModel
        One sensor model per image (its orientation is the reference).
    degree : int
        Polynomial degree in time of line-scan corrections (0, 1 or 2); ignored by other sensors.
    jitter_lines : float, or sequence of (float or None), optional
        Knot spacing (image lines, >= 1) of a cubic B-spline attitude correction of line-scan images on
        top of their polynomial (:class:`~lunarmap.camera.corrections.LineScanCorrections`): one for all
        line-scan images or one per image (``None``: that image without); ignored by other sensors. Give
        the spline a prior (:class:`~lunarmap.adjust.jitter.JitterSmoothness`).
    corrections : sequence of Corrections, optional
        The corrections of each image, overriding ``sensor.corrections(degree)``.
    names : sequence of str, optional
        Image names, for messages.

    Raises
    ------
    AdjustmentInputError
        A sensor that is not a SensorModel, or corrections that do not belong to their sensor.
    DistortionPartialsError
        A camera whose distortion model has no partial derivatives.
    JitterKnotSpacingError
        A knot spacing below one line.
    """

    def __init__(self, sensors: Sequence[SensorModel], degree: int = 1,
                 corrections: Sequence[Corrections] | None = None, names: Sequence[str] | None = None,
                 jitter_lines: float | Sequence[float | None] | None = None) -> None:
        self.sensors = list(sensors)
        if not self.sensors:
            raise AdjustmentInputError("the image model needs at least one sensor")
        self.names = [str(n) for n in names] if names is not None else [f"image {i}" for i in range(len(self.sensors))]
        if len(self.names) != len(self.sensors):
            raise AdjustmentInputError(f"{len(self.names)} names for {len(self.sensors)} sensors")
        for i, s in enumerate(self.sensors):
            if not isinstance(s, SensorModel):
                raise AdjustmentInputError(f"{self.names[i]}: {type(s).__name__} is not a lunarmap SensorModel")
        if jitter_lines is None or np.ndim(jitter_lines) == 0:   # type: ignore[arg-type]
            jitter = [jitter_lines] * len(self.sensors)
        else:
            jitter = list(jitter_lines)   # type: ignore[arg-type]
            if len(jitter) != len(self.sensors):
                raise AdjustmentInputError(f"{len(jitter)} jitter knot spacings for {len(self.sensors)} sensors")
        if corrections is None:
            corr = []
            for name, s, jl in zip(self.names, self.sensors, jitter):
                try:
                    if jl is not None and isinstance(s, LineScanCamera):
                        corr.append(s.corrections(degree=degree, jitter_lines=jl))  # type: ignore[arg-type]
                    else:
                        corr.append(s.corrections(degree=degree))
                except DistortionPartialsError as exc:
                    raise DistortionPartialsError(f"{name}: {exc}") from None
        else:
            corr = list(corrections)
            if len(corr) != len(self.sensors):
                raise AdjustmentInputError(f"{len(corr)} corrections for {len(self.sensors)} sensors")
            for name, s, c in zip(self.names, self.sensors, corr):
                if c.sensor is not s:
                    raise AdjustmentInputError(f"{name}: the corrections given belong to another sensor")
        self.corrections: list[Corrections] = corr
        self.n_params = max(c.n_params for c in corr)
        widest = max(corr, key=lambda c: c.n_params)
        self.param_names = tuple(widest.names)
        self._mask = np.zeros((len(corr), self.n_params), dtype=bool)
        for i, c in enumerate(corr):
            self._mask[i, :c.n_params] = True
        is_frame = np.array([isinstance(c, FrameCorrections) for c in corr])
        self._frame_images = np.flatnonzero(is_frame)
        self._frame_local = -np.ones(len(corr), dtype=np.int64)
        self._frame_local[self._frame_images] = np.arange(self._frame_images.size)
        self._stack: FrameStack | None = (FrameCorrections.stack([corr[i] for i in self._frame_images])  # type: ignore[misc]
                                          if self._frame_images.size else None)

    def __repr__(self) -> str:
        kinds: dict[str, int] = {}
        for c in self.corrections:
            kinds[type(c).__name__] = kinds.get(type(c).__name__, 0) + 1
        return f"SensorImageModel({len(self.sensors)} images: {kinds}, {self.n_params} parameters per image)"

    # -- the ImageModel protocol ---------------------------------------------------------------
    @property
    def n_images(self) -> int:
        return len(self.sensors)

    @property
    def param_mask(self) -> NDArray[np.bool_]:
        """``(n_images, n_params)``: True where an image has that parameter."""
        return self._mask.copy()

    def initial_params(self) -> NDArray[np.float64]:
        """Zero corrections ``(n_images, n_params)``: the sensors as given."""
        return np.zeros((self.n_images, self.n_params))

    def param_names_of(self, image: int) -> tuple[str, ...]:
        """Names of the parameters of one image (without padding)."""
        return tuple(self.corrections[image].names)

    def param_units_of(self, image: int) -> tuple[str, ...]:
        """Units of the parameters of one image (without padding)."""
        return tuple(self.corrections[image].units)

    def _evaluate(self, params: NDArray, cam_idx: NDArray, X: NDArray, jacobian: bool):
        params = np.asarray(params, dtype=float)
        cam_idx = np.asarray(cam_idx, dtype=np.int64)
        X = np.asarray(X, dtype=float)
        n = cam_idx.size
        pix = np.empty((n, 2))
        jc = np.zeros((n, 2, self.n_params)) if jacobian else None
        jx = np.empty((n, 2, 3)) if jacobian else None
        is_frame = self._frame_local[cam_idx] >= 0
        if self._stack is not None and is_frame.any():
            sel = np.flatnonzero(is_frame)
            fp = params[self._frame_images][:, :6]
            p, c, x = self._stack.partials(fp, self._frame_local[cam_idx[sel]], X[sel], jacobian)
            pix[sel] = p
            if jacobian:
                jc[sel, :, :6] = c          # type: ignore[index]
                jx[sel] = x                 # type: ignore[index]
        rest = np.flatnonzero(~is_frame)
        if rest.size:
            order = rest[np.argsort(cam_idx[rest], kind="stable")]
            images, starts = np.unique(cam_idx[order], return_index=True)
            bounds = np.append(starts, order.size)

            def one(k: int) -> None:
                i = images[k]
                rows = order[bounds[k]:bounds[k + 1]]
                corr = self.corrections[i]
                p_i = params[i, :corr.n_params]
                if jacobian:
                    pix[rows], jc[rows, :, :corr.n_params], jx[rows] = corr.partials(p_i, X[rows])  # type: ignore[index]
                else:
                    pix[rows] = corr.project(p_i, X[rows])

            threads = min(_IMAGE_THREADS.get(), images.size)
            if threads > 1:
                for _ in _pool(threads).map(one, range(images.size)):
                    pass        # (re-raises an image's error)
            else:
                for k in range(images.size):
                    one(k)
        return pix, jc, jx

    def project(self, params: NDArray, cam_idx: NDArray, X: NDArray) -> NDArray[np.float64]:
        """``(line, sample)`` pixels ``(n, 2)`` of observations of images ``cam_idx`` of points ``X (n, 3)`` metres."""
        return self._evaluate(params, cam_idx, X, False)[0]

    def linearize(self, params: NDArray, cam_idx: NDArray, X: NDArray):
        """Pixels ``(n, 2)``, ``d/d params (n, 2, n_params)``, ``d/d X (n, 2, 3)`` (pixels per metre)."""
        return self._evaluate(params, cam_idx, X, True)

    def project_indexed(self, params: NDArray, cam_idx: NDArray, points: NDArray, pt_idx: NDArray) -> NDArray:
        return self.project(params, cam_idx, np.asarray(points)[np.asarray(pt_idx, dtype=np.int64)])

    def linearize_indexed(self, params: NDArray, cam_idx: NDArray, points: NDArray, pt_idx: NDArray):
        return self.linearize(params, cam_idx, np.asarray(points)[np.asarray(pt_idx, dtype=np.int64)])

    def rays(self, params: NDArray, cam_idx: NDArray, xy: NDArray) -> tuple[NDArray, NDArray]:
        """Origins and unit directions ``(n, 3)`` of the image observations' rays, metres, from the sensors
        corrected by ``params`` (:meth:`adjusted`)."""
        sensors = self.adjusted(params) if np.any(params) else self.sensors
        origins, dirs = self._rays(sensors, np.asarray(cam_idx, dtype=np.int64), np.asarray(xy, dtype=float))
        return origins, dirs / np.linalg.norm(dirs, axis=1, keepdims=True)

    @staticmethod
    def _rays(sensors: Sequence[SensorModel], cam_idx: NDArray, xy: NDArray) -> tuple[NDArray, NDArray]:
        origins = np.empty((cam_idx.size, 3))
        dirs = np.empty((cam_idx.size, 3))
        for i in np.unique(cam_idx):
            m = cam_idx == i
            origins[m], dirs[m] = sensors[i].rays(xy[m, 0], xy[m, 1])
        return origins, dirs

    def initial_points(self, params: NDArray, cam_idx: NDArray, pt_idx: NDArray, xy: NDArray, n_pt: int,
                       height: float = 0.0) -> NDArray[np.float64]:
        """Start values ``(n_pt, 3)`` metres: the point nearest (least squares) to its rays.

        Rays come from the sensors corrected by ``params`` (:meth:`adjusted`); points with a single
        ray (control points) are put on it at ``height`` metres.
        """
        cam_idx = np.asarray(cam_idx, dtype=np.int64)
        pt_idx = np.asarray(pt_idx, dtype=np.int64)
        xy = np.asarray(xy, dtype=float)
        sensors = self.adjusted(params) if np.any(params) else self.sensors
        origins, dirs = self._rays(sensors, cam_idx, xy)
        count = np.bincount(pt_idx, minlength=n_pt)
        X = np.full((n_pt, 3), np.nan)
        multi = count >= 2
        if multi.any():
            use = multi[pt_idx]
            X[multi] = midpoint_intersection(origins[use], dirs[use], pt_idx[use], n_pt)[multi]
        single = np.flatnonzero(count == 1)
        if single.size:
            first = np.full(n_pt, -1, dtype=np.int64)
            first[pt_idx[::-1]] = np.arange(pt_idx.size)[::-1]
            rows = first[single]
            for i in np.unique(cam_idx[rows]):
                m = rows[cam_idx[rows] == i]
                X[pt_idx[m]] = sensors[i].image_to_ground(xy[m, 0], xy[m, 1], height=height, on_miss="nan")
        return X

    # -- results -------------------------------------------------------------------------------
    def adjusted(self, params: NDArray) -> list[SensorModel]:
        """New sensor models with the corrections ``params (n_images, n_params)`` applied; the originals are untouched."""
        params = np.asarray(params, dtype=float)
        if params.shape != (self.n_images, self.n_params):
            raise AdjustmentInputError(f"parameters must be ({self.n_images}, {self.n_params}), got {params.shape}")
        return [c.apply(params[i, :c.n_params]) for i, c in enumerate(self.corrections)]
