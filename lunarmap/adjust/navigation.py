"""Navigation observations (spacecraft position and attitude per image) grouped by orbit,
with per-orbit offset and drift.

DLR paper (``seeds/004``), Eqs. 2-3: every exterior-orientation parameter ``n`` of image
``j`` in orbit ``o`` is observed as

    value_jn = observed_jn + c_on + s_j d_on + e_jn,      e_jn ~ N(0, sigma_jn^2)

with a per-orbit offset ``c_on`` and drift ``d_on`` (``s_j``: time or along-orbit distance
of image ``j``).  Offsets and drifts are, per parameter ``n`` (or for all at once), ``"fixed"``
(held at their initial value), ``"free"`` unknowns, or ``"observed"`` (unknowns with a zero-mean
pseudo-observation of sigma ``offset_sigma`` / ``drift_sigma``: random effects drawn per orbit).

Freeing attitude AND position offsets of a narrow-angle frame camera leaves the split between
them to perspective effects only: for a Clementine-like block the posterior sigma of the
positions grows to kilometres and of the attitudes to tenths of a degree (vs 10 m and 0.001
degree navigation noise), where the linearised covariance no longer describes the estimator
(second-order terms of a 0.2 degree rotation at 400 km reach half a pixel).  The DLR paper frees
only the offsets it detects (Section 4.3); ``"observed"`` with realistic sigmas is the other
well-posed choice.

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
    offset, drift : {"fixed", "free", "observed"} or sequence of p of them
        One mode for all parameters, or one per parameter.
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
        offset_modes = self._modes("offset", offset, p)
        drift_modes = self._modes("drift", drift, p)
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
        self.offset_modes, self.drift_modes = offset_modes, drift_modes
        self.offset = offset if isinstance(offset, str) else tuple(offset_modes)
        self.drift = drift if isinstance(drift, str) else tuple(drift_modes)
        self.offset_sigma = self._pseudo_sigma("offset", offset_sigma, offset_modes, p)
        self.drift_sigma = self._pseudo_sigma("drift", drift_sigma, drift_modes, p)
        self.name = name
        self.n_extra = 2 * self.n_orbits * p   # [offsets (n_orb, p) | drifts (n_orb, p)]
        self.n_obs_scalar = int(used.sum()) + self.n_orbits * int(np.sum(offset_modes == "observed")) + \
            self.n_orbits * int(np.sum(drift_modes == "observed"))
        self._build()

    @staticmethod
    def _modes(what: str, mode, p: int) -> NDArray:
        modes = np.array([mode] * p if isinstance(mode, str) else list(mode), dtype=object)
        if modes.shape != (p,) or any(m not in _MODES for m in modes):
            raise AdjustmentInputError(f"{what} must be one of {_MODES} or a sequence of {p} of them, got {mode!r}")
        return modes

    @staticmethod
    def _pseudo_sigma(what: str, sigma, modes: NDArray, p: int):
        observed = modes == "observed"
        if not observed.any():
            return None if sigma is None else np.broadcast_to(np.asarray(sigma, float), (p,))
        if sigma is None:
            raise AdjustmentInputError(f"'observed' {what} needs {what}_sigma")
        sig = np.array(np.broadcast_to(np.asarray(sigma, float), (p,)))
        if not np.all(np.isfinite(sig[observed]) & (sig[observed] > 0)):
            raise AdjustmentInputError(f"{what}_sigma must be finite and > 0 for the 'observed' parameters")
        return sig

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
        for base, modes, sig in ((ncr, self.offset_modes, self.offset_sigma),
                                 (ncr + self.n_orbits * p, self.drift_modes, self.drift_sigma)):
            # zero-mean pseudo-observations of the observed offsets/drifts, orbit-major order
            j = np.nonzero(np.tile(modes == "observed", self.n_orbits))[0]
            if j.size:
                r_.append(nrow + np.arange(j.size))
                c_.append(base + j)
                v_.append(1.0 / np.tile(sig, self.n_orbits)[j])
                nrow += j.size
        self._J = sp.csr_matrix((np.concatenate(v_), (np.concatenate(r_), np.concatenate(c_))),
                                shape=(nrow, ncr + self.n_extra))
        self._rows = rows

    def initial_extra(self) -> NDArray:
        return np.zeros(self.n_extra)

    def extra_free(self) -> NDArray[np.bool_]:
        f = np.zeros(self.n_extra, dtype=bool)
        h = self.n_orbits * self.p
        f[:h] = np.tile(self.offset_modes != "fixed", self.n_orbits)
        f[h:] = np.tile(self.drift_modes != "fixed", self.n_orbits)
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
        r = self._J @ x
        r[: rows.size] -= self.obs.ravel()[rows] * self.w.ravel()[rows]
        return r, self._J
