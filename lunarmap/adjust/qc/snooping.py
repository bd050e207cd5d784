"""Baarda's data snooping in every observation group (DLR paper, ``seeds/004``, section 4.1).

After each adjustment every observation ``i`` is tested with its w-test (Baarda 1968)::

    w_i = v_i / (sigma_i sqrt(r_i))

``v_i / sigma_i`` the whitened residual, ``r_i`` its redundancy number
(:class:`~lunarmap.adjust.precision.Precision`: image coordinates, control point coordinates,
navigation observations), against the a-priori ``sigma0 = 1`` (or the a-posteriori one, Pope's
tau-test, ``sigma0="aposteriori"``; or ``"robust"``, ``1.4826 median |w|`` of the image coordinates,
which many gross errors do not inflate). Observations with ``r_i < min_redundancy`` cannot be tested
(a gross error there is invisible) and are counted, not tested. If the largest ``|w|`` exceeds the
limit (the paper: 4), only that observation is acted on, the block is adjusted again and tested
again, until no test fails: an image observation is removed; a navigation or control observation
is not removed but down-weighted, ``P_new = P_old / factor`` (the paper: 5); an observation
already down-weighted ``max_downweights`` times and still failing is flagged and its weight cut
to ``1e-6`` of the a-priori one.

Once no test fails, image observations removed earlier (by the snooping, by a robust adjustment
before it, or by Sequent on a point still in the adjustment) that the final adjustment predicts within the
limit are given back (``reinstate``, once each) and the testing goes on: while large errors are still in the block they spread into the other
observations of their points, and the largest w-test may point at a good one.

Before that, images and points stripped around a gross error of their own (``stripped``): an error
that pulls its image's orientation or its point makes the w-tests of the good observations around it
exceed its own, and one-at-a-time removal leaves it fitted with no redundancy. Each image or point that
lost a third of its observations is checked by leaving each of them out in turn (the image resected on
the adjusted points, the point intersected; the whole block adjusted per leave-out for images of blocks
up to ``trial_observations``); a decisive culprit is removed and the good ones reinstated.

Rounds linearised at the navigation (``linearised``, the default unless a robust adjustment came
first) come before the non-linear ones: one Gauss-Newton step from the a-priori images and the points
intersected through them (:meth:`~.ledger.Ledger.adjust_linearised`), until no test fails (or the largest
``|w|`` is below ``linear_until``). Errors of thousands of sigma drag the non-linear adjustment hundreds of
km from the navigation, where its w-tests no longer point at them; in the linear model each error shows in
its own residual with its redundancy number's share (measured on the DLR blocks, Baarda alone, 20
draws: all 23 errors in 18 instead of 15, no false removal in 16 instead of 6). The non-linear rounds
then finish: once no test fails, every down-weighted navigation and control row gets its a-priori
weight back once and is tested again (freed, an image slides where position and attitude trade, and
its residual says nothing).

Last, once nothing is left to test, swap or give back (``separable``), every point with a removed ray is
checked by the likelihood-ratio tests of its leave-one-out intersections: a decisive other culprit is
swapped in; where two or more rays each explain the misfit (an error along the epipolar lines of the
point's other rays), the data cannot say which is wrong and the point is withdrawn with all its rays
(``"withdrawn"`` decisions), as a 2-ray point with an error is (:func:`_unattributed_points`).

``per_round="point"`` acts in one round on the largest failing image observation of every point
(and the largest failing navigation / control observation), for large blocks where one removal
per adjustment would take too many rounds; the paper's way is ``"one"``.
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ...errors import AdjustmentDivergedError, DatumDefectError, QualityControlError, QualityControlInputError
from ..normal import image_residuals, prior_terms, term_residuals
from ..solver import SolverOptions
from .ledger import Decision, Ledger
from .ledger import _last_result as _result

__all__ = ["w_tests", "snooping_step"]


_log = logging.getLogger(__name__)

#: a leave-one-out fit (resection or intersection) is decisive when it fits the other observations within this many limits and
#: the next best leave-out's RMS is this many times larger
DECISIVE = 5.0

#: point-normal eigenvalue ratios tried in turn when the precision fails: gross errors can drag a point onto
#: a projection centre, where its partials blow up and its normal block is rounding noise
_FALLBACK_RATIOS = (1e-6, 1e-4, 1e-2)


def _precision(res):
    """The result's posterior precision with redundancy numbers, treating degenerate points as undetermined if
    the plain computation fails (recorded in ``Precision.method``)."""
    from ..precision import posterior_precision

    try:
        return res.precision()
    except DatumDefectError as exc:
        last = exc
    for ratio in _FALLBACK_RATIOS:
        try:
            pr = posterior_precision(res, redundancy=True, undetermined_ratio=ratio)
        except DatumDefectError as exc:
            last = exc
            continue
        pr.method += f" (points with normal-matrix eigenvalue ratio < {ratio:g} undetermined)"
        res._precision = pr
        return pr
    raise QualityControlError(f"data snooping: the posterior precision of adjustment with sigma0 {res.sigma0:.3g} "
                              f"failed even with degenerate points set aside ({last})") from last


def w_tests(ledger: Ledger, sigma0: str = "apriori", min_redundancy: float = 0.02, limit: float = 4.0) -> dict:
    """w-tests of every observation of the ledger's last adjustment.

    Returns
    -------
    dict
        ``image`` (n_obs, 2), ``image_r`` (n_obs, 2); ``control`` (k, 3), ``control_r`` (k, 3) in the
        order of the base priors (NaN for fixed ones); ``terms`` list of (m_t,), ``terms_r``; NaN
        where not tested (removed, fixed, redundancy below ``min_redundancy``, pseudo-observations);
        ``untestable`` the number of observations below ``min_redundancy``; ``untestable_large`` the image
        observations among them with a whitened residual above ``limit`` times sigma0 (an error no test can see); ``sigma0``.
    """
    res = _result(ledger)
    pb = res.problem
    pr = _precision(res)
    s0 = res.sigma0 if sigma0 == "aposteriori" else 1.0
    z = image_residuals(pb, res.state)
    r = pr.redundancy_numbers
    act = (res.state.obs_weight > 0)[:, None] & np.ones((1, 2), bool)
    ok = act & (r >= min_redundancy)
    untestable = int(np.sum(act & ~ok))
    # an error where the tests cannot see it: an untestable observation whose whitened residual is large anyway
    with np.errstate(invalid="ignore"):
        untestable_large = int(np.sum(np.any(act & ~ok & (np.abs(z) > limit * s0), axis=1)))
    with np.errstate(invalid="ignore", divide="ignore"):
        w_img = np.where(ok, z / (s0 * np.sqrt(np.where(ok, r, 1.0))), np.nan)
    if sigma0 == "robust" and ok.any():
        # sigma0 from the median standardised residual: the a-posteriori one of a block with many gross
        # errors is theirs, and no test would fail against it
        s0 = max(1.4826 * float(np.median(np.abs(w_img[ok]))), 1e-12)
        w_img = w_img / s0
    out: dict[str, Any] = {"image": w_img, "image_r": np.where(act, r, np.nan)}
    base = ledger.base.priors
    k = 0 if base is None else base.idx.size
    w_c = np.full((k, 3), np.nan)
    r_c = np.full((k, 3), np.nan)
    pt = prior_terms(pb, res.points)
    if pt is not None and base is not None and k:
        rows = np.flatnonzero(~base.fixed)            # weighted base priors come first in pb.priors
        zc, rc = pt[1][:rows.size], pr.control_redundancy[:rows.size]
        okc = rc >= min_redundancy
        untestable += int(np.sum(~okc))
        with np.errstate(invalid="ignore", divide="ignore"):
            w_c[rows] = np.where(okc, zc / (s0 * np.sqrt(np.where(okc, rc, 1.0))), np.nan)
        r_c[rows] = rc
    out["control"], out["control_r"] = w_c, r_c
    wt, rt = [], []
    for i, t in enumerate(pb.terms):
        rx = term_residuals(t, res.cam_params, res._term_extra(i), res.points)
        rr = pr.term_redundancy[i]
        table = getattr(t, "row_table", None)
        obs_rows = np.ones(rx.size, bool) if table is None else table()["kind"] == 0
        # a DTM row of a point out of the adjustment is out with it (its residual is where the point was left)
        obs_rows = obs_rows & ~ledger.term_rows_out(i)
        okt = obs_rows & (rr >= min_redundancy)
        untestable += int(np.sum(obs_rows & ~okt))
        with np.errstate(invalid="ignore", divide="ignore"):
            wt.append(np.where(okt, rx / (s0 * np.sqrt(np.where(okt, rr, 1.0))), np.nan))
        rt.append(rr)
    out["terms"], out["terms_r"] = wt, rt
    out["untestable"] = untestable
    out["untestable_large"] = untestable_large
    out["sigma0"] = res.sigma0
    out["sigma0_used"] = s0
    return out


def _term_info(ledger: Ledger, t: int, row: int) -> tuple[int, int, str]:
    term = ledger.terms[t]
    table = getattr(term, "row_table", None)
    if hasattr(term, "row_label"):           # an altimetry shot: its track and shot
        return -1, -1, term.row_label(row)
    if getattr(term, "uses_points", False):
        # a reference DTM row: the point it observes (steep or changed terrain) is named
        j = int(term.point_index[row])
        ids = getattr(term, "point_ids", None)
        return -1, -1, f"{getattr(term, 'name', f'term {t}')} point {ids[row] if ids is not None else j}"
    if table is None:
        return -1, -1, getattr(term, "name", f"term {t}")
    rt = table()
    img, par, orb = int(rt["image"][row]), int(rt["param"][row]), int(rt["orbit"][row])
    names = list(getattr(ledger.base.model, "param_names", []))
    kind = "attitude" if par < len(names) and names[par].startswith("w") else "position"
    label = term.orbit_names[orb] if getattr(term, "orbit_names", None) else orb
    return img, par, f"{getattr(term, 'name', 'navigation')} {kind} orbit {label}"


#: steps whose image-observation removals data snooping may give back: its own and a robust adjustment's (a
#: redescending weight function cuts good observations near a large error, whose weight 0 then hides them
#: from the w-tests for good)
REINSTATABLE_STEPS = ("baarda", "robust")


def _removed_images(ledger: Ledger, steps: tuple) -> NDArray[np.int64]:
    """Image observations removed by any of ``steps`` and still out (weight 0), sorted."""
    idx = np.array(sorted({d.index for d in ledger.decisions if d.step in steps and d.kind == "image"
                           and d.action == "removed"}), np.int64)
    if not idx.size:
        return idx
    keep = ledger.weights.image_weight[idx] == 0.0
    if ledger.withdrawn_points:         # out for good with their points
        keep &= ~np.isin(ledger.base.obs.pt_idx[idx], np.fromiter(ledger.withdrawn_points, np.int64))
    return idx[keep]


def _reinstatable(ledger: Ledger, limit: float, done: set) -> NDArray[np.int64]:
    """Image observations removed by data snooping, a robust adjustment or Sequent (on points still in) that the
    final adjustment predicts within the limit.

    While large errors are still in the block they spread into the other observations of their
    points and images, and the largest w-test may point at a good observation. Once no test fails,
    every observation removed so far whose residual against the adjustment, ``|v| / sigma``, is below
    the limit (its w-test could only be smaller: the prediction's variance adds to ``sigma^2``) is
    given back, once; the testing then goes on.
    """
    res = _result(ledger)
    o = ledger.base.obs
    removed = _removed_images(ledger, REINSTATABLE_STEPS)
    # Sequent's removals on points still in the adjustment too: it judges a point's rays before any adjustment,
    # and a gross error along the epipolar line of a good ray makes it reject the good one with it (measured on
    # bench/qc_blocks.py's random blocks: the good ray kept out after the error was found); a point Sequent took
    # out has no adjusted position to predict its rays from
    seq = _removed_images(ledger, ("sequent",))
    seq = seq[~ledger.weights.dropped_points[o.pt_idx[seq]]]
    removed = np.setdiff1d(np.union1d(removed, seq), np.fromiter(done, np.int64, len(done)))
    if removed.size == 0:
        return removed
    x = ledger.base.model.project(res.cam_params, o.cam_idx[removed], res.points[o.pt_idx[removed]])
    z = np.abs(x - o.xy[removed]) / (o.sigma[removed] * ledger.weights.image_sigma[removed][:, None])
    return removed[np.all(np.isfinite(z), axis=1) & (np.max(z, axis=1) <= limit)]


def _restorable(ledger: Ledger, limit: float, done: set, every: bool = False) -> list:
    """Down-weighted navigation rows and control points whose whitened residual at their a-priori weight is
    within the limit (see :func:`_reinstatable`); keys ``("term", t, row)`` / ``("control", k)``. ``every``:
    all of them, whatever their residual (each once)."""
    res = _result(ledger)
    out: list[tuple] = []
    assert ledger.weights.term_vc is not None and ledger.weights.control_vc is not None
    for t, f in enumerate(ledger.weights.term_sigma):
        rows = np.flatnonzero(ledger.weights.term_downweighted(t))
        if rows.size == 0:
            continue
        rx = term_residuals(res.problem.terms[t], res.cam_params, res._term_extra(t), res.points)
        # back to the group's weight (its variance component; the a-priori sigma without one)
        z = np.abs(rx[rows]) * f[rows] / ledger.weights.term_vc[t][rows]
        out += [("term", t, int(r)) for r, zz in zip(rows, z)
                if (every or zz <= limit) and ("term", t, int(r)) not in done]
    k = np.flatnonzero(ledger.weights.control_downweighted())
    if k.size:
        pt = prior_terms(res.problem, res.points)
        base = ledger.base.priors
        assert pt is not None and base is not None, "down-weighted control points without priors"
        rows = np.cumsum(~base.fixed) - 1
        for kk in k:
            if base.fixed[kk]:
                continue
            z = np.max(np.abs(pt[1][rows[kk]])) * ledger.weights.control_sigma[kk] / ledger.weights.control_vc[kk]
            if (every or z <= limit) and ("control", int(kk)) not in done:
                out.append(("control", int(kk)))
    return out


def _resect(model, params: NDArray, cam: int, free: NDArray, X: NDArray, xy: NDArray, sig: NDArray,
            iterations: int = 8) -> NDArray:
    """Whitened residuals ``(m, 2)`` of image ``cam``'s observations ``xy`` (sigmas ``sig (m, 2)``, pixels) of
    the fixed points ``X (m, 3)`` after a Gauss-Newton resection of its free parameters (started at
    ``params[cam]``; ``params`` all images' parameters, as the model expects them)."""
    P = params.copy()
    ci = np.full(X.shape[0], cam, np.int64)
    for _ in range(iterations):
        x, J, _ = model.linearize(P, ci, X)
        r = ((x - xy) / sig).ravel()
        A = (J[:, :, free] / sig[:, :, None]).reshape(-1, int(free.sum()))
        if not (np.all(np.isfinite(r)) and np.all(np.isfinite(A))):
            return np.full(xy.shape, np.nan)        # diverged: this leave-out is not a candidate
        step, *_ = np.linalg.lstsq(A, -r, rcond=None)
        P[cam, free] += step
        if np.max(np.abs(step)) < 1e-12 * (1.0 + np.max(np.abs(P[cam]))):
            break
    return (model.project(P, ci, X) - xy) / sig


def _nav_rows(ledger: Ledger, cam: int) -> list[NDArray[np.int64]]:
    """Rows of every term (navigation observations) that belong to image ``cam``."""
    out = []
    for term in ledger.terms:
        table = getattr(term, "row_table", None)
        out.append(np.zeros(0, np.int64) if table is None else np.flatnonzero(table()["image"] == cam))
    return out


def _trial_costs(ledger: Ledger, cand: NDArray[np.int64], cam: int, options: SolverOptions | None) -> NDArray:
    """Final cost of the whole block with each of the candidate observations ``cand`` left out in turn (the
    others in; image ``cam``'s navigation rows at their a-priori weight, ``cam < 0`` none); the ledger is not
    changed."""
    import copy
    import dataclasses

    from ..solver import solve
    from ..weights import reweighted_problem

    res = _result(ledger)
    opts = dataclasses.replace(options or SolverOptions(), check_datum=False)
    rows = _nav_rows(ledger, cam) if cam >= 0 else []
    cost = np.full(cand.size, np.inf)
    for k in range(cand.size):
        w = copy.deepcopy(ledger.weights)
        w.image_weight[cand] = 1.0
        w.image_weight[cand[k]] = 0.0
        for t, r in enumerate(rows):
            for row in np.atleast_1d(r):
                w.restore_term(t, int(row))
        try:
            pb = ledger._finite(reweighted_problem(ledger.base, w, res.cam_params, res.points, ledger.terms))
            cost[k] = solve(pb, opts).cost
        except (ArithmeticError, ValueError, np.linalg.LinAlgError, DatumDefectError, AdjustmentDivergedError):
            continue                # a trial that cannot be adjusted is no candidate
    return cost


def _fit_stats(zs: list) -> tuple[NDArray, NDArray, NDArray]:
    """RMS, largest absolute value and square sum (chi-square) of each leave-out's whitened residuals."""
    n = len(zs)
    rms, top, chi2 = np.full(n, np.inf), np.full(n, np.inf), np.full(n, np.inf)
    for k, z in enumerate(zs):
        if z.size and np.all(np.isfinite(z)):
            chi2[k] = float(np.sum(z * z))
            rms[k], top[k] = np.sqrt(chi2[k] / z.size), np.max(np.abs(z))
    return rms, top, chi2


def _image_fits(ledger: Ledger, unit: int, cand: NDArray[np.int64]) -> tuple[NDArray, NDArray, NDArray]:
    """RMS, largest whitened residual and chi-square of the other candidates with each candidate left out in
    turn, image ``unit`` resected on the adjusted points."""
    res = _result(ledger)
    model = ledger.base.model
    o = ledger.base.obs
    n = cand.size
    sig = o.sigma[cand] * ledger.weights.image_sigma[cand][:, None]
    free_all = ledger.base.cam_param_free
    free = np.asarray(free_all[unit], bool) if free_all is not None else np.ones(model.n_params, bool)
    X, xy = res.points[o.pt_idx[cand]], o.xy[cand]
    with np.errstate(all="ignore"):
        zs = [_resect(model, res.cam_params, unit, free, X[np.arange(n) != k], xy[np.arange(n) != k],
                      sig[np.arange(n) != k]) for k in range(n)]
    return _fit_stats(zs)


def _point_fits(ledger: Ledger, units: list[int], cands: list[NDArray[np.int64]]
                ) -> list[tuple[NDArray, NDArray, NDArray]]:
    """For each point ``units[j]``: RMS, largest whitened residual and chi-square of the other candidate rays
    ``cands[j]`` with each left out in turn, the point intersected from the adjusted images; a control point's
    observed coordinates (at their current weight) count among its observations (measured, DLR blunder draw
    11: a 10.8-px error on a control point's ray looked like a height change to the rays alone, chi-square
    0.27 leaving out a good ray; the whole block adjusted per leave-out: +121).

    All leave-outs of all points are one vectorised intersection (a line-scan projection costs the same for
    one ray as for thousands; per point it was most of the run's snooping time)."""
    from ..intersection import intersect_points

    res = _result(ledger)
    model = ledger.base.model
    o = ledger.base.obs
    # one pseudo-point per (point, left-out ray), from every other candidate ray of its point
    obs_l: list[NDArray] = []
    pk_l: list[NDArray] = []
    x0_l: list[NDArray] = []
    first = [0]
    for unit, cand in zip(units, cands):
        n = cand.size
        rk, ri = np.nonzero(~np.eye(n, dtype=bool))
        obs_l.append(cand[ri])
        pk_l.append(first[-1] + rk)
        first.append(first[-1] + n)
        # a point set aside has stale coordinates: start from the model's own guess (NaN marks it)
        ok = not ledger.weights.dropped_points[unit] and np.all(np.isfinite(res.points[unit]))
        x0_l.append(np.repeat((res.points[unit] if ok else np.full(3, np.nan))[None, :], n, axis=0))
    if not units:
        return []
    obs, pk, x0 = np.concatenate(obs_l), np.concatenate(pk_l), np.concatenate(x0_l)
    sig = o.sigma[obs] * ledger.weights.image_sigma[obs][:, None]
    n_pt = first[-1]
    prior_xyz = prior_W = None
    pri = ledger.base.priors
    if pri is not None and pri.idx.size:
        row = np.full(ledger.base.n_points, -1, np.int64)
        row[pri.idx] = np.arange(pri.idx.size)
        r_of = row[np.repeat(np.asarray(units, np.int64), np.diff(first))]
        has = r_of >= 0
        if np.any(has):
            Wk = pri.sqrt_weight() / ledger.weights.control_sigma[:, None, None]
            prior_W = np.zeros((n_pt, 3, 3))
            prior_xyz = np.zeros((n_pt, 3))
            prior_W[has] = Wk[r_of[has]]
            prior_xyz[has] = pri.xyz[r_of[has]]
    out = [(np.full(c.size, np.inf), np.full(c.size, np.inf), np.full(c.size, np.inf)) for c in cands]
    with np.errstate(all="ignore"):
        try:
            bad = ~np.all(np.isfinite(x0), axis=1)
            if np.any(bad):
                guess = model.initial_points(res.cam_params, o.cam_idx[obs], pk, o.xy[obs], n_pt)
                x0[bad] = guess[bad]
            Xk = intersect_points(model, res.cam_params, o.cam_idx[obs], pk, o.xy[obs], sig, n_pt=n_pt,
                                  x0=x0, prior_xyz=prior_xyz, prior_sqrt_weight=prior_W).xyz
        except (ValueError, np.linalg.LinAlgError, ArithmeticError):
            if len(units) == 1:
                return out
            # one point that cannot be intersected does not take the others' checks with it
            return [_point_fits(ledger, [u], [c])[0] for u, c in zip(units, cands)]
        x = model.project(res.cam_params, o.cam_idx[obs], Xk[pk])
        z = (x - o.xy[obs]) / sig
        zp = None if prior_W is None else np.einsum("nij,nj->ni", prior_W, Xk - prior_xyz)
    order = np.argsort(pk, kind="stable")
    bounds = np.searchsorted(pk[order], np.arange(n_pt + 1))
    zs = [z[order[bounds[i]:bounds[i + 1]]].ravel() for i in range(n_pt)]
    if zp is not None and prior_W is not None:
        zs = [np.concatenate([zi, zp[i]]) if np.any(prior_W[i]) else zi for i, zi in enumerate(zs)]
    return [_fit_stats(zs[first[j]:first[j + 1]]) for j in range(len(units))]


def _swap(ledger: Ledger, out: int, rem: NDArray[np.int64], rnd: int, value: float, why: str) -> bool:
    """Make image observation ``out`` the one removed among ``rem`` (the removed candidates of one image or
    point): remove it if still in, give the others back. False if nothing changes."""
    back = np.setdiff1d(rem, [out])
    live_out = ledger.weights.image_weight[out] > 0
    if not back.size and not live_out:
        return False
    if live_out:
        ledger.remove_image(out, "baarda", rnd, value=value)
        ledger.decisions[-1].group += f" ({why})"
    if back.size:
        ledger.reinstate_image(back, "baarda", rnd)
    return True


def _stripped_swaps(ledger: Ledger, limit: float, done: set, rnd: int, hits: dict, options=None, trials=None,
                    min_rays: int = 3, max_rays: int = 60) -> int:
    """Images and points stripped around a gross error of their own: swap it for the good observations removed
    in its place.

    A large error pulls its image's orientation (and its point), so the w-tests of the image's *good*
    observations and navigation rows, or of the point's other rays, exceed its own; one-at-a-time snooping
    then removes them until the error is fitted with no redundancy left (measured on the DLR blocks,
    ``bench_qc.py --part blunders``); Sequent can do the same to a point whose error lies along an epipolar
    line. For every image or point that has lost at least a third of its observations (and two) to the
    snooping or to Sequent, each of its observations (active or removed; for an image, on points still in
    the block) is left out in turn: the image resected on the adjusted points, the point intersected from
    the adjusted images. A leave-out is decisive if it fits the others within ``DECISIVE`` limits and every
    other leave-out leaves an RMS ``DECISIVE`` times larger or, for a point, a chi-square larger by
    ``limit**2`` (its leave-outs differ in one ray: the likelihood-ratio test). Where none is for an image
    (its points carry too much of the error's pull) and the block is small (``trials``), the whole block is
    adjusted once per
    leave-out and the lowest cost is decisive if the next is higher by ``limit**2 / 2`` (a likelihood-ratio
    test). The
    decisive observation is removed, the others reinstated, an image's down-weighted navigation rows given
    their a-priori weight back; the testing goes on. Each image and point at most once.

    Returns
    -------
    int
        The number of swaps made.
    """
    o = ledger.base.obs
    # Sequent's and a robust adjustment's removals too: a gross error along the epipolar line can pair with a
    # good ray, and Sequent then removes the point's other good rays (and the point with them); a redescending
    # weight function cuts the good rays a large error pulls
    n_swaps = 0
    # an image's swap assumes one error of its own: it does not undo Sequent's removals, which judged the
    # rays of a point (an image with two errors would get one back)
    for kind, of, removed in (("image", o.cam_idx, _removed_images(ledger, ("baarda", "robust"))),
                              ("point", o.pt_idx, _removed_images(ledger, ("baarda", "sequent", "robust")))):
        # a swap changes only its own unit's observations, so every unit's candidates can be gathered first
        units, cands, rems = [], [], []
        for unit in np.unique(of[removed]):
            unit = int(unit)
            if (kind, unit) in done:
                continue
            mine = np.flatnonzero(of == unit)
            rem = np.intersect1d(mine, removed)
            rem = rem[ledger.weights.image_weight[rem] == 0.0]
            # a point set aside keeps the weights of its rays: they are candidates too
            live = ledger.active[mine] if kind == "image" else ledger.weights.image_weight[mine] > 0
            cand = np.union1d(mine[live], rem)
            if kind == "image":     # a resection needs the adjusted points: none of points set aside
                cand = cand[~ledger.weights.dropped_points[o.pt_idx[cand]]
                            & np.all(np.isfinite(_result(ledger).points[o.pt_idx[cand]]), axis=1)]
            if rem.size < max(2, cand.size // 3) or not (min_rays <= cand.size <= max_rays):
                continue
            done.add((kind, unit))
            units.append(unit)
            cands.append(cand)
            rems.append(rem)
        fits = _point_fits(ledger, units, cands) if kind == "point" else None
        for j, (unit, cand, rem) in enumerate(zip(units, cands, rems)):
            rms, top, chi2 = fits[j] if fits is not None else _image_fits(ledger, unit, cand)
            order = np.argsort(rms)
            best = int(order[0])
            # or, for a point, the likelihood-ratio test of the image trials below: the leave-outs differ in one
            # ray, and an error along the epipolar line of all but one good ray leaves that ray's leave-out an
            # RMS only ~2x the error's (measured: 1.65 vs 0.74 over 10 coordinates, chi-square 27.2 vs 5.5)
            lr = kind == "point" and chi2[order[1]] - chi2[best] >= limit ** 2
            if not (top[best] <= DECISIVE * limit and (rms[order[1]] >= DECISIVE * rms[best] or lr)):
                if kind != "image" or trials is None or trials["left"] < cand.size:
                    continue
                trials["left"] -= cand.size
                cost = _trial_costs(ledger, cand, unit, options)
                order = np.argsort(cost)
                best = int(order[0])
                if not (np.isfinite(cost[best]) and 2.0 * (cost[order[1]] - cost[best]) >= limit ** 2):
                    continue
                # and the observations it gives back fit: an image with a second error of its own would get
                # that one back (each given-back coordinate allowed limit**2, the w-test's own bound)
                n_back = 2 * (rem.size - 1) + sum(int(np.sum(ledger.weights.term_downweighted(t)[r]))
                                                  for t, r in enumerate(_nav_rows(ledger, unit)))
                if 2.0 * (cost[best] - _result(ledger).cost) > limit ** 2 * max(n_back, 1):
                    continue
            if not _swap(ledger, int(cand[best]), rem, rnd, np.nan, f"left out of its stripped {kind}"):
                continue                        # nothing would change
            if kind == "image":
                for t, r in enumerate(_nav_rows(ledger, unit)):
                    for row in r[ledger.weights.term_downweighted(t)[r]]:
                        ledger.weights.restore_term(t, int(row))
                        hits.pop((t, int(row)), None)     # a navigation error of its own is tested afresh
                        ledger.decisions.append(Decision("baarda", rnd, ledger.term_kind(t), int(row), unit,
                                                         action="reinstated", term=t))
            n_swaps += 1
    return n_swaps


def _unattributed_points(ledger: Ledger, limit: float, judged: set, rnd: int, max_rays: int = 60) -> int:
    """Points whose failing ray the data cannot single out: withdrawn with all their rays.

    Once nothing is left to test, swap or give back, every point that has rays removed (by the snooping,
    Sequent or a robust adjustment, and not given back) and at least 3 rays in all is checked by leaving
    each ray out in turn, the point intersected through the adjusted images: ``chi2_k``, the square sum of
    the other rays' whitened residuals. Leave-outs differ in one ray, so ``chi2_k - chi2_best`` is the
    likelihood-ratio test of "ray best is the error" against "ray k is" (Baarda's separability).

    * ``chi2`` of the second best larger by ``limit**2``: the best is the error; if it is a ray still in,
      it is removed and the point's removed rays are given back;
    * two or more leave-outs fit (``chi2 <= limit**2``), one of them a removed ray's: the removal is one
      guess among equally good ones (an error along the epipolar lines of its point's other rays -- three
      rays of one strip, an along-track error: any two rays intersect), and keeping the point keeps an
      error with it as often as not. The point is withdrawn, as a 2-ray point with an error is (measured:
      DLR blunder draws 8 and 13, leave-one-out chi-square 0.21 / 0.67 / 25.6 and 0.05 / 0.31 / 0.36).

    Each point once per set of removed rays. Returns the number of points acted on.
    """
    o = ledger.base.obs
    removed = _removed_images(ledger, ("baarda", "sequent", "robust"))
    units, cands, rems = [], [], []
    for unit in np.unique(o.pt_idx[removed]) if removed.size else []:
        unit = int(unit)
        mine = np.sort(ledger.rays_of(unit))
        rem = np.intersect1d(mine, removed)
        key = ("point", unit, tuple(int(i) for i in rem))
        if key in judged:
            continue
        cand = np.union1d(mine[ledger.weights.image_weight[mine] > 0], rem)
        judged.add(key)
        if not (3 <= cand.size <= max_rays):
            continue
        units.append(unit)
        cands.append(cand)
        rems.append(rem)
    if not units:
        return 0
    acted = 0
    lim2 = limit ** 2
    for unit, cand, rem, (_, _, chi2) in zip(units, cands, rems, _point_fits(ledger, units, cands)):
        order = np.argsort(chi2)
        best, second = int(order[0]), int(order[1])
        if not chi2[best] <= lim2:
            continue                    # no single ray explains the point's misfit
        if chi2[second] - chi2[best] >= lim2:
            # the removal was the right one unless the swap changes something
            acted += _swap(ledger, int(cand[best]), rem, rnd, float(np.sqrt(chi2[second] - chi2[best])),
                           "the decisive leave-out of its point")
            continue
        fit = chi2 <= lim2
        if np.sum(fit) >= 2 and np.any(np.isin(cand[fit], rem)):
            ledger.withdraw_point(unit, "baarda", rnd, value=float(np.sqrt(chi2[second] - chi2[best])),
                                  why=f"{int(np.sum(fit))} of its {cand.size} rays each explain its misfit")
            acted += 1
    return acted


def _finished(ledger: Ledger, limit: float, reinstate: bool, reinstated: set, restored: set, stripped: bool) -> bool:
    """No test fails: is there nothing left to give back, so the snooping would end now? (Stripped images and
    points and the separability checks are not tried: their verdict needs adjustments.)"""
    if stripped and ledger.decisions and any(d.step == "baarda" and d.action == "removed" for d in ledger.decisions):
        return False
    if reinstate and (_reinstatable(ledger, limit, reinstated).size or _restorable(ledger, limit, restored, every=True)):
        return False
    return True


def snooping_step(ledger: Ledger, limit: float = 4.0, factor: float = 5.0, max_rounds: int = 500,
                  per_round: str = "one", sigma0: str = "apriori", min_redundancy: float = 0.02,
                  max_downweights: int = 3, reinstate: bool = True, stripped: bool = True,
                  trial_observations: int = 20000, max_trials: int = 200, linearised: bool = True,
                  linear_until: float | None = None, separable: bool = True,
                  options: SolverOptions | None = None) -> dict:
    """Data snooping on the ledger's problem until no w-test exceeds ``limit`` (module docstring).

    Returns
    -------
    dict
        ``rounds`` (adjustments), ``max_w`` of the last round, ``untestable`` observations and
        ``untestable_large`` (those with large residuals), ``tests`` (the last :func:`w_tests`),
        ``budget_spent`` (why the run's budget stopped the rounds, ``""`` if it did not), ``round_limit``
        (``max_rounds`` reached with tests still failing).

    Raises
    ------
    QualityControlInputError
        ``limit <= 0``, ``factor <= 1``, unknown ``per_round`` or ``sigma0``.
    """
    if not (np.isfinite(limit) and limit > 0):
        raise QualityControlInputError(f"the Baarda limit must be > 0, got {limit!r}")
    if not (np.isfinite(factor) and factor > 1):
        raise QualityControlInputError(f"the down-weighting factor must be > 1, got {factor!r}")
    if per_round not in ("one", "point"):
        raise QualityControlInputError(f"per_round must be 'one' or 'point', got {per_round!r}")
    if sigma0 not in ("apriori", "aposteriori", "robust"):
        raise QualityControlInputError(f"sigma0 must be 'apriori', 'aposteriori' or 'robust', got {sigma0!r}")
    reinstated: set[int] = set()
    restored: set = set()
    judged: set = set()
    resected: set = set()
    # whole-block leave-one-out adjustments for stripped images, on small blocks only (each costs a solve)
    o = ledger.base.obs
    trials = {"left": max_trials} if o.n <= trial_observations else None
    hits_term: dict[tuple[int, int], int] = {}
    hits_ctl: dict[int, int] = {}
    tests = {}
    rnd = 0
    budget_spent, round_limit = "", False
    linear, n_linear = linearised, 0
    until = limit if linear_until is None else max(float(linear_until), limit)
    if linear:
        # points an earlier non-linear adjustment set aside (dragged onto a projection centre) are judged by
        # their rays in the linear model
        ledger.reinstate_set_aside("baarda")
    for rnd in range(1, max_rounds + 1):
        if linear and ledger.adjust_linearised(options) is not None:
            n_linear += 1
        else:
            linear = False
            ledger.adjust(options)
        try:
            tests = w_tests(ledger, sigma0, min_redundancy, limit)
        except QualityControlError:
            if linear:
                linear = False      # test the non-linear adjustment instead
                continue
            # no precision at this state (gross errors distort it beyond repair): remove the image
            # observation with the largest normalised residual, without a w-test, and go on
            res = _result(ledger)
            z = np.max(np.abs(res.image_residuals()) / res.problem.obs.sigma, axis=1)
            z[~ledger.active] = -1.0
            i = int(np.argmax(z))
            ledger.remove_image(i, "baarda", rnd, value=float(z[i]))
            ledger.decisions[-1].group += " (no precision: largest residual)"
            continue
        wi = np.abs(tests["image"])
        wi_obs = np.nanmax(np.where(np.isnan(wi), -1.0, wi), axis=1)
        _log.info("quality control: Baarda round %d (%s): largest |w| %.2f (limit %.1f), %d image observations "
                  "failing, %d removed so far", rnd, "linearised" if linear else "non-linear",
                  float(wi_obs.max()) if wi_obs.size else 0.0, limit, int(np.sum(wi_obs > limit)),
                  int(np.sum(~ledger.active)))
        cands: list[tuple[float, str, int, int]] = []      # (|w|, kind, a, b)
        if wi_obs.size and wi_obs.max() > limit:
            if per_round == "one":
                i = int(np.argmax(wi_obs))
                cands.append((wi_obs[i], "image", i, -1))
            else:
                fail = np.flatnonzero(wi_obs > limit)
                top: dict[int, int] = {}
                for i in fail[np.argsort(-wi_obs[fail])]:
                    top.setdefault(int(o.pt_idx[i]), int(i))
                cands += [(wi_obs[i], "image", i, -1) for i in top.values()]
        wc = np.abs(tests["control"])
        if wc.size and np.nanmax(np.where(np.isnan(wc), -1, wc)) > limit:
            kc, ac = np.unravel_index(np.nanargmax(np.where(np.isnan(wc), -1, wc)), wc.shape)
            cands.append((wc[kc, ac], "control", int(kc), int(ac)))
        for t, wt in enumerate(tests["terms"]):
            aw = np.abs(wt)
            if aw.size and np.nanmax(np.where(np.isnan(aw), -1, aw)) > limit:
                row = int(np.nanargmax(np.where(np.isnan(aw), -1, aw)))
                cands.append((aw[row], "term", t, row))
        if linear and cands and max(c[0] for c in cands) <= until:
            cands = []          # no gross error left: the rest is for the non-linear rounds
        if ledger.budget.exhausted() and (cands or linear or not _finished(ledger, limit, reinstate, reinstated,
                                                                          restored, stripped)):
            # something is left to do, and no round to do it in: the tests are of the last adjustment, the
            # state the run ends in
            budget_spent = ledger.budget.exhausted()
            break
        if not cands:
            if linear:
                # no test fails in the linear model: the rounds go on non-linear, from its solution, where
                # stripped images and points and the reinstatement are judged
                linear = False
                continue
            if stripped and _stripped_swaps(ledger, limit, resected, rnd, hits_term, options, trials):
                continue
            back, rows = np.zeros(0, np.int64), []
            if reinstate:
                back = _reinstatable(ledger, limit, reinstated)
                # a navigation row down-weighted while an error pulled its image leaves the image free to slide
                # where position and attitude trade (a narrow camera sees their sum): its residual then says
                # nothing, so each row is given its weight back once, together with its partners, and tested
                # again
                rows = _restorable(ledger, limit, restored, every=True)
            if not back.size and not rows:
                # the final state: is every removal the one its point's data single out?
                if separable and _unattributed_points(ledger, limit, judged, rnd):
                    continue
                break
            reinstated.update(int(i) for i in back)
            if back.size:
                ledger.reinstate_image(back, "baarda", rnd)
            for key in rows:
                restored.add(key)
                # back to its group's variance component, not to the a-priori sigma
                if key[0] == "control":
                    ledger.weights.restore_control(key[1])
                else:
                    ledger.weights.restore_term(key[1], key[2])
                kind = "control" if key[0] == "control" else ledger.term_kind(key[1])
                ledger.decisions.append(Decision("baarda", rnd, kind, key[-1], action="reinstated",
                                                 term=-1 if key[0] == "control" else key[1]))
            continue
        cands.sort(key=lambda c: -c[0])
        if per_round == "one":
            cands = cands[:1]
        for _val, kind, a, b in cands:
            if kind == "image":
                comp = int(np.nanargmax(np.where(np.isnan(wi[a]), -1, wi[a])))
                ledger.remove_image(a, "baarda", rnd, value=float(tests["image"][a, comp]),
                                    redundancy=float(tests["image_r"][a, comp]), component=comp)
            elif kind == "control":
                n = hits_ctl[a] = hits_ctl.get(a, 0) + 1
                f = factor if n <= max_downweights else 1e6
                ledger.downweight_control(a, f, "baarda", rnd, float(tests["control"][a, b]),
                                          float(tests["control_r"][a, b]), component=b)
                if n > max_downweights:
                    ledger.decisions[-1].action = "flagged"
            else:
                img, par, group = _term_info(ledger, a, b)
                n = hits_term[(a, b)] = hits_term.get((a, b), 0) + 1
                f = factor if n <= max_downweights else 1e6
                ledger.downweight_term(a, b, f, "baarda", rnd, float(tests["terms"][a][b]),
                                       float(tests["terms_r"][a][b]), image=img, component=par, group=group)
                if n > max_downweights:
                    ledger.decisions[-1].action = "flagged"
    else:
        round_limit = True
        ledger.adjust(options)
        tests = w_tests(ledger, sigma0, min_redundancy, limit)
    allw = np.concatenate([np.abs(tests["image"]).ravel(), np.abs(tests["control"]).ravel()] +
                          [np.abs(w) for w in tests["terms"]])
    return {"rounds": rnd, "linear_rounds": n_linear, "max_w": float(np.nanmax(allw)) if np.any(np.isfinite(allw)) else np.nan,
            "untestable": tests.get("untestable", 0), "untestable_large": tests.get("untestable_large", 0),
            "tests": tests, "budget_spent": budget_spent, "round_limit": round_limit}
