"""Quality control of the block adjustment (issue 11; the DLR paper, ``seeds/004``, sections 3-4).

:func:`quality_control` runs, in the order asked for, on any :class:`~lunarmap.adjust.BundleProblem`
(any image model: frame and line-scan cameras, RFMs, the BAL model):

* ``"sequent"`` -- pre-screening of conjugate points by intersecting them from pairs and growing
  subsets of their rays (:mod:`.sequent`);
* ``"robust"`` -- robust (Danish; or Huber, Cauchy) reweighting of the image observations inside the
  iteration (:mod:`.robust`);
* ``"baarda"`` -- data snooping with w-tests of every observation: image coordinates, navigation
  positions and attitudes, control coordinates (:mod:`.snooping`);
* ``"variance"`` -- variance components of the paper's groups: image coordinates per camera,
  navigation positions and attitudes per orbit, control points
  (:func:`~lunarmap.adjust.variance.estimate_variance_components`);
* ``"offsets"`` -- two-stage detection of per-orbit navigation offsets and drifts (:mod:`.offsets`).

Every run ends with a final status per observation (:mod:`.status`) and a verdict on whether the block
it leaves is clean (:mod:`.ending`: a :class:`~lunarmap.errors.QualityControlWarning` and report flags if not).

Indices never change (:mod:`.ledger`): removed observations get weight 0, points without rays are
held fixed, so the :class:`QCReport` refers to the user's own observations, points and images.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
import xarray as xr
from numpy.typing import NDArray

from ...errors import (
    AdjustmentError,
    QualityControlError,
    QualityControlInputError,
    QualityControlWarning,
    VarianceComponentError,
    warn,
)
from ..problem import BundleProblem
from ..result import AdjustmentResult
from ..solver import SolverOptions
from ..variance import ObservationGroups, VarianceComponents, estimate_variance_components, observation_groups
from .ending import SIGMA0_ALPHA, Budget, assess
from .ledger import Decision, Ledger, _last_result
from .offsets import offset_drift_step
from .report import QCReport
from .robust import CONSENSUS_CUT, CONSENSUS_RAYS, WEIGHT_FUNCTIONS, consensus_points, robust_step, weight_function
from .sequent import SequentResult, sequent_screening
from .snooping import snooping_step, w_tests
from .status import STATUSES, final_status

__all__ = ["quality_control", "QCOptions", "QCResult", "QCReport", "Decision", "Ledger", "STEPS",
           "sequent_screening", "SequentResult", "robust_step", "snooping_step", "w_tests", "offset_drift_step",
           "WEIGHT_FUNCTIONS", "weight_function", "block_result", "Budget", "final_status", "STATUSES",
           "auto_robust_decision", "AUTO_ROBUST_FRACTION"]

_log = logging.getLogger(__name__)

#: the quality-control steps, by name
STEPS = ("sequent", "robust", "baarda", "variance", "offsets")


@dataclass
class QCOptions:
    """Settings of :func:`quality_control` (keyword arguments of each step's function).

    Attributes
    ----------
    sequent_limit_km : float
        Sequent limit (:func:`~.sequent.sequent_screening`).
    units_per_km : float
        Length unit of the block per kilometre (1000 for metres).
    robust, baarda, variance, offsets : dict
        Keyword arguments of :func:`~.robust.robust_step`, :func:`~.snooping.snooping_step`,
        :func:`~lunarmap.adjust.variance.estimate_variance_components`, :func:`~.offsets.offset_drift_step`.
    solver : SolverOptions, optional
    robust_start : bool
        Without the Sequent step, start every point at the intersection of its best pair of rays
        (nothing is removed; a gross error then cannot drag the start).
    max_rounds : int, optional
        Budget of the run: adjustments after the first one (:class:`~.ending.Budget`; default no limit).
    max_seconds : float, optional
        Budget of the run: wall-clock seconds, checked between rounds (default no limit).
    sigma0_alpha : float
        Two-sided significance of the chi-square test of the final sigma0 (:func:`~.ending.assess`).
    robust_prepass : {"auto", True, False}
        Steps that start with ``"baarda"`` (no Sequent, no robust step before it): run a robust (Danish)
        pre-pass before the data snooping. ``"auto"`` decides from the w-tests of the first least-squares
        adjustment (:func:`auto_robust_decision`); ``True`` / ``False`` force it. The decision and its
        deciding figures are in ``report.summary["auto_robust_start"]``.
    """

    sequent_limit_km: float = 10.0
    units_per_km: float = 1000.0
    robust: dict = field(default_factory=dict)
    baarda: dict = field(default_factory=dict)
    variance: dict = field(default_factory=dict)
    offsets: dict = field(default_factory=dict)
    solver: SolverOptions | None = None
    robust_start: bool = True
    max_rounds: int | None = None
    max_seconds: float | None = None
    sigma0_alpha: float = SIGMA0_ALPHA
    robust_prepass: str | bool = "auto"


@dataclass
class QCResult:
    """Outcome of :func:`quality_control`.

    Attributes
    ----------
    result : AdjustmentResult
        The last adjustment (with the final weights).
    problem : BundleProblem
        The problem of the last adjustment (same indices as the input).
    report : QCReport
    ledger : Ledger
        Weights and decisions (reuse it to continue).
    sequent : SequentResult or None
    variance : VarianceComponents or None
    offsets : dict or None
        :func:`~.offsets.offset_drift_step`'s outcome.
    """

    result: AdjustmentResult
    problem: BundleProblem
    report: QCReport
    ledger: Ledger
    sequent: SequentResult | None = None
    variance: VarianceComponents | None = None
    offsets: dict | None = None

    def image_status(self) -> NDArray[np.str_]:
        """The final status (:data:`~.status.STATUSES`) of every image observation, by index: the image rows of
        :meth:`QCReport.final_status`; for a report without the table, ``"in"`` / ``"removed"`` from the
        ledger's active flags."""
        st = self.report.status
        if st is None:
            return np.where(self.ledger.active, "in", "removed")
        out = np.full(self.problem.obs.n, "in", dtype=object)
        img = st["kind"].values == "image"
        out[st["index"].values[img].astype(np.int64)] = st["status"].values[img]
        return out.astype(str)

    @property
    def removed_image_observations(self) -> NDArray[np.int64]:
        """Image observations that are not in the final adjustment (removed, withdrawn or set aside: every
        image observation whose :meth:`image_status` is not ``"in"``)."""
        return np.flatnonzero(self.image_status() != "in")


def _best_pair_start(problem: BundleProblem, units_per_km: float) -> BundleProblem:
    """The problem with every free point starting at the intersection of its best pair of rays.

    Without the Sequent pre-screening a gross error of thousands of pixels drags the least-squares
    intersection of a point far off, and the adjustment started there can drag it onto a projection
    centre (where its partials blow up); the best pair (:mod:`.sequent`) is a start free of it.
    Nothing is removed.
    """
    seq = sequent_screening(problem, limit_km=1e12, units_per_km=units_per_km, pairs_only=True)
    best = seq.points["best_pair"].values
    ok = np.all(best >= 0, axis=1) & ~problem.point_fixed()
    if problem.priors is not None:
        ok[problem.priors.idx] = False
    pts = np.flatnonzero(ok)
    if pts.size == 0:
        return problem
    o = problem.obs
    obs = best[pts].ravel()
    from ..intersection import intersect_points

    X = problem.points.copy()
    with np.errstate(all="ignore"):
        Xb = intersect_points(problem.model, problem.cam_params, o.cam_idx[obs], np.repeat(np.arange(pts.size), 2),
                              o.xy[obs], o.sigma[obs], n_pt=pts.size).xyz
    good = np.all(np.isfinite(Xb), axis=1)
    X[pts[good]] = Xb[good]
    # a pair of gross errors can intersect behind another camera of the point: keep those starts
    return _with_starts(problem, X)



def _consensus_start(problem: BundleProblem, cut: float = CONSENSUS_CUT,
                     max_rays: int = CONSENSUS_RAYS) -> BundleProblem:
    """The problem with every free point starting at the pair intersection most of its rays agree with
    (:func:`~.robust.consensus_points` at the problem's images).

    A redescending robust adjustment cannot leave the basin it starts in: from the pair of smallest
    intersection sigma (:func:`_best_pair_start`), a gross error along the epipolar line of one good ray is a
    consistent pair at a wrong position, and the point's other good rays are then cut as its outliers.
    Points whose winning intersection is behind one of their cameras keep their start; nothing is removed.
    """
    o = problem.obs
    free = ~problem.point_fixed()
    if problem.priors is not None:
        free[problem.priors.idx] = False
    use = (np.asarray(problem.obs_weight) > 0) & free[o.pt_idx]
    Xc = consensus_points(problem.model, problem.cam_params, o.cam_idx[use], o.pt_idx[use], o.xy[use],
                          o.sigma[use], problem.n_points, cut, max_rays)
    ok = np.all(np.isfinite(Xc), axis=1)
    X = problem.points.copy()
    X[ok] = Xc[ok]
    # a pair can intersect behind another camera of its point: those keep their start
    return _with_starts(problem, X)


def _with_starts(problem: BundleProblem, X: np.ndarray) -> BundleProblem:
    """The problem with points ``X``, except those a camera of theirs cannot project (behind it, or not
    finite there), which keep their previous start."""
    o = problem.obs
    with np.errstate(all="ignore"):
        x = problem.model.project(problem.cam_params, o.cam_idx, X[o.pt_idx])
    bad = np.zeros(problem.n_points, bool)
    bad[o.pt_idx[~np.all(np.isfinite(x), axis=1)]] = True
    X[bad] = problem.points[bad]
    return dataclasses.replace(problem, points=X)

#: the auto robust pre-pass runs when more than this fraction of the active image observations fail their w-test
#: after the first least-squares adjustment. Off (1.0) by default: on 20 random blocks of bench/qc_blocks.py the
#: dirty blocks fail 96-99 % of their w-tests there, and a pre-pass on all of them found every error in 13/20
#: blocks against 17/20 for data snooping alone, false removals beyond the clean block's in 6/20 against 2/20
AUTO_ROBUST_FRACTION = 1.0


def auto_robust_decision(ledger: Ledger, baarda: dict | None = None, budget: Budget | None = None,
                         fraction: float = AUTO_ROBUST_FRACTION) -> dict:
    """Whether data snooping alone should be preceded by a robust pre-pass, from the ledger's last adjustment.

    Data snooping removes one observation per adjustment, each judged against a solution that all the
    others still distort. Where many large errors are in the block, their residuals spread into the good
    observations of their points and images: the w-tests of most observations fail, the largest one may
    point at a good observation, and the rounds needed exceed what the run can pay. The deciding figures,
    from the w-tests of the last adjustment (the first least-squares one) with the snooping's own settings:

    * ``failing_fraction``: active image observations with ``|w|`` above the limit, over the active ones;
      above ``fraction`` the pre-pass runs;
    * ``failing`` against ``rounds_available`` (the snooping's ``max_rounds``, or the run's budget left if
      smaller): one removal per round cannot take more errors than it has rounds, so the pre-pass runs when
      the failing observations outnumber them;
    * no precision at the first adjustment (gross errors distort it beyond repair): the pre-pass runs.

    Parameters
    ----------
    ledger : Ledger
        After its first adjustment.
    baarda : dict, optional
        The snooping's keyword arguments (``limit``, ``sigma0``, ``min_redundancy``, ``max_rounds``).
    budget : Budget, optional
        The run's budget (its rounds left bound the snooping's).
    fraction : float
        Failing fraction above which the pre-pass runs.

    Returns
    -------
    dict
        ``run`` (bool), ``reason`` (str), ``failing``, ``active``, ``failing_fraction``, ``max_w``,
        ``rounds_available`` (None: no limit), ``limit``, ``fraction``.
    """
    kw = baarda or {}
    limit = float(kw.get("limit", 4.0))
    rounds = int(kw.get("max_rounds", 500))
    if budget is not None and budget.max_rounds is not None:
        rounds = min(rounds, max(int(budget.max_rounds) - budget.rounds, 0))
    act = ledger.active
    out: dict = {"limit": limit, "fraction": float(fraction), "active": int(act.sum()), "rounds_available": rounds}
    try:
        tests = w_tests(ledger, str(kw.get("sigma0", "apriori")), float(kw.get("min_redundancy", 0.02)), limit)
    except QualityControlError as exc:
        out.update(run=True, failing=-1, failing_fraction=float("nan"), max_w=float("nan"),
                   reason=f"no precision at the first adjustment ({str(exc)[:120]})")
        return out
    # an observation's largest |w| over its coordinates (0 where none was tested: NaN)
    w_obs = np.nan_to_num(np.abs(tests["image"]), nan=0.0).max(axis=1)
    failing = int(np.sum(act & (w_obs > limit)))
    frac = failing / max(int(act.sum()), 1)
    out.update(failing=failing, failing_fraction=float(frac), max_w=float(np.max(w_obs[act])) if act.any() else 0.0)
    if frac > fraction:
        out.update(run=True, reason=f"{100 * frac:.1f} % of the image observations fail their w-test "
                                    f"(> {100 * fraction:g} %)")
    elif failing > rounds:
        out.update(run=True, reason=f"{failing} image observations fail their w-test, more than the "
                                    f"{rounds} rounds the snooping has")
    else:
        out.update(run=False, reason=f"{100 * frac:.1f} % of the image observations fail their w-test "
                                     f"(<= {100 * fraction:g} %), {failing} <= {rounds} rounds")
    return out


def _auto_robust_start(ledger: Ledger, steps: list, opt: QCOptions, budget: Budget, summary: dict) -> list:
    """The steps to run when data snooping comes first: a robust pre-pass before it when
    :func:`auto_robust_decision` (or ``QCOptions.robust_prepass`` forcing it) says so; the decision in
    ``summary["auto_robust_start"]``."""
    # the figures also when the choice is forced: the report says what the rule would have decided
    dec = auto_robust_decision(ledger, opt.baarda, budget)
    dec["mode"] = "auto"
    if opt.robust_prepass != "auto":
        dec.update(mode="forced", rule=dec["run"], run=bool(opt.robust_prepass),
                   reason=f"QCOptions.robust_prepass={opt.robust_prepass!r} (the rule: {dec['reason']})")
    summary["auto_robust_start"] = dec
    _log.info("quality control: robust pre-pass %s (%s)", "on" if dec["run"] else "off", dec["reason"])
    if not dec["run"]:
        return list(steps)
    summary["steps_run"] = ["robust"] + list(steps)
    return ["robust"] + list(steps)


def _groups(ledger: Ledger, image_group, image_group_names) -> ObservationGroups:
    pb = dataclasses.replace(ledger.base, terms=list(ledger.terms))
    groups = observation_groups(pb, image_group, image_group_names)
    for t, g in enumerate(groups.terms):
        # a DTM row out with its point weighs nothing and is explained by nothing: its redundancy number 1 with a
        # zero residual would pull its group's variance component down
        g[ledger.term_rows_out(t)] = -1
    return groups


def quality_control(problem: BundleProblem, steps: Sequence[str] = ("sequent", "baarda", "variance"),
                    image_group: NDArray | None = None, image_group_names: list | None = None,
                    options: QCOptions | None = None) -> QCResult:
    """Quality-controlled adjustment of ``problem`` (module docstring); the steps run in the order given.

    The steps start from a least-squares adjustment of the whole block, except when ``"robust"`` comes
    first: then the robust adjustment is the first one (``summary["first_adjustment"]``), started from the
    problem's values (each free point at its best pair of rays, ``QCOptions.robust_start``). A least-squares
    adjustment of a block with gross errors drags points far along their rays and the robust weights
    computed from it start from that damage: measured on the 2,000-image block, it cost most of the run
    and found a fraction of the errors.

    Parameters
    ----------
    problem : BundleProblem
        Observations with their a-priori sigmas; navigation observations as camera-level terms.
    steps : sequence of str
        Any of :data:`STEPS`, in the order to run them (each at most once).
    image_group : (n_img,), optional
        Camera (or any group label) of every image: the image-coordinate groups of the variance
        components and of the report (default one group).
    image_group_names : list of str, optional
    options : QCOptions, optional

    The run's cost is bounded by ``QCOptions.max_rounds`` / ``max_seconds`` (:class:`~.ending.Budget`); a step
    the budget does not reach is skipped. A step that fails on the data (an adjustment error inside it) ends
    the run on what it has: its error is a flag and a ``"failed"`` decision, not an exception. The report's
    :meth:`~.report.QCReport.final_status` gives every observation's final status.

    Raises
    ------
    QualityControlInputError
        An unknown or repeated step, a bad setting of a step, a bad budget.
    VarianceComponentError
        A group whose variance component cannot be estimated (unless ``variance={"on_weak": "keep"}``).
    AdjustmentError
        The first adjustment fails (there is no result to report).

    Warns
    -----
    QualityControlWarning
        The run ended without a clean block (:func:`~.ending.assess`: budget spent, a step failed, sigma0
        outside its chi-square bounds, large w-tests or untestable residuals left, no redundancy); the flags
        are in ``report.summary["flags"]`` and ``report.clean`` is False.
    """
    opt = options or QCOptions()
    steps = list(steps)
    bad = [s for s in steps if s not in STEPS]
    if bad or len(set(steps)) != len(steps):
        raise QualityControlInputError(f"quality-control steps must be distinct names of {STEPS}, got {steps}")
    if not (0.0 < opt.sigma0_alpha < 1.0):
        raise QualityControlInputError(f"sigma0_alpha must be in (0, 1), got {opt.sigma0_alpha!r}")
    if isinstance(opt.robust_prepass, str) and opt.robust_prepass != "auto" or \
            not isinstance(opt.robust_prepass, (str, bool)):
        raise QualityControlInputError(f"robust_prepass must be 'auto', True or False, got {opt.robust_prepass!r}")
    budget = Budget(opt.max_rounds, opt.max_seconds)
    groups0 = observation_groups(problem, image_group, image_group_names)
    obs_names = np.array(groups0.names, dtype=object)[groups0.image]
    ledger = Ledger(problem, obs_names)
    ledger.budget = budget
    robust_first_step = steps[:1] == ["robust"]
    if "sequent" not in steps and opt.robust_start:
        # a robust adjustment first starts every point where most of its rays agree; the data snooping keeps the
        # best pair's start it was measured with (its first rounds are linearised at the navigation anyway)
        problem = (_consensus_start(problem) if robust_first_step
                   else _best_pair_start(problem, opt.units_per_km))
        ledger.base = problem
    seq = vc = off = None
    summary: dict = {"steps": steps}
    robust_first = steps[:1] == ["robust"]
    if robust_first:
        # the robust adjustment is the first one: a least-squares adjustment of a block with gross errors
        # drags points far along their rays and crawls for its whole iteration budget, and the robust
        # weights computed from it start from that damage (measured on the 2,000-image block and the DLR
        # blocks: the README's quality-control section)
        first, sigma0_first = None, np.nan
        summary["first_adjustment"] = "robust"
        _log.info("quality control: steps %s; the first adjustment is the robust one", " -> ".join(steps))
    else:
        first = ledger.adjust(opt.solver)
        sigma0_first = first.sigma0
        summary["first_adjustment"] = "least squares"
        _log.info("quality control: first adjustment, sigma0 %.3f; steps %s", first.sigma0, " -> ".join(steps))
    run_steps = list(steps)
    if steps[:1] == ["baarda"] and "sequent" not in steps:
        run_steps = _auto_robust_start(ledger, steps, opt, budget, summary)
    prepass = run_steps[:1] == ["robust"] and not robust_first
    for k_step, step in enumerate(run_steps):
        why = budget.exhausted()
        if why:
            summary["budget_spent"] = why
            summary["steps_unfinished"] = run_steps[k_step:]
            break
        ledger.step = step
        t_step, n_dec = time.perf_counter(), len(ledger.decisions)
        try:
            if prepass and k_step == 0:
                # the pre-pass starts from the problem's values (each free point at its best pair of rays), not
                # from the least-squares adjustment whose damage made it necessary; points that adjustment set
                # aside on a projection centre are judged by their rays again
                ledger.reinstate_set_aside("robust")
                ledger.result = None
            first, sigma0_first, seq, vc, off = _run_step(step, run_steps, ledger, problem, opt, summary, first,
                                                          sigma0_first, robust_first, image_group,
                                                          image_group_names, seq, vc, off)
        except (QualityControlInputError, VarianceComponentError):
            raise
        except AdjustmentError as exc:
            # the data broke a step (a geometry no start value fits, a precision that cannot be computed):
            # the run ends on what it has, flagged, instead of dying on the data it was meant to clean
            _log.warning("quality control: step %s failed on the data: %s", step, exc)
            summary.setdefault("step_errors", []).append(f"{step}: {type(exc).__name__}: {exc}")
            summary["steps_unfinished"] = run_steps[k_step:]
            ledger.decisions.append(Decision(step, 0, "step", k_step, action="failed", group=str(exc)[:200]))
            try:
                ledger.adjust(opt.solver)           # the result of what the steps decided so far
            except AdjustmentError as exc2:
                summary["step_errors"].append(f"final adjustment: {type(exc2).__name__}: {exc2}")
                if ledger.result is None:
                    raise
            break
        if summary.get("budget_spent"):
            summary["steps_unfinished"] = run_steps[k_step:]
            break
        acted = [d for d in ledger.decisions[n_dec:]
                 if d.action in ("removed", "downweighted", "flagged", "withdrawn")]
        _log.info("quality control: %s done in %.1f s: %d observations removed / down-weighted / flagged, "
                  "%d image observations active", step, time.perf_counter() - t_step, len(acted),
                  int(ledger.active.sum()))
    if ledger.result is None:
        ledger.adjust(opt.solver)
    res = _last_result(ledger)
    summary["sigma0_first"] = float(sigma0_first)
    summary["sigma0_last"] = float(res.sigma0)
    summary["rounds"] = budget.rounds
    summary["seconds"] = float(time.perf_counter() - budget.start)
    flags = assess(res, summary, float(opt.baarda.get("limit", 4.0)), opt.sigma0_alpha, ledger.active)
    summary["clean"] = not flags
    summary["flags"] = flags
    if flags:
        warn("quality control ended without a clean block: " + "; ".join(flags), QualityControlWarning)
    groups_ds = None
    if vc is not None:
        groups_ds = xr.Dataset({"sigma_factor": ("group", vc.scale), "sigma_factor_sigma": ("group", vc.scale_sigma),
                                "redundancy": ("group", vc.redundancy), "observations": ("group", vc.observations),
                                "estimated": ("group", vc.estimated)},
                               coords={"group": np.array(vc.names, dtype=object)})
        if vc.correlation is not None:
            groups_ds["sigma_factor_sigma_joint"] = ("group", vc.scale_sigma_joint)
            groups_ds["correlation"] = (("group", "group_other"), vc.correlation)
            groups_ds = groups_ds.assign_coords(group_other=np.array(vc.names, dtype=object))
    status = final_status(ledger)
    if summary.get("auto_robust_start", {}).get("run"):
        # what the pre-pass took out and nothing gave back: the final status table's rows it decided
        summary["auto_robust_start"]["removed"] = int(np.sum((status["step"].values == "robust")
                                                             & (status["status"].values != "in")))
    report = QCReport(list(ledger.decisions), groups_ds, [] if off is None else off["rounds"], summary, status)
    return QCResult(res, res.problem, report, ledger, seq, vc, off)


def _run_step(step: str, steps: list, ledger: Ledger, problem: BundleProblem, opt: QCOptions, summary: dict,
              first, sigma0_first: float, robust_first: bool, image_group, image_group_names, seq, vc, off):
    """One step of :func:`quality_control` (its loop body); returns the state the loop carries."""
    if step == "sequent":
        # the first adjustment may have set aside points that gross errors dragged onto a projection
        # centre, with all their good rays; Sequent tests the rays themselves, so it gets them back
        ledger.reinstate_set_aside("sequent")
        seq = sequent_screening(ledger.problem(first if first is not None else ledger.result),
                                opt.sequent_limit_km, opt.units_per_km, active=ledger.active,
                                cam_params=problem.cam_params)
        st = seq.points["status"].values
        rejected = np.flatnonzero(ledger.active & ~seq.keep)
        sig = seq.points["sigma"].values
        ledger.remove_image(rejected, "sequent", 0, value=sig[problem.obs.pt_idx[rejected]])
        summary["sequent_points_removed"] = int(np.sum(st == 2))
        ledger.result = None   # start the next adjustment from the problem's own values
    elif step == "robust":
        kw = dict(opt.robust)
        # weights from the start's residuals where the start is a robust one (no Sequent before: each point at the
        # pair its rays agree with, or its best pair); after Sequent the points start at the model's guess, whose
        # residuals say little, and the large errors are gone (measured: DLR blunder draw 4, Sequent -> robust, 3
        # good observations out with start weights, 0 without)
        kw.setdefault("start_weights", "sequent" not in steps[:steps.index("robust")])
        out = robust_step(ledger, options=opt.solver, **kw)
        if robust_first:
            sigma0_first = out["sigma0"]
    elif step == "baarda":
        kw = dict(opt.baarda)
        # after a robust adjustment its solution is the better start; before one, the a-priori values
        # (the navigation) are, and the first rounds are linearised there
        kw.setdefault("linearised", "robust" not in steps[:steps.index("baarda")])
        out = snooping_step(ledger, options=opt.solver, **kw)
        summary["baarda_linear_rounds"] = out["linear_rounds"]
        summary["baarda_rounds"] = out["rounds"]
        summary["max_w"] = out["max_w"]
        summary["untestable"] = out["untestable"]
        summary["untestable_large"] = out["untestable_large"]
        if out["round_limit"]:
            summary["baarda_round_limit"] = True
        if out["budget_spent"]:
            summary["budget_spent"] = out["budget_spent"]
    elif step == "variance":
        groups = _groups(ledger, image_group, image_group_names)
        kw = dict(opt.variance)
        vc = estimate_variance_components(ledger.base, groups, opt.solver, weights=ledger.weights,
                                          start=ledger.result, terms=ledger.terms, **kw)
        ledger.weights = vc.weights
        ledger.result = vc.result
        ledger.budget.rounds += len(vc.history)     # its adjustments, made outside the ledger, count too
        for name, f, e in zip(vc.names, vc.scale, vc.estimated):
            ledger.decisions.append(Decision("variance", len(vc.history), "group", 0, value=float(f),
                                             action="sigma scaled" if e else "kept", group=name))
    elif step == "offsets":
        off = offset_drift_step(ledger, options=opt.solver, **opt.offsets)
    return first, sigma0_first, seq, vc, off


def block_result(qc: QCResult, block):
    """A :class:`~lunarmap.adjust.block.BlockResult` of a quality-controlled :class:`~lunarmap.adjust.block.Block`
    (adjusted sensors, points, check points), the block's problem replaced by the final one."""
    from ..block import BlockResult

    # every field of the block kept (terrain, jitter, altimetry...): only its problem is the QC's final one
    return BlockResult(dataclasses.replace(block, problem=qc.problem), qc.result)
