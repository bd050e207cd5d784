"""Navigation observations (spacecraft position and attitude per image) grouped by orbit,
with per-orbit offset and drift.

DLR paper (``seeds/004``), Eqs. 2-3: every exterior-orientation parameter ``n`` of image
``j`` in orbit ``o`` is observed as

    value_jn = observed_jn + c_on + s_j d_on + e_jn,      e_jn ~ N(0, sigma_jn^2)

with a per-orbit offset ``c_on`` and drift ``d_on`` (``s_j``: time or along-orbit distance
of image ``j``).  Offsets and drifts are, per term, ``"fixed"`` (held at their initial value),
``"free"`` unknowns, or ``"observed"`` (unknowns with a zero-mean pseudo-observation of sigma
``offset_sigma`` / ``drift_sigma``).

The parameters are those of the image model (for :class:`FrameModel`: ``[w (radians), C]``),
so the attitude observation is the correction relative to the reference attitude ``R0``.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from ..errors import AdjustmentInputError

__all__ = ["NavigationObservations"]

_MODES = ("fixed", "free", "observed")


class NavigationObservations:
    """Weighted navigation observations of image parameters with per-orbit offset/drift.

    Parameters
    ----------
    observed : (n_img, p)
        Observed parameter values (units of the image model: radians, metres); NaN rows allowed
        only where ``sigma`` is ``inf`` (no observation).
    sigma : (n_img, p) or (p,)
        Standard deviations, same units; ``inf`` = that parameter is not observed.
    orbit : (n_img,) int
        Orbit (or camera group) of every image.
    s : (n_img,) float
        Along-orbit coordinate of every image (seconds or metres) for the drift.
    offset, drift : {"fixed", "free", "observed"}
    offset_sigma, drift_sigma : (p,) float
        Sigma of the pseudo-observations when ``"observed"`` (units per parameter; drift per unit of ``s``).
    name : str
        Group name used in residual statistics.
    """

    def __init__(self, observed, sigma, orbit, s=None, offset: str = "fixed", drift: str = "fixed",
                 offset_sigma=None, drift_sigma=None, name: str = "navigation"):
        obs = np.asarray(observed, dtype=float)
        n, p = obs.shape
        sig = np.array(np.broadcast_to(np.asarray(sigma, dtype=float), (n, p)))
        if offset not in _MODES or drift not in _MODES:
            raise AdjustmentInputError(f"offset/drift must be one of {_MODES}, got {offset!r}/{drift!r}")
        if np.any(~(sig > 0)):
            raise AdjustmentInputError("navigation sigma must be > 0 (use inf for 'not observed')")
        used = np.isfinite(sig)
        if not np.all(np.isfinite(obs[used])):
            raise AdjustmentInputError(f"navigation observations: {int(np.sum(~np.isfinite(obs[used])))} NaN/inf "
                                       "values with a finite sigma")
        orbit = np.asarray(orbit, dtype=np.int64)
        if orbit.shape != (n,) or orbit.min() < 0:
            raise AdjustmentInputError("orbit must be (n_img,) non-negative integers")
        self.s = np.zeros(n) if s is None else np.asarray(s, dtype=float)
        if self.s.shape != (n,) or not np.all(np.isfinite(self.s)):
            raise AdjustmentInputError("s must be (n_img,) finite values")
        self.obs = np.where(used, obs, 0.0)
        self.w = np.where(used, 1.0 / sig, 0.0)   # sqrt of weights
        self.used = used
        self.orbit = orbit
        self.n_orbits = int(orbit.max()) + 1
        self.p = p
        self.offset, self.drift = offset, drift
        self.offset_sigma = None if offset_sigma is None else np.broadcast_to(np.asarray(offset_sigma, float), (p,))
        self.drift_sigma = None if drift_sigma is None else np.broadcast_to(np.asarray(drift_sigma, float), (p,))
        if offset == "observed" and self.offset_sigma is None or drift == "observed" and self.drift_sigma is None:
            raise AdjustmentInputError("'observed' offset/drift needs offset_sigma/drift_sigma")
        self.name = name
        self.n_extra = 2 * self.n_orbits * p   # [offsets (n_orb, p) | drifts (n_orb, p)]
        self.n_obs_scalar = int(used.sum()) + (self.n_orbits * p if offset == "observed" else 0) + \
            (self.n_orbits * p if drift == "observed" else 0)
        self._build()

    def _build(self):
        n, p = self.obs.shape
        rows = np.nonzero(self.used.ravel())[0]
        img, par = rows // p, rows % p
        m = rows.size
        k = np.arange(m)
        w = self.w.ravel()[rows]
        ncr = n * p
        off_col = ncr + self.orbit[img] * p + par
        dr_col = ncr + self.n_orbits * p + self.orbit[img] * p + par
        r_ = [k, k, k]
        c_ = [rows, off_col, dr_col]
        v_ = [w, -w, -w * self.s[img]]
        nrow = m
        if self.offset == "observed":
            j = np.arange(self.n_orbits * p)
            r_.append(nrow + j)
            c_.append(ncr + j)
            v_.append(1.0 / np.tile(self.offset_sigma, self.n_orbits))
            nrow += j.size
        if self.drift == "observed":
            j = np.arange(self.n_orbits * p)
            r_.append(nrow + j)
            c_.append(ncr + self.n_orbits * p + j)
            v_.append(1.0 / np.tile(self.drift_sigma, self.n_orbits))
            nrow += j.size
        self._J = sp.csr_matrix((np.concatenate(v_), (np.concatenate(r_), np.concatenate(c_))),
                                shape=(nrow, ncr + self.n_extra))
        self._rows = rows

    def initial_extra(self) -> NDArray:
        return np.zeros(self.n_extra)

    def extra_free(self) -> NDArray[np.bool_]:
        f = np.zeros(self.n_extra, dtype=bool)
        h = self.n_orbits * self.p
        f[:h] = self.offset != "fixed"
        f[h:] = self.drift != "fixed"
        return f

    def observed_images(self) -> NDArray[np.bool_]:
        return self.used.any(axis=1)

    def offsets(self, extra: NDArray) -> NDArray:
        """Per-orbit offsets ``(n_orb, p)`` from this term's extra parameters."""
        return extra[: self.n_orbits * self.p].reshape(self.n_orbits, self.p)

    def drifts(self, extra: NDArray) -> NDArray:
        """Per-orbit drifts ``(n_orb, p)`` (parameter units per unit of ``s``)."""
        return extra[self.n_orbits * self.p:].reshape(self.n_orbits, self.p)

    def linearize(self, cam_params: NDArray, extra: NDArray):
        """Whitened residuals (value - observed - offset - s drift) / sigma and their Jacobian (linear model)."""
        x = np.concatenate([cam_params.ravel(), extra])
        rows = self._rows
        img = rows // self.p
        r = self._J @ x
        r[: rows.size] -= self.obs.ravel()[rows] * self.w.ravel()[rows]
        return r, self._J
