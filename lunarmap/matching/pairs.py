"""Match interest points of one image into another: prediction -> pyramid NCC -> least-squares matching.

The per-pair core of the tie-point chain; :mod:`.tiepoints` runs it over
image pairs and :mod:`.parallel` on dask.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import xarray as xr
from numpy.typing import ArrayLike, NDArray

from ..camera.sensor import SensorModel
from ..errors import InvalidInputError, InvalidPixelsWarning, NoOverlapWarning, warn
from .interest import invalid_mask
from .lsm import lsm_match
from .ncc import ncc_match
from .predict import Prediction, predict_conjugates
from .pyramid import build_pyramid
from .resample import _windowed
from .windowed import spatial_order

__all__ = ["MatchParams", "PairMatches", "match_points", "as_array", "STATUS"]

Array = NDArray[np.float64]

#: Status codes of a match attempt.
STATUS = {"ok": 0, "outside": 1, "ncc_failed": 2, "low_correlation": 3, "lsm_failed": 4, "outlier": 5,
          "thinned": 6}


@dataclass
class MatchParams:
    """Tuning of the matching chain (pixels unless stated).

    Attributes
    ----------
    half : int
        Window half-size; windows are ``2 half + 1`` square (7 -> 15 x 15).
    search : float
        NCC search radius around the prediction, image-1 pixels.
    pyramid_levels : int
        Maximum pyramid reductions.
    min_ncc, min_correlation : float
        Minimum NCC peak and minimum LSM correlation coefficient.
    max_shift : float
        LSM may move a match at most this far from the NCC position.
    saturation : float, optional
        Grey level at which pixels count as saturated (invalid).
    bias_sample : int
        When ``search`` exceeds ``2 * local_search``, the prediction's common offset (a navigation error
        shifts every conjugate of a pair alike) is first measured on this many points spread over the
        image with the full ``search``; every point is then matched around its shifted prediction with
        ``local_search``. 0 disables it.
    local_search : float
        Search radius after the offset is removed, image-1 pixels (terrain relief parallax and the
        offset's variation over the image must fit in it).
    presmooth : float
        Gaussian smoothing (pixels) of both images before least-squares matching
        (:func:`~lunarmap.matching.lsm.lsm_match`: against sub-pixel locking, with the sigma of the
        correlated noise it leaves).
    relief : bool
        Least-squares matching estimates a quadratic relief displacement along each pair's epipolar
        line, so the match is the conjugate of the window's centre, not of its average plane.
    """

    half: int = 7
    search: float = 16.0
    pyramid_levels: int = 4
    min_ncc: float = 0.6
    min_correlation: float = 0.7
    max_shift: float = 3.0
    lsm_iterations: int = 30
    saturation: float | None = None
    bias_sample: int = 64
    local_search: float = 16.0
    presmooth: float = 1.0
    relief: bool = True


@dataclass
class PairMatches:
    """Matches of image-1 points in image 2 (one row per attempted point; NaN where failed)."""

    line1: Array
    sample1: Array
    line2: Array
    sample2: Array
    sigma_line: Array
    sigma_sample: Array
    correlation: Array
    status: NDArray[np.int8]
    prediction: Prediction
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def ok(self) -> NDArray[np.bool_]:
        return self.status == STATUS["ok"]

    def subset(self, mask: NDArray[np.bool_]) -> "PairMatches":
        p = self.prediction
        pred = Prediction(p.line[mask], p.sample[mask], p.affine[mask], p.epipolar[mask], p.height[mask])
        return PairMatches(self.line1[mask], self.sample1[mask], self.line2[mask], self.sample2[mask],
                           self.sigma_line[mask], self.sigma_sample[mask], self.correlation[mask],
                           self.status[mask], pred, dict(self.meta))


def as_array(image: xr.DataArray | NDArray, label: str, saturation: float | None = None) -> Array:
    """Image pixels as float64 with invalid (NaN, infinite, saturated) pixels set to NaN; warns if any."""
    arr = image.values if isinstance(image, xr.DataArray) else np.asarray(image)
    if arr.ndim != 2:
        raise InvalidInputError(f"{label}: images must be 2-D (line, sample), got shape {arr.shape}")
    arr = np.asarray(arr, dtype=float)
    bad = invalid_mask(arr, saturation)
    if bad.any():
        warn(f"{label}: {int(bad.sum())} of {bad.size} pixels are NaN, infinite or saturated; "
             f"windows touching them are not matched", InvalidPixelsWarning)
        arr = np.where(bad, np.nan, arr)
    return arr


def _pyramid(image: Any, levels: int) -> list[Any]:
    """Pyramid of an in-memory image, or the levels of a windowed one (stored or derived by window)."""
    return image.pyramid(levels) if _windowed(image) else build_pyramid(image, levels)


def _fill_affine(pred: Prediction) -> None:
    """Points near an image edge lose their finite-difference affine map: use the median one."""
    good = np.all(np.isfinite(pred.affine), axis=(1, 2))
    if good.any() and not good.all():
        pred.affine[~good] = np.median(pred.affine[good], axis=0)
        pred.epipolar[~good] = np.median(pred.epipolar[good], axis=0)


def match_points(image1: NDArray, image2: NDArray, sensor1: SensorModel, sensor2: SensorModel,
                 line1: ArrayLike, sample1: ArrayLike, height: ArrayLike | xr.DataArray = 0.0,
                 params: MatchParams | None = None, label: str = "pair",
                 pyramids: tuple[list[Array], list[Array]] | None = None) -> PairMatches:
    """Match image-1 points into image 2.

    Parameters
    ----------
    image1, image2 : ndarray or WindowedImage
        Grey levels with NaN at invalid pixels (see :func:`as_array`), or images read by window
        (:class:`~lunarmap.matching.windowed.WindowedImage`: images of any size; same results).
    sensor1, sensor2 : SensorModel
        Sensor models (cameras or RPCs).
    line1, sample1 : array_like (n,)
        Points of image 1, pixels (CSM).
    height : float, array_like or xarray.DataArray
        Prediction height (metres) or coarse DTM; see :func:`predict_conjugates`.
    params : MatchParams
    label : str
        Name used in warnings.
    pyramids : optional
        Pre-computed pyramids of both images (reuse across pairs).

    Returns
    -------
    PairMatches
    """
    params = params or MatchParams()
    l1 = np.atleast_1d(np.asarray(line1, dtype=float))
    s1 = np.atleast_1d(np.asarray(sample1, dtype=float))
    n = l1.size
    status = np.zeros(n, dtype=np.int8)
    pred = predict_conjugates(sensor1, sensor2, l1, s1, height)
    _fill_affine(pred)
    inside = np.isfinite(pred.line) & np.isfinite(pred.sample)
    status[~inside] = STATUS["outside"]
    if n and not inside.any():
        warn(f"{label}: no overlap: none of {n} points of the first image is predicted inside the second",
             NoOverlapWarning)
    nan = np.full(n, np.nan)
    res = PairMatches(l1, s1, nan.copy(), nan.copy(), nan.copy(), nan.copy(), nan.copy(), status, pred,
                      {"label": label})
    idx = np.flatnonzero(inside)
    if idx.size == 0:
        return res
    pyr1, pyr2 = pyramids or (_pyramid(image1, params.pyramid_levels), _pyramid(image2, params.pyramid_levels))
    search = params.search
    pl, ps = pred.line[idx], pred.sample[idx]
    if params.bias_sample > 0 and params.search > 2.0 * params.local_search and idx.size > params.bias_sample:
        offset = _prediction_offset(pyr1, pyr2, l1[idx], s1[idx], pl, ps, pred.affine[idx], params)
        if offset is not None:
            pl, ps = pl + offset[0], ps + offset[1]
            search = params.local_search
            res.meta["prediction_offset_px"] = (float(offset[0]), float(offset[1]))
    # Points in Z order of image 1: each batch of the correlation and of LSM then covers a compact
    # region of both images (few, small windows of an image read by window); every point is matched
    # on its own, so the order changes no result.
    order = spatial_order(l1[idx], s1[idx])
    idx, pl, ps = idx[order], pl[order], ps[order]
    ncc = ncc_match(pyr1, pyr2, l1[idx], s1[idx], pl, ps, pred.affine[idx], half=params.half, search=search)
    failed = ~np.isfinite(ncc.correlation)
    low = ~failed & (ncc.correlation < params.min_ncc)
    status[idx[failed]] = STATUS["ncc_failed"]
    status[idx[low]] = STATUS["low_correlation"]
    go = ~(failed | low)
    j = idx[go]
    if j.size == 0:
        return res
    lsm = lsm_match(image1, image2, l1[j], s1[j], ncc.line[go], ncc.sample[go], pred.affine[j], half=params.half,
                    max_iter=params.lsm_iterations, max_shift=params.max_shift,
                    presmooth=params.presmooth, epipolar=pred.epipolar[j] if params.relief else None)
    conv = lsm.converged
    status[j[~conv]] = STATUS["lsm_failed"]
    weak = conv & (lsm.correlation < params.min_correlation)
    status[j[weak]] = STATUS["low_correlation"]
    good = conv & ~weak
    k = j[good]
    res.line2[k] = lsm.line[good]
    res.sample2[k] = lsm.sample[good]
    res.sigma_line[k] = lsm.sigma_line[good]
    res.sigma_sample[k] = lsm.sigma_sample[good]
    res.correlation[k] = lsm.correlation[good]
    return res


def _prediction_offset(pyr1: list[Array], pyr2: list[Array], l1: Array, s1: Array, pl: Array, ps: Array,
                       affine: Array, params: MatchParams) -> tuple[float, float] | None:
    """Median offset (image-2 pixels) of NCC matches from their predictions, on a sample spread over image 1.

    ``None`` when fewer than 8 sample points match with the full search at ``min_ncc``.
    """
    order = np.lexsort((s1, l1))              # spread the sample over the image, deterministically
    pick = order[np.linspace(0, order.size - 1, params.bias_sample).round().astype(np.intp)]
    ncc = ncc_match(pyr1, pyr2, l1[pick], s1[pick], pl[pick], ps[pick], affine[pick], half=params.half,
                    search=params.search)
    good = np.isfinite(ncc.correlation) & (ncc.correlation >= params.min_ncc)
    if np.count_nonzero(good) < 8:
        return None
    dl = ncc.line[good] - pl[pick][good]
    ds = ncc.sample[good] - ps[pick][good]
    return float(np.median(dl)), float(np.median(ds))
