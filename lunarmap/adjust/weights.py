"""Reweighting a block: per-observation sigma factors for image, control and camera-level observations.

Quality control changes weights without changing the problem's shape, so that every index (images,
points, observations) keeps its meaning from the first adjustment to the last:

* image observations: their sigma times a factor, or a weight factor 0 (removed);
* control points: their sigma (covariance) times a factor;
* camera-level terms (navigation observations): every whitened row divided by a factor
  (:class:`ScaledTerm`), i.e. the observation's sigma times that factor;
* points that lost their rays are held fixed where they are (a zero-sigma prior), so that they
  neither move nor weigh on the images, and images without observations keep their parameters.

:func:`reweighted_problem` builds such a problem from a base problem and a :class:`Weights`.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from ..errors import AdjustmentInputError
from .problem import BundleProblem, ImageObservations, PointPriors

__all__ = ["ScaledTerm", "Weights", "reweighted_problem"]

#: sigma factor of a term row out with its point (:meth:`Weights.term_rows_out`): weight 1e-12 of its own
OUT_FACTOR = 1e6


class ScaledTerm:
    """A camera-level term whose observation ``i`` has its sigma multiplied by ``factor[i]``.

    Every other attribute is the wrapped term's (``name``, ``orbit``, :meth:`row_table`, ...).
    """

    def __init__(self, term, factor: NDArray[np.float64]):
        factor = np.asarray(factor, dtype=float)
        if factor.shape != (term.n_obs_scalar,):
            raise AdjustmentInputError(f"{getattr(term, 'name', 'term')}: {factor.shape} sigma factors for "
                                       f"{term.n_obs_scalar} observations")
        if not np.all(factor > 0):
            raise AdjustmentInputError("sigma factors must be > 0")
        self.term = term
        self.factor = factor
        self._scale = sp.diags(1.0 / factor)

    def __getattr__(self, name):
        return getattr(self.term, name)

    @property
    def n_extra(self) -> int:
        return self.term.n_extra

    @property
    def n_obs_scalar(self) -> int:
        return self.term.n_obs_scalar

    def initial_extra(self) -> NDArray:
        return self.term.initial_extra()

    def extra_free(self) -> NDArray[np.bool_]:
        return self.term.extra_free()

    def observed_images(self) -> NDArray[np.bool_]:
        return self.term.observed_images()

    def linearize(self, cam_params: NDArray, extra: NDArray, points: NDArray | None = None):
        if getattr(self.term, "uses_points", False):     # a point-observing term (reference DTM heights)
            r, J, Jp = self.term.linearize(cam_params, extra, points)
            f = self.factor.reshape((-1,) + (1,) * (np.ndim(Jp) - 1))   # (m, 3) or (m, k, 3) partials
            return r / self.factor, (self._scale @ sp.csr_matrix(J)).tocsr(), Jp / f
        r, J = self.term.linearize(cam_params, extra)
        return r / self.factor, (self._scale @ sp.csr_matrix(J)).tocsr()


@dataclass
class Weights:
    """Weight changes of a problem (all factors multiply the base problem's sigmas).

    Attributes
    ----------
    image_weight : (n_obs,)
        Weight factor of each image observation (1 a-priori, 0 removed; robust weights between).
    image_sigma : (n_obs,)
        Sigma factor of each image observation (variance components).
    control_sigma : (k,)
        Sigma factor of each control point of the base priors (in ``priors.idx`` order).
    term_sigma : list of (m_t,)
        Sigma factor of every row of every camera-level term.
    dropped_points : (n_pt,) bool
        Points held fixed because they have too few observations left.
    fixed_images : (n_img,) bool
        Images whose parameters are held at their current values (no observations left).
    control_vc, term_vc : (k,), list of (m_t,)
        The part of ``control_sigma`` / ``term_sigma`` that is a variance component of the row's group
        (1 until a variance-component step scales the group): a row is down-weighted when its factor is
        above its group's, and given back (reinstated) it returns to its group's factor, not to 1 (a
        reinstated row at its a-priori sigma would weigh 1 / component^2 times its group's rows).
    """

    image_weight: NDArray[np.float64]
    image_sigma: NDArray[np.float64]
    control_sigma: NDArray[np.float64]
    term_sigma: list
    dropped_points: NDArray[np.bool_]
    fixed_images: NDArray[np.bool_]
    extra: dict = field(default_factory=dict)
    control_vc: NDArray[np.float64] | None = None
    term_vc: list | None = None

    def __post_init__(self) -> None:
        if self.control_vc is None:
            self.control_vc = np.ones_like(np.asarray(self.control_sigma, float))
        if self.term_vc is None:
            self.term_vc = [np.ones_like(np.asarray(f, float)) for f in self.term_sigma]

    def term_downweighted(self, t: int) -> NDArray[np.bool_]:
        """Rows of term ``t`` whose sigma factor is above their group's variance component (down-weighted)."""
        assert self.term_vc is not None
        return self.term_sigma[t] > self.term_vc[t] * (1.0 + 1e-9)

    def term_rows_out(self, term) -> NDArray[np.bool_]:
        """Rows of ``term`` out of the adjustment with their point: a point-observing term's (reference DTM
        heights) rows whose point is dropped (held fixed without its rays); none for other terms.

        Such a row's residual is where the point was left, not a measurement of the terrain: it gets
        :data:`OUT_FACTOR` in :func:`reweighted_problem`, so that it weighs nothing.
        """
        if not getattr(term, "uses_points", False):
            return np.zeros(term.n_obs_scalar, bool)
        if hasattr(term, "rows_out"):          # rows on several points (altimetry shots): the term's own rule
            return np.asarray(term.rows_out(np.asarray(self.dropped_points, bool)), bool)
        return np.asarray(self.dropped_points, bool)[np.asarray(term.point_index, np.int64)]

    def control_downweighted(self) -> NDArray[np.bool_]:
        """Control points whose sigma factor is above their group's variance component (down-weighted)."""
        assert self.control_vc is not None
        return self.control_sigma > self.control_vc * (1.0 + 1e-9)

    def restore_term(self, t: int, row: int) -> None:
        """Give row ``row`` of term ``t`` its group's weight back (its variance component, 1 without one)."""
        assert self.term_vc is not None
        self.term_sigma[t][row] = self.term_vc[t][row]

    def restore_control(self, k: int) -> None:
        """Give control point ``k`` its group's weight back (its variance component, 1 without one)."""
        assert self.control_vc is not None
        self.control_sigma[k] = self.control_vc[k]

    @classmethod
    def neutral(cls, problem: BundleProblem) -> "Weights":
        """No change: every factor 1, nothing removed (the base problem's own ``obs_weight`` kept)."""
        k = 0 if problem.priors is None else problem.priors.idx.size
        return cls(np.asarray(problem.obs_weight, float).copy(), np.ones(problem.obs.n), np.ones(k),
                   [np.ones(t.n_obs_scalar) for t in problem.terms], np.zeros(problem.n_points, bool),
                   np.zeros(problem.n_images, bool))

    def copy(self) -> "Weights":
        assert self.control_vc is not None and self.term_vc is not None
        return Weights(self.image_weight.copy(), self.image_sigma.copy(), self.control_sigma.copy(),
                       [t.copy() for t in self.term_sigma], self.dropped_points.copy(), self.fixed_images.copy(),
                       dict(self.extra), self.control_vc.copy(), [t.copy() for t in self.term_vc])


def reweighted_problem(base: BundleProblem, w: Weights, cam_params: NDArray | None = None,
                       points: NDArray | None = None, terms: list | None = None) -> BundleProblem:
    """``base`` with the weights ``w`` (module docstring), starting from ``cam_params`` / ``points``.

    Parameters
    ----------
    base : BundleProblem
        The problem as first given (a-priori sigmas).
    w : Weights
    cam_params, points : ndarray, optional
        Start values (e.g. the previous adjustment's); default the base problem's.
    terms : list, optional
        Camera-level terms replacing the base problem's (same rows), e.g. navigation observations
        with other offset/drift modes.
    """
    o = base.obs
    X = np.array(base.points if points is None else points, dtype=float)
    priors = base.priors
    if priors is not None and not np.all(w.control_sigma == 1.0):
        f = w.control_sigma
        assert priors.sigma is not None         # filled by PointPriors._validate
        priors = PointPriors(priors.idx, priors.xyz, priors.sigma * f[:, None],
                             None if priors.cov is None else priors.cov * (f * f)[:, None, None])
    drop = w.dropped_points.copy()
    if priors is not None:
        drop[priors.idx] = False          # a control point without rays is still determined by its prior
    if drop.any():
        idx = np.flatnonzero(drop)
        if priors is None:
            priors = PointPriors(idx, X[idx], np.zeros((idx.size, 3)))
        else:
            cov = None if priors.cov is None else np.concatenate([priors.cov, np.zeros((idx.size, 3, 3))])
            priors = PointPriors(np.concatenate([priors.idx, idx]), np.concatenate([priors.xyz, X[idx]]),
                                 np.concatenate([priors.sigma, np.zeros((idx.size, 3))]), cov)
    weight = np.where(drop[o.pt_idx], 0.0, w.image_weight)
    sigma = o.sigma * w.image_sigma[:, None]
    terms = list(base.terms) if terms is None else list(terms)
    if len(terms) != len(w.term_sigma):
        raise AdjustmentInputError(f"{len(w.term_sigma)} term weight vectors for {len(terms)} terms")
    # a point-observing row of a dropped point weighs nothing: its point stays where it was left
    factors = [np.where(w.term_rows_out(t), OUT_FACTOR * f, f) for t, f in zip(terms, w.term_sigma)]
    terms = [t if np.all(f == 1.0) else ScaledTerm(t, f) for t, f in zip(terms, factors)]
    free = np.asarray(base.cam_param_free, bool) & ~w.fixed_images[:, None]
    return dataclasses.replace(base, cam_params=np.array(base.cam_params if cam_params is None else cam_params),
                               points=X, obs=ImageObservations(o.cam_idx, o.pt_idx, o.xy, sigma), priors=priors,
                               terms=terms, cam_param_free=free, obs_weight=weight)
