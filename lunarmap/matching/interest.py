"""Förstner interest operator with non-maximum suppression and an even spread over the image.

For every pixel the structure tensor ``N = sum_window [[gl^2, gl gs], [gl gs, gs^2]]``
of the image gradients gives the Förstner (1987) measures
``w = det N / tr N`` (the weight, i.e. inverse size of the error ellipse of a
point located there) and ``q = 4 det N / tr(N)^2`` (roundness, 1 for a
circular ellipse). Candidates have ``q >= q_min`` and ``w >= w_factor *
median(w)``; local maxima of ``w`` survive non-maximum suppression; the best
``per_cell`` of each ``cell x cell`` block are kept so points spread evenly.
"""

from __future__ import annotations

import numpy as np
from dask.sizeof import sizeof
from numpy.typing import NDArray
from scipy import ndimage

from ..errors import BlankTileWarning, InvalidInputError, warn

__all__ = ["foerstner", "InterestPoints", "invalid_mask"]

Array = NDArray[np.float64]


class InterestPoints(tuple):
    """``(line, sample, strength)`` arrays (CSM pixel centres; ``w`` in grey level^2 / px^2)."""

    __slots__ = ()

    def __new__(cls, line: Array, sample: Array, strength: Array) -> "InterestPoints":
        return super().__new__(cls, (line, sample, strength))

    @property
    def line(self) -> Array:
        return self[0]

    @property
    def sample(self) -> Array:
        return self[1]

    @property
    def strength(self) -> Array:
        return self[2]

    def __len__(self) -> int:  # number of points, not of fields
        return int(self[0].size)

    def __reduce__(self):  # pickle (dask workers) through the 3-argument constructor
        return (InterestPoints, (self[0], self[1], self[2]))


@sizeof.register(InterestPoints)
def _sizeof_points(points: InterestPoints) -> int:
    # dask's generic tuple estimate samples len() items, but len() counts points, not the 3 fields:
    # it failed (and warned) on every task result with more than 10 points.
    return int(sum(np.asarray(a).nbytes for a in points)) + 64


def invalid_mask(image: NDArray, saturation: float | None = None) -> NDArray[np.bool_]:
    """True at NaN/infinite pixels and at pixels ``>= saturation`` (grey levels)."""
    bad = ~np.isfinite(image)
    if saturation is not None:
        with np.errstate(invalid="ignore"):
            bad |= image >= saturation
    return bad


def foerstner(image: NDArray, window: int = 5, nms: int = 7, cell: int = 32, per_cell: int = 2,
              q_min: float = 0.5, w_factor: float = 1.0, min_contrast: float = 1.0, border: int = 8,
              saturation: float | None = None, origin: tuple[int, int] = (0, 0),
              core: tuple[int, int, int, int] | None = None, label: str = "image") -> InterestPoints:
    """Förstner interest points of one image or tile.

    Parameters
    ----------
    image : ndarray, shape (H, W)
        Grey levels; NaN marks invalid pixels.
    window : int
        Side of the structure-tensor window, pixels.
    nms : int
        Side of the non-maximum-suppression window, pixels.
    cell, per_cell : int
        Even spread: at most ``per_cell`` points per ``cell x cell`` block (pixels).
    q_min, w_factor : float
        Roundness threshold and weight threshold (relative to the median weight).
    min_contrast : float
        Tiles whose grey-level standard deviation is below this (grey levels)
        count as blank: no points, a :class:`BlankTileWarning`.
    border : int
        No points closer than this to the image (or invalid pixels), pixels:
        a matching window must fit.
    saturation : float, optional
        Pixels at or above this grey level are invalid.
    origin : (int, int)
        Array index of ``image[0, 0]`` in the full image (for tiles).
    core : (l0, l1, s0, s1), optional
        Keep only points whose array indices (full image) fall in this range
        (the tile without its halo).
    label : str
        Name used in warnings.

    Returns
    -------
    InterestPoints
        ``line``, ``sample`` (CSM, full image) and strength ``w``, strongest first.
    """
    img = np.asarray(image, dtype=float)
    if img.ndim != 2:
        raise InvalidInputError(f"{label}: interest points need a 2-D image, got shape {img.shape}")
    if window < 3 or nms < 1 or cell < 1 or per_cell < 1:
        raise InvalidInputError("window >= 3, nms >= 1, cell >= 1 and per_cell >= 1 are required")
    empty = InterestPoints(np.empty(0), np.empty(0), np.empty(0))
    bad = invalid_mask(img, saturation)
    # Blankness is judged on the tile itself, not on the halo borrowed from its neighbours.
    if core is not None:
        r0, c0 = max(core[0] - origin[0], 0), max(core[2] - origin[1], 0)
        region = (slice(r0, max(core[1] - origin[0], r0)), slice(c0, max(core[3] - origin[1], c0)))
    else:
        region = (slice(None), slice(None))
    valid_frac = 1.0 - bad[region].mean() if bad[region].size else 0.0
    good = img[region][~bad[region]]
    if valid_frac < 0.05 or good.size < window * window or float(np.std(good)) < min_contrast:
        why = ("mostly NaN or saturated" if valid_frac < 0.05 or good.size < window * window
               else f"grey-level spread {float(np.std(good)) if good.size else 0.0:.3g} < {min_contrast}")
        warn(f"{label}: no texture ({why}); no interest points there", BlankTileWarning)
        return empty
    filled = np.where(bad, float(np.mean(img[~bad])), img)
    gl, gs = np.gradient(filled)
    area = float(window * window)
    nll = ndimage.uniform_filter(gl * gl, window) * area
    nss = ndimage.uniform_filter(gs * gs, window) * area
    nls = ndimage.uniform_filter(gl * gs, window) * area
    det = nll * nss - nls * nls
    tr = nll + nss
    with np.errstate(invalid="ignore", divide="ignore"):
        w = np.where(tr > 0, det / tr, 0.0)
        q = np.where(tr > 0, 4.0 * det / (tr * tr), 0.0)
    # Exclude a border and the neighbourhood of invalid pixels (a matching window must fit).
    reach = max(border, window // 2 + 1)
    keep = ~ndimage.binary_dilation(bad, iterations=reach) if bad.any() else np.ones_like(bad)
    keep[:reach, :] = keep[-reach:, :] = False
    keep[:, :reach] = keep[:, -reach:] = False
    if not keep.any():
        return empty
    w_min = w_factor * float(np.median(w[keep]))
    cand = keep & (q >= q_min) & (w >= w_min) & (w > 0) & (w == ndimage.maximum_filter(w, nms))
    i, j = np.nonzero(cand)
    gi, gj = i + origin[0], j + origin[1]
    if core is not None:
        inside = (gi >= core[0]) & (gi < core[1]) & (gj >= core[2]) & (gj < core[3])
        i, j, gi, gj = i[inside], j[inside], gi[inside], gj[inside]
    strength = w[i, j]
    # Even spread: rank candidates inside their cell by strength, keep the best few.
    cell_id = (gi // cell) * (1 << 20) + gj // cell
    order = np.lexsort((-strength, cell_id))
    cid = cell_id[order]
    first = np.r_[0, np.flatnonzero(np.diff(cid)) + 1]
    rank = np.arange(cid.size) - np.repeat(first, np.diff(np.r_[first, cid.size]))
    sel = order[rank < per_cell]
    sel = sel[np.argsort(-strength[sel], kind="stable")]
    return InterestPoints(gi[sel] + 0.5, gj[sel] + 0.5, strength[sel])
