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
    along_mad : float
        The along-epipolar tolerance widens to ``along_mad`` robust standard deviations
        (1.4826 MAD) of the along-epipolar residuals of the matches that pass across it:
        relief away from the tile's plane moves true matches along the epipolar line by its
        parallax, which grows with the convergence angle (0 keeps ``tol_along`` fixed).
    min_points : int
        Tiles with fewer matches use the whole pair's model.
    seed : int
        Random seed (results are reproducible).
    """

    tile: float = 256.0
    tol_cross: float = 1.0
    tol_along: float = 3.0
    along_mad: float = 3.5
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
    best = int(np.argmax(count))
    inl = size[best] < 1.0
    tol_along = prm.tol_along
    if e_hat is not None and prm.along_mad > 0:
        tol_along = _along_tolerance(r - pred[best], e_hat, prm)
    # Refit to the inliers (twice: the refit can admit or reject a few borderline matches).
    for _ in range(2):
        if inl.sum() < 3:
            break
        c, *_ = np.linalg.lstsq(x[inl], r[inl], rcond=None)
        res = r - x @ c
        if e_hat is not None and prm.along_mad > 0:
            tol_along = _along_tolerance(res, e_hat, prm)
        inl = _residual_norms(res[None], e_hat, prm.tol_cross, tol_along)[0] < 1.0
    return inl


def _along_tolerance(res: Array, e_hat: Array, prm: RansacParams) -> float:
    """Along-epipolar tolerance (pixels) from the spread of the matches that pass across the epipolar line."""
    along = res[:, 0] * e_hat[:, 0] + res[:, 1] * e_hat[:, 1]
    cross = -res[:, 0] * e_hat[:, 1] + res[:, 1] * e_hat[:, 0]
    a = along[np.abs(cross) < prm.tol_cross]
    if a.size < 3:
        return prm.tol_along
    mad = 1.4826 * np.median(np.abs(a - np.median(a)))
    return max(prm.tol_along, prm.along_mad * mad)


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
        finite = np.isfinite(norm)
        # Where relief causes no parallax (zero base) there is no epipolar direction: isotropic.
        med = np.median(norm[finite]) if finite.any() else 0.0
        if med > 0:
            valid = finite & (norm > 1e-3 * med)
            e_hat = np.empty((n, 2))
            e_hat[valid] = e[valid] / norm[valid, None]
            # A point whose epipolar derivative could not be computed (its image-2 position
            # at the perturbed height left the image) takes the mean direction of the others:
            # the epipolar direction varies slowly over an image.
            mean = e_hat[valid].mean(axis=0)
            e_hat[~valid] = mean / np.hypot(*mean)
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
