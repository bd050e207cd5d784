"""Quality control against a simulation's truth: which removed tie observations were wrong.

A matcher's tie point has no simulator identity, so its true ground point is not known; what is known are
the truth cameras and the true DTM. An observation's **true error** is its distance (pixels) from the true
conjugate of its point's other rays: each ray is cast through its image's truth camera onto the true DTM,
the ground point projected into the observation's image through that image's truth camera, and the error
is the smallest over the point's other rays (an observation with at least one right partner is right; both
rays of a mismatched 2-ray point are wrong, as no test can tell which of them is).

:func:`true_tie_errors` computes those errors, :func:`removal_scores` compares a removal flag with them at
several thresholds (precision, recall, false removals as a share of the good observations), and
:func:`qc_against_truth` does both for a run's ``residuals.nc``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import xarray as xr
from numpy.typing import ArrayLike

from ..errors import EvaluationInputError

__all__ = ["QC_TRUTH_LIMITS_PX", "QC_TRUTH_LIMITS_SIGMA", "qc_against_truth", "removal_scores", "true_tie_errors"]

#: Smallest convergence of a point's other rays for the "others" true error, degrees.
_MIN_CONVERGENCE_DEG = 2.0

#: Thresholds (multiples of an observation's sigma) of the curve in sigmas.
QC_TRUTH_LIMITS_SIGMA = (2.0, 3.0, 4.0, 5.0)

#: Thresholds (pixels) of the true error above which an observation counts as wrong, for the curve.
QC_TRUTH_LIMITS_PX = (0.5, 1.0, 2.0, 3.0, 5.0, 10.0)


def true_tie_errors(observed: ArrayLike, image: ArrayLike, point: ArrayLike, truth: Mapping[str, Any],
                    names: Sequence[str], dtm: xr.DataArray, method: str = "nearest") -> np.ndarray:
    """True error of every tie observation: its distance from the true conjugates of its point's other rays.

    ``method="nearest"``: the smallest distance over the other rays, each cast onto the true DTM (module
    docstring); lenient: a ray that agrees with one partner is right even where the point's rays disagree
    among themselves. ``method="others"``: the distance from the projection of the point intersected
    (least squares, truth cameras) from all its *other* rays (one other ray, or other rays converging by less
    than 2 degrees: the "nearest" error); strict: a
    wrong ray among the others moves that point, so the good rays of a point with a wrong ray can count as
    wrong too.

    Parameters
    ----------
    observed : array_like (n, 2)
        Measured ``(line, sample)`` of every observation, pixels.
    image : array_like (n,) int
        Image of every observation (an index into ``names``).
    point : array_like (n,) int
        Tie point of every observation.
    truth : mapping image name -> SensorModel
        The truth cameras (``image_to_ground(..., dtm=)``, ``ground_to_image``).
    names : sequence of str
        Image names, in the order of ``image``'s indices.
    dtm : xarray.DataArray
        The true DTM (heights in metres above the reference sphere, dims ``lat`` x ``lon``, degrees).
    method : {"nearest", "others"}
        How the true conjugate is found (above).

    Returns
    -------
    ndarray (n,)
        Pixels; ``inf`` for an observation whose point has no other ray that reaches the DTM (a single ray,
        or every other ray off the DTM).

    Raises
    ------
    EvaluationInputError
        Arrays of different lengths, an image index outside ``names``, an image without a truth camera, or
        an unknown ``method``.
    """
    from ..camera.intersect import DtmSampler

    if method not in ("nearest", "others"):
        raise EvaluationInputError(f"method must be 'nearest' or 'others', got {method!r}")

    obs = np.asarray(observed, float)
    img = np.asarray(image, np.int64)
    pt = np.asarray(point, np.int64)
    n = img.size
    if obs.shape != (n, 2) or pt.shape != (n,) or img.shape != (n,):
        raise EvaluationInputError(f"observed must be (n, 2) with image and point (n,), got {obs.shape}, "
                                   f"{img.shape}, {pt.shape}")
    if n and (img.min() < 0 or img.max() >= len(names)):
        raise EvaluationInputError(f"image indices must be in [0, {len(names)}), got {img.min()}..{img.max()}")
    missing = sorted({names[i] for i in np.unique(img)} - set(truth))
    if missing:
        raise EvaluationInputError(f"no truth camera for image(s) {missing}")
    sampler = DtmSampler(dtm)
    ground = np.full((n, 3), np.nan)
    for i in np.unique(img):
        m = img == i
        ground[m] = truth[names[i]].image_to_ground(obs[m, 0], obs[m, 1], dtm=sampler, on_miss="nan")
    # every ordered pair (a, b) of different rays of one point: b's ground point projected into a's image
    order = np.argsort(pt, kind="stable")
    starts = np.flatnonzero(np.r_[True, np.diff(pt[order]) != 0]) if n else np.zeros(0, np.int64)
    ends = np.r_[starts[1:], n]
    a_list, b_list = [], []
    for s0, e0 in zip(starts, ends):
        idx = order[s0:e0]
        if idx.size > 1:
            a, b = np.meshgrid(idx, idx, indexing="ij")
            off = a != b
            a_list.append(a[off])
            b_list.append(b[off])
    err = np.full(n, np.inf)
    if a_list:
        a, b = np.concatenate(a_list), np.concatenate(b_list)
        d = np.full(a.size, np.inf)
        for i in np.unique(img[a]):
            m = (img[a] == i) & np.all(np.isfinite(ground[b]), axis=1)
            if m.any():
                li, sa = truth[names[i]].ground_to_image(ground[b[m]], within_image=False)
                d[m] = np.hypot(li - obs[a[m], 0], sa - obs[a[m], 1])
        np.minimum.at(err, a, np.where(np.isfinite(d), d, np.inf))
    if method == "others":
        err = _leave_one_out_errors(obs, img, pt, truth, names, err)
    return err


def _leave_one_out_errors(obs: np.ndarray, img: np.ndarray, pt: np.ndarray, truth: Mapping[str, Any],
                          names: Sequence[str], nearest: np.ndarray) -> np.ndarray:
    """Distance of every observation from the projection of its point intersected from its other rays."""
    n = img.size
    O, D = np.zeros((n, 3)), np.zeros((n, 3))
    for i in np.unique(img):
        m = img == i
        o, d = truth[names[i]].rays(obs[m, 0], obs[m, 1])
        O[m], D[m] = o, d / np.linalg.norm(d, axis=1, keepdims=True)
    # least squares over rays: sum of (I - d d^T) X = sum of (I - d d^T) o, the point's sums less the ray's own
    P = np.eye(3)[None] - D[:, :, None] * D[:, None, :]
    q = np.einsum("nij,nj->ni", P, O)
    _, inv, count = np.unique(pt, return_inverse=True, return_counts=True)
    A, b = np.zeros((count.size, 3, 3)), np.zeros((count.size, 3))
    np.add.at(A, inv, P)
    np.add.at(b, inv, q)
    A_o, b_o = A[inv] - P, b[inv] - q
    # two or more other rays that converge by >= _MIN_CONVERGENCE_DEG (the smallest eigenvalue of the sum of
    # projectors is 1 - cos(angle) for two rays): near-parallel rays (two cameras side by side) place the
    # point far along the ray and project a noise of hundredths of a pixel into pixels; those keep "nearest"
    many = count[inv] >= 3
    lam = np.linalg.eigvalsh(np.where(many[:, None, None], A_o, np.eye(3)[None]))[:, 0]
    ok = many & (lam >= 1.0 - np.cos(np.radians(_MIN_CONVERGENCE_DEG)))
    err = nearest.copy()
    if ok.any():
        X = np.linalg.solve(A_o[ok], b_o[ok][..., None])[..., 0]
        d = np.full(int(ok.sum()), np.inf)
        for i in np.unique(img[ok]):
            m = img[ok] == i
            li, sa = truth[names[i]].ground_to_image(X[m], within_image=False)
            d[m] = np.hypot(li - obs[ok][m, 0], sa - obs[ok][m, 1])
        err[ok] = d
    return err


def removal_scores(error_px: ArrayLike, removed: ArrayLike,
                   limits_px: Sequence[float] = QC_TRUTH_LIMITS_PX) -> list[dict[str, Any]]:
    """Removals against the true errors, at every threshold of what counts as wrong.

    Parameters
    ----------
    error_px : array_like (n,)
        True error of every observation, pixels (:func:`true_tie_errors`; ``inf`` = no partner to judge by,
        counted as wrong).
    removed : array_like (n,) bool
        Observations quality control took out.
    limits_px : sequence of float
        An observation is **wrong** when its true error is above the limit (pixels).

    Returns
    -------
    list of dict
        One per limit: ``limit_px``, ``observations``, ``removed``, ``wrong``, ``good``, ``removed_wrong``,
        ``removed_good`` (counts), ``precision`` (wrong among the removed), ``recall`` (removed among the
        wrong), ``false_removal_share`` (removed among the good); a ratio over zero observations is NaN.
    """
    err = np.asarray(error_px, float)
    rem = np.asarray(removed, bool)
    if err.shape != rem.shape or err.ndim != 1:
        raise EvaluationInputError(f"error_px and removed must be 1-D of one length, got {err.shape}, {rem.shape}")
    if np.any(np.isnan(err)):
        raise EvaluationInputError("error_px has NaN (an unknown true error); use inf for 'no partner'")

    def ratio(a: int, b: int) -> float:
        return a / b if b else float("nan")

    out = []
    for lim in limits_px:
        wrong = err > float(lim)
        rw, rg = int(np.sum(rem & wrong)), int(np.sum(rem & ~wrong))
        nw, ng, nr = int(wrong.sum()), int((~wrong).sum()), int(rem.sum())
        out.append({"limit_px": float(lim), "observations": int(err.size), "removed": nr, "wrong": nw, "good": ng,
                    "removed_wrong": rw, "removed_good": rg, "precision": ratio(rw, nr), "recall": ratio(rw, nw),
                    "false_removal_share": ratio(rg, ng)})
    return out


def qc_against_truth(residuals: xr.Dataset, truth: Mapping[str, Any], names: Sequence[str], dtm: xr.DataArray,
                     limit_px: float = 1.0, limits_px: Sequence[float] = QC_TRUTH_LIMITS_PX,
                     limits_sigma: Sequence[float] = QC_TRUTH_LIMITS_SIGMA) -> dict[str, Any]:
    """The tie observations quality control removed, against the simulation's true conjugates.

    Parameters
    ----------
    residuals : xarray.Dataset
        A run's ``outputs/adjustment/residuals.nc`` (``observed``, ``image``, ``point``, ``point_type``,
        ``qc_removed``, optionally ``qc_status``).
    truth : mapping image name -> SensorModel
        The truth cameras.
    names : sequence of str
        Image names in the order of ``residuals['image']``.
    dtm : xarray.DataArray
        The true DTM (``lat`` x ``lon``).
    limit_px : float
        The headline threshold (pixels) of a true mismatch.
    limits_px : sequence of float
        Thresholds of the curve (pixels).
    limits_sigma : sequence of float
        Thresholds of the curve in multiples of each observation's sigma (``curve_sigma``).

    Returns
    -------
    dict
        At ``limit_px``: ``observations``, ``removed``, ``wrong``, ``good``, ``removed_wrong``, ``removed_good``
        (counts of tie observations), ``precision``, ``recall``, ``false_removal_share``; also
        ``removed_median_px`` and ``kept_median_px`` (true errors), ``limit_px``, ``curve`` (the same
        figures at every limit of ``limits_px``, :func:`removal_scores`), ``curve_sigma`` (at ``limits_sigma`` times each
        observation's sigma, from ``residual`` / ``normalized`` when ``residuals`` has them; the entries'
        ``limit_px`` is then the limit in sigmas, ``limit_sigma``; ``curve_sigma_others`` with the
        strict true error) and ``sigma_px_median``, ``by_status`` (observations and
        wrong ones per final QC status, when ``residuals`` has ``qc_status``), ``curve_others``, ``removed_median_others_px`` and ``kept_median_others_px`` (the same with
        the strict true error, ``method="others"`` of :func:`true_tie_errors`), ``orphaned_kept`` (kept observations
        left alone on their point by the removals: they no longer take part) and ``no_partner`` (observations
        whose point has no other ray to judge them by, counted as wrong).
    """
    tie = residuals["point_type"].values.astype(str) == "tie"
    obs = np.asarray(residuals["observed"].values, float)[tie]
    img = np.asarray(residuals["image"].values)[tie]
    pt = np.asarray(residuals["point"].values)[tie]
    removed = (residuals["qc_removed"].values.astype(bool)[tie] if "qc_removed" in residuals
               else np.zeros(int(tie.sum()), bool))
    err = true_tie_errors(obs, img, pt, truth, names, dtm)
    head = removal_scores(err, removed, [limit_px])[0]
    fin = np.isfinite(err)
    kept_per_point = np.bincount(np.unique(pt, return_inverse=True)[1], weights=~removed)
    orphaned = ~removed & (kept_per_point[np.unique(pt, return_inverse=True)[1]] < 2)
    out: dict[str, Any] = {
        **head,
        "removed_median_px": float(np.median(err[removed & fin])) if (removed & fin).any() else float("nan"),
        "kept_median_px": float(np.median(err[~removed & fin])) if (~removed & fin).any() else float("nan"),
        "curve": removal_scores(err, removed, limits_px),
        "orphaned_kept": int(orphaned.sum()), "no_partner": int(np.sum(~fin)),
    }
    # the strict measure of what is wrong (the point from all other rays), for the same curve
    strict = true_tie_errors(obs, img, pt, truth, names, dtm, method="others")
    out["curve_others"] = removal_scores(strict, removed, limits_px)
    out["removed_median_others_px"] = float(np.median(strict[removed])) if removed.any() else float("nan")
    out["kept_median_others_px"] = float(np.median(strict[~removed])) if (~removed).any() else float("nan")
    if "residual" in residuals and "normalized" in residuals:
        # the sigma the final adjustment weighted each observation with (residual / normalized residual),
        # for the curve in sigmas; the true error also holds the partner ray's noise, so k sigma over-counts
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.abs(np.asarray(residuals["residual"].values, float)[tie]
                           / np.asarray(residuals["normalized"].values, float)[tie])
        sig = np.nanmedian(np.where(np.isfinite(ratio) & (ratio > 0), ratio, np.nan), axis=1)
        if np.all(np.isfinite(sig)):
            out["sigma_px_median"] = float(np.median(sig))
            out["curve_sigma"] = [{**removal_scores(err / sig, removed, [k])[0], "limit_sigma": k}
                                  for k in limits_sigma]
            out["curve_sigma_others"] = [{**removal_scores(strict / sig, removed, [k])[0], "limit_sigma": k}
                                         for k in limits_sigma]
    if "qc_status" in residuals:
        # removed (a failing test of its own) vs withdrawn (with a point no test could single a ray out of)
        status = residuals["qc_status"].values.astype(str)[tie]
        wrong = err > float(limit_px)
        out["by_status"] = {str(k): {"observations": int(np.sum(status == k)), "wrong": int(np.sum((status == k) & wrong))}
                            for k in np.unique(status)}
    return out
