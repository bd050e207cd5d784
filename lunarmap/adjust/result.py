"""Results of a block adjustment as xarray Datasets.

``AdjustmentResult`` holds the adjusted unknowns, a-posteriori sigma0, the
iteration trace and residuals; :meth:`AdjustmentResult.precision` computes the
posterior covariances (:mod:`.precision`).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import xarray as xr
from numpy.typing import NDArray

__all__ = ["AdjustmentResult"]


#: Guards the lazy posterior precision of every result (a module lock: results must pickle).
_PRECISION_LOCK = threading.RLock()


@dataclass
class AdjustmentResult:
    """Outcome of :func:`lunarmap.adjust.solve`."""

    problem: Any
    state: Any
    structure: Any
    cost_initial: float
    iterations: int
    accepted: int
    converged: bool
    message: str
    trace: list
    solve_seconds: float
    setup_seconds: float
    options: Any
    free_red: NDArray
    #: how the reduced camera system was solved ("direct" or "pcg", :class:`~lunarmap.adjust.SolverOptions`)
    linear_solver: str = "direct"
    #: CG iterations of every step (empty for the direct solver)
    linear_iterations: list = field(default_factory=list)
    _precision: Any = field(default=None, repr=False)

    # --- unknowns --------------------------------------------------------
    @property
    def cam_params(self) -> NDArray:
        return self.state.cam_params

    @property
    def points(self) -> NDArray:
        return self.state.points

    @property
    def extra(self) -> NDArray:
        return self.state.extra

    @property
    def cost(self) -> float:
        """Final cost, half the weighted sum of squared residuals (dimensionless)."""
        return float(self.state.cost)

    @property
    def redundancy(self) -> int:
        """Scalar observations minus unknowns (observations with weight 0 do not count)."""
        n_removed = 2 * int(np.sum(self.state.obs_weight == 0))
        return self.problem.n_observations() - n_removed - self.problem.n_unknowns()

    @property
    def sigma0(self) -> float:
        """A-posteriori standard deviation of unit weight, ``sqrt(v^T P v / r)`` (dimensionless).

        NaN when the block has no redundancy (``r <= 0``: quality control can remove that many observations).
        """
        r = self.redundancy
        return float(np.sqrt(2.0 * self.cost / r)) if r > 0 else float("nan")

    # --- residuals -------------------------------------------------------
    def image_residuals(self) -> NDArray:
        """Image residuals ``projected - observed``, pixels, ``(n_obs, 2)``."""
        o = self.problem.obs
        x = self.problem.model.project(self.cam_params, o.cam_idx, self.points[o.pt_idx])
        return x - o.xy

    def rms_px(self) -> float:
        """RMS over observations of the 2-D image residual norm, pixels."""
        v = self.image_residuals()
        return float(np.sqrt(np.mean(np.sum(v * v, axis=1))))

    def group_quadratic_forms(self) -> dict[str, tuple[float, int]]:
        """Weighted sum of squared residuals ``v^T P v`` and number of scalar observations per group.

        Groups: ``image``, ``control``, and each camera-level term by its ``name``.
        Divide by the group's summed redundancy numbers for a group variance factor
        (variance-component estimation).
        """
        from .normal import image_residuals, prior_terms, term_residuals

        out = {}
        r = image_residuals(self.problem, self.state)
        out["image"] = (float(np.sum(r * r)), int(2 * np.sum(self.state.obs_weight > 0)))
        pt = prior_terms(self.problem, self.points)
        if pt is not None:
            out["control"] = (float(np.sum(pt[1] ** 2)), int(pt[1].size))
        for i, t in enumerate(self.problem.terms):
            rx = term_residuals(t, self.cam_params, self._term_extra(i), self.points)
            out[getattr(t, "name", f"term{i}")] = (float(rx @ rx), int(rx.size))
        return out

    def _term_extra(self, i: int) -> NDArray:
        s = sum(t.n_extra for t in self.problem.terms[:i])
        return self.state.extra[s:s + self.problem.terms[i].n_extra]

    # --- precision -------------------------------------------------------
    def precision(self, method: str = "auto"):
        """Posterior precision (computed once): see :func:`lunarmap.adjust.precision.posterior_precision`."""
        if self._precision is None:
            from .precision import posterior_precision

            with _PRECISION_LOCK:   # computed once even when threads ask at the same time
                if self._precision is None:
                    self._precision = posterior_precision(self, method=method, redundancy=True)
        return self._precision

    # --- datasets --------------------------------------------------------
    def images_dataset(self, with_precision: bool = False) -> xr.Dataset:
        """Adjusted image parameters (units of the image model) and, optionally, their sigma and 6x6 covariances."""
        names = list(getattr(self.problem.model, "param_names", [f"p{i}" for i in range(self.cam_params.shape[1])]))
        ds = xr.Dataset({"params": (("image", "param"), self.cam_params)},
                        coords={"image": np.arange(self.cam_params.shape[0]), "param": names})
        if with_precision:
            pr = self.precision()
            ds["sigma"] = (("image", "param"), np.sqrt(np.diagonal(pr.cam_cov, axis1=1, axis2=2)))
            ds["covariance"] = (("image", "param", "param2"), pr.cam_cov)
        ds.attrs.update(sigma0=self.sigma0, redundancy=self.redundancy, iterations=self.iterations,
                        converged=int(self.converged), message=self.message)
        return ds

    def points_dataset(self, with_precision: bool = False) -> xr.Dataset:
        """Adjusted points (length unit of the block) and, optionally, sigma and 3x3 covariances."""
        ds = xr.Dataset({"xyz": (("point", "axis"), self.points)},
                        coords={"point": np.arange(self.points.shape[0]), "axis": ["x", "y", "z"]})
        if with_precision:
            pr = self.precision()
            ds["sigma"] = (("point", "axis"), np.sqrt(np.diagonal(pr.pt_cov, axis1=1, axis2=2)))
            ds["covariance"] = (("point", "axis", "axis2"), pr.pt_cov)
        ds.attrs.update(sigma0=self.sigma0)
        return ds

    def residuals_dataset(self) -> xr.Dataset:
        """Image residuals (pixels), normalised residuals, weights and, if computed, redundancy numbers."""
        o = self.problem.obs
        v = self.image_residuals()
        ds = xr.Dataset(
            {"residual": (("obs", "coord"), v), "normalized": (("obs", "coord"), v / o.sigma),
             "weight_factor": ("obs", self.state.obs_weight), "image": ("obs", o.cam_idx), "point": ("obs", o.pt_idx)},
            coords={"obs": np.arange(o.n), "coord": ["x", "y"]})
        if self._precision is not None and self._precision.redundancy_numbers is not None:
            ds["redundancy_number"] = (("obs", "coord"), self._precision.redundancy_numbers)
        ds.attrs.update(rms_px=self.rms_px(), sigma0=self.sigma0)
        return ds
