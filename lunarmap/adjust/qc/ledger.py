"""The state of a quality-controlled adjustment: weights of every observation and every decision taken.

A :class:`Ledger` starts from a problem's a-priori weights and records what each quality-control
step does to them: image observations removed (weight 0), navigation and control observations
down-weighted (their sigma times ``sqrt(factor)``, i.e. ``P_new = P_old / factor``, the DLR paper's
``P/5``), points that lost their rays held fixed, images without observations held fixed. Every
change is a :class:`Decision` (step, round, observation, test value, redundancy number, action).
Indices never change: observation ``i`` of the base problem is observation ``i`` of every
adjustment, so the decisions refer to the user's own measurements.
"""

from __future__ import annotations

import dataclasses
from dataclasses import asdict, dataclass
from types import SimpleNamespace
from typing import cast

import numpy as np
from numpy.typing import NDArray

from ...errors import AdjustmentInputError, QualityControlError
from ..intersection import intersect_points
from ..problem import BundleProblem
from ..result import AdjustmentResult
from ..solver import SolverOptions, solve
from ..weights import Weights, reweighted_problem
from .ending import Budget

__all__ = ["Decision", "Ledger", "DEGENERATE_NORMAL"]

#: decision groups of points set aside by an adjustment (not for their rays)
ASIDE_CENTRE, ASIDE_BEHIND = "point on a projection centre", "point behind a camera"
#: a free point whose normal-block trace exceeds this multiple of the median point's sits on a projection centre
DEGENERATE_NORMAL = 1e4


@dataclass
class Decision:
    """One quality-control decision.

    Attributes
    ----------
    step : str
        ``"sequent"``, ``"robust"``, ``"baarda"``, ``"variance"``, ``"offsets"``.
    round : int
        Adjustment round within the step (0 for pre-screening).
    kind : str
        ``"image"``, ``"control"``, ``"navigation"``, ``"terrain"`` (a reference DTM height), ``"point"``,
        ``"camera"``.
    index : int
        Image observation index, control point index (``priors`` order), term row, point or image.
    image, point : int
        Image and point concerned (-1 if none).
    component : int
        Coordinate (0 line, 1 sample), axis (0-2) or navigation parameter (-1 if none).
    value : float
        The test value: w-test, robust weight, sigma of the intersection (length unit), ...
    redundancy : float
        Redundancy number of the observation (NaN if not computed).
    action : str
        ``"removed"``, ``"downweighted"``, ``"dropped"`` (point without enough rays),
        ``"fixed"`` (image without observations), ``"flagged"``, ``"reinstated"``, ``"withdrawn"`` (with its
        point: :meth:`Ledger.withdraw_point`).
    group : str
        Observation group (e.g. ``"image 0"``, ``"navigation position orbit 1"``).
    term : int
        The term of a ``"navigation"`` or ``"terrain"`` row (``index`` is its row; -1 for other kinds): rows of
        two terms share row numbers.
    """

    step: str
    round: int
    kind: str
    index: int
    image: int = -1
    point: int = -1
    component: int = -1
    value: float = float("nan")
    redundancy: float = float("nan")
    action: str = "removed"
    group: str = ""
    term: int = -1

    def as_dict(self) -> dict:
        return asdict(self)


#: a point whose intersection through the a-priori images lies this many times the median point's distance
#: from its guess has an error of hundreds of pixels and is not a start for the linearised rounds
RUNAWAY = 10.0


def _last_result(ledger: Ledger) -> AdjustmentResult:
    """The ledger's last adjustment (the quality-control steps run after one)."""
    res = ledger.result
    assert res is not None, "quality control step before the ledger's first adjustment"
    return res


class Ledger:
    """Weights and decisions of a quality-controlled adjustment of ``problem`` (module docstring).

    Parameters
    ----------
    problem : BundleProblem
        The base problem (a-priori weights).
    image_group_names : (n_obs,) str, optional
        Group name of every image observation, for the decisions.
    """

    def __init__(self, problem: BundleProblem, image_group_names: NDArray | None = None):
        self.base = problem
        self.weights = Weights.neutral(problem)
        self.decisions: list[Decision] = []
        self.terms = list(problem.terms)
        o = problem.obs
        self._obs_group = (np.asarray(image_group_names, dtype=object) if image_group_names is not None
                           else np.full(o.n, "image", dtype=object))
        self._control_pts = np.zeros(problem.n_points, bool)
        if problem.priors is not None:
            self._control_pts[problem.priors.idx[~problem.priors.fixed]] = True
        self.result: AdjustmentResult | None = None
        self._track_order = np.argsort(o.pt_idx, kind="stable")
        self._track_start = np.searchsorted(o.pt_idx[self._track_order], np.arange(problem.n_points + 1))
        self._touched: set[int] = set()
        #: points taken out with all their rays (:meth:`withdraw_point`); never given back
        self.withdrawn_points: set[int] = set()
        self._adjusted = False
        self._linear_points: NDArray | None = None
        self.step = "adjust"      # the step running, for decisions taken inside adjust()
        #: the run's budget (:class:`~.ending.Budget`); every adjustment after the first counts one round
        self.budget = Budget()

    # -- state -----------------------------------------------------------------------------------
    @property
    def active(self) -> NDArray[np.bool_]:
        """Image observations still in the adjustment."""
        return (self.weights.image_weight > 0) & ~self.weights.dropped_points[self.base.obs.pt_idx]

    def problem(self, start: AdjustmentResult | None = None) -> BundleProblem:
        """The reweighted problem, starting from ``start``'s unknowns (default the last result's).

        Points that lost an observation since ``start`` start from a fresh intersection of their
        remaining rays: a gross error may have dragged them far off, and a start there can make
        the next adjustment as bad.
        """
        start = start if start is not None else self.result
        cam, pts = (None, None) if start is None else (start.cam_params, start.points.copy())
        if pts is not None and cam is not None and self._touched:
            pts = self._reintersect(cam, pts)
        return reweighted_problem(self.base, self.weights, cam, pts, self.terms)

    def _reintersect(self, cam: NDArray, pts: NDArray) -> NDArray:
        o = self.base.obs
        act = self.active
        touched = np.array(sorted(self._touched), np.int64)
        self._touched.clear()
        rays = np.bincount(o.pt_idx[act], minlength=self.base.n_points)
        touched = touched[(rays[touched] >= 2) & ~self._control_pts[touched]]
        if touched.size == 0:
            return pts
        remap = -np.ones(self.base.n_points, np.int64)
        remap[touched] = np.arange(touched.size)
        use = act & (remap[o.pt_idx] >= 0)
        try:
            X = intersect_points(self.base.model, cam, o.cam_idx[use], remap[o.pt_idx[use]], o.xy[use],
                                 o.sigma[use] * self.weights.image_sigma[use][:, None], n_pt=touched.size).xyz
        except (ValueError, np.linalg.LinAlgError):
            return pts
        ok = np.all(np.isfinite(X), axis=1)
        pts[touched[ok]] = X[ok]
        return pts

    def adjust(self, options: SolverOptions | None = None, start: AdjustmentResult | None = None,
               reweight=None) -> AdjustmentResult:
        """Adjust the reweighted problem; the result is kept as the next start.

        The datum is tested (``SolverOptions.check_datum``) in the first adjustment only: removing
        observations does not change it, and a start dragged off by a gross error can make the
        undamped test system indefinite where the damped iteration is not.
        """
        opts = options or SolverOptions()
        if self._adjusted:
            opts = dataclasses.replace(opts, check_datum=False)
            self.budget.rounds += 1
        self.result = solve(self._finite(self.problem(start)), opts, reweight=reweight)
        self._adjusted = True
        for _ in range(3):
            bad = self._degenerate(self.result)
            if bad.size == 0:
                break
            # points dragged onto a projection centre by gross errors (their partials blow up there):
            # nothing about them can be tested; set them aside with all their rays
            for j in bad:
                self.weights.dropped_points[j] = True
                self.decisions.append(Decision(self.step, 0, "point", int(j), -1, int(j), -1, np.nan, np.nan,
                                               "dropped", ASIDE_CENTRE))
            # held fixed with weight 0, but its projections must stay finite (0 * NaN is NaN in the cost):
            # back to its start value, or another value every one of its images sees (_finite)
            pts = self.result.points.copy()
            pts[bad] = self.base.points[bad]
            self.result = solve(self._finite(reweighted_problem(self.base, self.weights, self.result.cam_params, pts,
                                                                self.terms)),
                                dataclasses.replace(opts, check_datum=False), reweight=reweight)
        return self.result

    def adjust_linearised(self, options: SolverOptions | None = None) -> AdjustmentResult | None:
        """One Gauss-Newton step from the problem's own values: the adjustment linearised at the a-priori
        images (the navigation), every point that lost a ray first intersected again from its active rays
        through them. Returns the result (kept as the next start), or None where the step did not reduce
        the cost (the a-priori values are too far for the linear model; the ledger is then unchanged).

        Gross errors of thousands of sigma make the non-linear least-squares adjustment run far from the
        a-priori values (measured on the DLR blocks: points moved 300-1,000 km, a 17-ray point onto a
        projection centre), where the w-tests no longer point at the errors; in the linear model each
        error shows in its own residual with the share its redundancy number gives it.
        """
        opts = dataclasses.replace(options or SolverOptions(), max_iterations=1,
                                   initial_mu=min((options or SolverOptions()).initial_mu, 1e-12))
        if self._adjusted:
            opts = dataclasses.replace(opts, check_datum=False)
            self.budget.rounds += 1
        o = self.base.obs
        touched = set(self._touched)
        if self._linear_points is None:
            # every point at its intersection through the a-priori images: a start that is only the model's
            # guess (narrow rays) is too far for one step, and its residuals would fail the tests (measured:
            # w = 17 on a block without errors); but a 2-ray point with an error of thousands of pixels
            # intersects thousands of km away (measured: 2,800 km, the step rejected), and then the model's
            # guess is the better start for that point (next: the points that moved more than RUNAWAY times the
            # median move back at the guess, then every point at its guess)
            self._touched = set(range(self.base.n_points))
            guess = self.base.points.copy()
            X = self._reintersect(self.base.cam_params, guess.copy())
            moved = np.linalg.norm(X - guess, axis=1)
            far = moved > RUNAWAY * np.median(moved)
            starts = [X, np.where(far[:, None], guess, X), guess] if far.any() else [X, guess]
            self._touched = set(touched)
        else:
            starts = [self._linear_points]
        self._touched.update(int(j) for j in np.unique(o.pt_idx[~(self.weights.image_weight > 0)]))
        lost = set(self._touched)
        res = None
        for pts in starts:
            self._touched = set(lost)
            # problem() reads only the start's cam_params and points
            start = cast(AdjustmentResult, SimpleNamespace(cam_params=self.base.cam_params, points=pts))
            res = solve(self._finite(self.problem(start)), opts)
            self._adjusted = True
            if res.accepted > 0 and not self._degenerate(res).size:
                self._linear_points = pts
                break
            res = None
        if res is None:
            self._touched = touched     # the next (non-linear) adjustment starts from the last result
            return None
        self.result = res
        return res

    def _finite(self, pb: BundleProblem) -> BundleProblem:
        """``pb`` with every point's projections finite, so that its cost is (weight 0 times NaN is NaN).

        A point whose start is behind one of its cameras (or at infinity) after a gross error -- its
        start intersected with a blunder, or reset there -- moves to the first of: the intersection
        of its active rays, its base start, its control value, the median of the other points whose
        projections are all finite. Unless that is the intersection of its own active rays (then it
        is adjusted as usual), it is set aside (weight 0) and the decision recorded: a quality-control
        run never dies on the data it is meant to clean.
        """
        o = self.base.obs
        model = pb.model
        # a point without finite coordinates (a diverged iteration) is not projected: a line-scan
        # camera refuses a NaN ground point instead of returning NaN
        bad_obs = ~np.all(np.isfinite(pb.points), axis=1)[o.pt_idx]
        ok = ~bad_obs
        if ok.any():
            x = model.project(pb.cam_params, o.cam_idx[ok], pb.points[o.pt_idx[ok]])
            bad_obs[ok] = ~np.all(np.isfinite(x), axis=1)
        if not bad_obs.any():
            return pb
        bad_pt = np.zeros(self.base.n_points, bool)
        bad_pt[o.pt_idx[bad_obs]] = True
        pts = pb.points.copy()
        good = ~bad_pt & np.all(np.isfinite(pts), axis=1)
        median = np.median(pts[good], axis=0) if good.any() else None
        act = self.active
        ctl_value = {}
        if self.base.priors is not None:
            ctl_value = {int(j): x for j, x in zip(self.base.priors.idx, self.base.priors.xyz)}
        drop = []
        for j in np.flatnonzero(bad_pt):
            track = self._track_order[self._track_start[j]:self._track_start[j + 1]]

            def sees(X):
                if X is None or not np.all(np.isfinite(X)):
                    return False
                x = model.project(pb.cam_params, o.cam_idx[track], np.broadcast_to(X, (track.size, 3)))  # noqa: B023
                return bool(np.all(np.isfinite(x)))

            use = track[act[track]]
            X_int = None
            if use.size >= 2 and not self.weights.dropped_points[j]:
                try:
                    X_int = intersect_points(model, pb.cam_params, o.cam_idx[use], np.zeros(use.size, np.int64),
                                             o.xy[use], o.sigma[use] * self.weights.image_sigma[use][:, None],
                                             n_pt=1).xyz[0]
                except (ValueError, np.linalg.LinAlgError):
                    X_int = None
            if sees(X_int):
                pts[j] = X_int
                continue
            for X in (self.base.points[j], ctl_value.get(int(j)), self._model_guess(pb, track), median):
                if sees(X):
                    pts[j] = X
                    break
            else:
                # any other point all of this point's images see (its neighbours in those images first)
                X = self._seen_by_all(pb, track, pts, good)
                if X is None:
                    raise QualityControlError(f"point {int(j)} is behind a camera from every start value tried (its "
                                              "intersection, its start, its rays' own guess, every other point)")
                pts[j] = X
            if not self.weights.dropped_points[j] and not self._control_pts[j]:
                drop.append(int(j))
        for jd in drop:
            self.weights.dropped_points[jd] = True
            self.decisions.append(Decision(self.step, 0, "point", jd, -1, jd, -1, np.nan, np.nan, "dropped",
                                           ASIDE_BEHIND))
        return reweighted_problem(self.base, self.weights, pb.cam_params, pts, self.terms)

    def _model_guess(self, pb: BundleProblem, track: NDArray[np.int64]) -> NDArray | None:
        """The model's own guess of a point from its rays ``track`` at the problem's images (their nearest point,
        or a single ray on the reference surface); None where it has none."""
        o = self.base.obs
        if track.size == 0:
            return None
        try:
            with np.errstate(all="ignore"):
                X = self.base.model.initial_points(pb.cam_params, o.cam_idx[track], np.zeros(track.size, np.int64),
                                                   o.xy[track], 1)[0]
        except (ValueError, np.linalg.LinAlgError, AdjustmentInputError):
            return None
        return X if np.all(np.isfinite(X)) else None

    def _seen_by_all(self, pb: BundleProblem, track: NDArray[np.int64], pts: NDArray,
                     good: NDArray[np.bool_]) -> NDArray | None:
        """A point position (another point's) that every image of ``track`` projects finitely, preferring points
        observed in the most of those images; None if there is none."""
        o = self.base.obs
        imgs = np.unique(o.cam_idx[track])
        seen = np.bincount(o.pt_idx[np.isin(o.cam_idx, imgs)], minlength=self.base.n_points)
        cand = np.flatnonzero(good & np.all(np.isfinite(pts), axis=1))
        for j in cand[np.argsort(-seen[cand], kind="stable")][:200]:
            with np.errstate(all="ignore"):
                x = pb.model.project(pb.cam_params, imgs, np.broadcast_to(pts[j], (imgs.size, 3)))
            if np.all(np.isfinite(x)):
                return pts[j].copy()
        return None

    def _degenerate(self, res: AdjustmentResult) -> NDArray[np.int64]:
        """Free tie points whose normal block is ``DEGENERATE_NORMAL`` times the median point's: partials blown
        up near a projection centre (a point cannot be there; sigma and track length spread normal blocks
        over two orders of magnitude at most)."""
        from ..normal import Terms, linearize

        pb = res.problem
        fixed = pb.point_fixed()
        lin = linearize(pb, res.state, res.structure, Terms(pb), fixed)
        tr = np.trace(lin.V, axis1=1, axis2=2)
        free = ~fixed & ~self._control_pts & (np.bincount(pb.obs.pt_idx[res.state.obs_weight > 0],
                                                           minlength=pb.n_points) >= 2)
        if free.sum() < 3:
            return np.zeros(0, np.int64)
        med = float(np.median(tr[free]))
        return np.flatnonzero(free & ~(tr <= DEGENERATE_NORMAL * med))

    def rays_of(self, j: int) -> NDArray[np.int64]:
        """Image observations of point ``j`` (active or not)."""
        return self._track_order[self._track_start[j]:self._track_start[j + 1]]

    def obs_group(self, i: int) -> str:
        return str(self._obs_group[i])

    # -- decisions ---------------------------------------------------------------------------------
    def remove_image(self, obs: NDArray[np.int64] | int, step: str, rnd: int, value=np.nan, redundancy=np.nan,
                     component=-1) -> None:
        """Remove image observations (weight 0); points left with too few rays are dropped."""
        o = self.base.obs
        obs = np.atleast_1d(np.asarray(obs, np.int64))
        val = np.broadcast_to(np.asarray(value, float), obs.shape)
        red = np.broadcast_to(np.asarray(redundancy, float), obs.shape)
        comp = np.broadcast_to(np.asarray(component, np.int64), obs.shape)
        for i, v, r, c in zip(obs, val, red, comp):
            if self.weights.image_weight[i] == 0.0:
                continue
            self.weights.image_weight[i] = 0.0
            self.decisions.append(Decision(step, rnd, "image", int(i), int(o.cam_idx[i]), int(o.pt_idx[i]), int(c),
                                           float(v), float(r), "removed", self.obs_group(int(i))))
        self._touched.update(int(j) for j in np.unique(o.pt_idx[obs]))
        self._settle(step, rnd, np.unique(o.pt_idx[obs]), np.unique(o.cam_idx[obs]))

    def _settle(self, step: str, rnd: int, points: NDArray, images: NDArray) -> None:
        """Drop points with fewer than 2 rays (control points excepted); fix images without observations."""
        o = self.base.obs
        act = self.active
        rays = np.bincount(o.pt_idx[act], minlength=self.base.n_points)
        for j in points:
            if not self.weights.dropped_points[j] and rays[j] < 2 and not self._control_pts[j]:
                self.weights.dropped_points[j] = True
                self.decisions.append(Decision(step, rnd, "point", int(j), -1, int(j), -1, float(rays[j]), np.nan,
                                               "dropped", "point"))
                # its remaining rays leave with it
                track = self._track_order[self._track_start[j]:self._track_start[j + 1]]
                left = track[act[track]]
                for i in left:
                    self.decisions.append(Decision(step, rnd, "image", int(i), int(o.cam_idx[i]), int(j), -1, np.nan,
                                                   np.nan, "dropped", self.obs_group(int(i))))
        act = self.active
        per_img = np.bincount(o.cam_idx[act], minlength=self.base.n_images)
        observed = np.zeros(self.base.n_images, bool)
        for t in self.terms:
            observed |= np.asarray(t.observed_images(), bool)
        for k in np.unique(np.concatenate([images, o.cam_idx[~act]])) if images.size else []:
            if per_img[k] == 0 and not observed[k] and not self.weights.fixed_images[k]:
                self.weights.fixed_images[k] = True
                self.decisions.append(Decision(step, rnd, "camera", int(k), int(k), -1, -1, 0.0, np.nan, "fixed",
                                               "image parameters"))

    def withdraw_point(self, j: int, step: str, rnd: int, value=np.nan, why: str = "") -> None:
        """Take point ``j`` out with all its rays, for good: a gross error among them that the data cannot
        attribute to one ray (each ray, removed earlier or not, gets a ``"withdrawn"`` decision, which
        supersedes a removal: none of them is judged wrong on its own)."""
        o = self.base.obs
        track = self.rays_of(j)
        for i in track:
            self.weights.image_weight[i] = 0.0
            self.decisions.append(Decision(step, rnd, "image", int(i), int(o.cam_idx[i]), int(j), -1, float(value),
                                           np.nan, "withdrawn", self.obs_group(int(i))))
        self.decisions.append(Decision(step, rnd, "point", int(j), -1, int(j), -1, float(value), np.nan, "withdrawn",
                                       f"point ({why})" if why else "point"))
        self.withdrawn_points.add(int(j))
        if not self._control_pts[j]:        # a control point keeps its coordinates' observation
            self.weights.dropped_points[j] = True
        self._touched.add(int(j))
        self._settle(step, rnd, np.array([j]), np.unique(o.cam_idx[track]))

    def reinstate_image(self, obs: NDArray[np.int64], step: str, rnd: int, value=np.nan) -> None:
        """Give removed image observations their weight back; their points return if they have 2 rays again."""
        o = self.base.obs
        obs = np.atleast_1d(np.asarray(obs, np.int64))
        val = np.broadcast_to(np.asarray(value, float), obs.shape)
        for i, v in zip(obs, val):
            self.weights.image_weight[i] = 1.0
            self.decisions.append(Decision(step, rnd, "image", int(i), int(o.cam_idx[i]), int(o.pt_idx[i]), -1,
                                           float(v), np.nan, "reinstated", self.obs_group(int(i))))
        pts = np.unique(o.pt_idx[obs])
        ok = self.weights.image_weight > 0
        rays = np.bincount(o.pt_idx[ok], minlength=self.base.n_points)
        for j in pts:
            if self.weights.dropped_points[j] and rays[j] >= 2:
                self.weights.dropped_points[j] = False
                self.decisions.append(Decision(step, rnd, "point", int(j), -1, int(j), -1, float(rays[j]), np.nan,
                                               "reinstated", "point"))
        self._touched.update(int(j) for j in pts)
        for k in np.unique(o.cam_idx[obs]):
            self.weights.fixed_images[k] = False

    def reinstate_set_aside(self, step: str, rnd: int = 0) -> NDArray[np.int64]:
        """Give back the points set aside by an adjustment (on a projection centre, behind a camera).

        Those decisions judge a point by where gross errors dragged it, not by its rays; a screening
        that tests the rays themselves (Sequent) runs on them again, and the next adjustment starts
        them from a fresh intersection of the rays it keeps. Returns the points given back.
        """
        aside = {d.index for d in self.decisions if d.kind == "point" and d.action == "dropped"
                 and d.group in (ASIDE_CENTRE, ASIDE_BEHIND)}
        back = np.array(sorted(j for j in aside if self.weights.dropped_points[j]), np.int64)
        o = self.base.obs
        rays = np.bincount(o.pt_idx[self.weights.image_weight > 0], minlength=self.base.n_points)
        back = back[rays[back] >= 2] if back.size else back
        for j in back:
            self.weights.dropped_points[j] = False
            self.decisions.append(Decision(step, rnd, "point", int(j), -1, int(j), -1, float(rays[j]), np.nan,
                                           "reinstated", "point"))
        self._touched.update(int(j) for j in back)
        return back

    def term_kind(self, term: int) -> str:
        """A term's observation kind in decisions: ``"terrain"`` for one that observes points (reference DTM
        heights), ``"navigation"`` otherwise."""
        return "terrain" if getattr(self.terms[term], "uses_points", False) else "navigation"

    def term_rows_out(self, term: int) -> NDArray[np.bool_]:
        """Rows of term ``term`` that are out with their point (:meth:`Weights.term_rows_out`): not tested, in no
        variance group, their final status their point's."""
        return self.weights.term_rows_out(self.terms[term])

    def downweight_term(self, term: int, row: int, factor: float, step: str, rnd: int, value=np.nan,
                        redundancy=np.nan, image=-1, component=-1, group="navigation") -> None:
        """``P_new = P_old / factor`` for one row of a term (navigation observation; a reference DTM height,
        recorded as kind ``"terrain"`` with its point)."""
        self.weights.term_sigma[term][row] *= np.sqrt(factor)
        kind = self.term_kind(term)
        # a row observing several points (an altimetry shot) names its nearest one (first)
        point = int(np.atleast_1d(self.terms[term].point_index[row])[0]) if kind == "terrain" else -1
        self.decisions.append(Decision(step, rnd, kind, int(row), int(image), point, int(component), float(value),
                                       float(redundancy), "downweighted", group, term=int(term)))

    def downweight_control(self, k: int, factor: float, step: str, rnd: int, value=np.nan, redundancy=np.nan,
                           component=-1) -> None:
        """``P_new = P_old / factor`` for control point ``k`` (``priors`` order)."""
        self.weights.control_sigma[k] *= np.sqrt(factor)
        assert self.base.priors is not None, "control points down-weighted in a problem without priors"
        self.decisions.append(Decision(step, rnd, "control", int(k), -1, int(self.base.priors.idx[k]), int(component),
                                       float(value), float(redundancy), "downweighted", "control"))

    def of_step(self, step: str) -> list[Decision]:
        return [d for d in self.decisions if d.step == step]
