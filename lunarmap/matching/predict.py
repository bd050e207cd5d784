"""Conjugate-point prediction through sensor models (rigorous cameras or RPCs).

A point ``p1`` of image 1 is projected to the ground at a height (or onto a
DTM) and back into image 2. Finite differences of the same chain give the
local affine map ``A = d p2 / d p1`` (image-2 pixels per image-1 pixel), which
carries the scale, rotation and shear between the images and initialises the
affine part of least-squares matching, and the epipolar direction
``e = d p2 / d h`` (image-2 pixels per metre of height), along which terrain
relief displaces conjugates.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import xarray as xr
from numpy.typing import ArrayLike, NDArray

from ..camera.intersect import DtmSampler
from ..camera.sensor import SensorModel
from ..errors import InvalidInputError

__all__ = ["Prediction", "predict_conjugates"]

Array = NDArray[np.float64]


@dataclass
class Prediction:
    """Predicted conjugates in image 2 of points of image 1.

    Attributes
    ----------
    line, sample : ndarray (n,)
        Predicted image-2 coordinates, pixels (NaN where not seen).
    affine : ndarray (n, 2, 2)
        ``d(line2, sample2) / d(line1, sample1)``, dimensionless (pixels per pixel).
    epipolar : ndarray (n, 2)
        ``d(line2, sample2) / d height``, pixels per metre.
    height : ndarray (n,)
        Heights used, metres.
    """

    line: Array
    sample: Array
    affine: Array
    epipolar: Array
    height: Array


def _ground(sensor: SensorModel, line: Array, sample: Array, height: Array | None,
            dtm: xr.DataArray | None) -> Array:
    if dtm is not None:
        return sensor.image_to_ground(line, sample, dtm=dtm, on_miss="nan")
    assert height is not None, "_ground needs a height or a DTM"
    return sensor.image_to_ground(line, sample, height=height, on_miss="nan")


def predict_conjugates(sensor1: SensorModel, sensor2: SensorModel, line: ArrayLike, sample: ArrayLike,
                       height: ArrayLike | xr.DataArray = 0.0, step: float = 2.0, dh: float = 10.0,
                       radius: float | None = None) -> Prediction:
    """Predict conjugates of image-1 points in image 2, with local affine maps and epipolar directions.

    Parameters
    ----------
    sensor1, sensor2 : SensorModel
        Models of images 1 and 2 (cameras or RPCs).
    line, sample : array_like (n,)
        Image-1 coordinates, pixels (CSM).
    height : float, array_like (n,), xarray.DataArray or DtmSampler
        Height above the reference (metres) at which to predict, or a (coarse)
        DTM on ``lat`` x ``lon`` (or its sampler, which several pairs can share
        without a copy each) to intersect image-1 rays with (only for
        sensors whose ``image_to_ground`` accepts ``dtm=``).
    step : float
        Finite-difference step for the affine map, image-1 pixels.
    dh : float
        Height step for the epipolar direction, metres.
    radius : float, optional
        Reference radius for heights read back from DTM intersections, metres
        (default ``sensor1.reference_radius``).

    Returns
    -------
    Prediction
    """
    line = np.atleast_1d(np.asarray(line, dtype=float))
    sample = np.atleast_1d(np.asarray(sample, dtype=float))
    if line.shape != sample.shape or line.ndim != 1:
        raise InvalidInputError("line and sample must be 1-D arrays of equal length")
    n = line.size
    dtm = height if isinstance(height, (xr.DataArray, DtmSampler)) else None
    if dtm is not None:
        g0 = _ground(sensor1, line, sample, None, dtm)
        if radius is None:
            radius = float(sensor1.reference_radius)
        h = np.linalg.norm(g0, axis=-1) - radius
    else:
        h = np.broadcast_to(np.asarray(height, dtype=float), (n,)).copy()
        if not np.all(np.isfinite(h)):
            raise InvalidInputError("prediction heights hold NaN or infinite values")
    ok = np.isfinite(h)
    hh = np.where(ok, h, 0.0)
    # Five image-1 positions per point: p, p + step*line, p + step*sample, and p at h + dh.
    dl = np.array([0.0, step, 0.0, 0.0])
    ds = np.array([0.0, 0.0, step, 0.0])
    dz = np.array([0.0, 0.0, 0.0, dh])
    L = (line[:, None] + dl).ravel()
    S = (sample[:, None] + ds).ravel()
    H = (hh[:, None] + dz).ravel()
    g = _ground(sensor1, L, S, H, None)
    bad = ~np.all(np.isfinite(g), axis=-1)
    g = np.where(bad[:, None], 0.0, g)
    l2, s2 = sensor2.ground_to_image(g)
    l2 = np.where(bad, np.nan, np.asarray(l2, dtype=float)).reshape(n, 4)
    s2 = np.where(bad, np.nan, np.asarray(s2, dtype=float)).reshape(n, 4)
    affine = np.empty((n, 2, 2))
    affine[:, 0, 0] = (l2[:, 1] - l2[:, 0]) / step
    affine[:, 1, 0] = (s2[:, 1] - s2[:, 0]) / step
    affine[:, 0, 1] = (l2[:, 2] - l2[:, 0]) / step
    affine[:, 1, 1] = (s2[:, 2] - s2[:, 0]) / step
    epi = np.stack([(l2[:, 3] - l2[:, 0]) / dh, (s2[:, 3] - s2[:, 0]) / dh], axis=-1)
    pl = np.where(ok, l2[:, 0], np.nan)
    ps = np.where(ok, s2[:, 0], np.nan)
    return Prediction(line=pl, sample=ps, affine=affine, epipolar=epi, height=h)
