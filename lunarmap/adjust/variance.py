"""Variance components of groups of observations, estimated from the adjustment (Helmert / Förstner).

For a group ``k`` of observations with whitened residuals ``v_i / sigma_i`` and redundancy numbers
``r_i`` (:class:`~lunarmap.adjust.precision.Precision`), the estimate of the group's variance
factor is::

    s_k^2 = sum_{i in k} (v_i / sigma_i)^2 / sum_{i in k} r_i

(the DLR paper, ``seeds/004``, section 4.2: variance estimation after Rao; ``r_k`` is the group's
share of the redundancy, and ``sigma(s_k) ~ s_k / sqrt(2 r_k)``). Scaling the group's sigmas by
``s_k`` and adjusting again, until every factor is 1, gives weights that match the data, whatever
the starting sigmas. The groups (:func:`observation_groups`) are the paper's: image coordinates
per camera, navigation positions and attitudes per orbit, control points. This is also what the
matcher's tie points need: least-squares matching reports its sigma from the fit of one window,
while check and control measurements, made with a known sigma, keep theirs.

``s_k / sqrt(2 r_k)`` ignores that groups can trade against each other: a narrow camera sees its
navigation position and attitude only as a sum, and the data then fix their sum, not their split.
:func:`variance_component_covariance` gives the joint (Helmert) covariance of all groups from the dense
redundancy matrix of small blocks; its correlations name the groups the data cannot separate
(measured on the DLR blocks: position / attitude of one orbit -0.96 to -0.997).
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from ..errors import AdjustmentInputError, VarianceComponentError
from .normal import prior_terms, term_residuals
from .problem import BundleProblem, ImageObservations
from .result import AdjustmentResult
from .solver import SolverOptions, solve
from .weights import Weights, reweighted_problem

#: a group's redundancy below this during the iteration means its variance is heading to 0 (not estimable)
BOUNDARY_REDUNDANCY = 0.05

_log = logging.getLogger(__name__)

__all__ = ["VarianceEstimate", "image_variance_factors", "estimate_image_variances", "ObservationGroups",
           "observation_groups", "group_variance_factors", "VarianceComponents", "estimate_variance_components",
           "variance_component_covariance"]


@dataclass
class VarianceEstimate:
    """Outcome of :func:`estimate_image_variances`.

    Attributes
    ----------
    result : AdjustmentResult
        The last adjustment (sigmas of the estimated groups rescaled).
    scale : ndarray (k,)
        Total factor applied to each group's a-priori sigma (dimensionless).
    history : list of ndarray (k,)
        The variance factors ``s_k^2`` estimated in each round (1 when converged).
    redundancy : ndarray (k,)
        Each group's share of the redundancy in the last round.
    """

    result: AdjustmentResult
    scale: NDArray[np.float64]
    history: list = field(default_factory=list)
    redundancy: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))


def image_variance_factors(result: AdjustmentResult, groups: NDArray[np.int64],
                           n_groups: int | None = None) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Variance factors ``s_k^2`` and redundancies ``r_k`` of groups of image observations.

    Parameters
    ----------
    result : AdjustmentResult
    groups : ndarray (n_obs,) int
        Group of every image observation (both coordinates belong to it); ``-1`` leaves an observation out.
    n_groups : int, optional

    Raises
    ------
    AdjustmentInputError
        A group with no redundancy (its factor cannot be estimated).
    """
    groups = np.asarray(groups, dtype=np.int64)
    o = result.problem.obs
    if groups.shape != (o.n,):
        raise AdjustmentInputError(f"groups must give one group per image observation ({o.n}), got {groups.shape}")
    k = int(groups.max()) + 1 if n_groups is None else int(n_groups)
    red = result.precision().redundancy_numbers
    w = result.state.obs_weight[:, None]
    z = result.image_residuals() / o.sigma
    use = groups >= 0
    vpv = np.bincount(groups[use], weights=np.sum(w[use] * z[use] ** 2, axis=1), minlength=k)
    r = np.bincount(groups[use], weights=np.sum(red[use], axis=1), minlength=k)
    if np.any(r <= 0.5):
        bad = int(np.argmax(r <= 0.5))
        raise AdjustmentInputError(f"image observation group {bad} has redundancy {r[bad]:.2f}: its variance "
                                   "factor cannot be estimated")
    return vpv / r, r.astype(np.float64)


def estimate_image_variances(problem: BundleProblem, groups: NDArray[np.int64], estimate: NDArray[np.bool_],
                             options: SolverOptions | None = None, rounds: int = 5,
                             tol: float = 0.02) -> VarianceEstimate:
    """Adjust, estimate the variance factors of the groups in ``estimate``, rescale their sigmas, repeat.

    Parameters
    ----------
    problem : BundleProblem
    groups : ndarray (n_obs,) int
        Group of every image observation.
    estimate : ndarray (k,) bool
        Groups whose sigma is estimated; the others keep their a-priori sigma.
    options : SolverOptions, optional
    rounds : int
        Maximum number of adjustments.
    tol : float
        Stop when every estimated factor is within ``1 +- tol``.
    """
    groups = np.asarray(groups, dtype=np.int64)
    estimate = np.asarray(estimate, dtype=bool)
    k = estimate.size
    scale = np.ones(k)
    history = []
    pb = problem
    result = solve(pb, options)
    for rnd in range(max(rounds, 1)):
        factors, r = image_variance_factors(result, groups, k)
        history.append(factors)
        _log.info("variance estimation round %d: sigma0 %.4f, variance factors %s (sigma scale so far %s)", rnd + 1,
                  result.sigma0, " ".join(f"{f:.3f}" for f in factors), " ".join(f"{x:.3f}" for x in scale))
        step = np.where(estimate, np.sqrt(factors), 1.0)
        if np.all(np.abs(factors[estimate] - 1.0) <= tol):
            return VarianceEstimate(result, scale, history, r)
        scale *= step
        o = pb.obs
        sigma = o.sigma * np.where(groups >= 0, step[np.maximum(groups, 0)], 1.0)[:, None]
        # the next round starts where this one ended (image parameters and points): only the weights change
        pb = dataclasses.replace(pb, cam_params=result.cam_params, points=result.points,
                                 obs=ImageObservations(o.cam_idx, o.pt_idx, o.xy, sigma),
                                 cam_param_free=pb.cam_param_free, obs_weight=pb.obs_weight)
        result = solve(pb, options)
    factors, r = image_variance_factors(result, groups, k)
    history.append(factors)
    return VarianceEstimate(result, scale, history, r)



@dataclass
class ObservationGroups:
    """Groups of the observations of a problem for variance components (``-1``: in no group).

    Attributes
    ----------
    names : list of str
    image : (n_obs,) int
        Group of every image observation (both coordinates).
    control : (k,) int
        Group of every control point of ``problem.priors`` (all three coordinates).
    terms : list of (m_t,) int
        Group of every row of every camera-level term.
    """

    names: list
    image: NDArray[np.int64]
    control: NDArray[np.int64]
    terms: list

    @property
    def n(self) -> int:
        return len(self.names)


def _kind_of(name: str) -> str:
    return "attitude" if name.startswith("w") else "position" if name.startswith("c") else name


def observation_groups(problem: BundleProblem, image_group: NDArray | None = None,
                       image_group_names: list | None = None, control: bool = True,
                       navigation: bool = True) -> ObservationGroups:
    """The DLR paper's groups: image coordinates per camera, navigation positions / attitudes per orbit,
    control points.

    Parameters
    ----------
    problem : BundleProblem
    image_group : (n_img,) int, optional
        Camera (or any group) of every image; default one group of all image observations.
    image_group_names : list of str, optional
        Names of the image groups (default ``"image <g>"``).
    control : bool
        One group of all weighted control points.
    navigation : bool
        Groups of navigation observations (terms with a ``row_table``, e.g.
        :class:`~lunarmap.adjust.navigation.NavigationObservations`): per orbit, one of positions
        (parameters ``c*``) and one of attitudes (``w*``); their offset/drift pseudo-observations are
        in no group.
    """
    names: list[str] = []
    o = problem.obs
    if image_group is None:
        img = np.zeros(o.n, np.int64)
        names.append("image")
    else:
        lab = np.asarray(image_group)
        if lab.shape != (problem.n_images,):
            raise AdjustmentInputError(f"image_group needs one group per image ({problem.n_images}), got {lab.shape}")
        uniq, inv = np.unique(lab, return_inverse=True)
        img = inv[o.cam_idx].astype(np.int64)
        if image_group_names is not None and len(image_group_names) != uniq.size:
            raise AdjustmentInputError(f"{len(image_group_names)} names for {uniq.size} image groups")
        names += list(image_group_names) if image_group_names is not None else [f"image {u}" for u in uniq]
    k = 0 if problem.priors is None else problem.priors.idx.size
    ctl = -np.ones(k, np.int64)
    if control and k and problem.priors is not None:
        weighted = ~problem.priors.fixed
        if weighted.any():
            ctl[weighted] = len(names)
            names.append("control")
    terms: list[NDArray[np.int64]] = []
    param_names = list(getattr(problem.model, "param_names", []))
    for t in problem.terms:
        g = -np.ones(t.n_obs_scalar, np.int64)
        table = getattr(t, "row_table", None)
        if getattr(t, "variance_group", False):
            # a reference DTM: all its rows one group (its own variance component); an altimeter: its shots
            # (its offsets' pseudo-observations in no group)
            g[t.group_rows() if hasattr(t, "group_rows") else slice(None)] = len(names)
            names.append(str(getattr(t, "name", f"term {len(terms)}")))
        elif navigation and table is not None:
            rt = table()
            obs_rows = rt["kind"] == 0
            kinds = np.array([_kind_of(param_names[j]) if j < len(param_names) else f"p{j}" for j in rt["param"]])
            label = getattr(t, "name", "navigation")
            orbit_names = getattr(t, "orbit_names", None)
            for orb in np.unique(rt["orbit"][obs_rows]):
                for kd in sorted(set(kinds[obs_rows & (rt["orbit"] == orb)])):
                    sel = obs_rows & (rt["orbit"] == orb) & (kinds == kd)
                    g[sel] = len(names)
                    names.append(f"{label} {kd} orbit {orbit_names[orb] if orbit_names else int(orb)}")
        terms.append(g)
    return ObservationGroups(names, img, ctl, terms)


def group_variance_factors(result: AdjustmentResult, groups: ObservationGroups
                           ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.int64]]:
    """Variance factors ``s_k^2``, redundancies ``r_k``, weighted square sums ``v'Pv_k`` and observation counts.

    Removed image observations (weight 0) do not count. The groups refer to the base problem; a
    problem with extra fixed priors appended (dropped points) is handled.
    """
    from .normal import image_residuals

    pb = result.problem
    pr = result.precision()
    k = groups.n
    vpv, red, cnt = np.zeros(k), np.zeros(k), np.zeros(k, np.int64)
    st = result.state
    w = st.obs_weight
    active = w > 0
    z = image_residuals(pb, st)
    g = groups.image
    use = active & (g >= 0)
    np.add.at(vpv, g[use], np.sum(z[use] ** 2, axis=1))
    np.add.at(red, g[use], np.sum(pr.redundancy_numbers[use], axis=1))
    np.add.at(cnt, g[use], 2)
    pt = prior_terms(pb, result.points)
    if pt is not None and pr.control_redundancy is not None and groups.control.size:
        weighted = ~pb.priors.fixed
        n_base = groups.control.size
        gc = groups.control[weighted[:n_base]]          # weighted rows of the base priors come first
        rows = np.arange(gc.size)
        use = gc >= 0
        np.add.at(vpv, gc[use], np.sum(pt[1][rows[use]] ** 2, axis=1))
        np.add.at(red, gc[use], np.sum(pr.control_redundancy[rows[use]], axis=1))
        np.add.at(cnt, gc[use], 3)
    for i, (t, gt) in enumerate(zip(pb.terms, groups.terms)):
        rx = term_residuals(t, result.cam_params, result._term_extra(i), result.points)
        use = gt >= 0
        np.add.at(vpv, gt[use], rx[use] ** 2)
        np.add.at(red, gt[use], pr.term_redundancy[i][use])
        np.add.at(cnt, gt[use], 1)
    with np.errstate(invalid="ignore", divide="ignore"):
        f = vpv / red
    return f, red, vpv, cnt


@dataclass
class VarianceComponents:
    """Outcome of :func:`estimate_variance_components`.

    Attributes
    ----------
    names : list of str
    scale : (k,)
        Estimated sigma of each group divided by its a-priori sigma (dimensionless).
    scale_sigma : (k,)
        Standard deviation of ``scale``, ``scale / sqrt(2 r_k)``.
    redundancy : (k,)
        Each group's share of the redundancy in the last adjustment.
    observations : (k,)
        Scalar observations of each group.
    estimated : (k,) bool
        Groups whose sigma was estimated (others kept their a-priori sigma).
    history : list of (k,)
        Variance factors of every round (1 when converged).
    weights : Weights
        The sigma factors of the last adjustment (apply with :func:`~lunarmap.adjust.weights.reweighted_problem`).
    result : AdjustmentResult
        The last adjustment.
    converged : bool
    scale_sigma_joint : (k,), optional
        Standard deviation of ``scale`` from the joint (Helmert) covariance of all estimated groups
        (:func:`variance_component_covariance`): larger than ``scale_sigma`` where the data trade one
        group against another. None for blocks above its size limit; NaN for groups not estimated (a
        group frozen at the boundary, ``on_weak="freeze"``, counts as estimated here).
    correlation : (k, k), optional
        Correlation of the estimated groups' variance factors (NaN rows for groups not estimated);
        near -1 for groups the data cannot separate.
    """

    names: list
    scale: NDArray[np.float64]
    scale_sigma: NDArray[np.float64]
    redundancy: NDArray[np.float64]
    observations: NDArray[np.int64]
    estimated: NDArray[np.bool_]
    history: list
    weights: Weights
    result: AdjustmentResult
    converged: bool
    scale_sigma_joint: NDArray[np.float64] | None = None
    correlation: NDArray[np.float64] | None = None


def _apply_group_scale(w: Weights, groups: ObservationGroups, step: NDArray) -> None:
    g = groups.image
    w.image_sigma[g >= 0] *= step[g[g >= 0]]
    n_base = groups.control.size
    gc = groups.control
    w.control_sigma[:n_base][gc >= 0] *= step[gc[gc >= 0]]
    for f, gt in zip(w.term_sigma, groups.terms):
        f[gt >= 0] *= step[gt[gt >= 0]]
    # the groups' own factors, that a down-weighted row returns to when it is given back
    assert w.control_vc is not None and w.term_vc is not None
    w.control_vc[:n_base][gc >= 0] *= step[gc[gc >= 0]]
    for f, gt in zip(w.term_vc, groups.terms):
        f[gt >= 0] *= step[gt[gt >= 0]]


def _back_to_apriori(w: Weights, groups: ObservationGroups, total: NDArray, weak: NDArray) -> NDArray:
    """Give the ``weak`` groups their a-priori sigma back (in ``w``); returns the running scales, exactly 1 there."""
    _apply_group_scale(w, groups, np.where(weak, 1.0 / total, 1.0))
    return np.where(weak, 1.0, total)


def _weak_group(groups: ObservationGroups, r: NDArray, n: NDArray, j: int,
                min_redundancy: float) -> VarianceComponentError:
    """The error for group ``j``, whose redundancy is too small for its variance component."""
    return VarianceComponentError(
        f"group {groups.names[j]!r} has redundancy {max(float(r[j]), 0.0):.2f} ({int(n[j])} observations): its variance "
        f"component cannot be estimated (needs >= {min_redundancy:g}); merge it with another group, or "
        f"keep its a-priori sigma (on_weak='keep')")


def estimate_variance_components(problem: BundleProblem, groups: ObservationGroups,
                                 options: SolverOptions | None = None, weights: Weights | None = None,
                                 estimate: NDArray | None = None, rounds: int = 60, tol: float = 1e-3,
                                 min_redundancy: float = 1.0, on_weak: str = "raise",
                                 start: AdjustmentResult | None = None, accelerate: bool = True,
                                 terms: list | None = None) -> VarianceComponents:
    """Adjust, estimate every group's variance factor, rescale the groups' sigmas, repeat until all are 1.

    Parameters
    ----------
    problem : BundleProblem
        The base problem (its sigmas are the starting values).
    groups : ObservationGroups
    options : SolverOptions, optional
    weights : Weights, optional
        Weights to start from (e.g. after blunder removal); their sigma factors are updated.
    estimate : (k,) bool, optional
        Groups to estimate (default all); the others keep their sigma but count in the adjustment.
    rounds : int
        Maximum number of adjustments.
    tol : float
        Stop when every estimated factor ``s_k^2`` is within ``1 +- tol``.
    min_redundancy : float
        A group with less redundancy cannot be estimated.
    on_weak : {"raise", "keep", "freeze"}
        What to do with such a group -- or with one whose redundancy collapses while its sigma keeps
        shrinking (the boundary of the estimate: the data cannot tell it from another group, e.g.
        a narrow camera's navigation positions from its attitudes): raise
        :class:`~lunarmap.errors.VarianceComponentError`, keep its a-priori sigma, or freeze it
        where the iteration took it (both with ``estimated`` False).
    start : AdjustmentResult, optional
        Start values of the first adjustment.
    accelerate : bool
        Anderson acceleration of the iteration (else each round multiplies a group's sigma by ``s_k``).
    terms : list, optional
        Camera-level terms replacing the problem's (same rows as ``groups.terms``).

    Raises
    ------
    VarianceComponentError
        A group with redundancy below ``min_redundancy`` (``on_weak="raise"``); names the group.
    """
    from ..errors import QualityControlInputError

    if on_weak not in ("raise", "keep", "freeze"):
        raise QualityControlInputError(f"on_weak must be 'raise', 'keep' or 'freeze', got {on_weak!r}")
    if not (tol > 0 and min_redundancy > 0):
        raise QualityControlInputError(f"tol and min_redundancy must be > 0, got {tol}, {min_redundancy}")
    k = groups.n
    est = np.ones(k, bool) if estimate is None else np.asarray(estimate, bool).copy()
    if est.shape != (k,):
        raise QualityControlInputError(f"estimate needs {k} values (one per group), got {est.shape}")
    frozen = np.zeros(k, bool)      # taken to the boundary by the iteration and left there ("freeze")
    w = Weights.neutral(problem) if weights is None else weights.copy()
    # the datum does not depend on the weights; extreme starting weights (x100 / x0.01 of the truth)
    # would trip the eigenvalue test of the first adjustment (the posterior precision still
    # refuses a singular system)
    opts = dataclasses.replace(options or SolverOptions(), check_datum=False)
    total = np.ones(k)
    history = []
    cam, pts = (None, None) if start is None else (start.cam_params, start.points)
    result = solve(reweighted_problem(problem, w, cam, pts, terms), opts)
    f, r, _, n = group_variance_factors(result, groups)
    # a group's redundancy never exceeds its observation count; and one with (numerically) none at the first
    # adjustment has none at any weights: an observation with redundancy number 0 is one the parameters need
    # (h_ii = 1 whatever the positive weights), so iterating cannot give it any (a block with r = 0 spent its
    # whole round budget before the error)
    few = est & ((n <= min_redundancy) | ~(r > 1e-9 * np.maximum(n, 1)))
    if few.any():
        if on_weak == "raise":
            raise _weak_group(groups, r, n, int(np.argmax(few)), min_redundancy)
        est &= ~few
    converged = False
    # Anderson acceleration of the fixed-point iteration x <- x + log f(x) on the log variance
    # scales: groups that the data separate poorly (navigation positions vs attitudes of a narrow
    # camera) otherwise gain ~1 % per round
    xs: list[NDArray] = []
    fs: list[NDArray] = []
    x = np.zeros(k)
    saved = None
    scales: list[NDArray] = []
    for _ in range(max(rounds, 1)):
        f, r, _, n = group_variance_factors(result, groups)
        # a group with (numerically) no redundancy in this round cannot move: its factor is 0 / 0; one with
        # almost none cannot shrink either -- its factor is noise, and following it down makes the weights
        # explode within a few rounds (it can grow: a too-small sigma is what takes the redundancy away)
        live = (est & (r > 1e-9 * np.maximum(n, 1)) & np.isfinite(f) & (f > 0)
                & ~((r < BOUNDARY_REDUNDANCY) & (f < 1.0)))
        if saved is not None and (live != est).any():
            # an accelerated step overshot into a group without redundancy: back to the plain iteration
            w, result, x, total, f, r, n, live = saved
            accelerate, saved = False, None
            xs, fs = [], []
        history.append(f.copy())
        # a group whose redundancy has collapsed is at the boundary (its sigma heading to 0: the data
        # cannot tell it from another group, e.g. positions from attitudes): decide on it now
        scales.append(total.copy())
        shrinking = np.zeros(k, bool)
        if len(scales) > 10:
            last = np.array(scales[-6:])
            shrinking = np.all(np.diff(last, axis=0) < 0.0, axis=0)
        collapsed = est & (r < BOUNDARY_REDUNDANCY) & (f < 1.0) & shrinking
        # groups below the redundancy needed do not hold the others up (they are decided on below)
        settled = live & (r >= min_redundancy)
        if collapsed.any() or (np.all(np.abs(f[settled] - 1.0) <= tol) and settled.any()):
            weak = est & (~(r >= min_redundancy) | collapsed)
            if not weak.any():
                converged = True
                break
            if on_weak == "raise":
                raise _weak_group(groups, r, n, int(np.argmax(weak)), min_redundancy)
            est &= ~weak
            if on_weak == "freeze":
                frozen |= weak
            if on_weak == "keep":
                # back to the a-priori sigma of the weak groups, estimate the others again
                total = _back_to_apriori(w, groups, total, weak)
                x = np.where(weak, 0.0, x)
            # "freeze": the weak groups stay where the iteration took them
            xs, fs, saved = [], [], None
            result = solve(reweighted_problem(problem, w, result.cam_params, result.points, terms), opts)
            continue
        F = np.where(live, np.log(np.where(live, f, 1.0)), 0.0)
        xs.append(x.copy())
        fs.append(F)
        x_new = x + F
        saved = None
        if accelerate and len(xs) >= 2 and np.max(np.abs(F)) < 0.2:
            m = min(len(xs) - 1, 3)
            dX = np.column_stack([xs[-i] - xs[-i - 1] for i in range(1, m + 1)])
            dF = np.column_stack([fs[-i] - fs[-i - 1] for i in range(1, m + 1)])
            gamma = np.linalg.lstsq(dF, F, rcond=None)[0]
            cand = x + F - (dX + dF) @ gamma
            # near the fixed point only, and within a factor 1.5 of the plain step's variance per group
            x_new = np.where(live, np.clip(cand, x + F - 0.4, x + F + 0.4), x)
            saved = (w.copy(), result, x.copy(), total.copy(), f, r, n, live)
        step = np.exp(0.5 * (x_new - x))
        x = x_new
        total *= step
        _apply_group_scale(w, groups, step)
        result = solve(reweighted_problem(problem, w, result.cam_params, result.points, terms), opts)
    f, r, _, n = group_variance_factors(result, groups)
    weak = est & ~(r >= min_redundancy)
    if not converged and on_weak != "raise" and weak.any():
        # out of rounds with groups still below the redundancy needed: they are not estimated
        est &= ~weak
        if on_weak == "freeze":
            frozen |= weak
        if on_weak == "keep":
            total = _back_to_apriori(w, groups, total, weak)
            result = solve(reweighted_problem(problem, w, result.cam_params, result.points, terms), opts)
            f, r, _, n = group_variance_factors(result, groups)
    if not converged and on_weak == "raise" and np.any(est & ~(r >= min_redundancy)):
        j = int(np.argmax(est & ~(r >= min_redundancy)))
        raise VarianceComponentError(
            f"group {groups.names[j]!r} has redundancy {r[j]:.2f} ({int(n[j])} observations) after {rounds} "
            f"rounds: its variance component cannot be estimated (needs >= {min_redundancy:g})")
    scale = total * np.sqrt(np.where(est & np.isfinite(f) & (f > 0), f, 1.0))
    joint = corr = None
    # a group frozen at the boundary was estimated until the data could not tell it from another: the joint
    # covariance shows with which (its sigma is the trade-off's, not the sigma of a known group)
    cov = variance_component_covariance(result, groups, est | frozen)
    if cov is not None:
        D, corr = cov
        joint = scale * np.sqrt(np.diag(D)) / 2.0
    return VarianceComponents(list(groups.names), scale, scale / np.sqrt(2.0 * np.maximum(r, 1e-12)), r, n, est,
                              history, w, result, converged, joint, corr)


#: the joint covariance of variance components needs the dense redundancy matrix: blocks up to this many
#: observation rows
JOINT_MAX_ROWS = 3000


def _dense_design(result: AdjustmentResult, groups: ObservationGroups) -> tuple[NDArray, NDArray]:
    """The whitened design matrix of the adjustment's free unknowns (image rows, camera-level term rows,
    control rows), and the group of every row (-1: none)."""
    from .normal import Terms, linearize

    pb = result.problem
    st = result.structure
    terms = Terms(pb)
    fixed_pt = pb.point_fixed()
    lin = linearize(pb, result.state, st, terms, fixed_pt)
    o = pb.obs
    p = lin.Ac.shape[2]
    n_red = result.free_red.size
    img = np.flatnonzero(result.state.obs_weight > 0)
    m_img = 2 * img.size
    m_t = 0 if lin.Jx is None else lin.Jx.shape[0]
    pt = prior_terms(pb, result.points)
    m_p = 0 if pt is None else 3 * pt[0].size
    J = np.zeros((m_img + m_t + m_p, n_red + 3 * pb.n_points))
    rows = np.arange(m_img).reshape(-1, 2)
    cols = o.cam_idx[img][:, None] * p + np.arange(p)
    J[rows[:, :, None], cols[:, None, :]] = lin.Ac[img]
    cols = n_red + o.pt_idx[img][:, None] * 3 + np.arange(3)
    J[rows[:, :, None], cols[:, None, :]] = lin.Ap[img]
    g = [np.repeat(groups.image[img], 2)]
    if m_t and lin.Jx is not None:
        J[m_img:m_img + m_t, :n_red] = lin.Jx.toarray()
        if lin.xp_rows is not None and lin.xp_idx is not None and lin.xp_J is not None:
            # point-observing term rows (reference DTM heights)
            cols = n_red + lin.xp_idx[:, None] * 3 + np.arange(3)
            J[m_img + lin.xp_rows[:, None], cols] = lin.xp_J
        g += list(groups.terms)
    if m_p:
        idx, _, W = pt
        rows = m_img + m_t + np.arange(m_p).reshape(-1, 3)
        cols = n_red + idx[:, None] * 3 + np.arange(3)
        J[rows[:, :, None], cols[:, None, :]] = W
        gc = -np.ones(idx.size, np.int64)
        n_base = groups.control.size
        weighted = ~pb.priors.fixed
        mine = groups.control[weighted[:n_base]]      # weighted rows of the base priors come first
        gc[:mine.size] = mine
        g.append(np.repeat(gc, 3))
    free = np.concatenate([result.free_red, np.repeat(~fixed_pt, 3)]) & np.any(J != 0.0, axis=0)
    return J[:, free], np.concatenate(g).astype(np.int64)


def variance_component_covariance(result: AdjustmentResult, groups: ObservationGroups,
                                  estimated: NDArray | None = None, max_rows: int = JOINT_MAX_ROWS
                                  ) -> tuple[NDArray, NDArray] | None:
    """Joint covariance of the estimated groups' variance factors ``s_k^2`` at the adjustment (Helmert).

    With ``R = I - A (A^T A)^-1 A^T`` the redundancy matrix of the whitened design ``A``, the square sums
    ``q_k = v^T P_k v`` of normally distributed observations have ``Cov(q_k, q_l) = 2 H_kl``,
    ``H_kl = sum_{i in k, j in l} R_ij^2`` (``H_kk ~ r_k`` when the groups do not interact), and at the
    converged weights (all ``s_k^2 = 1``) the estimates have covariance ``D = 2 H^-1`` over the estimated
    groups. Two groups the images see only as a sum (a narrow camera's navigation positions and
    attitudes) show as a correlation near -1 and a ``sqrt(D_kk / 4)`` far above ``1 / sqrt(2 r_k)``.

    Returns
    -------
    (D, correlation) : ((k, k), (k, k)), or None
        NaN in the rows and columns of groups not estimated; None if the block has more than
        ``max_rows`` observation rows (the redundancy matrix is dense).
    """
    k = groups.n
    est = np.ones(k, bool) if estimated is None else np.asarray(estimated, bool)
    n_rows = 2 * int(np.sum(result.state.obs_weight > 0)) + sum(t.size for t in groups.terms) + 3 * groups.control.size
    if n_rows > max_rows:
        return None
    J, g = _dense_design(result, groups)
    # R = I - A Q A^T through the thin QR of A (no normal matrix: its condition number is squared)
    qmat, rr = np.linalg.qr(J)
    keep = np.abs(np.diag(rr)) > 1e-12 * np.max(np.abs(np.diag(rr)))
    qmat = qmat[:, keep]
    R = -(qmat @ qmat.T)
    R[np.diag_indices_from(R)] += 1.0
    sel = np.flatnonzero(est)
    G = np.zeros((g.size, sel.size))
    for c, j in enumerate(sel):
        G[g == j, c] = 1.0
    H = G.T @ (R * R) @ G
    D = np.full((k, k), np.nan)
    corr = np.full((k, k), np.nan)
    if sel.size:
        Dk = 2.0 * np.linalg.pinv(H)
        d = np.sqrt(np.maximum(np.diag(Dk), 0.0))
        D[np.ix_(sel, sel)] = Dk
        with np.errstate(invalid="ignore", divide="ignore"):
            corr[np.ix_(sel, sel)] = Dk / np.outer(d, d)
    return D, corr
