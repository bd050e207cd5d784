"""Robust reweighting of image observations inside the adjustment (the "Robust" / Danish method).

The DLR paper (``seeds/004``, section 4.1) eliminates gross errors of image observations with the
robust method of Klein and Förstner (1984): the weight of every observation is recomputed during
the iteration from its normalised residual ``u``, so that large residuals lose their weight and
the solution moves towards the good observations. Weight functions (:data:`WEIGHT_FUNCTIONS`,
``c`` the tuning constant, in units of ``u``):

* ``"danish"`` (Krarup's Danish method, the paper's): ``w = 1`` for ``|u| <= c``,
  ``w = exp(1 - (u / c)^2)`` beyond -- continuous at ``c``, redescending fast (``w = 0.05`` at
  ``2c``); the paper gives no formula, this is the common exponential form;
* ``"huber"``: ``w = min(1, c / |u|)`` (ISIS jigsaw and ASP offer it; never rejects);
* ``"cauchy"``: ``w = 1 / (1 + (u / c)^2)`` (jigsaw's and ASP's Cauchy loss).

The normalised residual of an image observation is the larger of its two coordinates'
``|v| / (s sigma)`` (``normalise="sigma"``) or ``|v| / (s sigma sqrt(r))`` with redundancy
numbers ``r`` (``"redundancy"``, the standardised residual: fairer where redundancies vary, but
each round costs a posterior precision), ``s`` the a-priori ``sigma0 = 1`` (``scale="apriori"``)
or a robust estimate ``1.4826 median |v / sigma|`` (``"mad"``) over the observations subject to it.

``mode="iteration"`` reweights after every accepted step of the solver (its ``reweight`` hook);
``"rounds"`` adjusts to convergence with fixed weights, then reweights, until the weights settle.
Observations whose final weight is below ``min_weight`` are removed (weight 0), the others get
their a-priori weight back: the robust step decides, the adjustments after it are plain least squares.

The first weights come from the start's own residuals (``start_weights``; iteratively reweighted least
squares from a robust start, :func:`consensus_points`): with unit weights the first step would be a
least-squares one, and an error of thousands of pixels drags its narrow-angle point far along its rays
before any reweighting, after which the point's good rays are cut as its outliers. The rejections are
then tested against the least-squares adjustment without them (``give_back``, the w-test limit): those
it predicts within the limit are given back (status ``in``), as the data snooping gives back its own;
a point or an image the step left without rays of its own to be judged by is judged by its consensus
intersection or its resection on the adjusted points. Measured on bench/qc_blocks.py's random blocks
(50 blocks, ``--seed 0`` / ``--seed 50``): median false removals beyond the clean block's 14.5 / 12.0
before, 0 / 0 after (the CHANGELOG has the table).
"""

from __future__ import annotations

from types import SimpleNamespace
from typing import Callable, cast

import numpy as np
from numpy.typing import NDArray

from ...errors import QualityControlInputError
from ..normal import AdjustmentState
from ..solver import SolverOptions
from .ledger import Ledger, _last_result

__all__ = ["WEIGHT_FUNCTIONS", "weight_function", "robust_step", "consensus_points", "CONSENSUS_CUT", "CONSENSUS_RAYS"]


#: truncation of the consensus intersections' cost (whitened 2-D residual, sigmas): a ray farther from a pair's
#: intersection than this is an outlier to it. The clean random blocks' rays at the navigation reach 3-4.7 sigma
#: (99th percentile of their own least-squares intersection), the paper's small errors 10-40 px (11-46 sigma)
CONSENSUS_CUT = 5.0
#: rays of a point among which its pairs are tried (the first ones of its track): the cost grows with the
#: cube of the track length, and a long track has good pairs among any dozen of its rays
CONSENSUS_RAYS = 12


def consensus_points(model, cam_params: NDArray, cam_idx: NDArray, pt_idx: NDArray, xy: NDArray, sigma: NDArray,
                     n_pt: int, cut: float = CONSENSUS_CUT, max_rays: int = CONSENSUS_RAYS) -> NDArray:
    """``(n_pt, 3)``: every point at the pair intersection of its rays that most of them agree with (NaN for
    points with fewer than 2 rays or no finite pair).

    Every pair of a point's rays (among its first ``max_rays``) is intersected at the images ``cam_params``,
    and scored by the truncated square sum of all the point's rays' whitened residuals,
    ``sum min(|z|^2, cut^2)`` (MSAC: each ray an inlier with its misfit or an outlier at a fixed cost); the
    lowest wins. Rays ``(cam_idx, pt_idx, xy, sigma (n, 2) pixels)``.
    """
    from ..intersection import intersect_points
    from ..precision import ordered_track_pairs

    cam_idx, pt_idx = np.asarray(cam_idx, np.int64), np.asarray(pt_idx, np.int64)
    out = np.full((n_pt, 3), np.nan)
    order = np.argsort(pt_idx, kind="stable")
    start = np.searchsorted(pt_idx[order], np.arange(n_pt + 1))
    length = np.diff(start)
    pos = np.arange(order.size) - start[pt_idx[order]]
    cand = order[pos < max_rays]
    if cand.size < 2:
        return out
    A, B = ordered_track_pairs(pt_idx[cand], n_pt)
    keep = A < B
    A, B = cand[A[keep]], cand[B[keep]]
    if A.size == 0:
        return out
    n_pairs = A.size
    obs2 = np.concatenate([A, B])
    with np.errstate(all="ignore"):
        try:
            Xp = intersect_points(model, cam_params, cam_idx[obs2], np.concatenate([np.arange(n_pairs)] * 2),
                                  xy[obs2], sigma[obs2], n_pt=n_pairs).xyz
        except (ValueError, np.linalg.LinAlgError, ArithmeticError):
            return out
    J = pt_idx[A]
    # every pair against every ray of its point
    reps = length[J]
    pair_of = np.repeat(np.arange(n_pairs), reps)
    offs = np.arange(pair_of.size) - np.repeat(np.cumsum(reps) - reps, reps)
    ray = order[np.repeat(start[J], reps) + offs]
    with np.errstate(all="ignore"):
        x = model.project(cam_params, cam_idx[ray], Xp[pair_of])
        z2 = np.sum(((x - xy[ray]) / sigma[ray]) ** 2, axis=1)
    z2 = np.where(np.isfinite(z2), z2, np.inf)

    def winners(c2: float) -> NDArray[np.int64]:
        cost = np.bincount(pair_of, weights=np.minimum(z2, c2), minlength=n_pairs)
        cost[~np.all(np.isfinite(Xp), axis=1)] = np.inf
        srt = np.lexsort((cost, J))
        win = np.ones(srt.size, bool)
        win[1:] = J[srt][1:] != J[srt][:-1]
        k = srt[win]
        return k[np.isfinite(cost[k])]

    k = winners(cut * cut)
    # the cut in units of the rays' own scatter where it exceeds their sigmas: at the navigation the good rays of
    # a point miss each other's intersections by the navigation's errors (measured on the DLR blocks: 29 of 34
    # points with a good ray beyond 5 sigma of the best pair), and a cut they all exceed decides nothing. The
    # scatter is the median 2-D residual of the winners' rays (1.177 sigma for normal errors; gross errors are
    # a minority of the rays)
    if k.size:
        zk = np.sqrt(z2[np.isin(pair_of, k)])
        zk = zk[np.isfinite(zk)]
        scale = float(np.median(zk)) / 1.177 if zk.size else 1.0
        if scale > 1.0:
            k = winners((cut * scale) ** 2)
    out[J[k]] = Xp[k]
    return out


def _danish(u: NDArray, c: float) -> NDArray:
    a = np.abs(u) / c
    return np.where(a <= 1.0, 1.0, np.exp(1.0 - a * a))


def _huber(u: NDArray, c: float) -> NDArray:
    a = np.abs(u)
    return np.where(a <= c, 1.0, c / np.maximum(a, 1e-300))


def _cauchy(u: NDArray, c: float) -> NDArray:
    return 1.0 / (1.0 + (u / c) ** 2)


#: weight functions by name: ``w(u, c)`` and a default tuning constant ``c``
WEIGHT_FUNCTIONS: dict[str, tuple[Callable[[NDArray, float], NDArray], float]] = {
    "danish": (_danish, 3.0),
    "huber": (_huber, 1.5),
    "cauchy": (_cauchy, 2.385),
}


def weight_function(name: str) -> tuple[Callable[[NDArray, float], NDArray], float]:
    """The weight function ``w(u, c)`` and its default ``c`` (:data:`WEIGHT_FUNCTIONS`).

    Raises
    ------
    QualityControlInputError
        An unknown name (the message lists the known ones).
    """
    try:
        return WEIGHT_FUNCTIONS[name]
    except KeyError:
        raise QualityControlInputError(f"unknown robust weight function {name!r}; known: "
                                       f"{', '.join(sorted(WEIGHT_FUNCTIONS))}") from None


def _normalised(ledger: Ledger, state: AdjustmentState, scale: str, red: NDArray | None,
                subject: NDArray[np.bool_] | None = None) -> NDArray:
    """``(n_obs,)`` normalised residual of every image observation (larger coordinate); the robust scale
    (``"mad"``) from the ``subject`` observations."""
    pb = ledger.base
    o = pb.obs
    x = pb.model.project(state.cam_params, o.cam_idx, state.points[o.pt_idx])
    z = (x - o.xy) / (o.sigma * ledger.weights.image_sigma[:, None])
    if red is not None:
        z = z / np.sqrt(np.clip(red, 1e-3, None))
    act = ledger.active if subject is None else ledger.active & subject
    s = 1.0
    if scale == "mad":
        s = 1.4826 * float(np.median(np.abs(z[act]))) if act.any() else 1.0
        s = max(s, 1e-12)
    return np.max(np.abs(z), axis=1) / s


def robust_step(ledger: Ledger, function: str = "danish", c: float | None = None, mode: str = "iteration",
                normalise: str = "sigma", scale: str = "apriori", min_weight: float = 0.1, max_rounds: int = 30,
                warmup: int = 3, observations: NDArray[np.bool_] | None = None, give_back: float | None = 4.0,
                start_weights: bool = True, options: SolverOptions | None = None) -> dict:
    """Robust adjustment of the ledger's problem (module docstring); removes what it rejects.

    ``observations`` (``(n_obs,)`` bool, default all): the image observations the robust weights apply to,
    e.g. the matcher's tie points; the others (measured control and check points) keep their weights
    and are left to the data snooping. The ``"mad"`` scale comes from them alone.

    ``give_back`` (default 4, the w-test's limit; None: off): rejections whose whitened residual against the
    least-squares adjustment without them is within it are given back (module docstring). ``start_weights``:
    the first weights from the start's residuals (for a robust start; :func:`~lunarmap.adjust.qc.quality_control`
    turns it off after Sequent, whose points start at the model's guess).

    Returns
    -------
    dict
        ``weights`` (n_obs,) the final robust weights, ``u`` the final normalised residuals,
        ``rounds`` adjustments made, ``removed`` observation indices (not given back), ``given_back`` those
        given back, ``sigma0`` the a-posteriori sigma0 of the robust adjustment (with its final weights, before
        the removals).

    Raises
    ------
    QualityControlInputError
        Unknown function / mode / normalisation / scale, ``c <= 0``, ``min_weight`` outside (0, 1).
    """
    fn, c0 = weight_function(function)
    c = c0 if c is None else float(c)
    if not (np.isfinite(c) and c > 0):
        raise QualityControlInputError(f"the robust tuning constant must be > 0, got {c!r}")
    if mode not in ("iteration", "rounds"):
        raise QualityControlInputError(f"robust mode must be 'iteration' or 'rounds', got {mode!r}")
    if normalise not in ("sigma", "redundancy"):
        raise QualityControlInputError(f"normalise must be 'sigma' or 'redundancy', got {normalise!r}")
    if scale not in ("apriori", "mad"):
        raise QualityControlInputError(f"scale must be 'apriori' or 'mad', got {scale!r}")
    if not (0.0 < min_weight < 1.0):
        raise QualityControlInputError(f"min_weight must be in (0, 1), got {min_weight!r}")
    base_w = ledger.weights.image_weight.copy()
    subject = None
    if observations is not None:
        subject = np.asarray(observations, bool)
        if subject.shape != base_w.shape:
            raise QualityControlInputError(f"observations needs one flag per image observation ({base_w.size}), "
                                           f"got shape {subject.shape}")
    still = ledger.active
    active = still if subject is None else still & subject
    robust = np.ones_like(base_w)
    red = None
    rounds = 0

    calls = {"n": 0}

    def weights_for(state: AdjustmentState) -> NDArray:
        # the MAD scale of all observations subject to the step: one of only those the current weights accept
        # shrinks round by round where the sigmas are uneven (a matcher's), and takes good observations with it
        # (measured: 90 % of the good ones out at 50 % mismatches)
        u = _normalised(ledger, state, scale, red, active)
        # the first reweightings with Huber's convex function: a redescending one applied to the residuals
        # of a solution that large errors still distort cuts good observations off for good
        f = _huber if calls["n"] < warmup else fn
        calls["n"] += 1
        # never exactly 0: a point keeps its rays; observations not subject to it keep theirs
        wu = f(u, c)
        # a projection that is not finite (a start behind a camera) says nothing about its observation: weight 1,
        # the iteration decides (a NaN weight would make the cost NaN)
        wu = np.where(np.isfinite(wu), wu, 1.0)
        w = np.where(active, np.maximum(wu, 1e-10), np.where(still, 1.0, 0.0))
        return w

    if ledger.result is None and start_weights:
        # the first weights from the start's own residuals (IRLS): with unit weights the first step is a
        # least-squares one, and an error of thousands of pixels on a narrow-angle point drags the point hundreds
        # of km along its rays before any reweighting (measured on bench/qc_blocks.py's random blocks: 175 km,
        # every good ray of the point then cut as its outliers)
        pb0 = ledger._finite(ledger.problem())
        robust = weights_for(cast(AdjustmentState, SimpleNamespace(cam_params=pb0.cam_params, points=pb0.points)))
        ledger.weights.image_weight = base_w * robust
    if mode == "iteration":
        if normalise == "redundancy":   # redundancy numbers of a plain adjustment, held for the iteration
            red = ledger.adjust(options).precision().redundancy_numbers
        last = {"w": robust}

        def hook(state: AdjustmentState):
            w = weights_for(state)
            if np.max(np.abs(w - last["w"])) < 1e-3:
                return None
            last["w"] = w
            return base_w * w

        result = ledger.adjust(options, reweight=hook)
        robust = last["w"]
        rounds = 1
    else:
        result = ledger.adjust(options)
        for rounds in range(1, max_rounds + 1):  # noqa: B007 (the count is reported after the loop)
            if normalise == "redundancy":
                red = result.precision().redundancy_numbers
            w = weights_for(result.state)
            change = float(np.max(np.abs(w - robust)))
            robust = w
            ledger.weights.image_weight = base_w * robust
            if change < 1e-3 or ledger.budget.exhausted():
                break
            result = ledger.adjust(options)
    u = _normalised(ledger, _last_result(ledger).state, scale, red, active)
    reject = np.flatnonzero(active & (robust < min_weight))
    ledger.weights.image_weight = base_w.copy()
    ledger.remove_image(reject, "robust", rounds, value=robust[reject])
    back = _give_back(ledger, reject, give_back, rounds, options) if give_back is not None else reject[:0]
    return {"weights": robust, "u": u, "rounds": rounds, "removed": np.setdiff1d(reject, back), "given_back": back,
            "sigma0": float(result.sigma0)}


def _give_back(ledger: Ledger, reject: NDArray[np.int64], limit: float, rnd: int,
               options: SolverOptions | None, max_rounds: int = 10) -> NDArray[np.int64]:
    """Give back the robust step's rejections that the least-squares adjustment without them predicts within
    ``limit``; returns them. The ledger's last adjustment is then one with the final weights.

    A robust weight is a verdict of the robust solution, where an observation's weight and its residual
    depend on each other: an observation near a large error, cut while the error still pulled its point or
    image, keeps a large residual because it has no weight. The test against the adjustment without the
    rejected observations decides instead, as the data snooping's give-back does: the whitened predicted
    residual ``|v| / sigma`` (larger coordinate) of a left-out observation bounds its w-test from above once
    it is back in (``w = v sqrt(r) / sigma`` with its redundancy number ``r <= 1``), so an observation within
    the limit would pass the snooping's own test. Given back together, adjusted again, until none is (at
    most ``max_rounds`` times; each observation once).
    """
    o = ledger.base.obs
    left = np.asarray(reject, np.int64)
    out: list[NDArray[np.int64]] = []
    tried: set[int] = set()
    for _ in range(max_rounds):
        res = ledger.adjust(options)
        if not left.size or ledger.budget.exhausted():
            break
        X = res.points[o.pt_idx[left]].copy()
        # a point left with fewer than 2 rays (set aside; a control point held by its coordinates alone) has no
        # position its rays determined
        n_act = np.bincount(o.pt_idx[ledger.active], minlength=ledger.base.n_points)
        aside = ledger.weights.dropped_points[o.pt_idx[left]] | (n_act[o.pt_idx[left]] < 2)
        if aside.any():
            X[aside] = _aside_points(ledger, res, np.unique(o.pt_idx[left[aside]]))[o.pt_idx[left[aside]]]
        with np.errstate(all="ignore"):
            x = ledger.base.model.project(res.cam_params, o.cam_idx[left], X)
            z = np.max(np.abs(x - o.xy[left]) / (o.sigma[left] * ledger.weights.image_sigma[left][:, None]), axis=1)
        ok = np.isfinite(z) & (z <= limit)
        if not ok.any():
            ok = _stripped_images(ledger, left, limit, tried)
        if not ok.any():
            break
        ledger.reinstate_image(left[ok], "robust", rnd, value=z[ok])
        out.append(left[ok])
        left = left[~ok]
    else:
        ledger.adjust(options)
    return np.sort(np.concatenate(out)) if out else left[:0]


def _aside_points(ledger: Ledger, res, pts: NDArray[np.int64]) -> NDArray:
    """``(n_points, 3)``: points ``pts`` that the robust step left with fewer than 2 rays, intersected at the
    adjusted images from the rays of their consensus (NaN elsewhere and where there is none).

    Such a point has no adjusted position to predict its rays from: the robust solution cut its good rays with
    its error (a 3-4-ray point of one strip, measured on bench/qc_blocks.py's random blocks). At the adjusted
    images its best-supported pair (:func:`consensus_points`) picks its inliers (within ``CONSENSUS_CUT``), and
    their least-squares intersection is the position its rays are judged against.
    """
    from ..intersection import intersect_points

    o = ledger.base.obs
    n = ledger.base.n_points
    out = np.full((n, 3), np.nan)
    rays = np.flatnonzero(np.isin(o.pt_idx, pts))
    rays = rays[~np.isin(o.pt_idx[rays], np.fromiter(ledger.withdrawn_points, np.int64, len(ledger.withdrawn_points)))]
    if rays.size < 2:
        return out
    sig = o.sigma[rays] * ledger.weights.image_sigma[rays][:, None]
    Xc = consensus_points(ledger.base.model, res.cam_params, o.cam_idx[rays], o.pt_idx[rays], o.xy[rays], sig, n)
    with np.errstate(all="ignore"):
        x = ledger.base.model.project(res.cam_params, o.cam_idx[rays], Xc[o.pt_idx[rays]])
        z = np.hypot(*((x - o.xy[rays]) / sig).T)
    inl = rays[np.isfinite(z) & (z <= CONSENSUS_CUT)]
    cnt = np.bincount(o.pt_idx[inl], minlength=n)
    inl = inl[cnt[o.pt_idx[inl]] >= 2]
    if not inl.size:
        return out
    has = np.flatnonzero(cnt >= 2)
    remap = np.full(n, -1, np.int64)
    remap[has] = np.arange(has.size)
    with np.errstate(all="ignore"):
        try:
            X = intersect_points(ledger.base.model, res.cam_params, o.cam_idx[inl], remap[o.pt_idx[inl]], o.xy[inl],
                                 o.sigma[inl] * ledger.weights.image_sigma[inl][:, None], n_pt=has.size,
                                 x0=Xc[has]).xyz
        except (ValueError, np.linalg.LinAlgError, ArithmeticError):
            return out
    out[has] = X
    return out


def _stripped_images(ledger: Ledger, left: NDArray[np.int64], limit: float, tried: set) -> NDArray[np.bool_]:
    """Which of the rejections ``left`` to give back from images the robust step stripped: ``(left.size,)``.

    The robust weights apply to image observations only: an image whose navigation has a gross error sees all its
    observations disagree with the orientation that navigation holds it at, and they are cut together (measured
    on bench/qc_blocks.py's random blocks: all 5 observations of an image with a 0.2-degree attitude error, which
    then no test could find). Judged against the adjustment, the image held by its wrong navigation, none fits.
    An image that lost at least half its observations to the step is resected on the adjusted points from all
    of them (its navigation left out), and each left out in turn: if all fit within ``limit`` (whitened residual)
    all come back; else if the leave-out of lowest chi-square fits within the limit, all but the left-out one.
    Each image once (``tried``).
    """
    from .snooping import _image_fits, _resect

    res = _last_result(ledger)
    o = ledger.base.obs
    back = np.zeros(left.size, bool)
    imgs, cnt = np.unique(o.cam_idx[left], return_counts=True)
    total = np.bincount(o.cam_idx, minlength=ledger.base.n_images)
    for k, c in zip(imgs, cnt):
        k = int(k)
        if k in tried or 2 * c < total[k]:
            continue
        tried.add(k)
        mine = np.flatnonzero(o.cam_idx == k)
        cand = mine[(ledger.active[mine] | np.isin(mine, left))
                    & ~ledger.weights.dropped_points[o.pt_idx[mine]]
                    & np.all(np.isfinite(res.points[o.pt_idx[mine]]), axis=1)]
        if cand.size < 4:
            continue
        free_all = ledger.base.cam_param_free
        free = (np.asarray(free_all[k], bool) if free_all is not None
                else np.ones(ledger.base.model.n_params, bool))
        if 2 * cand.size <= int(free.sum()):
            continue
        sig = o.sigma[cand] * ledger.weights.image_sigma[cand][:, None]
        with np.errstate(all="ignore"):
            z = _resect(ledger.base.model, res.cam_params, k, free, res.points[o.pt_idx[cand]], o.xy[cand], sig)
        if np.all(np.isfinite(z)) and np.max(np.abs(z)) <= limit:
            keep = cand
        else:
            if 2 * (cand.size - 1) <= int(free.sum()):
                continue
            _, top, chi2 = _image_fits(ledger, k, cand)
            best = int(np.argmin(chi2))
            if not (np.isfinite(chi2[best]) and top[best] <= limit):
                continue
            keep = np.delete(cand, best)
        back |= np.isin(left, keep)
    return back
