"""Variance factors of groups of image observations, estimated from the adjustment (Helmert / Förstner).

For a group ``k`` of image observations with whitened residuals ``v_i / sigma_i`` and redundancy
numbers ``r_i`` (:attr:`~lunarmap.adjust.precision.Precision.redundancy_numbers`), the estimate of
the group's variance factor is::

    s_k^2 = sum_{i in k} (v_i / sigma_i)^2 / sum_{i in k} r_i

(the DLR paper, ``seeds/004``, variance component estimation; ``r_k`` is the group's share of the
redundancy). Scaling the group's sigmas by ``s_k`` and adjusting again, until every factor is 1,
gives weights that match the data. This is what the matcher's tie points need: least-squares
matching reports its sigma from the fit of one window, which underestimates the real scatter of
matches between different images (resampling, relief, illumination), while check and control
measurements, made with a known sigma, keep theirs.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from ..errors import AdjustmentInputError
from .problem import BundleProblem, ImageObservations
from .result import AdjustmentResult
from .solver import SolverOptions, solve

__all__ = ["VarianceEstimate", "image_variance_factors", "estimate_image_variances"]


@dataclass
class VarianceEstimate:
    """Outcome of :func:`estimate_image_variances`.

    Attributes
    ----------
    result : AdjustmentResult
        The last adjustment (sigmas of the estimated groups rescaled).
    scale : ndarray (k,)
        Total factor applied to each group's a-priori sigma (dimensionless).
    history : list of ndarray (k,)
        The variance factors ``s_k^2`` estimated in each round (1 when converged).
    redundancy : ndarray (k,)
        Each group's share of the redundancy in the last round.
    """

    result: AdjustmentResult
    scale: NDArray[np.float64]
    history: list = field(default_factory=list)
    redundancy: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))


def image_variance_factors(result: AdjustmentResult, groups: NDArray[np.int64],
                           n_groups: int | None = None) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Variance factors ``s_k^2`` and redundancies ``r_k`` of groups of image observations.

    Parameters
    ----------
    result : AdjustmentResult
    groups : ndarray (n_obs,) int
        Group of every image observation (both coordinates belong to it); ``-1`` leaves an observation out.
    n_groups : int, optional

    Raises
    ------
    AdjustmentInputError
        A group with no redundancy (its factor cannot be estimated).
    """
    groups = np.asarray(groups, dtype=np.int64)
    o = result.problem.obs
    if groups.shape != (o.n,):
        raise AdjustmentInputError(f"groups must give one group per image observation ({o.n}), got {groups.shape}")
    k = int(groups.max()) + 1 if n_groups is None else int(n_groups)
    red = result.precision().redundancy_numbers
    w = result.state.obs_weight[:, None]
    z = result.image_residuals() / o.sigma
    use = groups >= 0
    vpv = np.bincount(groups[use], weights=np.sum(w[use] * z[use] ** 2, axis=1), minlength=k)
    r = np.bincount(groups[use], weights=np.sum(red[use], axis=1), minlength=k)
    if np.any(r <= 0.5):
        bad = int(np.argmax(r <= 0.5))
        raise AdjustmentInputError(f"image observation group {bad} has redundancy {r[bad]:.2f}: its variance "
                                   "factor cannot be estimated")
    return vpv / r, r


def estimate_image_variances(problem: BundleProblem, groups: NDArray[np.int64], estimate: NDArray[np.bool_],
                             options: SolverOptions | None = None, rounds: int = 5,
                             tol: float = 0.02) -> VarianceEstimate:
    """Adjust, estimate the variance factors of the groups in ``estimate``, rescale their sigmas, repeat.

    Parameters
    ----------
    problem : BundleProblem
    groups : ndarray (n_obs,) int
        Group of every image observation.
    estimate : ndarray (k,) bool
        Groups whose sigma is estimated; the others keep their a-priori sigma.
    options : SolverOptions, optional
    rounds : int
        Maximum number of adjustments.
    tol : float
        Stop when every estimated factor is within ``1 +- tol``.
    """
    groups = np.asarray(groups, dtype=np.int64)
    estimate = np.asarray(estimate, dtype=bool)
    k = estimate.size
    scale = np.ones(k)
    history = []
    pb = problem
    result = solve(pb, options)
    for _ in range(max(rounds, 1)):
        factors, r = image_variance_factors(result, groups, k)
        history.append(factors)
        step = np.where(estimate, np.sqrt(factors), 1.0)
        if np.all(np.abs(factors[estimate] - 1.0) <= tol):
            return VarianceEstimate(result, scale, history, r)
        scale *= step
        o = pb.obs
        sigma = o.sigma * np.where(groups >= 0, step[np.maximum(groups, 0)], 1.0)[:, None]
        # the next round starts where this one ended (image parameters and points): only the weights change
        pb = dataclasses.replace(pb, cam_params=result.cam_params, points=result.points,
                                 obs=ImageObservations(o.cam_idx, o.pt_idx, o.xy, sigma),
                                 cam_param_free=pb.cam_param_free, obs_weight=pb.obs_weight)
        result = solve(pb, options)
    factors, r = image_variance_factors(result, groups, k)
    history.append(factors)
    return VarianceEstimate(result, scale, history, r)

