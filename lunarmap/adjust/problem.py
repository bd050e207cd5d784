"""The inputs of a block adjustment: image observations, point priors, camera-level terms.

A :class:`BundleProblem` bundles

* an image model (:class:`ImageModel`: :class:`~lunarmap.adjust.sensors.SensorImageModel` over the
  project's sensor models, or the BAL :class:`~lunarmap.adjust.collinearity.FrameModel` kept for
  benchmarks);
* initial image parameters ``(n_img, n_params)`` and points ``(n_pt, 3)``;
* :class:`ImageObservations` (pixels, with sigma in pixels);
* :class:`PointPriors` (control points: observed coordinates with sigma,
  ``sigma = 0`` holds the coordinate fixed);
* optional camera-level terms (navigation observations, per-orbit offsets
  and drifts) implementing :class:`ReducedTerm`.

Per-observation weight factors (``obs_weight``) may be changed between
iterations (robust reweighting, data snooping); see ``solve(reweight=...)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from ..errors import AdjustmentInputError, InsufficientObservationsError, UnobservedParameterError

__all__ = ["ImageModel", "ImageObservations", "PointPriors", "ReducedTerm", "BundleProblem"]


def _finite(name: str, a: NDArray) -> None:
    bad = ~np.isfinite(a)
    if bad.any():
        first = int(np.argwhere(bad)[0][0])
        raise AdjustmentInputError(f"{name}: {int(bad.sum())} non-finite value(s) (NaN/inf), first at row {first}")


class ImageModel(Protocol):
    """What the solver needs of the images: parameters, projection and partials of observations.

    Attributes
    ----------
    n_images, n_params : int
        Images, and parameters per image (images with fewer parameters are padded).
    param_names : tuple of str
        Names of the ``n_params`` columns.
    param_mask : ndarray (n_images, n_params) bool
        Which parameters exist (padding columns are ``False`` and held fixed).
    """

    n_params: int
    param_names: tuple[str, ...]

    @property
    def n_images(self) -> int: ...

    @property
    def param_mask(self) -> NDArray[np.bool_]: ...

    def project(self, params: NDArray, cam_idx: NDArray, X: NDArray) -> NDArray:
        """Image coordinates ``(n, 2)`` of observations of images ``cam_idx`` of points ``X (n, 3)``."""

    def linearize(self, params: NDArray, cam_idx: NDArray, X: NDArray) -> tuple[NDArray, NDArray, NDArray]:
        """Image coordinates, ``d/d params (n, 2, n_params)`` and ``d/d X (n, 2, 3)``."""

    def project_indexed(self, params: NDArray, cam_idx: NDArray, points: NDArray, pt_idx: NDArray) -> NDArray:
        """:meth:`project` of ``points[pt_idx]`` (implementations may avoid the gather)."""

    def linearize_indexed(self, params: NDArray, cam_idx: NDArray, points: NDArray,
                          pt_idx: NDArray) -> tuple[NDArray, NDArray, NDArray]:
        """:meth:`linearize` of ``points[pt_idx]``."""

    def initial_points(self, params: NDArray, cam_idx: NDArray, pt_idx: NDArray, xy: NDArray, n_pt: int,
                       height: float = 0.0) -> NDArray:
        """Start values ``(n_pt, 3)`` of the points from their measurements (closed form, no iteration)."""


@dataclass
class ImageObservations:
    """Image measurements.

    Attributes
    ----------
    cam_idx, pt_idx : (n,) int
        Image and point of each measurement.
    xy : (n, 2) float
        Measured image coordinates, pixels (in the image model's convention).
    sigma : (n, 2) float
        A-priori standard deviations, pixels (broadcast from a scalar or per-image array by
        :meth:`BundleProblem.__post_init__`).
    """

    cam_idx: NDArray[np.int64]
    pt_idx: NDArray[np.int64]
    xy: NDArray[np.float64]
    sigma: Any = 1.0

    @property
    def n(self) -> int:
        return int(self.cam_idx.size)


@dataclass
class PointPriors:
    """Control points: observed object coordinates (length unit of the block) with sigma or covariance.

    Attributes
    ----------
    idx : (k,) int
        Points that are controlled.
    xyz : (k, 3) float
        Observed coordinates (body-fixed, length unit of the block, e.g. metres).
    sigma : (k, 3) or (k,) float, optional
        Per-axis standard deviations, same unit; a zero sigma holds that point fixed (all three
        coordinates).  Derived from ``cov`` when that is given.
    cov : (k, 3, 3) float, optional
        Full covariance (unit squared), e.g. propagated from latitude/longitude/height sigmas
        (:func:`lunarmap.adjust.control_points.lonlat_priors`); an all-zero matrix holds the point fixed.
    """

    idx: NDArray[np.int64]
    xyz: NDArray[np.float64]
    sigma: NDArray[np.float64] | None = None
    cov: NDArray[np.float64] | None = None

    @property
    def fixed(self) -> NDArray[np.bool_]:
        return np.all(self.sigma == 0.0, axis=1)

    @property
    def correlated(self) -> bool:
        """True if some covariance has non-zero off-diagonal terms (not expressible by ``sigma``)."""
        if self.cov is None:
            return False
        off = self.cov - np.einsum("kii->ki", self.cov)[:, :, None] * np.eye(3)
        return bool(np.any(off != 0.0))

    def sqrt_weight(self) -> NDArray[np.float64]:
        """``W (k, 3, 3)`` with ``W^T W = C^-1`` (inverse length unit); zero for fixed points.

        Whitened control residuals are ``W (X - xyz)``; ``W = L^-1`` with ``C = L L^T`` (Cholesky).
        """
        k = self.xyz.shape[0]
        W = np.zeros((k, 3, 3))
        free = ~self.fixed
        if self.cov is None:
            assert self.sigma is not None, "priors without sigma or cov"      # _validate
            W[free] = np.eye(3) / self.sigma[free][:, :, None]
        elif free.any():
            L = np.linalg.cholesky(self.cov[free])
            W[free] = np.linalg.inv(L)
        return W

    def _validate(self, n_pt: int) -> None:
        self.idx = np.asarray(self.idx, dtype=np.int64)
        self.xyz = np.asarray(self.xyz, dtype=float).reshape(-1, 3)
        k = self.xyz.shape[0]
        if self.idx.shape != (k,):
            raise AdjustmentInputError(f"control points: idx has shape {self.idx.shape}, xyz has {k} rows")
        _finite("control point coordinates", self.xyz)
        if self.cov is not None:
            cov = np.asarray(self.cov, dtype=float)
            if cov.shape != (k, 3, 3):
                raise AdjustmentInputError(f"control point covariance must be ({k}, 3, 3), got {cov.shape}")
            _finite("control point covariance", cov.reshape(k, 9))
            if not np.allclose(cov, np.swapaxes(cov, 1, 2), rtol=1e-12, atol=0.0):
                raise AdjustmentInputError("control point covariance matrices must be symmetric")
            zero = np.all(cov.reshape(k, 9) == 0.0, axis=1)
            ev = np.linalg.eigvalsh(cov[~zero]) if (~zero).any() else np.ones((0, 3))
            if np.any(ev <= 0.0):
                bad = int(np.nonzero(~zero)[0][np.argmax(np.any(ev <= 0.0, axis=1))])
                raise AdjustmentInputError(f"control point covariance of point {int(self.idx[bad])} is not positive "
                                           "definite (use an all-zero matrix to hold a point fixed)")
            self.cov = cov
            self.sigma = np.sqrt(np.einsum("kii->ki", cov))
        elif self.sigma is None:
            raise AdjustmentInputError("control points need sigma or cov")
        sig = np.asarray(self.sigma, dtype=float)
        self.sigma = np.array(np.broadcast_to(sig.reshape(-1, 1) if sig.ndim == 1 else sig, self.xyz.shape))
        _finite("control point sigma", self.sigma)
        if self.idx.size and (self.idx.min() < 0 or self.idx.max() >= n_pt):
            raise AdjustmentInputError(f"control point index out of range [0, {n_pt})")
        if np.any(self.sigma < 0):
            raise AdjustmentInputError("control point sigma must be >= 0 (0 = fixed)")
        if np.any((self.sigma == 0).any(axis=1) & ~self.fixed):
            raise AdjustmentInputError("control point sigma: zero for some but not all axes of a point "
                                       "(0 holds the whole point fixed)")
        if np.unique(self.idx).size != self.idx.size:
            raise AdjustmentInputError("control point indices repeat")


class ReducedTerm(Protocol):
    """Observations that involve only image parameters and extra parameters (navigation data).

    The reduced unknown vector is ``[image params (n_img * p) | extra (n_extra)]``.
    """

    n_extra: int
    n_obs_scalar: int

    def initial_extra(self) -> NDArray[np.float64]: ...

    def linearize(self, cam_params: NDArray, extra: NDArray) -> tuple[NDArray, sp.csr_matrix]:
        """Whitened residuals ``(m,)`` and their whitened Jacobian ``(m, n_red)``."""
        ...

    def extra_free(self) -> NDArray[np.bool_]: ...

    def observed_images(self) -> NDArray[np.bool_]:
        """``(n_img,)`` True for images whose parameters this term observes."""
        ...


@dataclass
class BundleProblem:
    """A complete adjustment problem; validated on construction."""

    model: ImageModel
    cam_params: NDArray[np.float64]
    points: NDArray[np.float64]
    obs: ImageObservations
    priors: PointPriors | None = None
    terms: list = field(default_factory=list)
    cam_param_free: NDArray[np.bool_] | None = None
    obs_weight: NDArray[np.float64] | None = None

    def __post_init__(self):
        self.cam_params = np.array(self.cam_params, dtype=float)
        self.points = np.array(self.points, dtype=float)
        o = self.obs
        o.cam_idx = np.asarray(o.cam_idx, dtype=np.int64)
        o.pt_idx = np.asarray(o.pt_idx, dtype=np.int64)
        o.xy = np.asarray(o.xy, dtype=float)
        n_img, p = self.cam_params.shape
        if p != self.model.n_params:
            raise AdjustmentInputError(f"cam_params has {p} columns, the image model needs {self.model.n_params}")
        n_model = self.model.n_images
        if n_model != n_img:
            raise AdjustmentInputError(f"cam_params has {n_img} rows but the image model describes {n_model} images")
        if self.points.ndim != 2 or self.points.shape[1] != 3:
            raise AdjustmentInputError(f"points must be (n, 3), got {self.points.shape}")
        n_pt = self.points.shape[0]
        if o.xy.shape != (o.n, 2) or o.pt_idx.shape != (o.n,):
            raise AdjustmentInputError("image observations: cam_idx, pt_idx (n,) and xy (n, 2) must agree")
        _finite("image observations xy", o.xy)
        _finite("initial image parameters", self.cam_params)
        _finite("initial points", self.points)
        for name, idx, top in (("cam_idx", o.cam_idx, n_img), ("pt_idx", o.pt_idx, n_pt)):
            if idx.size and (idx.min() < 0 or idx.max() >= top):
                raise AdjustmentInputError(f"image observations: {name} out of range [0, {top})")
        sig = np.asarray(o.sigma, dtype=float)
        if sig.ndim == 0:
            sig = np.full((o.n, 2), float(sig))
        elif sig.shape == (o.n,):
            sig = np.repeat(sig[:, None], 2, axis=1)
        elif sig.shape == (n_img,):  # one sigma per image (camera group)
            sig = np.repeat(sig[o.cam_idx][:, None], 2, axis=1)
        elif sig.shape != (o.n, 2):
            raise AdjustmentInputError(f"image observation sigma has shape {sig.shape}; expected scalar, "
                                       f"({o.n},), ({n_img},) or ({o.n}, 2)")
        o.sigma = np.array(sig, dtype=float)
        _finite("image observation sigma", o.sigma)
        if np.any(o.sigma <= 0):
            raise AdjustmentInputError("image observation sigma must be > 0 pixels")
        if self.priors is not None:
            self.priors._validate(n_pt)
        # padding columns of the image model never move, whatever the caller frees
        mask = np.asarray(self.model.param_mask, dtype=bool).reshape(n_img, p)
        if self.cam_param_free is None:
            self.cam_param_free = mask.copy()
        self.cam_param_free = np.asarray(self.cam_param_free, dtype=bool).reshape(n_img, p) & mask
        if self.obs_weight is None:
            self.obs_weight = np.ones(o.n)
        self._check_observability()

    @property
    def n_images(self) -> int:
        return self.cam_params.shape[0]

    @property
    def n_points(self) -> int:
        return self.points.shape[0]

    def point_fixed(self) -> NDArray[np.bool_]:
        fixed = np.zeros(self.n_points, dtype=bool)
        if self.priors is not None:
            fixed[self.priors.idx[self.priors.fixed]] = True
        return fixed

    def n_unknowns(self) -> int:
        assert self.cam_param_free is not None      # set by __post_init__
        n = int(self.cam_param_free.sum()) + 3 * int((~self.point_fixed()).sum())
        return n + sum(int(np.sum(t.extra_free())) for t in self.terms)

    def n_observations(self) -> int:
        """Scalar observations: 2 per image measurement, 3 per weighted control point, plus camera-level terms."""
        n = 2 * self.obs.n
        if self.priors is not None:
            n += 3 * int((~self.priors.fixed).sum())
        return n + sum(int(t.n_obs_scalar) for t in self.terms)

    def _check_observability(self) -> None:
        o = self.obs
        per_img = np.bincount(o.cam_idx, minlength=self.n_images)
        has_term = np.zeros(self.n_images, dtype=bool)
        for t in self.terms:
            has_term |= t.observed_images()
        assert self.cam_param_free is not None      # set by __post_init__
        free_img = self.cam_param_free.any(axis=1)
        lonely = np.nonzero((per_img == 0) & free_img & ~has_term)[0]
        if lonely.size:
            raise UnobservedParameterError(
                f"{lonely.size} image(s) have no observations but free parameters, first: image {int(lonely[0])}")
        per_pt = np.bincount(o.pt_idx, minlength=self.n_points)
        free_pt = ~self.point_fixed()
        weak = np.nonzero((per_pt < 2) & free_pt)[0]
        if self.priors is not None:
            weak = np.setdiff1d(weak, self.priors.idx[(per_pt[self.priors.idx] >= 1)])
        if weak.size:
            raise UnobservedParameterError(
                f"{weak.size} free point(s) are measured in fewer than 2 images, first: point {int(weak[0])} "
                f"({int(per_pt[weak[0]])} measurement(s))")
        n_u, n_o = self.n_unknowns(), self.n_observations()
        if n_o < n_u:
            raise InsufficientObservationsError(
                f"{n_o} scalar observations for {n_u} unknowns: too few observations (redundancy {n_o - n_u})")
