"""The "Sequent" pre-screening of conjugate points before the adjustment (DLR paper, ``seeds/004``, section 3).

Every conjugate point is intersected from its rays through the cameras as they are (the navigation):

1. from every pair of its rays: the "best stereo pair" is the one whose intersection has the smallest
   standard deviation ``sigma_P = s0 sqrt(trace N^-1)`` (``s0`` from the pair's own residuals,
   redundancy 1; ``N`` the 3x3 normal matrix of the point): it combines a long base (small
   ``N^-1``) and consistent rays (small ``s0``), the paper's three requirements. Among the pairs
   within the limit, the one whose two rays each form within-limit pairs with the most other rays
   of the point is preferred (not with ``pairs_only``; a departure from the paper: a gross error
   along the epipolar line gives a consistent pair at a wrong height). If even the best pair exceeds the limit the point
   is bad and all its rays are removed;
2. then one ray at a time (the one whose addition gives the smallest ``sigma_P``): a ray that
   pushes ``sigma_P`` beyond the limit is a bad image point and removed (and with it every ray
   still left, since the best of them already failed).

The limit is a length (the paper: 10 km for the simulation, 20 km for the Clementine data), so
gross errors of hundreds of pixels are caught while navigation errors of a few hundred metres
pass. All points are screened together: each step is one vectorised forward intersection of
every candidate ray set (:func:`~lunarmap.adjust.intersection.intersect_points`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import xarray as xr
from numpy.typing import NDArray

from ...errors import QualityControlInputError
from ..intersection import intersect_points
from ..precision import ordered_track_pairs
from ..problem import BundleProblem

__all__ = ["SequentResult", "sequent_screening"]


@dataclass
class SequentResult:
    """Outcome of :func:`sequent_screening`.

    Attributes
    ----------
    keep : (n_obs,) bool
        Image observations that passed.
    points : xarray.Dataset
        Per point: ``rays`` screened, ``kept`` rays, ``best_pair`` (two observation indices),
        ``pair_sigma`` of the best pair and ``sigma`` of the kept rays (length unit of the block),
        ``status`` (0 passed, 1 some rays removed, 2 point removed, 3 not screened: < 2 rays).
    limit : float
        The limit used (length unit of the block).
    """

    keep: NDArray[np.bool_]
    points: xr.Dataset
    limit: float

    @property
    def removed(self) -> NDArray[np.int64]:
        return np.flatnonzero(~self.keep)


def _sigma_p(model, cam_params, cam_idx, set_idx, xy, sigma, n_sets) -> NDArray:
    """``sigma_P`` of the intersection of every ray set (inf where it fails)."""
    with np.errstate(all="ignore"):
        try:
            res = intersect_points(model, cam_params, cam_idx, set_idx, xy, sigma, n_pt=n_sets)
        except (ValueError, FloatingPointError, np.linalg.LinAlgError):
            return np.full(n_sets, np.inf)
        s = np.sqrt(np.trace(res.cov, axis1=1, axis2=2))
    return np.where(np.isfinite(s) & np.all(np.isfinite(res.xyz), axis=1), s, np.inf)


def sequent_screening(problem: BundleProblem, limit_km: float = 10.0, units_per_km: float = 1000.0,
                      active: NDArray | None = None, cam_params: NDArray | None = None,
                      pairs_only: bool = False) -> SequentResult:
    """Screen every conjugate point's rays (module docstring).

    Parameters
    ----------
    problem : BundleProblem
        Its image model, image parameters (default ``problem.cam_params``: the navigation) and
        image observations with their sigma.
    limit_km : float
        Largest acceptable standard deviation of an intersected point, kilometres.
    units_per_km : float
        Length unit of the block per kilometre (1000 for metres, 1 for the BAL blocks' km).
    active : (n_obs,) bool, optional
        Observations to screen (others are ignored); default those with a non-zero weight.
    cam_params : ndarray, optional
        Image parameters to intersect with.
    pairs_only : bool
        Stop after the best pairs (step 1).

    Raises
    ------
    QualityControlInputError
        ``limit_km <= 0``.
    """
    if not (np.isfinite(limit_km) and limit_km > 0):
        raise QualityControlInputError(f"the Sequent limit must be a length > 0 km, got {limit_km!r}")
    limit = float(limit_km) * float(units_per_km)
    o = problem.obs
    model = problem.model
    cp = problem.cam_params if cam_params is None else cam_params
    act = np.asarray(np.asarray(problem.obs_weight) > 0 if active is None else active, bool)  # set by __post_init__
    n_pt = problem.n_points
    keep = act.copy()
    order = np.argsort(o.pt_idx, kind="stable")
    order = order[act[order]]
    start = np.searchsorted(o.pt_idx[order], np.arange(n_pt + 1))
    tracks = [order[start[j]:start[j + 1]] for j in range(n_pt)]
    rays = np.array([t.size for t in tracks])
    status = np.where(rays >= 2, 0, 3).astype(np.int8)
    best = -np.ones((n_pt, 2), np.int64)
    pair_sigma = np.full(n_pt, np.nan)
    final_sigma = np.full(n_pt, np.nan)
    # 1. every pair of every point
    act_idx = np.flatnonzero(act)
    A, B = ordered_track_pairs(o.pt_idx[act_idx], n_pt)
    keep_pair = A < B
    A, B = act_idx[A[keep_pair]], act_idx[B[keep_pair]]
    J = o.pt_idx[A]
    chosen: list[list[int]] = [[] for _ in range(n_pt)]
    if A.size:
        n_pairs = A.size
        obs2 = np.concatenate([A, B])
        sets = np.concatenate([np.arange(n_pairs)] * 2)
        s = _sigma_p(model, cp, o.cam_idx[obs2], sets, o.xy[obs2], o.sigma[obs2], n_pairs)
        # best pair per point: among the pairs within the limit, the one whose rays agree with the most
        # other rays of the point, then the smallest sigma. The smallest sigma alone can pick a gross
        # error along the epipolar line (a consistent pair at a wrong height), and Sequent would then
        # take out every good ray of the point (bench draw 19: 3 of 5 rays)
        ok = s <= limit
        support = (np.bincount(A[ok], minlength=o.n) + np.bincount(B[ok], minlength=o.n)).astype(np.int64)
        pair_support = np.where(ok, np.minimum(support[A], support[B]), -1)
        if pairs_only:
            # the robust start (no limit): the smallest sigma, as the paper; the consensus rule there
            # changed Baarda-alone starts and drove one draw to redundancy 0
            pair_support[:] = 0
        srt = np.lexsort((s, -pair_support, J))
        first = np.ones(srt.size, bool)
        first[1:] = J[srt][1:] != J[srt][:-1]
        k = srt[first]
        j = J[k]
        pair_sigma[j] = s[k]
        best[j, 0], best[j, 1] = A[k], B[k]
        failed = j[s[k] > limit]
        status[failed] = 2
        keep[np.isin(o.pt_idx, failed) & act] = False
        for jj, kk in zip(j[s[k] <= limit], k[s[k] <= limit]):
            chosen[jj] = [int(A[kk]), int(B[kk])]
    # 2. one ray at a time, the best candidate first
    while not pairs_only:
        cand_obs, cand_set, cand_pt, cand_new = [], [], [], []
        n_sets = 0
        for j in np.flatnonzero(status <= 1):
            rest = [i for i in tracks[j] if i not in chosen[j] and keep[i]]
            if not chosen[j] or not rest:
                continue
            for i in rest:
                members = chosen[j] + [i]
                cand_obs += members
                cand_set += [n_sets] * len(members)
                cand_pt.append(j)
                cand_new.append(i)
                n_sets += 1
        if n_sets == 0:
            break
        co = np.array(cand_obs)
        s = _sigma_p(model, cp, o.cam_idx[co], np.array(cand_set), o.xy[co], o.sigma[co], n_sets)
        cp_ = np.array(cand_pt)
        cn = np.array(cand_new)
        srt = np.lexsort((s, cp_))
        first = np.ones(srt.size, bool)
        first[1:] = cp_[srt][1:] != cp_[srt][:-1]
        for k in srt[first]:
            j = cp_[k]
            if s[k] <= limit:
                chosen[j].append(int(cn[k]))
                final_sigma[j] = s[k]
            else:
                # the best remaining ray fails: every remaining ray of this point is bad
                bad = [i for i in tracks[j] if i not in chosen[j] and keep[i]]
                keep[bad] = False
                status[j] = 1
    for j in np.flatnonzero(status <= 1):
        if np.isnan(final_sigma[j]):
            final_sigma[j] = pair_sigma[j]
    kept = np.bincount(o.pt_idx[keep], minlength=n_pt)
    ds = xr.Dataset({"rays": ("point", rays), "kept": ("point", kept),
                     "best_pair": (("point", "ray"), best),
                     "pair_sigma": ("point", pair_sigma), "sigma": ("point", final_sigma),
                     "status": ("point", status)},
                    coords={"point": np.arange(n_pt), "ray": [0, 1]},
                    attrs={"limit": limit, "limit_km": float(limit_km),
                           "status_meaning": "0 passed, 1 rays removed, 2 point removed, 3 not screened (< 2 rays)"})
    return SequentResult(keep, ds, limit)
