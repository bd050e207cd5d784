"""Image combinations of a site: every k-image subset, the study's progressive selection, on dask.

For each combination of images the check points are evaluated in one of two ways:

* ``mode="adjust"`` (the study's procedure): a block adjustment of just those images (their tie,
  control and check measurements, navigation observations if given) through
  :func:`~lunarmap.adjust.build_block` / :func:`~lunarmap.adjust.solve_block`, then the check-point
  errors against their reference coordinates (:func:`~lunarmap.evaluate.block_check_errors`);
* ``mode="intersect"``: the check points forward-intersected through the given sensors (for
  instance the adjusted cameras of the whole block) with only those images' measurements
  (:func:`~lunarmap.evaluate.triangulate`).

:func:`evaluate_combinations` runs all combinations of 2..n images (120 for seven images) as one
dask graph: the sensors and the network are scattered once to a ``distributed`` client (or passed
as one key to a local scheduler) and each combination is a task. :func:`progressive_selection`
starts from the best pair, adds the image that minimises the overall check-point error, and repeats
(Tables 4-6 of ``seeds/001``); :func:`compare_with_exhaustive` sets its choice at every k beside the
exhaustive optimum (Table 5).
"""

from __future__ import annotations

import time
from itertools import combinations as _combinations
from typing import Any, Mapping, Sequence

import dask
import numpy as np
import xarray as xr

from ..adjust.block import NavigationSpec, build_block, solve_block
from ..adjust.network import ControlNetwork
from ..adjust.solver import SolverOptions
from ..camera.sensor import SensorModel
from ..errors import EvaluationInputError, LunarmapError
from ..simulate.site import SimulatedSite
from .checkpoints import block_check_errors, check_point_errors, triangulate

__all__ = ["site_network", "subset_network", "evaluate_combination", "evaluate_combinations",
           "progressive_selection", "compare_with_exhaustive", "combination_name", "best_combinations"]

_FIELDS = ("along", "cross", "height", "overall", "expected_along", "expected_cross", "expected_height",
           "normalized_rms", "sigma0", "n_check", "n_tie", "seconds")


def combination_name(images: Sequence[str]) -> str:
    """``"A3+A4+A5"``: the images of a combination in the given order."""
    return "+".join(str(i) for i in images)


def site_network(site: SimulatedSite) -> ControlNetwork:
    """The measurements of a :func:`~lunarmap.simulate.lroc_site` as a control network (tie, control, check)."""
    n = site.point_id.size
    cov = np.full((n, 3, 3), np.nan)
    ctl = site.point_type == "control"
    cov[ctl] = np.eye(3) * site.control_sigma ** 2
    return ControlNetwork(point_id=site.point_id, point_type=site.point_type, xyz=site.control_xyz,
                          measure_point=site.measure_point, measure_image=site.measure_image,
                          line_sample=site.line_sample, measure_sigma=np.repeat(site.measure_sigma[:, None], 2, 1),
                          image_id=np.array(site.names), xyz_cov=cov, attrs={"source": "lunarmap.simulate.lroc_site"})


def subset_network(network: ControlNetwork, images: Sequence[str]) -> tuple[ControlNetwork, list[str]]:
    """The part of a network measured in some images.

    Tie and check points keep their measurements in those images and are dropped (and listed)
    with fewer than two; control points are kept with one or more (their coordinates are
    observed). Returns the network and the list of dropped points with the reason.
    """
    img = [str(i) for i in images]
    unknown = [i for i in img if i not in set(network.image_id.tolist())]
    if unknown:
        raise EvaluationInputError(f"image(s) {unknown} are not in the network ({network.image_id.tolist()})")
    index = {k: i for i, k in enumerate(network.image_id.tolist())}
    keep_img = np.zeros(network.image_id.size, bool)
    keep_img[[index[i] for i in img]] = True
    m = keep_img[network.measure_image]
    rays = np.bincount(network.measure_point[m], minlength=network.n_points)
    need = np.where(network.point_type == "control", 1, 2)
    keep_pt = rays >= need
    dropped = [f"{network.point_id[i]} ({network.point_type[i]}): {int(rays[i])} ray(s) in {img}"
               for i in np.flatnonzero(~keep_pt & (network.point_type != "tie"))]
    m &= keep_pt[network.measure_point]
    pmap = -np.ones(network.n_points, np.int64)
    pmap[keep_pt] = np.arange(int(keep_pt.sum()))
    new_img = np.array(img)
    imap = -np.ones(network.image_id.size, np.int64)
    imap[[index[i] for i in img]] = np.arange(len(img))
    cov = None if network.xyz_cov is None else network.xyz_cov[keep_pt]
    sub = ControlNetwork(point_id=network.point_id[keep_pt], point_type=network.point_type[keep_pt],
                         xyz=network.xyz[keep_pt], measure_point=pmap[network.measure_point[m]],
                         measure_image=imap[network.measure_image[m]], line_sample=network.line_sample[m],
                         measure_sigma=network.measure_sigma[m], image_id=new_img, xyz_cov=cov,
                         radius=network.radius, body=network.body, attrs=dict(network.attrs))
    return sub, dropped


def _row(images: Sequence[str], ds: xr.Dataset | None, status: str, sigma0: float = float("nan"),
         n_tie: int = 0, seconds: float = 0.0) -> dict[str, Any]:
    row: dict[str, Any] = {"images": tuple(images), "k": len(images), "status": status}
    if ds is None:
        row.update({f: float("nan") for f in _FIELDS})
        row.update(n_check=0, n_tie=n_tie, seconds=seconds)
        return row
    rms, exp = ds.attrs["rms"], ds.attrs["expected_rms"]
    row.update(along=float(rms[0]), cross=float(rms[1]), height=float(rms[2]), overall=float(ds.attrs["overall_rms"]),
               expected_along=float(exp[0]), expected_cross=float(exp[1]), expected_height=float(exp[2]),
               normalized_rms=float(ds.attrs["normalized_rms"]), sigma0=float(sigma0),
               n_check=int(ds.attrs["n_check"]), n_tie=int(n_tie), seconds=float(seconds))
    return row


def evaluate_combination(images: Sequence[str], sensors: Mapping[str, SensorModel], network: ControlNetwork, *,
                         mode: str = "adjust", degree: int = 1, navigation: NavigationSpec | None = None,
                         along_track: float | None = None, options: SolverOptions | None = None) -> dict[str, Any]:
    """Check-point errors of one combination of images (module docstring); a table row.

    Returns
    -------
    dict
        ``images``, ``k``, ``status`` (``"ok"`` or ``"skipped: <reason>"``), RMS ``along``, ``cross``,
        ``height``, ``overall`` (m), the predicted ``expected_*`` RMS sigma (m), ``normalized_rms``,
        ``sigma0`` (adjust mode), ``n_check``, ``n_tie``, ``seconds``.
    """
    t0 = time.perf_counter()
    images = [str(i) for i in images]
    if len(images) < 2 or len(set(images)) != len(images):
        raise EvaluationInputError(f"a combination needs two or more different images, got {images}")
    if mode not in ("adjust", "intersect"):
        raise EvaluationInputError(f"mode must be 'adjust' or 'intersect', got {mode!r}")
    missing = [i for i in images if i not in sensors]
    if missing:
        raise EvaluationInputError(f"no sensor model for image(s) {missing}")
    try:
        sub, dropped = subset_network(network, images)
        n_tie = int(np.sum(sub.point_type == "tie"))
        if mode == "adjust":
            block = build_block({i: sensors[i] for i in images}, sub, degree=degree, navigation=navigation)
            res = solve_block(block, options)
            ds = block_check_errors(res, along_track=along_track)
            ds.attrs["skipped"] = dropped
            return _row(images, ds, "ok", res.sigma0, n_tie, time.perf_counter() - t0)
        chk = np.flatnonzero(network.point_type == "check")
        meas = _check_measurements(network, chk)
        tri = triangulate(sensors, meas, images)
        ref = {str(k): network.xyz[i] for k, i in zip(network.point_id[chk], chk)}
        ds = check_point_errors(tri.xyz, np.array([ref[str(p)] for p in tri.point_id]), tri.covariance,
                                names=tri.point_id, along_track=along_track,
                                sensors={i: sensors[i] for i in images}, skipped=tri.skipped)
        return _row(images, ds, "ok", float("nan"), n_tie, time.perf_counter() - t0)
    except LunarmapError as exc:      # reported, not raised: one bad combination must not stop the table
        return _row(images, None, f"skipped: {type(exc).__name__}: {exc}", seconds=time.perf_counter() - t0)


def _check_measurements(network: ControlNetwork, chk: np.ndarray) -> xr.Dataset:
    sel = np.isin(network.measure_point, chk)
    pmap = -np.ones(network.n_points, np.int64)
    pmap[chk] = np.arange(chk.size)
    return xr.Dataset({"point_id": ("observation", pmap[network.measure_point[sel]]),
                       "image_id": ("observation", network.measure_image[sel]),
                       "line": ("observation", network.line_sample[sel, 0]),
                       "sample": ("observation", network.line_sample[sel, 1]),
                       "sigma_line": ("observation", network.measure_sigma[sel, 0]),
                       "sigma_sample": ("observation", network.measure_sigma[sel, 1])},
                      coords={"image": network.image_id.astype(object), "point": network.point_id[chk].astype(object)})


def _table(rows: list[dict[str, Any]]) -> xr.Dataset:
    names = [combination_name(r["images"]) for r in rows]
    data: dict[str, Any] = {f: ("combination", np.array([r[f] for r in rows], float),
                                {"units": "m"} if f in ("along", "cross", "height", "overall") or
                                f.startswith("expected") else {}) for f in _FIELDS}
    data["k"] = ("combination", np.array([r["k"] for r in rows], np.int64))
    data["status"] = ("combination", np.array([r["status"] for r in rows], dtype=object))
    tuples = np.empty(len(rows), dtype=object)
    for i, r in enumerate(rows):
        tuples[i] = tuple(r["images"])
    return xr.Dataset(data, coords={"combination": np.array(names, dtype=object), "images": ("combination", tuples)})


def _evaluate_many(combos: list[tuple[str, ...]], sensors: Mapping[str, SensorModel], network: ControlNetwork,
                   client: Any, scheduler: Any, **kw: Any) -> list[dict[str, Any]]:
    if not combos:
        return []
    if client is not None:
        data = client.scatter([dict(sensors), network], broadcast=True)
        futures = [client.submit(evaluate_combination, c, data[0], data[1], pure=False, **kw) for c in combos]
        return client.gather(futures)
    if scheduler in (None, "sync", "synchronous"):
        return [evaluate_combination(c, sensors, network, **kw) for c in combos]
    s, n = dask.delayed(dict(sensors), pure=True), dask.delayed(network, pure=True)
    tasks = [dask.delayed(evaluate_combination, pure=True)(c, s, n, **kw) for c in combos]
    return list(dask.compute(*tasks, scheduler=scheduler))


def evaluate_combinations(sensors: Mapping[str, SensorModel], network: ControlNetwork, *,
                          k: Sequence[int] | None = None, images: Sequence[str] | None = None,
                          mode: str = "adjust", degree: int = 1, navigation: NavigationSpec | None = None,
                          along_track: float | None = None, options: SolverOptions | None = None,
                          client: Any = None, scheduler: Any = None) -> xr.Dataset:
    """Check-point errors of every combination of ``k`` images (default all 2 <= k <= n), one dask task each.

    Parameters
    ----------
    sensors : mapping name -> SensorModel
        Navigation cameras (``mode="adjust"``) or the cameras to intersect through (``"intersect"``).
    network : ControlNetwork
        Tie, control and check measurements of all images (check points carry their reference xyz).
    k : sequence of int, optional
        Combination sizes.
    images : sequence of str, optional
        The images to combine (default: every image of the network that has a sensor).
    mode, degree, navigation, along_track, options
        See :func:`evaluate_combination`.
    client : distributed.Client, optional
        Run on this cluster (sensors and network scattered once to every worker).
    scheduler : str, optional
        Otherwise a local dask scheduler (``"threads"``, ``"processes"``); default serial.

    Returns
    -------
    xarray.Dataset
        Over ``combination`` (``"A3+A4"``; coordinate ``images`` holds the tuples): ``k``, ``along``,
        ``cross``, ``height``, ``overall`` (RMS, m), ``expected_*`` (m), ``normalized_rms``,
        ``sigma0``, ``n_check``, ``n_tie``, ``seconds``, ``status``; ``attrs["wall_seconds"]``.
    """
    names = [str(i) for i in (network.image_id.tolist() if images is None else images)]
    names = [n for n in names if n in sensors] if images is None else names
    if len(names) < 2:
        raise EvaluationInputError(f"combinations need at least two images, got {names}")
    sizes = list(range(2, len(names) + 1)) if k is None else [int(v) for v in k]
    bad = [v for v in sizes if not 2 <= v <= len(names)]
    if bad:
        raise EvaluationInputError(f"combination sizes must be between 2 and {len(names)}, got {bad}")
    combos = [c for v in sizes for c in _combinations(names, v)]
    t0 = time.perf_counter()
    rows = _evaluate_many(combos, sensors, network, client, scheduler, mode=mode, degree=degree,
                          navigation=navigation, along_track=along_track, options=options)
    ds = _table(rows)
    ds.attrs.update(wall_seconds=time.perf_counter() - t0, mode=mode, images=names)
    return ds


def best_combinations(table: xr.Dataset, per_k: int = 2) -> xr.Dataset:
    """The ``per_k`` best combinations (lowest overall error) of every size, ordered by size then error."""
    keep = []
    for v in np.unique(table.k.values):
        sub = table.where((table.k == v) & np.isfinite(table.overall), drop=True)
        order = np.argsort(sub.overall.values)[:per_k]
        keep += [str(c) for c in sub.combination.values[order]]
    return table.sel(combination=keep)


def progressive_selection(sensors: Mapping[str, SensorModel], network: ControlNetwork, *,
                          table: xr.Dataset | None = None, images: Sequence[str] | None = None,
                          mode: str = "adjust", degree: int = 1, navigation: NavigationSpec | None = None,
                          along_track: float | None = None, options: SolverOptions | None = None,
                          client: Any = None, scheduler: Any = None) -> xr.Dataset:
    """The study's progressive selection: best pair, then add the image that minimises the overall error.

    Each step evaluates the current combination plus each remaining image (in parallel), or looks
    the rows up in ``table`` (an :func:`evaluate_combinations` result) when given. The path runs to
    all images; ``attrs["stop_k"]`` is where the study's rule stops (the first step whose error is
    larger than the previous one's) and ``attrs["best_k"]`` the best size on the path.

    Returns
    -------
    xarray.Dataset
        Over ``step`` (k = 2..n): ``combination``, ``added`` (image), ``along``, ``cross``,
        ``height``, ``overall`` (m) and the other table fields; ``attrs["candidates"]`` the number of
        combinations evaluated.
    """
    names = [str(i) for i in (network.image_id.tolist() if images is None else images)]
    names = [n for n in names if n in sensors] if images is None else names
    if len(names) < 2:
        raise EvaluationInputError(f"progressive selection needs at least two images, got {names}")
    kw = dict(mode=mode, degree=degree, navigation=navigation, along_track=along_track, options=options)
    lookup: dict[frozenset, dict[str, Any]] = {}
    if table is not None:
        for i in range(table.sizes["combination"]):
            r = {f: table[f].values[i] for f in list(_FIELDS) + ["k", "status"]}
            r["images"] = tuple(table.images.values[i])
            lookup[frozenset(r["images"])] = r

    n_eval = 0

    def rows_for(combos: list[tuple[str, ...]]) -> list[dict[str, Any]]:
        nonlocal n_eval
        todo = [c for c in combos if frozenset(c) not in lookup]
        n_eval += len(todo)
        for c, r in zip(todo, _evaluate_many(todo, sensors, network, client, scheduler, **kw)):
            lookup[frozenset(c)] = r
        return [dict(lookup[frozenset(c)], images=tuple(c)) for c in combos]

    def best(rows: list[dict[str, Any]]) -> dict[str, Any]:
        ok = [r for r in rows if np.isfinite(r["overall"])]
        if not ok:
            raise EvaluationInputError("no combination could be evaluated: " +
                                       "; ".join(str(r["status"]) for r in rows[:3]))
        return min(ok, key=lambda r: r["overall"])

    path = [best(rows_for(list(_combinations(names, 2))))]
    added = [combination_name(path[0]["images"])]
    while len(path[-1]["images"]) < len(names):
        cur = path[-1]["images"]
        rest = [n for n in names if n not in cur]
        step = best(rows_for([cur + (n,) for n in rest]))
        path.append(step)
        added.append(step["images"][-1])
    overall = np.array([r["overall"] for r in path])
    worse = np.flatnonzero(np.diff(overall) > 0)
    stop_k = int(path[worse[0]]["k"]) if worse.size else int(path[-1]["k"])
    ds = _table(path).rename({"combination": "step"})
    ds = ds.assign_coords(step=np.arange(2, 2 + len(path)), combination=("step", [combination_name(r["images"])
                                                                                for r in path]),
                          added=("step", np.array(added, dtype=object)))
    ds.attrs.update(stop_k=stop_k, best_k=int(path[int(np.argmin(overall))]["k"]), candidates=n_eval,
                    mode=mode, images=names)
    return ds


def compare_with_exhaustive(progressive: xr.Dataset, table: xr.Dataset) -> xr.Dataset:
    """Table 5: at every k the progressive choice beside the exhaustive optimum and runner-up.

    Returns
    -------
    xarray.Dataset
        Over ``k``: ``progressive`` / ``optimum`` / ``second`` (combination names), their ``overall``
        errors (m) and ``excess`` = progressive / optimum - 1 (0 when the choice is the optimum).
    """
    ks = [int(v) for v in progressive.step.values]
    prog, opt, sec, e_p, e_o, e_s = [], [], [], [], [], []
    for k in ks:
        sub = table.where((table.k == k) & np.isfinite(table.overall), drop=True)
        order = np.argsort(sub.overall.values)
        opt.append(str(sub.combination.values[order[0]]))
        e_o.append(float(sub.overall.values[order[0]]))
        sec.append(str(sub.combination.values[order[1]]) if order.size > 1 else "")
        e_s.append(float(sub.overall.values[order[1]]) if order.size > 1 else float("nan"))
        row = progressive.sel(step=k)
        prog.append(str(row.combination.values))
        e_p.append(float(row.overall.values))
    e_p_a, e_o_a = np.array(e_p), np.array(e_o)
    return xr.Dataset({"progressive": ("k", np.array(prog, dtype=object)), "progressive_overall": ("k", e_p_a),
                       "optimum": ("k", np.array(opt, dtype=object)), "optimum_overall": ("k", e_o_a),
                       "second": ("k", np.array(sec, dtype=object)), "second_overall": ("k", np.array(e_s)),
                       "excess": ("k", e_p_a / e_o_a - 1.0)}, coords={"k": ks})
