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
   their posterior standard deviation are kept. With ``select="forward"`` (the default) every
   observed offset and drift is a candidate (stage 1 is then only reported: a parameter that the
   navigation holds tightly, such as kappa, shows a 1 degree offset as a few thousandths of a degree
   in its residuals), and they are freed one at a time, the one that lowers the cost most first
   (likelihood ratio ``sqrt(2 dcost) > k2``), until none is significant: for a narrow camera a roll and a cross-track position offset (a
   pitch and an along-track one) move the images alike, and freeing both leaves both undetermined
   (4,000 m +- 2,000 m in the paper's example 1 here). Which of such a pair is the navigation's
   error the images cannot say (0.39 degrees of roll is 4 km at 587 km): ``prefer="position"``
   frees a position offset or drift first when its test value is at least half the largest and
   significant --
   per-orbit biases of lunar orbiters come from the orbit determination -- and the report shows
   what was chosen;
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
from .ledger import Decision, Ledger, _last_result

__all__ = ["offset_drift_step"]


def _set_term(ledger: Ledger, t: int, new: NavigationObservations) -> None:
    """Replace term ``t``, keeping the sigma factors of its image rows (pseudo-observation rows reset)."""
    old = ledger.terms[t]
    n_img_rows = int(old.used.sum())
    f = np.ones(new.n_obs_scalar)
    f[:n_img_rows] = ledger.weights.term_sigma[t][:n_img_rows]
    ledger.terms[t] = new
    ledger.weights.term_sigma[t] = f
    assert ledger.weights.term_vc is not None
    vc = np.ones(new.n_obs_scalar)
    vc[:n_img_rows] = ledger.weights.term_vc[t][:n_img_rows]
    ledger.weights.term_vc[t] = vc


def _extra_slice(ledger: Ledger, t: int) -> slice:
    s0 = sum(term.n_extra for term in ledger.terms[:t])
    return slice(s0, s0 + ledger.terms[t].n_extra)


def _posterior(ledger: Ledger, t: int) -> tuple[NDArray, NDArray, NDArray, NDArray]:
    """Offsets, drifts (n_orb, p) and their posterior sigmas from the last adjustment."""
    res = _last_result(ledger)
    nav = ledger.terms[t]
    sl = _extra_slice(ledger, t)
    e = res.extra[sl]
    sig = np.sqrt(np.clip(np.diag(res.precision().extra_cov)[sl], 0.0, None))
    h = nav.n_orbits * nav.p
    return (e[:h].reshape(nav.n_orbits, nav.p), e[h:].reshape(nav.n_orbits, nav.p),
            sig[:h].reshape(nav.n_orbits, nav.p), sig[h:].reshape(nav.n_orbits, nav.p))


def _regress(ledger: Ledger, t: int, drifts: bool, k1: float, apriori: bool = False, skip: NDArray | None = None):
    """Stage 1 of the paper: offsets (and drifts) of the navigation residuals per orbit and parameter.

    The residuals are the adjusted parameters minus the observations and the offsets/drifts already
    free. ``apriori``: standard deviations from the navigation sigmas (else from the fit's scatter);
    ``skip (2, n_orb, p)``: offsets / drifts already free (not regressed; the other one of the pair is).
    """
    res = _last_result(ledger)
    nav = ledger.terms[t]
    n_orb, p = nav.n_orbits, nav.p
    # a-priori sigmas with the current factors of the image rows (rows are the used entries, row-major)
    fac = np.ones(nav.used.shape)
    fac[nav.used] = ledger.weights.term_sigma[t][:int(nav.used.sum())]
    sigma = nav.sigma * fac
    ex = res.extra[_extra_slice(ledger, t)]
    off, dr = nav.offsets(ex), nav.drifts(ex)
    corr = res.cam_params - nav.observed - off[nav.orbit] - nav.s[:, None] * dr[nav.orbit]
    skip = np.zeros((2, n_orb, p), bool) if skip is None else skip
    vals = np.zeros((2, n_orb, p))
    sigs = np.full((2, n_orb, p), np.inf)
    for o in range(n_orb):
        for j in range(p):
            m = (nav.orbit == o) & nav.used[:, j]
            n = int(m.sum())
            if n < 2 or (skip[0, o, j] and skip[1, o, j]):
                continue
            e, s, wgt = corr[m, j], nav.s[m], 1.0 / sigma[m, j] ** 2
            if skip[0, o, j]:
                models = [(False, True)] if drifts else []          # the offset is free: its drift alone
            elif skip[1, o, j]:
                models = [(True, False)]
            else:
                models = [(True, True), (True, False)] if drifts and n >= 3 else [(True, False)]
            for with_off, with_drift in models:
                cols = ([np.ones(n)] if with_off else []) + ([s] if with_drift else [])
                A = np.column_stack(cols)
                N = A.T @ (A * wgt[:, None])
                x = np.linalg.solve(N, A.T @ (wgt * e))
                v = e - A @ x
                dof = n - A.shape[1]
                s0sq = 1.0 if apriori else (float(wgt @ (v * v)) / dof if dof > 0 else 1.0)
                sx = np.sqrt(np.clip(np.diag(np.linalg.inv(N) * s0sq), 0.0, None))
                if with_drift and with_off:
                    if abs(x[1]) > k1 * sx[1]:
                        vals[:, o, j], sigs[:, o, j] = x, sx
                        break
                    continue        # the drift is not significant: test the offset alone (Eq. 5)
                k = 0 if with_off else 1
                vals[k, o, j], sigs[k, o, j] = x[0], sx[0]
    return vals, sigs


def _table(name: str, cands: NDArray, vals: NDArray, sigs: NDArray, free: NDArray, keep: NDArray,
           param_names) -> xr.Dataset:
    k, o, j = np.nonzero(cands)
    return xr.Dataset({"orbit": ("row", o), "param": ("row", np.array([param_names[x] for x in j], dtype=object)),
                       "kind": ("row", np.array(["offset", "drift"], dtype=object)[k]),
                       "value": ("row", vals[k, o, j]), "sigma": ("row", sigs[k, o, j]),
                       "free": ("row", free[k, o, j]), "significant": ("row", keep[k, o, j])},
                      attrs={"round": name})


def offset_drift_step(ledger: Ledger, term: int = 0, k1: float = 1.0, k2: float = 3.5, drifts: bool = True,
                      stage1: str = "residuals", select: str = "forward", prefer: str | None = "position",
                      options: SolverOptions | None = None) -> dict:
    """Find the significant per-orbit offsets and drifts of navigation term ``term`` (module docstring).

    The term is left with the kept ones free (the others fixed at zero), for the steps that follow.

    Parameters
    ----------
    ledger : Ledger
    term : int
        Index of the :class:`~lunarmap.adjust.navigation.NavigationObservations` among the problem's terms.
    k1 : float
        Stage-1 limit (the paper: 1, "larger than their standard deviations").
    k2 : float
        Stage-2 limit ("much larger"); 3.5 keeps the chance of a false offset among the ~50
        candidates of two orbits near 2 % (Bonferroni).
    drifts : bool
        Test drifts too.
    stage1 : {"residuals", "free"}
    select : {"forward", "all"}
    prefer : {"position", "attitude", None}
    options : SolverOptions, optional

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
    if select not in ("forward", "all"):
        raise QualityControlInputError(f"select must be 'forward' or 'all', got {select!r}")
    nav = ledger.terms[term]
    n_orb, p = nav.n_orbits, nav.p
    names = list(getattr(ledger.base.model, "param_names", [f"p{j}" for j in range(p)]))
    kinds = np.array(["attitude" if n.startswith("w") else "position" if n.startswith("c") else n for n in names])
    if prefer is not None and prefer not in ("position", "attitude"):
        raise QualityControlInputError(f"prefer must be None, 'position' or 'attitude', got {prefer!r}")
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
    if select == "forward":
        # one at a time: free the candidate whose freeing lowers the cost most (likelihood ratio,
        # t = sqrt(2 dcost), a-priori sigma0 = 1), until none is significant at k2. Freeing an attitude
        # and a position offset that move the images alike (a narrow camera's roll and cross-track
        # position) makes both undetermined; once one of them is free the other brings nothing.
        # the pool is every observed offset (and drift), not only stage 1's candidates: a parameter that the
        # navigation holds tightly (kappa, 0.01 degrees per image) shows a 1 degree offset in its residuals
        # as a few thousandths of a degree, below any stage-1 limit
        cands = np.stack([observed, observed & drifts])
        chosen = np.zeros_like(cands)
        _set_term(ledger, term, nav.replace(offset=modes(chosen[0]), drift=modes(chosen[1])))
        base_cost = ledger.adjust(options).cost
        start = ledger.result
        for _ in range(int(cands.sum())):
            t = np.zeros(cands.shape)
            for k, o, j in zip(*np.nonzero(cands & ~chosen)):
                trial = chosen.copy()
                trial[k, o, j] = True
                _set_term(ledger, term, nav.replace(offset=modes(trial[0]), drift=modes(trial[1])))
                t[k, o, j] = np.sqrt(max(0.0, 2.0 * (base_cost - ledger.adjust(options, start=start).cost)))
            if not (t.max() > k2):
                break
            if prefer is not None:
                # a confounded pair shares the signal: the preferred kind goes first when its test value is
                # at least half the largest
                pref = np.zeros_like(t, dtype=bool)
                pref[:, :, kinds == prefer] = True
                if np.any(pref & (t >= 0.5 * t.max()) & (t > k2)):
                    t = np.where(pref, t, 0.0)
            chosen[np.unravel_index(int(np.argmax(t)), t.shape)] = True
            _set_term(ledger, term, nav.replace(offset=modes(chosen[0]), drift=modes(chosen[1])))
            start = ledger.adjust(options, start=start)
            base_cost = start.cost
        cands = chosen
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
                                         f"{['offset', 'drift'][k]} free", f"orbit {nav.orbit_names[o]} {names[j]}"))
    return {"rounds": rounds, "kept": kept}
