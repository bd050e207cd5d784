"""Start values of a block's points on dirty data: bounds on an intersection, and a best guess (issue 27, item 4).

A forward intersection is only as good as its rays: one gross error among two rays puts a point
thousands of km away, behind a camera, or nowhere (non-finite). :func:`screen_starts` checks every
intersected point against two bounds:

* in front of every camera that sees it: ``(X - O_i) . d_i > 0`` for each ray (origin ``O_i``, unit
  direction ``d_i`` towards the scene);
* not too far: ``|X - O_i| <= max_range * H_i``, ``H_i`` the height of camera ``i`` above the reference
  sphere (without a radius: the block's median camera-to-point distance). ``max_range = 10`` admits
  views up to 84 degrees off nadir and rejects nearly parallel rays meeting thousands of km away;
* at a possible height (with the body's ``radius``): ``|h| <= H``, ``h = |X| - radius`` and ``H`` the
  median height of the cameras above the reference sphere: a point cannot be above the orbit it is
  seen from, nor as deep below the surface (topography is a few percent of any mapping orbit's height;
  nearly parallel rays of a 2-ray point with an error put it thousands of km off, inside the body).

A point that fails (or is not finite) is refused (``"raise"``), or started from its best guess
(``"best_guess"``): the least-squares intersection of its rays with robust (Huber, then Danish) weights,
started at the model's prediction -- the coordinate-wise median of where its rays meet the reference
surface; if that robust intersection also fails the bounds, the model's prediction itself. Every such
decision is recorded (:attr:`~lunarmap.adjust.block.Block.starts`): the data snooping then tests the
point's rays from a start no gross error dragged.
"""

from __future__ import annotations

import numpy as np
import xarray as xr
from numpy.typing import NDArray

from ..errors import AdjustmentInputError
from .intersection import intersect_points

__all__ = ["screen_starts", "UNINTERSECTABLE", "MAX_RANGE"]

#: what :func:`screen_starts` does with a point that cannot be intersected within the bounds
UNINTERSECTABLE = ("raise", "best_guess")
#: a point farther from one of its cameras than this many times that camera's height above the reference sphere is
#: not an intersection
MAX_RANGE = 10.0


def _violations(X: NDArray, pt_idx: NDArray, origins: NDArray, dirs: NDArray,
                n_pt: int) -> tuple[NDArray, NDArray, NDArray]:
    """Per point: not finite, behind a camera, farthest camera distance (length unit)."""
    with np.errstate(invalid="ignore"):
        v = X[pt_idx] - origins
        dist = np.linalg.norm(v, axis=1)
        behind_ray = ~(np.einsum("ij,ij->i", v, dirs) > 0)
    nonfinite = ~np.all(np.isfinite(X), axis=1)
    behind = np.zeros(n_pt, bool)
    np.logical_or.at(behind, pt_idx, behind_ray)
    far = np.zeros(n_pt)
    np.maximum.at(far, pt_idx, np.where(np.isfinite(dist), dist, np.inf))
    return nonfinite, behind & ~nonfinite, far


def _ray_scale(origins: NDArray, radius: float | None, typical: float) -> NDArray:
    """Per ray: the height of its camera above the sphere of ``radius`` (``typical`` where that is not positive
    or no radius is given), length unit."""
    if radius is None:
        return np.full(origins.shape[0], typical)
    h = np.linalg.norm(origins, axis=1) - float(radius)
    return np.where(h > 0, h, typical)


def _range_ratio(X: NDArray, pt_idx: NDArray, origins: NDArray, scale: NDArray, n_pt: int) -> NDArray:
    """Per point: its largest camera distance over that ray's scale (:func:`_ray_scale`)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        r = np.linalg.norm(X[pt_idx] - origins, axis=1) / scale
    out = np.zeros(n_pt)
    np.maximum.at(out, pt_idx, np.where(np.isfinite(r), r, np.inf))
    return out


def _surface_guess(model, params: NDArray, cam_idx: NDArray, pt_idx: NDArray, xy: NDArray, pts: NDArray) -> NDArray:
    """The model's prediction of each of ``pts``: the coordinate-wise median of its rays' hits on the reference
    surface (height 0); NaN where no ray hits it."""
    sensors = model.adjusted(params) if np.any(params) else model.sensors
    hits = np.full((cam_idx.size, 3), np.nan)
    for k in np.unique(cam_idx):
        m = cam_idx == k
        hits[m] = sensors[k].image_to_ground(xy[m, 0], xy[m, 1], height=0.0, on_miss="nan")
    out = np.full((pts.size, 3), np.nan)
    for n, j in enumerate(pts):
        h = hits[pt_idx == j]
        h = h[np.all(np.isfinite(h), axis=1)]
        if h.size:
            out[n] = np.median(h, axis=0)
    return out


def _robust_intersection(model, params, cam_idx, pt_idx, xy, sigma, x0: NDArray, rounds: int = 8) -> NDArray:
    """Iteratively reweighted intersection of points ``0..n-1`` (``pt_idx`` local) from ``x0``: Huber weights
    (c = 2) for the first 3 rounds, then Danish (``exp(-(u / c)^2)`` beyond c = 2.5), ``u`` the ray's
    whitened residual; a ray never weighs less than 1e-8 (every point keeps its rays)."""
    n = x0.shape[0]
    X = x0.copy()
    w = np.ones(cam_idx.size)
    sig = np.broadcast_to(np.asarray(sigma, float), xy.shape)
    for r in range(rounds):
        try:
            with np.errstate(all="ignore"):
                X = intersect_points(model, params, cam_idx, pt_idx, xy, sig / np.sqrt(w)[:, None], n_pt=n,
                                     x0=X, max_iterations=5).xyz
        except (ValueError, np.linalg.LinAlgError):
            return np.full_like(x0, np.nan)
        with np.errstate(all="ignore"):
            u = np.max(np.abs(model.project(params, cam_idx, X[pt_idx]) - xy) / sig, axis=1)
        u = np.where(np.isfinite(u), u, 1e6)
        if r < 3:
            w = np.where(u <= 2.0, 1.0, 2.0 / u)
        else:
            w = np.where(u <= 2.5, 1.0, np.exp(-((u - 2.5) / 2.5) ** 2))
        w = np.maximum(w, 1e-8)
    return X


def screen_starts(model, params: NDArray, obs, X: NDArray, check: NDArray[np.bool_], point_id: NDArray,
                  unintersectable: str = "raise", max_range: float = MAX_RANGE,
                  radius: float | None = None) -> tuple[NDArray, xr.Dataset]:
    """Check the intersected start values ``X`` of the points ``check`` (module docstring).

    Parameters
    ----------
    model : SensorImageModel
    params : (n_img, p) image parameters (the a-priori ones).
    obs : ImageObservations
    X : (n_pt, 3) start values, metres (the block's length unit).
    check : (n_pt,) bool
        The points to check (free points with 2 or more rays).
    point_id : (n_pt,) point names, for the messages and the record.
    unintersectable : {"raise", "best_guess"}
    max_range : float
        The distance bound, times each camera's height above the reference sphere.
    radius : float, optional
        Radius of the reference sphere (metres): the height bound (module docstring); None: not applied.

    Returns
    -------
    X : (n_pt, 3)
        The start values (best guesses in place of the points that failed).
    starts : xarray.Dataset
        One row (``start_point``) per point that failed: ``point`` index, ``point_id``, ``reason``
        (``"not finite"``, ``"behind a camera"``, ``"too far"``, ``"impossible height"``), ``distance`` (farthest camera, metres),
        ``start`` (``"robust intersection"`` or ``"model prediction"``), ``moved`` (metres from the rejected
        value; NaN if that was not finite).

    Raises
    ------
    AdjustmentInputError
        An unknown ``unintersectable`` or a ``max_range <= 1``; with ``"raise"``, points that fail the bounds
        (the count, the first one and why); with ``"best_guess"``, a point with no start value at all (no ray
        hits the reference surface and no intersection is within the bounds).
    """
    if unintersectable not in UNINTERSECTABLE:
        raise AdjustmentInputError(f"unintersectable must be one of {UNINTERSECTABLE}, got {unintersectable!r}")
    if not (np.isfinite(max_range) and max_range > 1.0):
        raise AdjustmentInputError(f"max_range must be a number > 1 (times a camera's height), "
                                   f"got {max_range!r}")
    X = np.array(X, float)
    n_pt = X.shape[0]
    empty = xr.Dataset({"point": ("start_point", np.zeros(0, np.int64)),
                        "point_id": ("start_point", np.zeros(0, dtype=object)),
                        "reason": ("start_point", np.zeros(0, dtype=object)),
                        "distance": ("start_point", np.zeros(0)), "start": ("start_point", np.zeros(0, dtype=object)),
                        "moved": ("start_point", np.zeros(0))})
    # the bounds are those of a perspective centre: an RFM's "ray" starts at the top of its fitted height range,
    # not at a camera (points above it are not behind anything), so its rays are not screened; a point seen
    # only by such sensors is checked for being finite alone
    physical = np.array([bool(getattr(sen, "rays_from_position", True)) for sen in model.sensors])
    nonfinite_all = np.asarray(check, bool) & ~np.all(np.isfinite(X), axis=1)
    use = np.asarray(check, bool)[obs.pt_idx] & physical[obs.cam_idx]
    if not use.any() and not nonfinite_all.any():
        return X, empty
    cam, pt, xy = obs.cam_idx[use], obs.pt_idx[use], obs.xy[use]
    origins, dirs = model.rays(params, cam, xy)
    nonfinite, behind, far = _violations(X, pt, origins, dirs, n_pt)
    nonfinite |= nonfinite_all
    ok_pts = np.asarray(check, bool) & ~nonfinite & ~behind
    dist_ok = np.linalg.norm(X[pt] - origins, axis=1)[ok_pts[pt]]
    # each ray's distance scale: its camera's height above the reference sphere (a block whose cameras descend,
    # Ranger's, spans altitudes a thousandfold), else the block's typical camera distance from the points that
    # pass the first bound
    scale = _ray_scale(origins, radius, float(np.median(dist_ok)) if dist_ok.size else np.inf)
    ratio = _range_ratio(X, pt, origins, scale, n_pt)
    bound = max_range
    toofar = np.asarray(check, bool) & ~nonfinite & ~behind & (ratio > bound)
    h_bound = np.inf
    height_bad = np.zeros(n_pt, bool)
    if radius is not None and origins.shape[0]:
        h_bound = float(np.median(np.linalg.norm(origins, axis=1))) - float(radius)
        if h_bound > 0:
            with np.errstate(invalid="ignore"):
                height_bad = ~(np.abs(np.linalg.norm(X, axis=1) - float(radius)) <= h_bound)
        else:
            h_bound = np.inf
    height_bad &= np.asarray(check, bool) & ~nonfinite & ~behind & ~toofar
    bad = np.asarray(check, bool) & (nonfinite | behind | toofar | height_bad)
    if not bad.any():
        return X, empty
    reason = np.where(nonfinite, "not finite", np.where(behind, "behind a camera",
                                                         np.where(toofar, "too far", "impossible height")))
    pts = np.flatnonzero(bad)
    if unintersectable == "raise":
        j = int(pts[0])
        what = {"not finite": "not finite", "behind a camera": "behind one of its cameras",
                "too far": f"{far[j] / 1000:.4g} km from a camera, {ratio[j]:.3g} times its height above the "
                           f"reference sphere (bound {bound:g})",
                "impossible height": f"{(np.linalg.norm(X[j]) - float(radius or 0.0)) / 1000:.4g} km above the "
                                     f"reference sphere (bound +-{h_bound / 1000:.4g} km)"}[str(reason[j])]
        counts = ", ".join(f"{int(np.sum(reason[pts] == r))} {r}"
                           for r in ("not finite", "behind a camera", "too far", "impossible height")
                           if np.any(reason[pts] == r))
        raise AdjustmentInputError(f"{pts.size} point(s) could not be intersected from their rays ({counts}; first: "
                                   f"{point_id[j]}, {what}); check their measurements, or build the block with "
                                   "unintersectable='best_guess' to start them from a robust guess")
    sel = np.isin(obs.pt_idx, pts)
    remap = -np.ones(n_pt, np.int64)
    remap[pts] = np.arange(pts.size)
    guess = _surface_guess(model, params, obs.cam_idx[sel], obs.pt_idx[sel], obs.xy[sel], pts)
    x0 = np.where(np.all(np.isfinite(guess), axis=1)[:, None], guess,
                  np.where(np.all(np.isfinite(X[pts]), axis=1)[:, None], X[pts], 0.0))
    Xr = _robust_intersection(model, params, obs.cam_idx[sel], remap[obs.pt_idx[sel]], obs.xy[sel], obs.sigma[sel],
                              x0)
    o2, d2 = model.rays(params, obs.cam_idx[sel], obs.xy[sel])
    nf2, bh2, _ = _violations(Xr, remap[obs.pt_idx[sel]], o2, d2, pts.size)
    ratio2 = _range_ratio(Xr, remap[obs.pt_idx[sel]], o2, _ray_scale(o2, radius, float(np.median(dist_ok))
                                                                      if dist_ok.size else np.inf), pts.size)
    with np.errstate(invalid="ignore"):
        ok_r = ~nf2 & ~bh2 & (ratio2 <= bound) & (np.abs(np.linalg.norm(Xr, axis=1) - float(radius or 0.0)) <= h_bound)
    ok_g = np.all(np.isfinite(guess), axis=1)
    if not np.all(ok_r | ok_g):
        j = int(pts[np.argmax(~(ok_r | ok_g))])
        raise AdjustmentInputError(f"point {point_id[j]}: no start value (its robust intersection is "
                                   f"{'not finite' if nf2[remap[j]] else 'out of bounds'} and none of its rays "
                                   "meets the reference surface)")
    new = np.where(ok_r[:, None], Xr, guess)
    with np.errstate(invalid="ignore"):
        moved = np.linalg.norm(new - X[pts], axis=1)
    X[pts] = new
    starts = xr.Dataset({"point": ("start_point", pts.astype(np.int64)),
                         "point_id": ("start_point", np.asarray(point_id, dtype=object)[pts]),
                         "reason": ("start_point", reason[pts].astype(object)),
                         "distance": ("start_point", np.where(np.isfinite(far[pts]), far[pts], np.nan)),
                         "start": ("start_point", np.where(ok_r, "robust intersection", "model prediction")
                                   .astype(object)),
                         "moved": ("start_point", moved)})
    starts.attrs["distance_bound"] = float(bound)     # times each camera's height
    starts.attrs["height_bound"] = float(h_bound)
    return X, starts
