"""RANSAC on a local geometric model, to drop mismatches.

Model. The sensor models already predict each conjugate at a reference height
(:mod:`.predict`); what is left, ``r = p2 - p2_pred``, is the sum of the
orientation error (smooth over the image) and the parallax of the terrain
relief along the epipolar direction ``e``. Over a tile of image 1 this field
is modelled as affine in the image-1 position, ``r = c + B (p1 - p1_mean)``
(6 parameters, exact for an orientation offset plus planar terrain), and a
match is an inlier when its model residual is below ``tol_cross`` across the
epipolar direction (where relief cannot move it) and below ``tol_along``
along it (where relief away from a plane can). Without epipolar directions
the tolerance is isotropic (``tol_cross``).

Fitting. Random minimal samples of 3 matches per tile are drawn all at once;
the 3 x 3 systems of every hypothesis are solved in one batched call and all
hypotheses are scored against all matches of the tile in one array
operation; the best is refitted to its inliers by least squares (Fischler and
Bolles 1981). Tiles with too few matches borrow the model of the whole pair.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import InvalidInputError

__all__ = ["RansacParams", "ransac_local_affine"]

Array = NDArray[np.float64]


@dataclass
class RansacParams:
    """Tuning of :func:`ransac_local_affine`.

    Attributes
    ----------
    tile : float
        Side of the image-1 tiles with their own model, pixels.
    tol_cross, tol_along : float
        Inlier tolerances across and along the epipolar direction, image-2 pixels.
    hypotheses : int
        Random minimal samples per tile.
    min_points : int
        Tiles with fewer matches use the whole pair's model.
    seed : int
        Random seed (results are reproducible).
    """

    tile: float = 256.0
    tol_cross: float = 1.0
    tol_along: float = 3.0
    hypotheses: int = 200
    min_points: int = 8
    seed: int = 0


def _design(p1: Array, centre: Array) -> Array:
    return np.column_stack([np.ones(p1.shape[0]), p1 - centre])


def _residual_norms(res: Array, e_hat: Array | None, tol_cross: float, tol_along: float) -> Array:
    """Scaled residual size (< 1 means inlier); ``res`` (..., n, 2)."""
    if e_hat is None:
        return np.hypot(res[..., 0], res[..., 1]) / tol_cross
    along = res[..., 0] * e_hat[:, 0] + res[..., 1] * e_hat[:, 1]
    cross = -res[..., 0] * e_hat[:, 1] + res[..., 1] * e_hat[:, 0]
    return np.maximum(np.abs(cross) / tol_cross, np.abs(along) / tol_along)


def _fit(p1: Array, r: Array, e_hat: Array | None, prm: RansacParams, rng: np.random.Generator
         ) -> NDArray[np.bool_]:
    """Inlier mask of one group of matches."""
    n = p1.shape[0]
    if n < 3:
        return np.zeros(n, dtype=bool)
    centre = p1.mean(axis=0)
    x = _design(p1, centre)  # (n, 3)
    k = prm.hypotheses
    # k distinct triples: argsort of random keys picks 3 without replacement per row.
    pick = np.argsort(rng.random((k, n)), axis=1)[:, :3]
    xs = x[pick]  # (k, 3, 3)
    ys = r[pick]  # (k, 3, 2)
    det = np.linalg.det(xs)
    # Nearly collinear triples give wild models: skip them.
    scale = np.prod(np.std(p1, axis=0)) + 1e-12
    good = np.abs(det) > 1e-3 * scale
    if not good.any():
        return np.zeros(n, dtype=bool)
    coef = np.linalg.solve(xs[good], ys[good])  # (k', 3, 2)
    pred = np.einsum("ni,kij->knj", x, coef)
    size = _residual_norms(r[None] - pred, e_hat, prm.tol_cross, prm.tol_along)  # (k', n)
    count = np.sum(size < 1.0, axis=1)
    inl = size[np.argmax(count)] < 1.0
    # Refit to the inliers (twice: the refit can admit or reject a few borderline matches).
    for _ in range(2):
        if inl.sum() < 3:
            break
        c, *_ = np.linalg.lstsq(x[inl], r[inl], rcond=None)
        inl = _residual_norms((r - x @ c)[None], e_hat, prm.tol_cross, prm.tol_along)[0] < 1.0
    return inl


def ransac_local_affine(line1: ArrayLike, sample1: ArrayLike, dline: ArrayLike, dsample: ArrayLike,
                        epipolar: ArrayLike | None = None, params: RansacParams | None = None
                        ) -> NDArray[np.bool_]:
    """Inlier mask of matches under a tile-wise affine model of the prediction residuals.

    Parameters
    ----------
    line1, sample1 : array_like (n,)
        Matched points in image 1, pixels.
    dline, dsample : array_like (n,)
        Residuals of the matched image-2 positions from the sensor-model
        prediction (or, without prediction, the image-2 positions themselves), pixels.
    epipolar : array_like (n, 2), optional
        ``d(line2, sample2)/dh`` per point (pixels per metre); only its direction is used.
    params : RansacParams

    Returns
    -------
    ndarray (n,) of bool
        True for matches consistent with their tile's model.
    """
    prm = params or RansacParams()
    p1 = np.column_stack([np.asarray(line1, float), np.asarray(sample1, float)])
    r = np.column_stack([np.asarray(dline, float), np.asarray(dsample, float)])
    n = p1.shape[0]
    if not (np.all(np.isfinite(p1)) and np.all(np.isfinite(r))):
        raise InvalidInputError("RANSAC input holds NaN or infinite coordinates; pass successful matches only")
    if prm.tol_cross <= 0 or prm.tol_along < prm.tol_cross or prm.tile <= 0 or prm.hypotheses < 1:
        raise InvalidInputError("RANSAC needs 0 < tol_cross <= tol_along, tile > 0 and hypotheses >= 1")
    e_hat = None
    if epipolar is not None:
        e = np.asarray(epipolar, float).reshape(n, 2)
        norm = np.hypot(e[:, 0], e[:, 1])
        # Where relief causes no parallax (zero base) there is no epipolar direction: isotropic.
        med = np.median(norm) if n else 0.0
        if n and np.isfinite(med) and med > 0:
            e_hat = np.where((norm > 1e-3 * med)[:, None], e / np.where(norm > 0, norm, 1.0)[:, None],
                             np.array([1.0, 0.0]))
    rng = np.random.default_rng(prm.seed)
    inliers = np.zeros(n, dtype=bool)
    if n == 0:
        return inliers
    cell = (np.floor(p1[:, 0] / prm.tile).astype(np.int64) << 32) + np.floor(p1[:, 1] / prm.tile).astype(np.int64)
    global_in = None
    for c in np.unique(cell):
        sel = np.flatnonzero(cell == c)
        if sel.size >= prm.min_points:
            inliers[sel] = _fit(p1[sel], r[sel], None if e_hat is None else e_hat[sel], prm, rng)
        else:
            if global_in is None:
                global_in = _fit(p1, r, e_hat, prm, rng)
            inliers[sel] = global_in[sel]
    return inliers
