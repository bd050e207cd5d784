"""The study's figures with matplotlib: each function returns a ``matplotlib.figure.Figure``.

Figures are built without ``pyplot`` (no global state, safe in threads and on servers); in a
notebook the returned figure displays itself, and ``path=`` writes it atomically (format from the
file suffix: ``.png``, ``.pdf``, ``.svg``). matplotlib is an optional dependency
(``pip install lunarmap[plot]``); without it these functions raise
:class:`~lunarmap.errors.MissingDependencyError`.

=====================================  =========================================================
function                               figure of ``seeds/001``
=====================================  =========================================================
:func:`plot_error_vs_convergence`      Fig. 3: check-point errors of pairs vs convergence, with
                                       the power law fitted to the height errors
:func:`plot_matching_error`            Fig. 7: matching error vs convergence, with its line
:func:`plot_precision_vs_convergence`  Fig. 9: Eq. 15 height and overall error with and without
                                       the matching error (and the adjustment's values)
:func:`plot_pair_quantity`             Figs. 4-5: a pair value (correlation, matching error,
                                       check-point error) vs shadow-tip distance or ratio of
                                       aspect ratios, with a least-squares line
:func:`plot_precision_vs_images`       Fig. 10: errors along the progressive selection vs k
:func:`plot_footprints`                footprints of a combination (Fig. 2)
=====================================  =========================================================
"""

from __future__ import annotations

import os
from typing import Any, Mapping, Sequence

import numpy as np
import xarray as xr

from ..atomic import atomic_write
from ..camera.geodesy import xyz_to_lonlat_height
from ..camera.sensor import SensorModel
from ..errors import EvaluationInputError, MissingDependencyError
from .footprint import footprint
from .theory import MatchingErrorModel, eq15_precision

__all__ = ["plot_error_vs_convergence", "plot_matching_error", "plot_precision_vs_convergence", "plot_pair_quantity",
           "plot_precision_vs_images", "plot_footprints", "save_figure", "power_law_fit"]

_COLOURS = {"along": "tab:blue", "cross": "tab:orange", "height": "tab:green", "overall": "k"}


def _figure(figsize: tuple[float, float] = (6.0, 4.2)) -> Any:
    try:
        from matplotlib.figure import Figure
    except ImportError:   # pragma: no cover - exercised only without matplotlib
        raise MissingDependencyError("plots need matplotlib: pip install 'lunarmap[plot]'") from None
    fig = Figure(figsize=figsize, layout="constrained")
    return fig


def save_figure(fig: Any, path: str | os.PathLike[str], dpi: int = 120) -> Any:
    """Write a figure atomically (format from the suffix); returns the path."""
    fmt = os.path.splitext(os.fspath(path))[1].lstrip(".").lower() or "png"
    return atomic_write(path, lambda tmp: fig.savefig(tmp, format=fmt, dpi=dpi))


def _finish(fig: Any, path: str | os.PathLike[str] | None) -> Any:
    if path is not None:
        save_figure(fig, path)
    return fig


def power_law_fit(x: Sequence[float], y: Sequence[float]) -> tuple[float, float]:
    """``y = a x^b`` by least squares in log-log: returns ``(a, b)``."""
    xa, ya = np.asarray(x, float), np.asarray(y, float)
    ok = (xa > 0) & (ya > 0) & np.isfinite(xa) & np.isfinite(ya)
    if ok.sum() < 2:
        raise EvaluationInputError("a power-law fit needs two or more positive values")
    b, log_a = np.polyfit(np.log(xa[ok]), np.log(ya[ok]), 1)
    return float(np.exp(log_a)), float(b)


def plot_error_vs_convergence(table: xr.Dataset, pairs: xr.Dataset, title: str = "",
                              path: str | os.PathLike[str] | None = None) -> Any:
    """Fig. 3: check-point RMS errors of the pairs of a combination table against their convergence angle.

    Parameters
    ----------
    table : xarray.Dataset
        :func:`~lunarmap.evaluate.evaluate_combinations` output (its ``k == 2`` rows are used).
    pairs : xarray.Dataset
        :func:`~lunarmap.evaluate.pair_geometry` of the same images.
    """
    t = table.where(table.k == 2, drop=True)
    if t.sizes.get("combination", 0) == 0:
        raise EvaluationInputError("the table has no pairs (k = 2)")
    keys = [str(c).replace("+", "/") for c in t.combination.values]
    have = set(str(p) for p in pairs.pair.values)
    keys2 = [k if k in have else "/".join(k.split("/")[::-1]) for k in keys]
    conv = pairs.convergence.sel(pair=keys2).values
    fig = _figure()
    ax = fig.add_subplot()
    for comp in ("along", "cross", "height", "overall"):
        ax.plot(conv, t[comp].values, "o", ms=4, color=_COLOURS[comp], label=comp)
    a, b = power_law_fit(conv, t.height.values)
    xs = np.linspace(max(conv.min(), 0.5), conv.max(), 100)
    ax.plot(xs, a * xs ** b, "-", color=_COLOURS["height"], lw=1, label=f"height ~ c^{b:.2f}")
    ax.set_xlabel("convergence angle (deg)")
    ax.set_ylabel("check-point RMS error (m)")
    ax.set_title(title or "pairs: error vs convergence")
    ax.legend(fontsize=8)
    return _finish(fig, path)


def plot_matching_error(errors: xr.Dataset, model: MatchingErrorModel | None = None, title: str = "",
                        path: str | os.PathLike[str] | None = None) -> Any:
    """Fig. 7: matching error (pixels) against convergence, from :func:`~lunarmap.evaluate.simulate_matching_errors`."""
    fig = _figure()
    ax = fig.add_subplot()
    c = errors.convergence.values
    for name, style in (("rms", "ko"), ("rms_sample", "^"), ("rms_line", "v")):
        if name in errors:
            ax.plot(c, errors[name].values, style, ms=5, label={"rms": "2-D", "rms_sample": "sample (across)",
                                                                "rms_line": "line (along)"}[name])
    if model is not None:
        xs = np.linspace(0, max(c.max(), 1.0), 50)
        ax.plot(xs, model.rms(xs), "k-", lw=1, label=f"{model.intercept:.3f} + {model.slope:.4f} c")
    ax.set_xlabel("convergence angle (deg)")
    ax.set_ylabel("matching error RMS (pixel)")
    ax.set_title(title or "matching error vs convergence")
    ax.legend(fontsize=8)
    return _finish(fig, path)


def plot_precision_vs_convergence(height_m: float, focal_px: float, sigma_px: float,
                                  model: MatchingErrorModel | None = None, adjusted: xr.Dataset | None = None,
                                  along: str = "linescan", max_convergence: float = 70.0, title: str = "",
                                  path: str | os.PathLike[str] | None = None) -> Any:
    """Fig. 9: Eq. 15 height and overall errors vs convergence, constant error and with the matching error.

    ``adjusted``: a :func:`~lunarmap.evaluate.pair_precision` (or any dataset over ``convergence`` with
    ``adjust_z`` / ``adjust_t``) drawn as points.
    """
    c = np.linspace(2.0, max_convergence, 200)
    fig = _figure()
    ax = fig.add_subplot()
    const = eq15_precision(c, height_m, focal_px, sigma_px, along=along)
    ax.plot(c, const.sigma_z, "-", color="tab:green", label=f"height, {sigma_px} px")
    ax.plot(c, const.sigma_t, "--", color="tab:green", label=f"overall, {sigma_px} px")
    if model is not None:
        m = eq15_precision(c, height_m, focal_px, model, along=along)
        ax.plot(c, m.sigma_z, "-", color="tab:red", label="height, matching error(c)")
        ax.plot(c, m.sigma_t, "--", color="tab:red", label="overall, matching error(c)")
        k = int(np.argmin(m.sigma_t.values))
        ax.axvline(c[k], color="tab:red", lw=0.5)
    k0 = int(np.argmin(const.sigma_t.values))
    ax.axvline(c[k0], color="tab:green", lw=0.5)
    if adjusted is not None:
        ax.plot(adjusted.convergence, adjusted.adjust_z, "o", mfc="none", color="tab:green", label="adjustment, height")
        ax.plot(adjusted.convergence, adjusted.adjust_t, "s", mfc="none", color="k", label="adjustment, overall")
    ax.set_yscale("log")
    ax.set_xlabel("convergence angle (deg)")
    ax.set_ylabel("standard deviation (m)")
    ax.set_title(title or f"Eq. 15, H = {height_m / 1e3:.0f} km")
    ax.legend(fontsize=7)
    return _finish(fig, path)


def plot_pair_quantity(pairs: xr.Dataset, values: Sequence[float] | xr.DataArray, quantity: str = "shadow_tip_distance",
                       ylabel: str = "correlation", title: str = "",
                       path: str | os.PathLike[str] | None = None) -> Any:
    """Figs. 4-5: a value per pair against a pair quantity (``shadow_tip_distance``, ``aspect_ratio_ratio``...).

    ``values`` is aligned with ``pairs.pair`` (a DataArray over ``pair`` is aligned by name).
    """
    if quantity not in pairs:
        raise EvaluationInputError(f"pair geometry has no {quantity!r}; it has {sorted(map(str, pairs.data_vars))}")
    y = values.sel(pair=pairs.pair).values if isinstance(values, xr.DataArray) else np.asarray(values, float)
    x = pairs[quantity].values
    if y.shape != x.shape:
        raise EvaluationInputError(f"{y.size} values for {x.size} pairs")
    fig = _figure()
    ax = fig.add_subplot()
    ax.plot(x, y, "ko", ms=4)
    ok = np.isfinite(x) & np.isfinite(y)
    if ok.sum() >= 2 and np.ptp(x[ok]) > 0:
        b, a = np.polyfit(x[ok], y[ok], 1)
        xs = np.linspace(x[ok].min(), x[ok].max(), 20)
        ax.plot(xs, a + b * xs, "k-", lw=1, label=f"{a:.3g} + {b:.3g} x, r = {np.corrcoef(x[ok], y[ok])[0, 1]:.2f}")
        ax.legend(fontsize=8)
    ax.set_xlabel(quantity.replace("_", " "))
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    return _finish(fig, path)


def plot_precision_vs_images(progressive: xr.Dataset, optimum: xr.Dataset | None = None, title: str = "",
                             path: str | os.PathLike[str] | None = None) -> Any:
    """Fig. 10: along / cross / height / overall error of the progressive selection against the number of images.

    ``optimum``: a :func:`~lunarmap.evaluate.compare_with_exhaustive` result, drawn as the exhaustive best.
    """
    k = progressive.step.values
    fig = _figure()
    ax = fig.add_subplot()
    for comp in ("along", "cross", "height", "overall"):
        ax.plot(k, progressive[comp].values, "o-", color=_COLOURS[comp], ms=4, label=comp)
    if optimum is not None:
        ax.plot(optimum.k, optimum.optimum_overall, "x", color="r", ms=8, label="exhaustive best (overall)")
    for i, name in enumerate(progressive.added.values):
        ax.annotate(str(name), (k[i], progressive.overall.values[i]), fontsize=7, xytext=(2, 4),
                    textcoords="offset points")
    ax.set_xlabel("number of images")
    ax.set_ylabel("check-point RMS error (m)")
    ax.set_xticks(k)
    ax.set_title(title or "progressive selection")
    ax.legend(fontsize=8)
    return _finish(fig, path)


def plot_footprints(sensors: Mapping[str, SensorModel], images: Sequence[str] | None = None,
                    points: np.ndarray | None = None, height: float = 0.0, title: str = "",
                    path: str | os.PathLike[str] | None = None) -> Any:
    """Footprints (longitude / latitude, degrees) of some images, with optional ground points ``(n, 3)``."""
    names = list(sensors) if images is None else [str(i) for i in images]
    missing = [n for n in names if n not in sensors]
    if missing:
        raise EvaluationInputError(f"no sensor model for image(s) {missing}")
    fig = _figure((5.5, 5.0))
    ax = fig.add_subplot()
    for n in names:
        fp = footprint(sensors[n], height, name=n)
        lon, lat, _ = xyz_to_lonlat_height(fp.xyz)
        ax.fill(np.append(lon, lon[0]), np.append(lat, lat[0]), alpha=0.15)
        ax.plot(np.append(lon, lon[0]), np.append(lat, lat[0]), lw=1, label=n)
    if points is not None:
        lon, lat, _ = xyz_to_lonlat_height(np.asarray(points, float))
        ax.plot(lon, lat, "k.", ms=3)
    ax.set_xlabel("longitude (deg E)")
    ax.set_ylabel("latitude (deg N)")
    ax.set_aspect(1.0 / max(np.cos(np.radians(np.mean(ax.get_ylim()))), 1e-3))
    ax.set_title(title or "+".join(names))
    ax.legend(fontsize=7)
    return _finish(fig, path)
