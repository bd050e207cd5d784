"""Multi-ray least-squares forward intersection with covariance (Ranger paper, ``seeds/000``).

For every point the collinearity equations of all its rays are solved for ``X`` by
Gauss-Newton (all points at once), starting from the closed-form "midpoint" solution
that minimises the squared distances to the rays.  As in the Ranger point solution the
precision is reported as ``S0 = sqrt(v^T P v / (2k - 3))`` (``k`` rays) and
``sigma_X, sigma_Y, sigma_Z`` = square roots of the diagonal of ``S0^2 N^-1``
(``N`` the 3x3 normal matrix of the point).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ..errors import AdjustmentInputError, UnobservedParameterError
from .schur import aggregation_matrix, inv_sym3

__all__ = ["IntersectionResult", "intersect_points", "midpoint_intersection"]


@dataclass
class IntersectionResult:
    """Intersected points (length unit of the cameras) with precision.

    ``cov`` (n, 3, 3) = ``S0^2 N^-1``; ``cov_apriori`` = ``N^-1`` (a-priori sigma0 = 1);
    ``s0`` (n,) dimensionless (redundancy 2k - 3, so 1 for a 2-ray point);
    ``sigma`` (n, 3) = sqrt(diag(cov)); ``n_rays`` (n,).
    """

    xyz: NDArray
    cov: NDArray
    cov_apriori: NDArray
    s0: NDArray
    sigma: NDArray
    n_rays: NDArray
    iterations: int


def midpoint_intersection(centres: NDArray, directions: NDArray, pt_idx: NDArray, n_pt: int) -> NDArray:
    """Closed-form point nearest (least squares) to its rays: ``sum(I - d d^T) X = sum(I - d d^T) C``."""
    d = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    M = np.eye(3)[None] - d[:, :, None] * d[:, None, :]
    agg = aggregation_matrix(pt_idx, n_pt)
    A = (agg @ M.reshape(-1, 9)).reshape(-1, 3, 3)
    b = agg @ np.einsum("nij,nj->ni", M, centres)
    return np.einsum("nij,nj->ni", inv_sym3(A), b)


def intersect_points(model, cam_params: NDArray, cam_idx, pt_idx, xy, sigma=1.0, n_pt: int | None = None,
                     x0: NDArray | None = None, max_iterations: int = 10, tol: float = 1e-10,
                     prior_xyz: NDArray | None = None, prior_sqrt_weight: NDArray | None = None) -> IntersectionResult:
    """Forward-intersect every point from its image measurements (and its observed coordinates, if any).

    Parameters
    ----------
    model : ImageModel
        The adjustment's image model (:class:`~lunarmap.adjust.sensors.SensorImageModel`, or the BAL
        ``FrameModel``); its ``initial_points`` gives the start values when ``x0`` is not given.
    cam_params : (n_img, p) image parameters.
    cam_idx, pt_idx : (n,) ints; xy : (n, 2) pixels; sigma : scalar or (n, 2) pixels.
    x0 : (n_pt, 3), optional start values.
    prior_xyz, prior_sqrt_weight : (n_pt, 3), (n_pt, 3, 3), optional
        Observed coordinates of the points (control points; length unit of the cameras) and their
        whitening matrices ``W`` (``W^T W`` the weight matrix, inverse length unit; zero for points
        without): the observations ``W (X - prior_xyz) = 0`` join the rays, and count in ``s0``'s
        redundancy (3 per point with a non-zero ``W``).

    Raises
    ------
    UnobservedParameterError
        A point has fewer than 2 rays.
    """
    cam_idx = np.asarray(cam_idx, np.int64)
    pt_idx = np.asarray(pt_idx, np.int64)
    xy = np.asarray(xy, float)
    if not np.all(np.isfinite(xy)):
        raise AdjustmentInputError("intersection: non-finite image coordinates")
    n_pt = int(pt_idx.max()) + 1 if n_pt is None else n_pt
    k = np.bincount(pt_idx, minlength=n_pt)
    if np.any(k < 2):
        raise UnobservedParameterError(f"intersection: {int(np.sum(k < 2))} point(s) with fewer than 2 rays, "
                                       f"first: point {int(np.argmax(k < 2))}")
    sig = np.broadcast_to(np.asarray(sigma, float), xy.shape)
    X = model.initial_points(cam_params, cam_idx, pt_idx, xy, n_pt) if x0 is None else np.array(x0, float)
    agg = aggregation_matrix(pt_idx, n_pt)
    W = None
    if prior_sqrt_weight is not None:
        W = np.asarray(prior_sqrt_weight, float)
        P = np.einsum("nki,nkj->nij", W, W)
        Xp = np.asarray(prior_xyz, float)
        if W.shape != (n_pt, 3, 3) or Xp.shape != (n_pt, 3):
            raise AdjustmentInputError(f"intersection: prior coordinates / weights need shapes ({n_pt}, 3) and "
                                       f"({n_pt}, 3, 3), got {Xp.shape} and {W.shape}")
        Xp = np.where(np.isfinite(Xp), Xp, 0.0)
    it = 0
    for it in range(1, max_iterations + 1):  # noqa: B007 (the count is reported after the loop)
        x, _, Jp = model.linearize(cam_params, cam_idx, X[pt_idx])
        A = Jp / sig[:, :, None]
        r = (x - xy) / sig
        N = (agg @ np.einsum("nki,nkj->nij", A, A).reshape(-1, 9)).reshape(-1, 3, 3)
        g = agg @ np.einsum("nki,nk->ni", A, r)
        if W is not None:
            N = N + P
            g = g + np.einsum("nij,nj->ni", P, X - Xp)
        dX = -np.einsum("nij,nj->ni", inv_sym3(N), g)
        X = X + dX
        if np.max(np.abs(dX)) <= tol * max(1.0, np.max(np.abs(X))):
            break
    x, _, Jp = model.linearize(cam_params, cam_idx, X[pt_idx])
    A = Jp / sig[:, :, None]
    r = (x - xy) / sig
    N = (agg @ np.einsum("nki,nkj->nij", A, A).reshape(-1, 9)).reshape(-1, 3, 3)
    vpv = agg @ np.sum(r * r, axis=1)
    dof = 2 * k - 3
    if W is not None:
        N = N + P
        vpv = vpv + np.sum(np.einsum("nij,nj->ni", W, X - Xp) ** 2, axis=1)
        dof = dof + 3 * np.any(W != 0.0, axis=(1, 2))
    Ninv = inv_sym3(N)
    s0 = np.sqrt(vpv / dof)
    cov = Ninv * (s0 ** 2)[:, None, None]
    return IntersectionResult(X, cov, Ninv, s0, np.sqrt(np.diagonal(cov, axis1=1, axis2=2)), k, it)
