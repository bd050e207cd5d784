"""Ground truth for simulated images: the true conjugate of an image point.

A point at ``(l1, s1)`` of image 1 sees the DTM at
``X = image1.image_to_ground(l1, s1, dtm=DTM)``; its true conjugate in image 2
is ``image2.ground_to_image(X)``. Both images were rendered from the same
DTM, so this is exact up to the DTM intersection tolerance (1 mm).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import xarray as xr
from numpy.typing import ArrayLike, NDArray

from ..camera.intersect import DtmSampler

__all__ = ["true_conjugates", "matching_errors"]

Array = NDArray[np.float64]


def true_conjugates(camera1: Any, camera2: Any, line: ArrayLike, sample: ArrayLike,
                    dtm: xr.DataArray | DtmSampler) -> tuple[Array, Array]:
    """True image-2 coordinates (pixels) of image-1 points (pixels); NaN where not seen."""
    line = np.atleast_1d(np.asarray(line, dtype=float))
    sample = np.atleast_1d(np.asarray(sample, dtype=float))
    g = camera1.image_to_ground(line, sample, dtm=dtm, on_miss="nan")
    bad = ~np.all(np.isfinite(g), axis=-1)
    l2, s2 = camera2.ground_to_image(np.where(bad[:, None], 0.0, g))
    return np.where(bad, np.nan, l2), np.where(bad, np.nan, s2)


def matching_errors(camera1: Any, camera2: Any, line1: ArrayLike, sample1: ArrayLike, line2: ArrayLike,
                    sample2: ArrayLike, dtm: xr.DataArray | DtmSampler) -> tuple[Array, Array]:
    """Matched minus true image-2 coordinates, ``(d_line, d_sample)`` in pixels."""
    tl, ts = true_conjugates(camera1, camera2, line1, sample1, dtm)
    return np.asarray(line2, dtype=float) - tl, np.asarray(sample2, dtype=float) - ts
