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

from typing import Sequence

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
    offset, drift : {"fixed", "free", "observed"}, sequence of p of them, or (n_orbits, p) of them
        One mode for all parameters, one per parameter, or one per orbit and parameter (the
        two-stage offset/drift detection of :mod:`lunarmap.adjust.qc.offsets` frees single ones).
    offset_sigma, drift_sigma : (p,) float
        Sigma of the pseudo-observations when ``"observed"`` (units per parameter; drift per unit of ``s``).
    name : str
        Group name used in residual statistics.
    orbit_names : sequence of str, optional
        A label of every orbit (e.g. the run's navigation groups), for reports; default the orbit index.
    """

    def __init__(self, observed, sigma, orbit, s=None, offset: str | Sequence[str] | NDArray = "fixed",
                 drift: str | Sequence[str] | NDArray = "fixed",
                 offset_sigma=None, drift_sigma=None, name: str = "navigation", orbit_names=None):
        obs = np.asarray(observed, dtype=float)
        n, p = obs.shape
        sig = np.array(np.broadcast_to(np.asarray(sigma, dtype=float), (n, p)))
        if np.any(~(sig > 0)):
            raise AdjustmentInputError("navigation sigma must be > 0 (use inf for 'not observed')")
        used = np.isfinite(sig)
        if not np.all(np.isfinite(obs[used])):
            raise AdjustmentInputError(f"navigation observations: {int(np.sum(~np.isfinite(obs[used])))} NaN/inf "
                                       "values with a finite sigma")
        orbit = np.asarray(orbit, dtype=np.int64)
        if orbit.shape != (n,) or orbit.min() < 0:
            raise AdjustmentInputError("orbit must be (n_img,) non-negative integers")
        n_orbits = int(orbit.max()) + 1
        offset_modes = self._modes("offset", offset, p, n_orbits)
        drift_modes = self._modes("drift", drift, p, n_orbits)
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
        self.offset = offset if isinstance(offset, str) else offset_modes.copy()
        self.drift = drift if isinstance(drift, str) else drift_modes.copy()
        self.offset_sigma = self._pseudo_sigma("offset", offset_sigma, offset_modes, p)
        self.drift_sigma = self._pseudo_sigma("drift", drift_sigma, drift_modes, p)
        self.name = name
        if orbit_names is not None and len(orbit_names) != self.n_orbits:
            raise AdjustmentInputError(f"orbit_names needs {self.n_orbits} labels, got {len(orbit_names)}")
        self.orbit_names = [str(x) for x in orbit_names] if orbit_names is not None else \
            [str(k) for k in range(self.n_orbits)]
        self.n_extra = 2 * self.n_orbits * p   # [offsets (n_orb, p) | drifts (n_orb, p)]
        self.n_obs_scalar = int(used.sum()) + int(np.sum(offset_modes == "observed")) + \
            int(np.sum(drift_modes == "observed"))
        self._sigma = np.where(used, sig, np.inf)
        self._build()

    @staticmethod
    def _modes(what: str, mode, p: int, n_orbits: int) -> NDArray:
        """Modes as an ``(n_orbits, p)`` array."""
        modes = np.array([mode] * p if isinstance(mode, str) else list(mode), dtype=object)
        if modes.shape == (p,):
            modes = np.tile(modes, (n_orbits, 1))
        if modes.shape != (n_orbits, p) or any(m not in _MODES for m in modes.ravel()):
            raise AdjustmentInputError(f"{what} must be one of {_MODES}, a sequence of {p} of them or ({n_orbits}, "
                                       f"{p}) of them, got {mode!r}")
        return modes

    @staticmethod
    def _pseudo_sigma(what: str, sigma, modes: NDArray, p: int):
        observed = (modes == "observed").any(axis=0)
        if not observed.any():
            return None if sigma is None else np.broadcast_to(np.asarray(sigma, float), (p,))
        if sigma is None:
            raise AdjustmentInputError(f"'observed' {what} needs {what}_sigma")
        sig = np.array(np.broadcast_to(np.asarray(sigma, float), (p,)))
        if not np.all(np.isfinite(sig[observed]) & (sig[observed] > 0)):
            raise AdjustmentInputError(f"{what}_sigma must be finite and > 0 for the 'observed' parameters")
        return sig

    @property
    def sigma(self) -> NDArray:
        """``(n_img, p)`` a-priori sigmas (``inf`` where not observed)."""
        return self._sigma.copy()

    @property
    def observed(self) -> NDArray:
        """``(n_img, p)`` observed values (0 where not observed)."""
        return self.obs.copy()

    def replace(self, observed=None, sigma=None, offset=None, drift=None) -> "NavigationObservations":
        """A copy with other observations, sigmas or offset/drift modes (``(n_orbits, p)`` allowed)."""
        return NavigationObservations(self.obs if observed is None else observed,
                                      self._sigma if sigma is None else sigma, self.orbit, self.s,
                                      self.offset_modes if offset is None else offset,
                                      self.drift_modes if drift is None else drift,
                                      self.offset_sigma, self.drift_sigma, self.name, self.orbit_names)

    def row_table(self) -> dict:
        """What every row of :meth:`linearize` observes.

        Returns
        -------
        dict of (n_obs_scalar,) arrays
            ``kind`` (0 = navigation observation of an image parameter, 1 = offset, 2 = drift
            pseudo-observation), ``image`` (-1 for pseudo-observations), ``param``, ``orbit``.
        """
        n, p = self.obs.shape
        rows = self._rows
        kind = [np.zeros(rows.size, np.int64)]
        image = [rows // p]
        param = [rows % p]
        orbit = [self.orbit[rows // p]]
        for k, modes in ((1, self.offset_modes), (2, self.drift_modes)):
            j = np.flatnonzero((modes == "observed").ravel())
            kind.append(np.full(j.size, k))
            image.append(np.full(j.size, -1))
            param.append(j % p)
            orbit.append(j // p)
        return {"kind": np.concatenate(kind), "image": np.concatenate(image), "param": np.concatenate(param),
                "orbit": np.concatenate(orbit)}

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
            j = np.nonzero((modes == "observed").ravel())[0]
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
        f[:h] = (self.offset_modes != "fixed").ravel()
        f[h:] = (self.drift_modes != "fixed").ravel()
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
