"""Two-stage detection of per-orbit offsets and drifts of the navigation (DLR paper, ``seeds/004``, section 4.3).

The navigation of an orbit may be off by an offset ``c`` and a drift ``d`` per parameter (Eqs. 3-4:
``value = observed + c + s d``, ``s`` the along-orbit coordinate). Freeing all of them at once is
ill-posed for a narrow camera (an attitude offset and a position offset move the images almost
alike), so the paper finds the ones that matter in stages:

1. ``"times 1"``: an adjustment with no offsets or drifts; the corrections it makes to the
   navigation are regressed, per orbit and parameter, on ``c`` and ``c + s d`` (Eqs. 5-6, weights
   of the navigation observations, standard deviations from the fit's own scatter). Those larger
   than ``k1`` times their standard deviation are candidates (the paper: ``k1 = 1``; a drift that
   is not significant is dropped and the offset alone tested). ``stage1="free"`` instead frees all
   offsets (and drifts) in this first adjustment and tests their posterior standard deviations;
2. ``"times 2"``: an adjustment with the candidates as free unknowns; those larger than ``k2`` times
   their posterior standard deviation are kept;
3. ``"results"``: the final adjustment with only the kept ones free.

Every round is reported (Tables 6, 7 and 10 of the paper): value and standard deviation of every
candidate, and which were kept.
"""

from __future__ import annotations

import numpy as np
import xarray as xr
from numpy.typing import NDArray

from ...errors import QualityControlInputError
from ..navigation import NavigationObservations
from ..solver import SolverOptions
from .ledger import Decision, Ledger

__all__ = ["offset_drift_step"]


def _set_term(ledger: Ledger, t: int, new: NavigationObservations) -> None:
    """Replace term ``t``, keeping the sigma factors of its image rows (pseudo-observation rows reset)."""
    old = ledger.terms[t]
    n_img_rows = int(old.used.sum())
    f = np.ones(new.n_obs_scalar)
    f[:n_img_rows] = ledger.weights.term_sigma[t][:n_img_rows]
    ledger.terms[t] = new
    ledger.weights.term_sigma[t] = f


def _extra_slice(ledger: Ledger, t: int) -> slice:
    s0 = sum(term.n_extra for term in ledger.terms[:t])
    return slice(s0, s0 + ledger.terms[t].n_extra)


def _posterior(ledger: Ledger, t: int) -> tuple[NDArray, NDArray, NDArray, NDArray]:
    """Offsets, drifts (n_orb, p) and their posterior sigmas from the last adjustment."""
    res = ledger.result
    nav = ledger.terms[t]
    sl = _extra_slice(ledger, t)
    e = res.extra[sl]
    sig = np.sqrt(np.clip(np.diag(res.precision().extra_cov)[sl], 0.0, None))
    h = nav.n_orbits * nav.p
    return (e[:h].reshape(nav.n_orbits, nav.p), e[h:].reshape(nav.n_orbits, nav.p),
            sig[:h].reshape(nav.n_orbits, nav.p), sig[h:].reshape(nav.n_orbits, nav.p))


def _regress(ledger: Ledger, t: int, drifts: bool, k1: float):
    """Stage 1 of the paper: offsets (and drifts) of the navigation corrections per orbit and parameter."""
    res = ledger.result
    nav = ledger.terms[t]
    n_orb, p = nav.n_orbits, nav.p
    # a-priori sigmas with the current factors of the image rows (rows are the used entries, row-major)
    fac = np.ones(nav.used.shape)
    fac[nav.used] = ledger.weights.term_sigma[t][:int(nav.used.sum())]
    sigma = nav.sigma * fac
    corr = res.cam_params - nav.observed
    vals = np.zeros((2, n_orb, p))
    sigs = np.full((2, n_orb, p), np.inf)
    for o in range(n_orb):
        for j in range(p):
            m = (nav.orbit == o) & nav.used[:, j]
            if m.sum() < 2:
                continue
            e, s, wgt = corr[m, j], nav.s[m], 1.0 / sigma[m, j] ** 2
            for with_drift in ((True, False) if drifts and m.sum() >= 3 else (False,)):
                A = np.column_stack([np.ones(m.sum()), s]) if with_drift else np.ones((m.sum(), 1))
                N = A.T @ (A * wgt[:, None])
                x = np.linalg.solve(N, A.T @ (wgt * e))
                v = e - A @ x
                dof = m.sum() - A.shape[1]
                s0sq = float(wgt @ (v * v)) / dof if dof > 0 else 1.0
                cov = np.linalg.inv(N) * s0sq
                sx = np.sqrt(np.clip(np.diag(cov), 0.0, None))
                if with_drift:
                    if abs(x[1]) > k1 * sx[1]:
                        vals[:, o, j], sigs[:, o, j] = x, sx
                        break
                    continue        # the drift is not significant: test the offset alone (Eq. 5)
                vals[0, o, j], sigs[0, o, j] = x[0], sx[0]
    return vals, sigs


def _table(name: str, cands: NDArray, vals: NDArray, sigs: NDArray, free: NDArray, keep: NDArray,
           param_names) -> xr.Dataset:
    k, o, j = np.nonzero(cands)
    return xr.Dataset({"orbit": ("row", o), "param": ("row", np.array([param_names[x] for x in j], dtype=object)),
                       "kind": ("row", np.array(["offset", "drift"], dtype=object)[k]),
                       "value": ("row", vals[k, o, j]), "sigma": ("row", sigs[k, o, j]),
                       "free": ("row", free[k, o, j]), "significant": ("row", keep[k, o, j])},
                      attrs={"round": name})


def offset_drift_step(ledger: Ledger, term: int = 0, k1: float = 1.0, k2: float = 3.0, drifts: bool = True,
                      stage1: str = "residuals", options: SolverOptions | None = None) -> dict:
    """Find the significant per-orbit offsets and drifts of navigation term ``term`` (module docstring).

    The term is left with the kept ones free (the others fixed at zero), for the steps that follow.

    Returns
    -------
    dict
        ``rounds``: list of xarray.Dataset, one per round (rows = candidates: orbit, param, kind,
        value, sigma, free, significant); ``kept``: ``(2, n_orbits, p)`` bool (offsets, drifts).

    Raises
    ------
    QualityControlInputError
        The term is not a :class:`~lunarmap.adjust.navigation.NavigationObservations`, a limit <= 0,
        an unknown ``stage1``.
    """
    if not (0 <= term < len(ledger.terms)) or not isinstance(ledger.terms[term], NavigationObservations):
        raise QualityControlInputError(f"term {term} of the block is not a NavigationObservations term: offsets and "
                                       "drifts belong to navigation observations")
    if not (k1 > 0 and k2 > 0):
        raise QualityControlInputError(f"the offset/drift test limits must be > 0, got {k1!r}, {k2!r}")
    if stage1 not in ("residuals", "free"):
        raise QualityControlInputError(f"stage1 must be 'residuals' or 'free', got {stage1!r}")
    nav = ledger.terms[term]
    n_orb, p = nav.n_orbits, nav.p
    names = list(getattr(ledger.base.model, "param_names", [f"p{j}" for j in range(p)]))
    observed = np.zeros((n_orb, p), bool)
    for o in range(n_orb):
        observed[o] = nav.used[nav.orbit == o].any(axis=0)
    rounds = []

    def modes(sel: NDArray) -> NDArray:
        return np.where(sel, "free", "fixed").astype(object)

    # stage 1
    if stage1 == "residuals":
        _set_term(ledger, term, nav.replace(offset="fixed", drift="fixed"))
        ledger.adjust(options)
        vals, sigs = _regress(ledger, term, drifts, k1)
        free = np.zeros((2, n_orb, p), bool)
        cands = np.isfinite(sigs) & (np.abs(vals) > k1 * sigs)
        shown = np.isfinite(sigs) & (vals != 0)
    else:
        free = np.stack([observed, observed & drifts])
        _set_term(ledger, term, nav.replace(offset=modes(free[0]), drift=modes(free[1])))
        ledger.adjust(options)
        c, d, sc, sd = _posterior(ledger, term)
        vals, sigs = np.stack([c, d]), np.stack([sc, sd])
        cands = free & (np.abs(vals) > k1 * sigs)
        shown = free
    rounds.append(_table("times 1", shown, vals, sigs, free, cands, names))
    # stage 2: the candidates free
    _set_term(ledger, term, nav.replace(offset=modes(cands[0]), drift=modes(cands[1])))
    ledger.adjust(options)
    c, d, sc, sd = _posterior(ledger, term)
    vals, sigs = np.stack([c, d]), np.stack([sc, sd])
    kept = cands & (np.abs(vals) > k2 * sigs)
    rounds.append(_table("times 2", cands, vals, sigs, cands, kept, names))
    # stage 3: only the kept ones
    _set_term(ledger, term, nav.replace(offset=modes(kept[0]), drift=modes(kept[1])))
    ledger.adjust(options)
    c, d, sc, sd = _posterior(ledger, term)
    vals, sigs = np.stack([c, d]), np.stack([sc, sd])
    rounds.append(_table("results", kept, vals, sigs, kept, kept & (np.abs(vals) > k2 * sigs), names))
    for k, o, j in zip(*np.nonzero(kept)):
        ledger.decisions.append(Decision("offsets", 3, "navigation", int(o), -1, -1, int(j),
                                         float(vals[k, o, j] / sigs[k, o, j]), np.nan,
                                         f"{['offset', 'drift'][k]} free", f"orbit {int(o)} {names[j]}"))
    return {"rounds": rounds, "kept": kept}
